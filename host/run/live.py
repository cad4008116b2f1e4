"""A live view of a run: what each channel is doing, on the board clock (rich).

Cost: the table is built on the event loop every ``period_s`` (a pass over the timeline's records) and
drawn by rich's refresh thread, in Python, holding the GIL (~6 ms a draw on a loaded machine; the loop
waits meanwhile). It is drawn as often as it changes (``1 / period_s``, 4 per second), not rich's
default of 8 a second with every other draw the same table: half the GIL time taken from the loop.
"""

from __future__ import annotations

import sys

import anyio
from rich.console import Console
from rich.live import Live
from rich.table import Table

from host.runtime.robot_runtime import RobotRuntime
from host.shell import Shell
from host.shell.timeline import Timeline


def channels(shell: Shell) -> list[str]:
    """The rows of the view: the main channel, then every channel of a visible mounted module."""
    out = ["main"]
    for m in shell.registry.modules():
        if not getattr(m, "hidden", False) and m.channel and m.channel not in out:
            out.append(m.channel)
    return out


def _table(shell: Shell, runtime: RobotRuntime, label: str, last: list[Timeline] | None = None) -> Table:
    """The channel table; ``last`` remembers the latest timeline so it stays shown between turns."""
    now = runtime.board_now_s()
    table = Table(title=f"{label}   board time {now:7.2f} s", title_justify="left", expand=False)
    table.add_column("channel", style="bold")
    table.add_column("running now")
    table.add_column("done", justify="right")
    table.add_column("last finished")
    tl = shell.timeline
    if last is not None:
        if tl is not None:
            last[:] = [tl]
        elif last:
            tl = last[0]
    records = list(tl) if tl is not None else []
    for ch in channels(shell):
        mine = [r for r in records if r.channel == ch]
        running = [r for r in mine if r.start is not None and r.end is None]
        finished = [r for r in mine if r.end is not None]
        now_txt = ", ".join(f"{r.function}{_args(r.args)}{' (held)' if r.persistent else ''}" for r in running)
        last = finished[-1] if finished else None
        table.add_row(ch, now_txt or "[dim]-[/dim]", str(len(finished)),
                      f"{last.function} [{last.outcome}]" if last else "")
    return table


def _args(args: dict) -> str:
    if not args:
        return ""
    text = " ".join(f"{k}={v!r}" if isinstance(v, str) else f"{k}={v}" for k, v in args.items())
    return f"({text[:40]})"


async def live_view(shell: Shell, runtime: RobotRuntime, label: str, period_s: float = 0.25) -> None:
    """Redraw the channel table until cancelled (only on a terminal)."""
    if not sys.stdout.isatty():
        await anyio.sleep_forever()
    console = Console()
    last: list[Timeline] = []
    with Live(_table(shell, runtime, label, last), console=console, refresh_per_second=1 / period_s,
              transient=False) as live:
        while True:
            await anyio.sleep(period_s)
            live.update(_table(shell, runtime, label, last))
