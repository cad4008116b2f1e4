"""A bounded stdio transport for the MCP SDK's ``Client``: one server subprocess.

:class:`StdioServer` starts the server command and gives the SDK's ``Client`` (``Client(server.
streams())``) the two message streams it expects, exactly as ``mcp.client.stdio.stdio_client``
does: newline-delimited JSON-RPC on the child's stdin/stdout, the child in its own process group,
and the spec's shutdown (close stdin, wait ``EXIT_GRACE`` s, then SIGTERM/SIGKILL the group with the
SDK's ``terminate_posix_process_tree``).

Hand-written rather than ``stdio_client`` because a mounted server is untrusted input to a robot
session, and the SDK's client (mcp 2.3) keeps an unbounded line buffer (a server writing without
newlines grows it without limit), logs every non-JSON stdout line with a traceback at ERROR (a
flooding server floods our stderr), and hands the child's stderr to a file object, so neither its
exit status nor the last thing it said is at hand when a call fails. Here:

* a stdout line longer than ``max_line`` bytes is dropped as it arrives (the partial line held
  never exceeds ``max_line``); a line that is not JSON-RPC is dropped and counted
  (:class:`StdioStats`; the first one is kept, clipped, for messages);
* stderr is read continuously into a ring of the last ``stderr_tail`` bytes
  (:meth:`StdioServer.stderr_tail`), so a chatty server never blocks on a full pipe;
* :meth:`StdioServer.exited` waits (bounded) for the exit status and stderr's end, for the message
  of a call the server died in.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from collections.abc import AsyncIterator, Mapping, Sequence
from dataclasses import dataclass

import anyio
import anyio.abc
import mcp_types as types
from anyio.streams.memory import MemoryObjectReceiveStream, MemoryObjectSendStream

from mcp.client.stdio import get_default_environment
from mcp.shared.message import SessionMessage

#: longest stdout line (one JSON-RPC message) accepted, in bytes
MAX_LINE = 8 * 1024 * 1024
#: bytes of the server's stderr kept (the tail)
STDERR_TAIL = 16 * 1024
#: seconds a server gets to exit after its stdin closes, before SIGTERM (then SIGKILL after as long)
EXIT_GRACE = 2.0
_READ = 65536
_POLL = 0.01
#: variables passed to a server besides the SDK's safe set (``get_default_environment``)
PASS_ENV = ("PYTHONPATH", "VIRTUAL_ENV", "LANG", "LC_ALL", "LC_CTYPE", "TMPDIR", "MUJOCO_GL")
_PASS_PREFIXES = ("GHOSTSHELL_",)

_IO_ERRORS = (anyio.EndOfStream, anyio.ClosedResourceError, anyio.BrokenResourceError, OSError)


def server_env(extra: Mapping[str, str] | None = None) -> dict[str, str]:
    """The environment a mounted server gets: the SDK's safe set, :data:`PASS_ENV`, ``GHOSTSHELL_*``."""
    env = get_default_environment()
    for key, value in os.environ.items():
        if key in PASS_ENV or key.startswith(_PASS_PREFIXES):
            env[key] = value
    env.update(extra or {})
    return env


@dataclass
class StdioStats:
    """What a server wrote that was not a JSON-RPC message."""

    junk_lines: int = 0  # non-empty stdout lines that are not JSON-RPC (dropped)
    oversized_lines: int = 0  # stdout lines longer than max_line (dropped as they arrived)
    first_junk: str = ""  # the first junk line, clipped
    stderr_bytes: int = 0  # everything the server wrote on stderr
    max_buffered: int = 0  # the longest partial stdout line held (bytes; at most max_line)

    def note(self) -> str:
        """One line on the junk, or ``""`` when there was none."""
        if not (self.junk_lines or self.oversized_lines):
            return ""
        first = f" (first: {self.first_junk!r})" if self.first_junk else ""
        return (f"dropped {self.junk_lines} non-JSON-RPC line(s) and {self.oversized_lines} line(s) over the "
                f"length limit on its stdout{first}")


class StdioServer:
    """One MCP server subprocess; :meth:`streams` is the transport, entered once."""

    def __init__(self, argv: Sequence[str], *, env: Mapping[str, str] | None = None, cwd: str | None = None,
                 max_line: int = MAX_LINE, stderr_tail: int = STDERR_TAIL) -> None:
        self.argv = list(argv)
        self.env = dict(env) if env is not None else server_env()
        self.cwd = cwd
        self.max_line = max_line
        self.stats = StdioStats()
        self.process: anyio.abc.Process | None = None
        self._tail_cap = stderr_tail
        self._tail = bytearray()
        self._stderr_done = anyio.Event()
        self._stdout_done = anyio.Event()

    # -- what the server said -------------------------------------------------
    @property
    def returncode(self) -> int | None:
        """The exit status once the server has exited (None while it runs or before it started)."""
        return None if self.process is None else self.process.returncode

    def stderr_tail(self, max_chars: int = 600) -> str:
        """The end of the server's stderr: its last lines, at most ``max_chars`` characters."""
        text = self._tail.decode("utf-8", "replace").strip()
        if len(text) > max_chars:
            text = "…" + text[-(max_chars - 1):]
        return " | ".join(line.strip() for line in text.splitlines() if line.strip())

    async def exited(self, timeout: float = 1.0) -> int | None:
        """Wait up to ``timeout`` s for the server to exit and its stderr to end; the exit status."""
        with anyio.move_on_after(timeout):
            while self.returncode is None:
                await anyio.sleep(_POLL)  # a poll, as the SDK's own stdio client does: wait() may never return
            await self._stderr_done.wait()
        return self.returncode

    # -- the transport ------------------------------------------------------------
    @contextlib.asynccontextmanager
    async def streams(self) -> AsyncIterator[tuple[MemoryObjectReceiveStream[SessionMessage | Exception],
                                                   MemoryObjectSendStream[SessionMessage]]]:
        """Start the server; yield (read stream, write stream) for ``mcp.Client``; stop it on exit.

        Raises ``OSError`` when the command cannot be started.
        """
        if self.process is not None:
            raise RuntimeError("StdioServer.streams() is entered once")
        self.process = process = await anyio.open_process(
            self.argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            env=self.env, cwd=self.cwd, start_new_session=True)
        read_send, read_recv = anyio.create_memory_object_stream[SessionMessage | Exception](0)
        write_send, write_recv = anyio.create_memory_object_stream[SessionMessage](0)
        async with anyio.create_task_group() as tg:
            tg.start_soon(self._read_stdout, read_send)
            tg.start_soon(self._read_stderr)
            tg.start_soon(self._write_stdin, write_recv, read_send)
            try:
                yield read_recv, write_send
            finally:
                with anyio.CancelScope(shield=True):
                    read_recv.close()  # the reader drains stdout from now on
                    write_send.close()
                    await self._stop(process)
                tg.cancel_scope.cancel()

    async def _read_stdout(self, send: MemoryObjectSendStream[SessionMessage | Exception]) -> None:
        process = self.process
        assert process is not None and process.stdout is not None
        buf = bytearray()
        skipping = False  # inside a line that went over max_line
        delivering = True
        try:
            while True:
                try:
                    chunk = await process.stdout.receive(_READ)
                except _IO_ERRORS:
                    return
                start = 0
                while True:
                    nl = chunk.find(b"\n", start)
                    piece = chunk[start:] if nl < 0 else chunk[start:nl]
                    if not skipping:
                        if len(buf) + len(piece) > self.max_line:
                            self.stats.oversized_lines += 1
                            buf.clear()
                            skipping = True
                        else:
                            buf += piece
                            self.stats.max_buffered = max(self.stats.max_buffered, len(buf))
                    if nl < 0:
                        break
                    if not skipping and delivering:
                        msg = self._parse(bytes(buf))
                        if msg is not None:
                            try:
                                await send.send(msg)
                            except (anyio.BrokenResourceError, anyio.ClosedResourceError):
                                delivering = False  # the session is gone: drain, so the server can exit
                    buf.clear()
                    skipping = False
                    start = nl + 1
        finally:
            send.close()  # EOF for the session: pending requests fail with "Connection closed"
            self._stdout_done.set()

    def _parse(self, line: bytes) -> SessionMessage | None:
        line = line.strip()
        if not line:
            return None
        try:
            return SessionMessage(types.jsonrpc_message_adapter.validate_json(line, by_name=False))
        except ValueError:
            self.stats.junk_lines += 1
            if not self.stats.first_junk:
                text = line[:120].decode("utf-8", "replace")
                self.stats.first_junk = text + ("…" if len(line) > 120 else "")
            return None

    async def _read_stderr(self) -> None:
        process = self.process
        assert process is not None and process.stderr is not None
        try:
            while True:
                try:
                    chunk = await process.stderr.receive(_READ)
                except _IO_ERRORS:
                    return
                self.stats.stderr_bytes += len(chunk)
                self._tail += chunk
                if len(self._tail) > self._tail_cap:
                    del self._tail[: len(self._tail) - self._tail_cap]
        finally:
            self._stderr_done.set()

    async def _write_stdin(self, recv: MemoryObjectReceiveStream[SessionMessage],
                           read_send: MemoryObjectSendStream[SessionMessage | Exception]) -> None:
        process = self.process
        assert process is not None and process.stdin is not None
        try:
            async with recv:
                async for message in recv:
                    data = message.message.model_dump_json(by_alias=True, exclude_unset=True) + "\n"
                    await process.stdin.send(data.encode("utf-8"))
        except (anyio.ClosedResourceError, anyio.BrokenResourceError, OSError):
            read_send.close()  # the server stopped reading: end the session rather than hang a request

    async def _stop(self, process: anyio.abc.Process) -> None:
        """Close stdin, give the server ``EXIT_GRACE`` s, then terminate its process group."""
        with contextlib.suppress(*_IO_ERRORS):
            assert process.stdin is not None
            await process.stdin.aclose()
        if not await self._wait_exit(process, EXIT_GRACE):
            if sys.platform == "win32":  # pragma: no cover - the project runs on POSIX
                with contextlib.suppress(OSError):
                    process.kill()
            else:
                from mcp.os.posix.utilities import terminate_posix_process_tree

                await terminate_posix_process_tree(process, EXIT_GRACE)
            await self._wait_exit(process, EXIT_GRACE)
        with anyio.move_on_after(EXIT_GRACE):  # a descendant may still hold the pipes
            await self._stdout_done.wait()
            await self._stderr_done.wait()
        for stream in (process.stdout, process.stderr):
            if stream is not None:
                with contextlib.suppress(*_IO_ERRORS):
                    await stream.aclose()

    @staticmethod
    async def _wait_exit(process: anyio.abc.Process, timeout: float) -> bool:
        with anyio.move_on_after(timeout):
            while process.returncode is None:
                await anyio.sleep(_POLL)
        return process.returncode is not None


def describe_exit(server: StdioServer, name: str, returncode: int | None, when: str = "") -> str:
    """``MCP server 'NAME' exited with status 3[ when]; its stderr ends: ...`` (and the junk statistics)."""
    tail = server.stderr_tail()
    said = f"; its stderr ends: {tail}" if tail else "; it wrote nothing on stderr"
    junk = server.stats.note()
    junk = f"; {junk}" if junk else ""
    when = f" {when}" if when else ""
    if returncode is None:
        return f"MCP server {name!r} closed the connection{when} (still running){said}{junk}"
    how = f"was killed by signal {-returncode}" if returncode < 0 else f"exited with status {returncode}"
    return f"MCP server {name!r} {how}{when}{said}{junk}"
