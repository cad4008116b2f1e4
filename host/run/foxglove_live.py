"""Live view: the foxglove-sdk WebSocket server on localhost, fed by a run's :class:`~host.run.mcap_log.RunLog`.

``start_live(run_log, port)`` starts the SDK's server (``foxglove.start_server``) on ``127.0.0.1:PORT``
as a second sink of the run log's context, so Foxglove (Open connection > Foxglove WebSocket,
``ws://127.0.0.1:PORT``) sees every channel the MCAP gets, as it is logged. The server advertises the
``Time`` capability and broadcasts the board time of every report, so the viewer's clock is the
board's (the same stamps as in the MCAP). Port 0 picks a free port (:attr:`LiveServer.port` says which).
While it serves, the run log re-sends ``/scene`` every :data:`host.run.mcap_log.SCENE_EVERY_S` board
seconds, so a viewer that connects late gets the robot's geometry (a file needs it once).

Threads: a session's run log is fed from its writer thread (:mod:`host.run.recording`), so the time
broadcast (``WebSocketServer.broadcast_time``) is called there; the SDK's server is thread-safe, and a
call after :meth:`LiveServer.stop` does nothing.

The protocol is the SDK's (Foxglove WebSocket protocol) under the subprotocol name :data:`SUBPROTOCOL`
(``foxglove.sdk.v1``), the only one foxglove-sdk's server accepts: a constant in its handshake, no option
(in 0.30.3, the newest on PyPI, and in the SDK's source from its first commit). A client that does not offer it, e.g. one
offering only the older name :data:`OLD_SUBPROTOCOL` (``foxglove.websocket.v1``, the same messages), gets
HTTP 400 at the handshake. Which viewers and clients connect: docs/guides/running.md, live view
(the Foxglove app and Lichtblick 1.22.1+ do; ``@foxglove/ws-protocol``'s ``FoxgloveClient`` does when its
WebSocket offers ``foxglove.sdk.v1``, not with its own ``SUPPORTED_SUBPROTOCOL``, still the old name).
The messages: JSON control messages (``serverInfo``,
``advertise``, ``subscribe``) and binary message data (opcode 1, subscription id u32 LE, log time u64
LE ns, payload; opcode 2 is the server time, u64 LE ns). Clients that connect, disconnect or stall are the server's business: a slow client
loses its oldest messages (:data:`BACKLOG` per client), never the run.

When it starts, the run prints :attr:`LiveServer.banner` (one line on stderr: the URL and the subprotocol).

Errors: :class:`LiveError` (one line) when the server cannot start, e.g. the port is taken.
"""

from __future__ import annotations

import foxglove
from foxglove.websocket import Capability

from host.run.mcap_log import SCENE_EVERY_S, RunLog

__all__ = ["BACKLOG", "DEFAULT_PORT", "OLD_SUBPROTOCOL", "SUBPROTOCOL", "LiveError", "LiveServer", "start_live"]

#: Foxglove's default WebSocket port (the app's "Foxglove WebSocket" connection suggests it)
DEFAULT_PORT = 8765
#: messages queued per client before the oldest are dropped (the SDK's message_backlog_size)
BACKLOG = 4096
HOST = "127.0.0.1"
#: the WebSocket subprotocol the SDK's server accepts (a client that does not offer it gets HTTP 400)
SUBPROTOCOL = "foxglove.sdk.v1"
#: the older name of the same protocol, refused by the SDK's server when offered alone
OLD_SUBPROTOCOL = "foxglove.websocket.v1"


class LiveError(RuntimeError):
    """The live server cannot start (the message says why, e.g. the port is taken)."""


class LiveServer:
    """A running live view; :meth:`stop` ends it (idempotent)."""

    def __init__(self, server: foxglove.WebSocketServer, run_log: RunLog) -> None:
        self.server = server
        self.port = int(server.port)
        self.url = f"ws://{HOST}:{self.port}"
        #: the line a run prints when the live view starts: where, and under which subprotocol
        self.banner = (f"foxglove: live view on {self.url}, WebSocket subprotocol {SUBPROTOCOL} "
                       f"(Foxglove: Open connection > Foxglove WebSocket; a client offering only "
                       f"{OLD_SUBPROTOCOL} gets HTTP 400)")
        self._run_log = run_log
        self._stopped = False
        run_log.time_listeners.append(self._time)
        run_log.scene_every_s = SCENE_EVERY_S

    def _time(self, board_ns: int) -> None:
        if not self._stopped:
            self.server.broadcast_time(board_ns)

    def stop(self) -> None:
        if self._stopped:
            return
        self._stopped = True
        if self._time in self._run_log.time_listeners:
            self._run_log.time_listeners.remove(self._time)
        self._run_log.scene_every_s = None
        self.server.stop()


def start_live(run_log: RunLog, port: int = DEFAULT_PORT, name: str = "ghostshell") -> LiveServer:
    """Serve ``run_log``'s channels live on ``ws://127.0.0.1:port`` (0: any free port)."""
    if not 0 <= port <= 65535:
        raise LiveError(f"--foxglove port must be 0..65535, got {port}")
    try:
        server = foxglove.start_server(name=f"{name} ({run_log.robot.name})", host=HOST, port=port,
                                       capabilities=[Capability.Time], context=run_log.context,
                                       message_backlog_size=BACKLOG)
    except (RuntimeError, OSError) as e:
        text = str(e).removeprefix("FoxgloveError: ")
        if "in use" in text:
            text = f"port {port} is taken ({text}); pick another with --foxglove PORT"
        raise LiveError(f"no live view: {text}") from e
    return LiveServer(server, run_log)
