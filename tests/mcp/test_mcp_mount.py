"""MCP servers mounted as shell functions (``host.mounts``), through the shell.

The servers are real subprocesses (``tests/support/weather_server.py``, official SDK), so these
tests run on real time: every wait is on a result or on the server's own event log (its
``events`` tool waits for an event), bounded by ``fail_after`` only as a hang guard.
"""

from __future__ import annotations

import contextlib
import re
import subprocess
import sys
import threading
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import anyio
import pytest

from host.mounts import McpCallError, McpMountError, MountOptions, MountSpec, mounted
from host.mounts.mcp_mount import McpMount
from host.shell.registry import Registry
from host.shell.shell import Shell
from host.shell.types import Module

SERVER = Path(__file__).resolve().parents[1] / "support" / "weather_server.py"
GUARD = 60  # seconds: a hang guard, never a synchronisation

pytestmark = pytest.mark.anyio


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"  # what the CLI runs on; the cancellation and failure paths also run on trio (BOTH)


BOTH = pytest.mark.parametrize("anyio_backend", ["asyncio", "trio"])


def weather_spec(*flags: str, name: str = "weather") -> MountSpec:
    return MountSpec(name, command=(sys.executable, str(SERVER), *flags))


@contextlib.asynccontextmanager
async def weather(*flags: str, registry: Registry | None = None, **options: Any) -> AsyncIterator[tuple[Shell, McpMount]]:
    reg = registry if registry is not None else Registry()
    async with mounted([weather_spec(*flags)], registry=reg, options=MountOptions(**options)) as mounts:
        yield Shell(reg), mounts[0]


async def events(mount: McpMount, wait_for: str | None = None) -> list[str]:
    """The server's event log, once ``wait_for`` is in it (the server waits on an event, up to 10 s)."""
    args: dict[str, Any] = {} if wait_for is None else {"wait_for": wait_for}
    return list(await mount.call("events", args))


async def test_prompt_shows_the_tools_as_typed_functions_with_notes() -> None:
    with anyio.fail_after(GUARD):
        async with weather() as (shell, mount):
            prompt = shell.prompt()
            assert "# module weather (channel weather): tools of the MCP server weather-test" in prompt
            assert ("def weather.get_forecast(\n    city: str,  # at most 40 characters\n"
                    "    days: int = 1,  # 1..7\n) -> None:") in prompt
            assert "Get the weather forecast for a city." in prompt and "city: City name, e.g. Lisbon" in prompt
            assert 'unit: Literal["C", "F"] = "C"' in prompt and "amount: float,  # > 0, <= 1000" in prompt
            assert "labels: list[str],  # at most 3 items" in prompt
            xml = shell.prompt("xml")
            assert '<weather.get_forecast city="..." days="1"/>' in xml and "greater than 0" in xml
            notes = "\n".join(mount.notes)
            # unsupported schema: the tool is skipped, with a note naming it and the construct
            assert "tool 'plot' skipped: parameter 'where' is an object" in notes
            assert "def weather.plot" not in prompt and "not available here: 'plot'" in prompt
            # an optional parameter that cannot be expressed is left out, the tool stays
            assert "optional parameter 'style' left out" in notes and "def weather.describe() -> None" in prompt
            # names: not an XML name -> mapped, clash with get_forecast -> suffixed; sync -> sync_
            assert "'get forecast!' is called <weather.get_forecast_2>" in notes
            assert "parameter 'sync' is the attribute sync_=" in notes
            assert mount.tools["weather.get_forecast_2"] == "get forecast!"
            assert all("\n" not in n for n in mount.notes)


@BOTH
async def test_a_call_returns_the_result_as_an_observation_beside_robot_functions(anyio_backend: str) -> None:
    nods: list[int] = []

    async def nod(times: int = 1) -> None:
        """Nod."""
        nods.append(times)

    reg = Registry([Module.from_functions("head", nod)])
    with anyio.fail_after(GUARD):
        async with weather(registry=reg) as (shell, mount):
            res = await shell.run_text('<nod times="2"/><weather.get_forecast city="Lisbon" days="3"/>'
                                       '<weather.convert amount="10"/><weather.tag labels=\'["sun", "wind"]\' sync_="true"/>'
                                       '<weather.get_forecast_2 city="Porto"/>')
            assert nods == [2]
            rec = res.timeline.one("weather.get_forecast")
            assert rec.outcome == "done" and rec.channel == "weather" and rec.args == {"city": "Lisbon", "days": 3}
            assert rec.result == "Lisbon: sunny, 21 C for 3 day(s)"
            assert ("[result weather.get_forecast[0]] weather.get_forecast returned "
                    "'Lisbon: sunny, 21 C for 3 day(s)'") in res.observation_text()
            assert res.timeline.one("weather.convert").result == {"value": 50.0, "unit": "F"}  # structured
            assert res.timeline.one("weather.tag").result == "tagged ['sun', 'wind'] sync=True"
            assert res.timeline.one("weather.get_forecast_2").result == "bad name answered for Porto"
            assert await events(mount) == ["get_forecast Lisbon 3"]
        assert "weather" not in [m.name for m in reg.modules()] and "nod" in reg  # unmounted on exit


async def test_the_mapper_refuses_bad_arguments_before_any_request() -> None:
    with anyio.fail_after(GUARD):
        async with weather() as (shell, mount):
            res = await shell.run_text(
                '<weather.get_forecast city="Lisbon" days="9"/><weather.get_forecast city="Lisbon" days="two"/>'
                '<weather.get_forecast days="2"/><weather.get_forecast city="Lisbon" hours="2"/>'
                f'<weather.get_forecast city="{"L" * 41}"/><weather.convert amount="0"/>'
                '<weather.convert amount="5" unit="K"/><weather.tag labels="sun"/>'
                '<weather.tag labels=\'["a", "b", "c", "d"]\'/><get_forecast city="Lisbon"/>')
            errors = [r.error for r in res.timeline]
            assert all(r.outcome == "failed" and r.start is None for r in res.timeline), res.timeline.table()
            assert "days='9' is out of range [1, 7]" in errors[0]
            assert "days='two' is not an integer" in errors[1]
            assert "missing required parameter(s): city" in errors[2]
            assert "has no parameter 'hours'" in errors[3]
            assert "at most 40 allowed" in errors[4]
            assert "must be greater than 0" in errors[5]
            assert "is not one of 'C', 'F'" in errors[6]
            assert "is not a JSON array" in errors[7]
            assert "4 items; at most 3 allowed" in errors[8]
            assert "unknown function <get_forecast>; did you mean weather.get_forecast" in errors[9]
            assert await events(mount) == []  # the server never heard of any of them


async def test_a_tool_error_or_protocol_error_fails_the_call_with_the_servers_message() -> None:
    with anyio.fail_after(GUARD):
        async with weather() as (shell, mount):
            res = await shell.run_text('<weather.fail message="the sky fell"/><weather.get_forecast city="Rome"/>')
            failed = res.timeline.one("weather.fail")
            assert failed.outcome == "failed" and "the sky fell" in (failed.error or "")
            assert "[error weather.fail[0]] weather.fail failed: McpCallError:" in res.observation_text()
            assert res.timeline.one("weather.get_forecast").outcome == "done"  # failures are local
            with pytest.raises(McpCallError, match="nope"):
                await mount.call("nope", {})


@BOTH
async def test_an_interrupt_cancels_the_request_and_the_server_sees_it(anyio_backend: str) -> None:
    with anyio.fail_after(GUARD):
        async with weather() as (shell, mount):
            results = []

            async def turn() -> None:
                results.append(await shell.run_text('<weather.slow seconds="60"/>'))

            async with anyio.create_task_group() as tg:
                tg.start_soon(turn)
                assert "started slow" in await events(mount, "started slow")
                assert shell.interrupt() == 1
            rec = results[0].timeline.one("weather.slow")
            assert rec.outcome == "interrupted" and results[0].interrupted
            assert "cancelled slow" in await events(mount, "cancelled slow")  # notifications/cancelled arrived
            res = await shell.run_text('<weather.get_forecast city="Oslo"/>')  # the server is still there
            assert res.timeline.one("weather.get_forecast").outcome == "done"


@BOTH
async def test_the_end_of_a_start_tags_lifecycle_cancels_its_request(anyio_backend: str) -> None:
    with anyio.fail_after(GUARD):
        async with weather() as (shell, mount):
            res = await shell.run_text('<weather.slow seconds="60"><weather.get_forecast city="Oslo"/></weather.slow>')
            assert res.timeline.one("weather.get_forecast").outcome == "done"
            assert res.timeline.one("weather.slow").end is not None
            assert "cancelled slow" in await events(mount, "cancelled slow")


@BOTH
async def test_a_call_with_no_answer_in_time_fails_and_is_cancelled(anyio_backend: str) -> None:
    with anyio.fail_after(GUARD):
        async with weather(call_timeout=0.5) as (shell, mount):
            res = await shell.run_text('<weather.slow seconds="60"/>')
            rec = res.timeline.one("weather.slow")
            assert rec.outcome == "failed"
            assert "no answer from MCP server 'weather' within 0.5 s; the request was cancelled" in (rec.error or "")
            assert "cancelled slow" in await events(mount, "cancelled slow")


@BOTH
async def test_a_server_dying_mid_call_fails_the_call_with_its_message_and_the_turn_ends(anyio_backend: str) -> None:
    with anyio.fail_after(GUARD):
        async with weather("--die-on-call") as (shell, mount):
            res = await shell.run_text('<weather.get_forecast city="Lisbon"/><weather.convert amount="3"/>')
            for rec in res.timeline:
                assert rec.outcome == "failed", res.timeline.table()
                assert "MCP server 'weather' exited with status 3" in (rec.error or "")
                assert "simulated crash while answering get_forecast" in (rec.error or "")
            assert not mount.connected
            with pytest.raises(McpCallError, match="exited with status 3"):
                await mount.call("get_forecast", {"city": "Oslo"})


async def test_a_server_that_cannot_start_is_one_clear_line() -> None:
    with anyio.fail_after(GUARD):
        with pytest.raises(McpMountError) as failed:
            async with weather("--fail-start"):
                pytest.fail("mounted a server that exited")
        msg = str(failed.value)
        assert "exited with status 2" in msg and "no API key configured" in msg and "\n" not in msg
        assert msg.startswith("--mount-mcp weather=")
        reg = Registry()  # the first server starts, the second cannot: the first is stopped again
        with pytest.raises(McpMountError, match="cannot start the server: FileNotFoundError"):
            async with mounted([weather_spec(), MountSpec("ghost", command=("/nonexistent/server",))], registry=reg):
                pytest.fail("mounted a missing command")
        assert reg.modules() == []  # nothing stays mounted


@BOTH
async def test_a_server_that_never_answers_fails_the_mount_at_its_timeout(anyio_backend: str) -> None:
    with anyio.fail_after(GUARD):
        with pytest.raises(McpMountError, match=r"gave no answer \(handshake and tools/list\) within 1 s"):
            async with weather("--hang-start", startup_timeout=1.0):
                pytest.fail("mounted a silent server")


async def test_a_flooding_server_is_bounded_and_still_answers() -> None:
    with anyio.fail_after(GUARD):
        async with weather("--flood", max_line=1024 * 1024) as (shell, mount):
            assert mount.stdio is not None
            stats = mount.stdio.stats
            assert stats.junk_lines == 20_000 and stats.oversized_lines == 1  # the 3 MiB line
            assert stats.first_junk.startswith("flood line 0")
            assert stats.max_buffered <= 1024 * 1024  # never held more than one line's limit
            assert stats.stderr_bytes > 4 * 1024 * 1024 and len(mount.stdio.stderr_tail(10_000)) <= 16 * 1024
            res = await shell.run_text('<weather.junk lines="5000"/><weather.get_forecast city="Lisbon"/>')
            assert [r.outcome for r in res.timeline] == ["done", "done"], res.timeline.table()
            assert stats.junk_lines == 25_000 and stats.oversized_lines == 2


async def test_mount_names_are_checked_before_anything_starts() -> None:
    async def nod() -> None:
        """Nod."""

    reg = Registry([Module.from_functions("head", nod)])
    with pytest.raises(McpMountError, match="'head' is already a module or channel of this shell"):
        async with mounted([MountSpec("head", command=("/nonexistent/server",))], registry=reg):
            pytest.fail("mounted over a robot module")
    with pytest.raises(McpMountError, match="NAME given twice"):
        async with mounted([weather_spec(), weather_spec()]):
            pytest.fail("mounted one name twice")


async def test_streamable_http_server_on_localhost() -> None:
    proc = subprocess.Popen([sys.executable, str(SERVER), "--http", "0"], stderr=subprocess.PIPE, text=True)
    ready = threading.Event()
    port: list[int] = []

    def drain() -> None:  # read uvicorn's stderr to the end (so the server never blocks on it)
        assert proc.stderr is not None
        for line in proc.stderr:
            m = re.search(r"Uvicorn running on http://127\.0\.0\.1:(\d+)", line)
            if m and not port:
                port.append(int(m.group(1)))
                ready.set()
        ready.set()

    threading.Thread(target=drain, daemon=True).start()
    try:
        assert await anyio.to_thread.run_sync(ready.wait, GUARD) and port, "the HTTP server did not start"
        spec = MountSpec("weather", url=f"http://127.0.0.1:{port[0]}/mcp")
        reg = Registry()
        with anyio.fail_after(GUARD):
            async with mounted([spec], registry=reg) as (mount,):
                shell = Shell(reg)
                res = await shell.run_text('<weather.get_forecast city="Lisbon" days="2"/>')
                assert res.timeline.one("weather.get_forecast").result == "Lisbon: sunny, 21 C for 2 day(s)"
                results = []

                async def turn() -> None:
                    results.append(await shell.run_text('<weather.slow seconds="60"/>'))

                async with anyio.create_task_group() as tg:
                    tg.start_soon(turn)
                    assert "started slow" in await events(mount, "started slow")
                    shell.interrupt()
                assert results[0].timeline.one("weather.slow").outcome == "interrupted"
                # over streamable HTTP the SDK aborts the request's POST; the server cancels the handler
                assert "cancelled slow" in await events(mount, "cancelled slow")
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    with anyio.fail_after(GUARD), pytest.raises(McpMountError, match="--mount-mcp weather=http://127.0.0.1"):
        async with mounted([MountSpec("weather", url=f"http://127.0.0.1:{port[0]}/mcp")]):
            pytest.fail("mounted a server that is not there")
