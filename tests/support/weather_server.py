"""A small MCP server (official SDK, ``MCPServer``) for the ``--mount-mcp`` tests.

Run: ``python tests/support/weather_server.py [--http PORT] [--die-on-call] [--flood] [--fail-start]
[--hang-start]`` (stdio unless ``--http``; ``--http 0`` picks a free port, announced by uvicorn on
stderr as ``Uvicorn running on http://127.0.0.1:PORT``).

Tools:

* ``get_forecast(city, days=1 (1..7))``: a made-up forecast (text); with ``--die-on-call`` the
  process prints a last word on stderr and exits with status 3 instead of answering;
* ``convert(amount > 0, unit="C"|"F")``: structured output (exclusive minimum, enum);
* ``tag(labels: list[str], sync=False)``: an array of scalars and a parameter called ``sync``;
* ``fail(message)``: a tool error (``isError``) carrying ``message``;
* ``slow(seconds=60)``: sleeps; a cancellation is recorded as the event ``cancelled slow``;
* ``events(wait_for=None, timeout=10)``: the events so far, after waiting (on an event, up to
  ``timeout``) for ``wait_for`` to have happened;
* ``junk(lines=1000)``: writes ``lines`` non-JSON lines (and a 2 MiB line with no JSON) onto the
  JSON-RPC stream and as much again on stderr, then answers;
* ``plot(where: Point)``: an object parameter (the mount skips this tool);
* ``get forecast!``: a tool name that is not an XML name (``get_forecast`` is taken too);
* ``describe(style: Style | None = None)``: an optional object parameter (the mount drops it).

``--flood`` writes 20 000 junk lines, one 3 MiB line and 4 MiB of stderr before serving;
``--fail-start`` exits 2 with a message before serving; ``--hang-start`` never serves.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import Annotated, Any, Literal

import anyio
from pydantic import BaseModel, Field

from mcp.server.mcpserver import MCPServer
from mcp.server.mcpserver.exceptions import ToolError


class Point(BaseModel):
    x: float
    y: float


class Style(BaseModel):
    colour: str = "blue"


def build(die_on_call: bool) -> MCPServer[Any]:
    server = MCPServer(name="weather-test", instructions="Made-up weather for tests.")
    events: list[str] = []
    changed = anyio.Event()

    def record(event: str) -> None:
        nonlocal changed
        events.append(event)
        changed.set()
        changed = anyio.Event()

    @server.tool()
    async def get_forecast(city: Annotated[str, Field(description="City name, e.g. Lisbon", max_length=40)],
                           days: Annotated[int, Field(ge=1, le=7, description="How many days")] = 1) -> str:
        """Get the weather forecast for a city."""
        if die_on_call:
            print("weather: simulated crash while answering get_forecast", file=sys.stderr, flush=True)
            os._exit(3)
        record(f"get_forecast {city} {days}")
        return f"{city}: sunny, 21 C for {days} day(s)"

    @server.tool()
    async def convert(amount: Annotated[float, Field(gt=0, le=1000)], unit: Literal["C", "F"] = "C") -> dict[str, Any]:
        """Convert a temperature to the other unit."""
        other = amount * 9 / 5 + 32 if unit == "C" else (amount - 32) * 5 / 9
        return {"value": round(other, 2), "unit": "F" if unit == "C" else "C"}

    @server.tool()
    async def tag(labels: Annotated[list[str], Field(max_length=3)], sync: bool = False) -> str:
        """Tag the forecast with labels."""
        return f"tagged {labels} sync={sync}"

    @server.tool()
    async def fail(message: str = "no weather today") -> str:
        """Always fails with `message`."""
        raise ToolError(message)

    @server.tool()
    async def slow(seconds: float = 60.0) -> str:
        """Sleep for `seconds`."""
        record("started slow")
        try:
            await anyio.sleep(seconds)
        except anyio.get_cancelled_exc_class():
            record("cancelled slow")
            raise
        return "slept"

    @server.tool(name="events")
    async def list_events(wait_for: str | None = None, timeout: float = 10.0) -> list[str]:
        """The events seen so far (after waiting up to `timeout` s for `wait_for`)."""
        with anyio.move_on_after(timeout):
            while wait_for is not None and wait_for not in events:
                await changed.wait()
        return list(events)

    @server.tool()
    async def junk(lines: int = 1000) -> str:
        """Write junk onto the JSON-RPC stream and stderr."""
        from mcp.server import stdio as sdk_stdio

        claim = sdk_stdio._claims.get(1)  # the JSON-RPC wire (fd 1 itself points at stderr while serving)
        wire = claim.private_fd if claim is not None and claim.private_fd is not None else 1
        payload = b"".join(b"junk line %d {not json\n" % i for i in range(lines))
        os.write(wire, payload + b"x" * (2 * 1024 * 1024) + b"\n")
        os.write(2, payload)
        return f"wrote {lines} junk lines"

    @server.tool()
    async def plot(where: Point) -> str:
        """Plot a point (an object parameter)."""
        return f"plotted {where}"

    @server.tool(name="get forecast!")
    async def bad_name(city: str) -> str:
        """A tool whose name is not an XML name."""
        return f"bad name answered for {city}"

    @server.tool()
    async def describe(style: Style | None = None) -> str:
        """Describe the weather (the style parameter is an object)."""
        return "described"

    return server


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--http", type=int, default=None)
    ap.add_argument("--die-on-call", action="store_true")
    ap.add_argument("--flood", action="store_true")
    ap.add_argument("--fail-start", action="store_true")
    ap.add_argument("--hang-start", action="store_true")
    args = ap.parse_args()
    if args.fail_start:
        print("weather: cannot start: no API key configured", file=sys.stderr, flush=True)
        sys.exit(2)
    if args.hang_start:
        while True:
            time.sleep(3600)
    if args.flood:
        junk = b"".join(b"flood line %d: not json at all\n" % i for i in range(20_000))
        os.write(1, junk + b"y" * (3 * 1024 * 1024) + b"\n")
        os.write(2, b"e" * (4 * 1024 * 1024) + b"\nweather: flood done\n")
    server = build(args.die_on_call)
    if args.http is not None:
        server.run("streamable-http", host="127.0.0.1", port=args.http)
    else:
        server.run("stdio")


if __name__ == "__main__":
    main()
