"""MCP servers as shell functions (``--mount-mcp NAME=COMMAND...`` / ``NAME=URL``).

``async with mounted(specs, registry=registry) as mounts:`` connects to every server with the
official ``mcp`` SDK ``Client`` (stdio through :class:`~host.mounts.stdio.StdioServer`, streamable
HTTP through the SDK's ``streamable_http_client``), lists its tools and mounts one
:class:`~host.shell.types.Module` per server: module and channel ``NAME``, one function
``NAME.TOOL`` per tool (``<weather.get_forecast city="Lisbon"/>``), its parameters converted from
the tool's JSON Schema by :mod:`host.mounts.schema` (so the mapper refuses a bad argument before
any request, with the same checks as a robot function). Leaving the block unmounts the modules
and stops the servers (stdin closed, then the process group terminated).

Names: the element name is the qualified ``NAME.TOOL``; a bare ``<get_forecast/>`` does not resolve
(the registry suggests the qualified name), so a tool never shadows a robot function and a robot
function never hides a tool. Tool and parameter names that are not XML names (or a parameter called
``sync``, the shell's own attribute) are mapped to valid unique names; each mapping is a note.

A call is one ``tools/call`` per element, run as the element's function: cancelling the element
(an interrupt, or a start-tag's lifecycle ending) cancels the request, and the SDK sends the
server ``notifications/cancelled`` (stdio; over streamable HTTP it aborts the request's POST).
Its result is the function's result, so it reaches the next turn as an observation like any
robot call's (``weather.get_forecast returned '...'``): the structured content when the server
sent some (``{"result": X}``, the SDK's wrapping of a non-object return, unwrapped to X), otherwise
the text blocks; images, audio and resources are named, not inlined; at most
``MountOptions.max_result_chars`` characters.

Errors (never a hung turn):

=====================================  ==========================================================
what                                   outcome
=====================================  ==========================================================
command not found / not executable     ``McpMountError`` at mount time (one line; the CLI exits 2)
server exits or fails the handshake    ``McpMountError`` with its exit status and stderr tail
no handshake + tools/list within       ``McpMountError`` (``MountOptions.startup_timeout``, 20 s)
``startup_timeout``
NAME already a module, or twice        ``McpMountError`` before any server starts
tool schema the mapper cannot express  tool skipped with a note naming the tool and the construct
tool error (``isError``)               failed call: ``McpCallError`` with the server's text
JSON-RPC error (e.g. unknown tool)     failed call with the server's message and code
no answer within ``call_timeout``      failed call; the request is cancelled (30 s)
server dies during or between calls    failed call: exit status, stderr tail, junk statistics
server floods stdout/stderr            junk lines dropped and counted, stderr kept as a bounded tail
=====================================  ==========================================================
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import anyio
import mcp_types as types
from mcp_types import CONNECTION_CLOSED

from host.mounts.schema import ToolInterface, Unsupported, clip, function_names, tool_interface
from host.mounts.spec import McpMountError, MountSpec, MountSpecError, check_specs, server_argv
from host.mounts.stdio import MAX_LINE, StdioServer, describe_exit
from host.shell.registry import Registry, RegistryError
from host.shell.types import FunctionSpec, Module

log = logging.getLogger(__name__)

#: pages of ``tools/list`` read at most
MAX_PAGES = 20


class McpCallError(RuntimeError):
    """A call that failed: the tool's error text, a protocol error, a timeout or the server gone."""


@dataclass(frozen=True)
class MountOptions:
    """Timeouts and bounds of mounted servers."""

    startup_timeout: float = 20.0  # start, handshake and tools/list
    call_timeout: float = 30.0  # one tools/call
    max_result_chars: int = 4000  # longest result kept (text or JSON)
    max_tools: int = 128  # tools mounted per server (the rest: one note)
    max_line: int = MAX_LINE  # longest stdout line (JSON-RPC message) from a stdio server, bytes
    #: entered around every tools/call (a lockstep session passes its streamer's ``hold``: the board
    #: clock stands still while the host waits on a server's wall-clock answer, as for a real LLM)
    around_call: Callable[[], contextlib.AbstractAsyncContextManager[Any]] | None = None


@dataclass
class McpMount:
    """One mounted server: its :class:`Module`, the notes on its tools, and :meth:`call`."""

    spec: MountSpec
    options: MountOptions = field(default_factory=MountOptions)
    module: Module | None = None
    notes: list[str] = field(default_factory=list)
    tools: dict[str, str] = field(default_factory=dict)  # element name -> the server's tool name
    server: str = ""  # the server's name and version as it introduced itself
    stdio: StdioServer | None = None
    _client: Any = None
    _gone: str | None = None
    _stop: anyio.Event = field(default_factory=anyio.Event)

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def connected(self) -> bool:
        """True while calls can reach the server."""
        alive = self.stdio is None or self.stdio.returncode is None
        return self._client is not None and self._gone is None and alive

    # -- calls ------------------------------------------------------------------
    async def call(self, tool: str, arguments: dict[str, Any]) -> Any:
        """One ``tools/call`` of ``tool``; its result (see the module docstring) or :class:`McpCallError`."""
        client = self._client
        if client is None or self._gone is not None:
            raise McpCallError(self._gone or f"MCP server {self.name!r} is not connected")
        timeout = self.options.call_timeout
        around = self.options.around_call() if self.options.around_call is not None else contextlib.nullcontext()
        async with around:
            return await self._call(client, tool, arguments, timeout)

    async def _call(self, client: Any, tool: str, arguments: dict[str, Any], timeout: float) -> Any:
        from mcp.shared.exceptions import MCPError

        with anyio.move_on_after(timeout):
            try:
                result = await client.call_tool(tool, arguments)
            except MCPError as exc:
                if exc.code == CONNECTION_CLOSED:
                    raise McpCallError(await self._gone_message()) from None
                raise McpCallError(f"MCP server {self.name!r}: {clip(exc.message, 500)} (error {exc.code})") from None
            except Exception as exc:
                if self._gone is not None or self._client is None:
                    raise McpCallError(await self._gone_message()) from None
                raise McpCallError(f"bad answer from MCP server {self.name!r}: {_describe(exc)}") from None
            return self._result(result)
        raise McpCallError(f"no answer from MCP server {self.name!r} within {timeout:g} s; the request was cancelled")

    def _result(self, result: types.CallToolResult) -> Any:
        limit = self.options.max_result_chars
        text = _content_text(result.content)
        if result.is_error:
            raise McpCallError(clip(text, limit) or "the tool reported an error without a message")
        value = result.structured_content
        if isinstance(value, dict) and set(value) == {"result"}:
            value = value["result"]  # the SDK's wrapping of a tool's non-object return value
        if value is None:
            return clip(text, limit) if text else None
        if isinstance(value, str):
            return clip(value, limit)
        dumped = json.dumps(value, ensure_ascii=False, default=str)
        return value if len(dumped) <= limit else clip(dumped, limit)

    async def _gone_message(self) -> str:
        if self._gone is None:
            if self.stdio is not None:
                code = await self.stdio.exited(1.0)
                self._gone = describe_exit(self.stdio, self.name, code)
            else:
                self._gone = f"MCP server {self.name!r} at {self.spec.url} closed the connection"
        return self._gone

    # -- life ---------------------------------------------------------------------
    async def _run(self, *, task_status: anyio.abc.TaskStatus[None] = anyio.TASK_STATUS_IGNORED) -> None:
        """Connect, list the tools, build the module, then hold the connection until stopped.

        Raises :class:`McpMountError` before ``task_status.started()``; afterwards nothing escapes
        (a dying server only makes later calls fail)."""
        from mcp import Client
        from mcp.client.streamable_http import streamable_http_client

        started = False
        opts = self.options
        try:
            if self.spec.url is not None:
                transport: Any = streamable_http_client(self.spec.url)
            else:
                # python: ghostshell's interpreter; ghostshell: another shell of this installation (item 5)
                self.stdio = StdioServer(server_argv(self.spec), max_line=opts.max_line)
                transport = self.stdio.streams()
            client = Client(transport, client_info=types.Implementation(name="ghostshell", version="0.1.0"),
                            cache=None)
            # The deadline covers start, handshake and tools/list, then is lifted: the scope must
            # enclose the client's whole life (its task groups cannot outlive a scope entered after them).
            with anyio.CancelScope(deadline=anyio.current_time() + opts.startup_timeout) as startup:
                async with client:
                    tools = await _list_tools(client, opts.max_tools)
                    startup.deadline = math.inf
                    info = client.server_info
                    self.server = f"{info.name} {info.version}".strip() if info is not None else ""
                    self._build(tools, client.instructions)
                    self._client = client
                    started = True
                    task_status.started()
                    await self._stop.wait()
            if startup.cancelled_caught and not started:
                raise McpMountError(await self._startup_failure(
                    f"the server gave no answer (handshake and tools/list) within {opts.startup_timeout:g} s",
                    timed_out=True))
        except McpMountError:
            raise
        except OSError as exc:
            if started:
                self._gone = f"MCP server {self.name!r}: {_describe(exc)}"
                return
            raise McpMountError(f"--mount-mcp {self.spec}: cannot start the server: {_describe(exc)}") from None
        except Exception as exc:  # a server's failure is reported, never propagated
            if not started:
                raise McpMountError(await self._startup_failure(
                    f"the handshake or tools/list failed: {_describe(exc)}")) from None
            self._gone = (await self._gone_message()) if self.stdio is not None else \
                f"MCP server {self.name!r} at {self.spec.url}: connection failed: {_describe(exc)}"
        finally:
            self._client = None
            if started and self._gone is None and not self._stop.is_set():
                self._gone = f"MCP server {self.name!r} is no longer connected"

    async def _startup_failure(self, reason: str, *, timed_out: bool = False) -> str:
        where = f"--mount-mcp {self.spec}"
        if self.stdio is not None and self.stdio.process is not None:
            code = None if timed_out else await self.stdio.exited(1.0)  # timed out: we stopped it
            if code is not None:
                return f"{where}: {describe_exit(self.stdio, self.name, code, 'before it was mounted')}"
            tail = self.stdio.stderr_tail()
            return f"{where}: {reason}" + (f"; its stderr ends: {tail}" if tail else "")
        return f"{where}: {reason}"

    def _build(self, tools: list[types.Tool], instructions: str | None) -> None:
        """The module: one function per expressible tool; a note per skipped tool or mapped name."""
        name = self.name
        if len(tools) > self.options.max_tools:
            self.notes.append(f"{name}: only the first {self.options.max_tools} of {len(tools)} tools are mounted")
            tools = tools[: self.options.max_tools]
        names = function_names(name, [t.name for t in tools])
        specs: list[FunctionSpec] = []
        for tool in tools:
            fname, rename = names[tool.name]
            try:
                iface = tool_interface(tool.input_schema, tool.description)
            except Unsupported as exc:
                self.notes.append(f"{name}: tool {tool.name!r} skipped: {exc}")
                continue
            except Exception as exc:  # a malformed schema skips its tool, never the mount
                self.notes.append(f"{name}: tool {tool.name!r} skipped: its input schema cannot be read "
                                  f"({_describe(exc)})")
                continue
            if rename:
                self.notes.append(f"{name}: {rename}")
            self.notes.extend(f"{fname}: {n}" for n in iface.notes)
            specs.append(self._function(fname, tool.name, iface, rename))
            self.tools[fname] = tool.name
        doc = f"tools of the MCP server {self.server or name}"
        if instructions:
            doc += f" ({clip(' '.join(instructions.split()), 300)})"
        if len(specs) < len(tools):
            skipped = [t.name for t in tools if t.name not in self.tools.values()]
            doc += f"; not available here: {', '.join(repr(s) for s in skipped[:10])}"
        self.module = Module(name, specs, name, doc)

    def _function(self, fname: str, tool: str, iface: ToolInterface, rename: str | None) -> FunctionSpec:
        wire = iface.wire

        async def call_tool(**kwargs: Any) -> Any:
            return await self.call(tool, {wire.get(k, k): v for k, v in kwargs.items()})

        call_tool.__name__ = call_tool.__qualname__ = fname
        doc = iface.doc
        if rename:
            doc = (doc + "\n" if doc else "") + f"(The server's tool {tool!r}.)"
        return FunctionSpec(name=fname, module=self.name, channel=self.name, impl=call_tool,
                            params=iface.params, doc=doc)


async def _list_tools(client: Any, max_tools: int) -> list[types.Tool]:
    tools: list[types.Tool] = []
    cursor: str | None = None
    for _ in range(MAX_PAGES):
        page = await client.list_tools(cursor=cursor)
        tools.extend(page.tools)
        cursor = page.next_cursor
        if not cursor or len(tools) > max_tools:
            break
    return tools


def _content_text(blocks: Sequence[Any]) -> str:
    """The text of result content blocks; other kinds are named, not inlined."""
    parts: list[str] = []
    for b in blocks:
        kind = getattr(b, "type", "")
        if kind == "text":
            parts.append(b.text)
        elif kind in ("image", "audio"):
            parts.append(f"[{kind} {b.mime_type}, {len(b.data) * 3 // 4} bytes, not shown]")
        elif kind == "resource_link":
            parts.append(f"[resource {b.uri}]")
        elif kind == "resource":
            res = b.resource
            text = getattr(res, "text", None)
            parts.append(text if isinstance(text, str) else f"[resource {res.uri}, {res.mime_type or 'binary'}]")
        else:
            parts.append(f"[{kind or type(b).__name__} content]")
    return "\n".join(p for p in parts if p)


def _describe(exc: BaseException) -> str:
    """One line for ``exc`` (the first leaf of an exception group)."""
    while isinstance(exc, BaseExceptionGroup) and exc.exceptions:
        exc = exc.exceptions[0]
    text = " ".join(str(exc).split())
    return clip(f"{type(exc).__name__}: {text}" if text else type(exc).__name__, 500)


@contextlib.asynccontextmanager
async def mounted(specs: Sequence[MountSpec], *, registry: Registry | None = None,
                  options: MountOptions | None = None) -> AsyncIterator[list[McpMount]]:
    """Start/connect every server in ``specs`` (in order) and yield one :class:`McpMount` each.

    With ``registry``, the names are checked against it before anything starts and the modules
    are mounted on it (unmounted on exit). Raises :class:`McpMountError` (one line) when a server
    cannot be mounted; the servers already started are stopped. Enter and leave it in one task.
    """
    opts = options or MountOptions()
    check_specs(specs, registry)
    mounts: list[McpMount] = []
    on_registry: list[str] = []
    alone: BaseException | None = None
    try:
        async with anyio.create_task_group() as tg:
            try:
                for spec in specs:
                    m = McpMount(spec, opts)
                    await tg.start(m._run)
                    mounts.append(m)
                if registry is not None:
                    for m in mounts:
                        assert m.module is not None
                        try:
                            registry.mount(m.module)
                        except RegistryError as exc:
                            raise McpMountError(f"--mount-mcp {m.spec.name}: {exc}") from None
                        on_registry.append(m.name)
                yield mounts
            finally:
                if registry is not None:
                    for name in reversed(on_registry):
                        with contextlib.suppress(RegistryError):
                            registry.unmount(name)
                for m in mounts:
                    m._stop.set()
    except BaseExceptionGroup as group:
        # The holders never raise, so a group holds one exception: a start() failure or the caller's
        # own (raised in the block). Give it back as it was raised, not wrapped by our task group.
        if len(group.exceptions) != 1:
            raise
        alone = group.exceptions[0]
    if alone is not None:
        raise alone


__all__ = ["McpCallError", "McpMount", "McpMountError", "MountOptions", "MountSpec", "MountSpecError",
           "check_specs", "mounted"]
