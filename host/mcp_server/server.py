"""``ghostshell mcp``: the shell as a Model Context Protocol server (official ``mcp`` SDK, 2.x).

One :class:`~host.run.robot_session.RobotSession` (one emulated board, one link, one
shell) lives as long as the server (the SDK's lifespan) and serves every call:

* tool ``run_program(xml)``: streams the function-token program into the shell
  (a turn) and returns its outcome, the board-measured timeline and the
  observations for the next turn; one program runs at a time;
* one tool per function of the robot (``pose``, ``joint_move``, ... and ``say``;
  :mod:`host.mcp_server.functions`), each running that one element as a turn: so another
  shell can mount this one (``--mount-mcp arm="ghostshell mcp --robot arm"``);
* tool ``interrupt(channels?)``: interrupts the running program (all channels,
  or the named ones) and returns how many calls were cancelled;
* tool ``state()``: board time, base pose, tilt, fell, busy channels, the scene;
* tool ``capture()``: a picture from the robot's camera as MCP image content (robots with a camera);
* resource ``ghostshell://functions`` and prompt ``system_prompt``: the
  function stubs as the LLM sees them (code-as-prompt).

Transports: stdio (default) and streamable HTTP bound to 127.0.0.1
(``--http PORT``; path ``/mcp``).

A program is checked against the shell's per-turn limits before it runs (a tool error, nothing
run); one that reaches the board-time bound (``SessionOptions.max_board_s``) is stopped with outcome
``limit`` and the server goes on. Ctrl-C / SIGTERM (:func:`serve`): the running program is
interrupted through the lifecycle tree, the robot goes to its rest pose, the session closes (the
board stops), exit 130; a second signal stops at once. Over stdio the requests are read by
:class:`_StdinLines` (a reader the signal can abandon: the SDK's reader thread would block the
exit until the client closed stdin). A stdio line that is not a JSON-RPC message gets a JSON-RPC 2.0
error reply (id null): -32700 Parse error for text that is not JSON, -32600 Invalid Request for JSON
that is no message (:class:`_AnswerBadLines`; the SDK 2.3 would debug-log and drop it, leaving the
client waiting); the server goes on.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
from collections.abc import AsyncIterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import anyio
from mcp.server.mcpserver import MCPServer
from mcp.server.mcpserver.exceptions import ToolError
from mcp.server.mcpserver.utilities.types import Image

from host.link.errors import LinkError
from host.mcp_server.functions import function_tools
from host.runtime.binding import signature_registry
from host.run.robot_session import RobotSession, SessionOptions
from host.run.stops import StopReason, StopSignals
from host.shell.limits import TurnLimits
from robots.registry import load_robot

#: the function stubs' resource URI
FUNCTIONS_URI = "ghostshell://functions"


@dataclass
class ServerState:
    """The session a server holds (while its lifespan runs) and the lock one program at a time takes."""

    session: RobotSession | None = None
    turn_lock: anyio.Lock = field(default_factory=anyio.Lock)
    #: the session's start-up error (a link that cannot be opened, a server that cannot be mounted), kept by
    #: the lifespan rather than raised into the SDK (stdio: nested exception groups; HTTP: uvicorn's traceback
    #: and exit status 3); :func:`serve` raises it once the server has stopped
    failed: BaseException | None = None
    #: called by the lifespan after ``failed`` is set: stops the server (set by :func:`serve`)
    stop_serving: Any = None
    #: called by the lifespan once the session has started (:func:`serve`'s ``on_started``)
    on_started: Any = None


def build_server(opts: SessionOptions, served: ServerState | None = None) -> MCPServer[Any]:
    """An ``MCPServer`` whose lifespan holds one robot session built from ``opts`` (in ``served.session``).

    Raises :class:`robots.description.RobotDataError` when ``opts.robot`` names no usable robot."""
    robot = load_robot(opts.robot, opts.robots_dir)
    st = served if served is not None else ServerState()
    holder: dict[str, RobotSession] = {}
    turn_lock = st.turn_lock

    @contextlib.asynccontextmanager
    async def lifespan(_server: Any) -> AsyncIterator[None]:
        started = False
        try:
            async with RobotSession(opts) as session:
                holder["session"] = st.session = session
                started = True
                if st.on_started is not None:
                    st.on_started()
                try:
                    yield None
                finally:
                    holder.pop("session", None)
                    st.session = None
        except (LinkError, RuntimeError, OSError) as e:  # a link, a mount (McpMountError): the session could not start
            if started or st.stop_serving is None:
                raise
            st.failed = e
        if st.failed is not None and not started:  # outside the except: the server's stop is no error "during" it
            st.stop_serving()
            yield None  # the server stops without a session; serve raises the error

    def session() -> RobotSession:
        s = holder.get("session")
        if s is None:
            raise ToolError("the robot session is not running")
        return s

    server = MCPServer(
        name="ghostshell",
        instructions=f"Drive the {robot.title} robot ({robot.servo_count} servos, emulated board) by streaming "
        "function-token programs: read the ghostshell://functions resource for the functions, then call "
        f"run_program with XML such as <pose name=\"{robot.start_pose}\"/>"
        + ("Hello!" if robot.peripherals.speaker else ""),
        lifespan=lifespan,
    )

    async def run(xml: str) -> dict[str, Any]:
        s = session()
        if turn_lock.locked():
            # ToolError: the client gets this message as an is_error result (no server traceback)
            raise ToolError("a program is already running; call interrupt() first or wait for it")
        why = TurnLimits().refuse_reply(xml)
        if why is not None:
            raise ToolError(f"{why}; nothing was run")
        if s.stop is not None and s.stop.kind == "signal":
            raise ToolError(f"the server is stopping ({s.stop.message})")
        async with turn_lock:
            turn = await s.run_turn(xml)
            if s.stop is not None and s.stop.name == "max_board_s":
                s.clear_stop()  # that bound cut this program only; the server goes on
        summary = turn.summary
        return {"outcome": summary.outcome, "fell": summary.fell, "duration_s": summary.duration_s,
                "executed_text": turn.executed_text,
                "timeline": [_call(asdict(c), turn.board_t0) for c in turn.calls],
                "observations": [str(o) for o in turn.result.observations],
                "error": summary.extra.get("error"), "scene": summary.extra.get("scene")}

    @server.tool()
    async def run_program(xml: str) -> dict[str, Any]:
        """Stream a function-token program (XML tokens and plain text to speak) into the shell and
        run it on the robot. Returns the outcome, the timeline (board seconds) and the observations."""
        return await run(xml)

    registry = signature_registry(robot, opts.vocabulary)
    for name, description, fn in function_tools(
            (s for m in registry.modules() if not m.hidden for s in m.functions), run):
        server.add_tool(fn, name=name, description=description)

    @server.tool()
    async def interrupt(channels: list[str] | None = None) -> dict[str, Any]:
        """Interrupt the running program: every channel, or only ``channels`` (e.g. ["head"])."""
        return {"cancelled": session().interrupt(channels)}

    @server.tool()
    async def state() -> dict[str, Any]:
        """The robot now: board time (s), base pose [x m, y m, yaw deg], tilt, fell, running calls."""
        return session().state()

    if robot.peripherals.camera is not None:
        @server.tool()
        async def capture() -> Image:
            """A picture from the robot's camera (PNG)."""
            path = await session().capture()
            return Image(path=path)

    @server.resource(FUNCTIONS_URI, mime_type="text/markdown")
    async def functions() -> str:
        """The robot's function stubs as the LLM sees them (code-as-prompt)."""
        return session().prompt(format="code")

    @server.prompt()
    async def system_prompt() -> str:
        """The GhostShell system prompt for driving this robot with function tokens."""
        return session().prompt(format="code")

    return server


def _call(d: dict[str, Any], t0: float) -> dict[str, Any]:
    """One timeline entry with start/end relative to the program's start (board seconds)."""
    for key in ("start", "end"):
        if d.get(key) is not None:
            d[key] = round(d[key] - t0, 4)
    return d


class _StdinLines:
    """The client's requests, one text line at a time, from a private copy of fd 0.

    The SDK's own reader reads ``sys.stdin`` in an AnyIO worker thread, which a cancellation cannot
    stop and the exiting interpreter waits for: a Ctrl-C would hang until the client closed stdin.
    Here a daemon thread does raw ``os.read`` calls (no lock the exiting interpreter needs), one
    chunk ahead of the consumer, and hands them to the event loop. A line is at most ``MAX_LINE``
    bytes (a longer one is passed on cut there; the SDK then answers a parse error), so nothing
    grows without bound. asyncio only (``serve`` runs on it).
    """

    MAX_LINE = 16 * 1024 * 1024

    def __init__(self, fd: int = 0) -> None:
        self.fd = os.dup(fd)
        self.buf = bytearray()
        self.eof = False
        self._chunks: Any = None
        self._more = threading.Event()

    def _reader(self, loop: Any) -> None:
        while True:
            self._more.wait()
            self._more.clear()
            try:
                chunk = os.read(self.fd, 65536)
            except OSError:
                chunk = b""
            loop.call_soon_threadsafe(self._chunks.put_nowait, chunk)
            if not chunk:
                return

    def __aiter__(self) -> _StdinLines:
        return self

    async def __anext__(self) -> str:
        import asyncio

        if self._chunks is None:
            self._chunks = asyncio.Queue()
            threading.Thread(target=self._reader, args=(asyncio.get_running_loop(),), name="mcp-stdin",
                             daemon=True).start()
        while b"\n" not in self.buf and len(self.buf) < self.MAX_LINE and not self.eof:
            self._more.set()
            chunk = await self._chunks.get()
            self.eof = not chunk
            self.buf += chunk
        if not self.buf:
            raise StopAsyncIteration
        end = self.buf.find(b"\n")
        cut = end + 1 if 0 <= end < self.MAX_LINE else min(len(self.buf), self.MAX_LINE)
        line = bytes(self.buf[:cut])
        del self.buf[:cut]
        return line.decode("utf-8", errors="replace")


class _AnswerBadLines:
    """The stdio transport's read stream, except that an item the SDK's reader could not parse (it passes
    the exception on) is answered on ``write`` with a JSON-RPC error response and not passed on.

    The SDK offers no hook on this path to the server (its dispatcher's ``on_stream_exception`` is not
    reachable through ``Server.run``), so this wraps the stream it reads (the SDK's ``ReadStream``
    protocol, ``last_context`` passed through)."""

    def __init__(self, read: Any, write: Any) -> None:
        self._read, self._write = read, write
        self.bad_lines = 0

    @property
    def last_context(self) -> Any:
        return getattr(self._read, "last_context", None)

    async def _answer(self, exc: Exception) -> None:
        from mcp.shared.message import SessionMessage
        from mcp_types import INVALID_REQUEST, PARSE_ERROR, ErrorData, JSONRPCError

        self.bad_lines += 1
        kinds = {e.get("type") for e in exc.errors()} if hasattr(exc, "errors") else set()
        code, text = (PARSE_ERROR, "Parse error") if "json_invalid" in kinds or not kinds else \
            (INVALID_REQUEST, "Invalid Request")
        await self._write.send(SessionMessage(JSONRPCError(jsonrpc="2.0", id=None,
                                                           error=ErrorData(code=code, message=text))))

    async def receive(self) -> Any:
        while True:
            item = await self._read.receive()
            if not isinstance(item, Exception):
                return item
            await self._answer(item)

    def __aiter__(self) -> _AnswerBadLines:
        return self

    async def __anext__(self) -> Any:
        try:
            return await self.receive()
        except (anyio.EndOfStream, anyio.ClosedResourceError):
            raise StopAsyncIteration from None

    async def aclose(self) -> None:
        await self._read.aclose()

    async def __aenter__(self) -> _AnswerBadLines:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()


async def _serve(opts: SessionOptions, http_port: int | None, on_started: Any = None) -> StopReason | None:
    """Serve until the client goes away (stdio), or a signal; returns the signal's stop (None otherwise)."""
    state = ServerState(on_started=on_started)
    server = build_server(opts, state)
    stopping = anyio.Event()

    def on_first(stop: StopReason) -> bool:
        session = state.session
        if session is None:  # not started (or already closing): nothing to bring to rest
            return False
        session.request_stop(stop)  # a running program is interrupted through the lifecycle tree
        stopping.set()
        return True

    signals = StopSignals(on_first)
    async with signals.guard(), anyio.create_task_group() as tg:
        async def run() -> None:
            if http_port is None:
                from mcp.server.stdio import stdio_server

                async with stdio_server(stdin=_StdinLines()) as (read, write):  # type: ignore[arg-type]
                    low = server._lowlevel_server
                    await low.run(_AnswerBadLines(read, write), write, low.create_initialization_options())
            else:
                await server.run_streamable_http_async(host="127.0.0.1", port=http_port)
            tg.cancel_scope.cancel()

        async def wind_down() -> None:
            await stopping.wait()
            async with state.turn_lock:  # the interrupted program has ended
                session = state.session
                if session is not None:
                    await session.go_to_rest()
            tg.cancel_scope.cancel()

        def stop_serving() -> None:
            if http_port is not None:  # uvicorn would log the cancelled lifespan as its shutdown failing
                logging.getLogger("uvicorn.error").disabled = True
            tg.cancel_scope.cancel()

        state.stop_serving = stop_serving
        tg.start_soon(run)
        tg.start_soon(wind_down)
    if state.failed is not None:
        raise state.failed
    return signals.first


def serve(opts: SessionOptions, http_port: int | None = None, on_started: Any = None) -> StopReason | None:
    """Run until the client disconnects (stdio) or the process is stopped; returns the signal that
    stopped it (see the module docstring), or None. A session that cannot start (its link, a mounted
    server) stops the server and raises its error here (:class:`host.link.LinkError`, ``McpMountError``);
    ``on_started()`` is called once it has started."""
    return anyio.run(_serve, opts, http_port, on_started, backend="asyncio")


def default_out() -> Path:
    return Path("runs") / "mcp"
