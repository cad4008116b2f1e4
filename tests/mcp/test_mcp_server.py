"""``ghostshell mcp`` over stdio, driven by the MCP SDK's own client: one board and one shell
across calls (the robot keeps where the previous program left it)."""

from __future__ import annotations

import base64
import json
import sys
from pathlib import Path
from typing import Any

import anyio
import pytest

from mcp import Client
from mcp.client.stdio import StdioServerParameters


def _json(result: Any) -> dict[str, Any]:
    assert not result.is_error, result.content
    if result.structured_content is not None:
        return dict(result.structured_content.get("result", result.structured_content))
    return dict(json.loads(result.content[0].text))


@pytest.mark.slow
def test_mcp_stdio_session(tmp_path: Path) -> None:
    params = StdioServerParameters(command=sys.executable,
                                   args=["-m", "host", "mcp", "--lockstep", "--out", str(tmp_path / "mcp")])

    async def main() -> None:
        async with Client(params, read_timeout_seconds=120) as client:
            tools = {t.name for t in (await client.list_tools()).tools}
            assert {"run_program", "interrupt", "state", "capture"} <= tools
            res = await client.read_resource("ghostshell://functions")
            stubs = res.contents[0].text
            assert "def head_act" in stubs and "def run_distance" in stubs
            prompt = await client.get_prompt("system_prompt")
            assert "def head_act" in prompt.messages[0].content.text

            first = _json(await client.call_tool("run_program", {"xml": '<run_distance distance="10"/>Hi!'}))
            assert first["outcome"] == "done" and not first["fell"]
            fns = [c["function"] for c in first["timeline"]]
            assert "run_distance" in fns and "speak" in fns
            rd = next(c for c in first["timeline"] if c["function"] == "run_distance")
            assert rd["outcome"] == "done" and rd["end"] > rd["start"] >= 0
            x1 = _json(await client.call_tool("state", {}))["base"][0]
            assert x1 > 0.05  # it walked ~10 cm

            second = _json(await client.call_tool("run_program", {"xml": '<run_distance distance="10"/>'}))
            assert second["outcome"] == "done"
            x2 = _json(await client.call_tool("state", {}))["base"][0]
            assert x2 > x1 + 0.05  # same board, same robot: it continued from where it stood

            bad = _json(await client.call_tool("run_program", {"xml": '<head_act action="dance"/>'}))
            assert any("dance" in o for o in bad["observations"])  # a failing call is an observation
            assert _json(await client.call_tool("interrupt", {}))["cancelled"] == 0  # nothing running

            pic = await client.call_tool("capture", {})
            if not pic.is_error:
                (img,) = [c for c in pic.content if c.type == "image"]
                assert img.mime_type == "image/png" and base64.b64decode(img.data)[:8] == b"\x89PNG\r\n\x1a\n"
            else:  # no offscreen GL on this machine: a clear reason, not a crash
                assert "render" in pic.content[0].text.lower() or "camera" in pic.content[0].text.lower()

    anyio.run(main, backend="asyncio")
    assert (tmp_path / "mcp" / "board_frames.jsonl").exists()


@pytest.mark.slow
def test_mcp_streamable_http_on_localhost(tmp_path: Path) -> None:
    import socket
    import subprocess

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen([sys.executable, "-m", "host", "mcp", "--http", str(port), "--lockstep",
                             "--out", str(tmp_path / "mcp")], stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stderr is not None
        for line in proc.stderr:  # uvicorn announces the bound socket once the app (and the board) is up
            if "Uvicorn running on" in line:
                assert f"127.0.0.1:{port}" in line
                break
        else:
            pytest.fail(f"the server exited ({proc.wait()}) before listening")

        async def main() -> dict[str, Any]:
            async with Client(f"http://127.0.0.1:{port}/mcp", read_timeout_seconds=60) as client:
                ran = _json(await client.call_tool("run_program", {"xml": '<head_act action="nod" duration="1"/>'}))
                assert ran["outcome"] == "done"
                return _json(await client.call_tool("state", {}))

        st = anyio.run(main, backend="asyncio")
        assert st["busy"] is False and st["fell"] is False and st["board_time_s"] > 1.0
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def test_a_second_program_while_one_runs_is_a_clear_tool_error(tmp_path: Path) -> None:
    """In process (the SDK's in-memory client): the busy refusal reaches the client with its message."""
    from host.mcp_server.server import build_server
    from host.run.robot_session import SessionOptions

    server = build_server(SessionOptions(lockstep=True, out=tmp_path / "mcp"))

    async def main() -> None:
        async with Client(server) as client:
            async with anyio.create_task_group() as tg:
                first: list[Any] = []

                async def long_program() -> None:
                    first.append(await client.call_tool("run_program", {"xml": '<head_act action="nod" duration="60"/>'}))

                tg.start_soon(long_program)
                while not _json(await client.call_tool("state", {}))["running"]:
                    await anyio.sleep(0.01)  # poll the server's state (no timing assumption)
                busy = await client.call_tool("run_program", {"xml": '<head_act action="shake"/>'})
                assert busy.is_error and "already running" in busy.content[0].text
                assert _json(await client.call_tool("interrupt", {}))["cancelled"] >= 1
            assert _json(first[0])["outcome"] == "interrupted"

    anyio.run(main, backend="asyncio")
