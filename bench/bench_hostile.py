"""Hostile LLM output through the whole shell (parser, mapper, scheduler, speech) on virtual time.

Two workloads, each fed in 16-character chunks to :class:`host.shell.shell.Shell` running on Trio's
``MockClock`` (so speech "plays" for its words-per-minute duration without wall-clock waiting):

* ``text``: N MB of plain prose (sentences) spoken through a simulated speaker;
* ``calls``: N tiny self-closing calls on one channel (``<nod/>`` x N).

Prints wall-clock seconds and throughput for each size with the limits lifted, so the growth
(linear or not) is visible, then the same hostile inputs under the default :class:`TurnLimits`.

    python bench/bench_hostile.py [--mb 0.5 1 2] [--calls 1000 2500 5000]
"""

from __future__ import annotations

import argparse
import time

import trio
from trio.testing import MockClock

from host.shell.limits import TurnLimits
from host.shell.registry import Registry
from host.shell.shell import Shell
from host.shell.types import Module, shell_function
from host.speech.tts import estimate_duration_s

PROSE = "The quick brown fox jumps over the lazy dog, and then it rests a while. "


def registry() -> Registry:
    @shell_function(speech=True)
    async def speak(text: str) -> None:
        """Say ``text``."""
        await trio.sleep(estimate_duration_s(text))

    async def nod(times: int = 1) -> None:
        """Nod."""
        await trio.sleep(0.01)

    return Registry([Module.from_functions("speak", speak, channel="speech"),
                     Module.from_functions("head", nod, channel="head")])


RAW = TurnLimits(max_text_chars=10**9, max_calls=10**9, max_queued_per_channel=10**9)


def run(text: str, chunk: int = 16, limits: TurnLimits | None = RAW) -> tuple[float, int]:
    shell = Shell(registry(), strict=False, limits=limits)
    pieces = [text[i : i + chunk] for i in range(0, len(text), chunk)]
    t0 = time.perf_counter()
    result = trio.run(shell.run_text, pieces, clock=MockClock(autojump_threshold=0))
    return time.perf_counter() - t0, len(result.timeline)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=float, nargs="*", default=[0.5, 1, 2])
    ap.add_argument("--calls", type=int, nargs="*", default=[1000, 2500, 5000])
    a = ap.parse_args()
    for mb in a.mb:
        text = PROSE * (int(mb * 1e6) // len(PROSE))
        s, n = run(text)
        print(f"text  {mb:5.2f} MB  {s:7.2f} s  {len(text) / 1e6 / s:6.2f} MB/s  ({n} calls)")
    for n_calls in a.calls:
        s, n = run("<nod/>" * n_calls)
        print(f"calls {n_calls:7d}  {s:7.2f} s  {n_calls / s:8.0f} calls/s  ({n} calls)")
    big = PROSE * (2_000_000 // len(PROSE))
    s, n = run(big, limits=None)
    print(f"default limits: 2 MB of text {s:.2f} s ({n} speech calls before the speech queue limit)")
    s, n = run("<nod/>" * 20_000, limits=None)
    print(f"default limits: 20000 calls {s:.2f} s ({n} on the timeline)")


if __name__ == "__main__":
    main()
