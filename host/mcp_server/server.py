"""``ghostshell mcp``: the shell as a Model Context Protocol server (official ``mcp`` SDK, 2.x).

One :class:`~host.run.session.RobotSession` (one emulated board, one link, one
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
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from dataclasses import asdict
from pathlib import Path
from typing import Any

import anyio
from mcp.server.mcpserver import MCPServer
from mcp.server.mcpserver.exceptions import ToolError
from mcp.server.mcpserver.utilities.types import Image

from host.mcp_server.functions import function_tools
from host.robot.binding import signature_registry
from host.run.session import RobotSession, SessionOptions
from robots.registry import load_robot

#: the function stubs' resource URI
FUNCTIONS_URI = "ghostshell://functions"


def build_server(opts: SessionOptions) -> MCPServer[Any]:
    """An ``MCPServer`` whose lifespan holds one robot session built from ``opts``.

    Raises :class:`robots.description.RobotDataError` when ``opts.robot`` names no usable robot."""
    robot = load_robot(opts.robot, opts.robots_dir)
    holder: dict[str, RobotSession] = {}
    turn_lock = anyio.Lock()

    @contextlib.asynccontextmanager
    async def lifespan(_server: Any) -> AsyncIterator[None]:
        async with RobotSession(opts) as session:
            holder["session"] = session
            try:
                yield None
            finally:
                holder.pop("session", None)

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
        async with turn_lock:
            turn = await s.run_turn(xml)
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


def serve(opts: SessionOptions, http_port: int | None = None) -> None:
    """Run until the client disconnects (stdio) or the process is stopped (HTTP)."""
    server = build_server(opts)
    if http_port is None:
        server.run("stdio")
    else:
        server.run("streamable-http", host="127.0.0.1", port=http_port)


def default_out() -> Path:
    return Path("runs") / "mcp"
