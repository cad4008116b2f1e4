"""Tracking recovery after a short link cut, over serial (pty) and CAN (SLCAN on a pty), realtime.

Each run walks (``move_strides`` x8, ~5.5 s) on a realtime emulated board with ``--faults cut=START+LENGTH``
(wall seconds = board seconds on a realtime board; shorter than watchdog + crouch delay, so the board
only HOLDs). Several cut starts put the resume at different gait phases. From the board's own log
(:mod:`host.run.tracking`): how long the board held, the time from the first valid message after
the cut until every servo is within 3 deg of the target of the last frame it applied for good, and
the peak error after the cut ("peak deg") and the largest after recovery to the end of the run
("then max"). Realtime: numbers depend on the machine's load (TICK_OVERRUNs).

    python bench/bench_recovery.py [--links pty can:slcan:pty] [--starts 3.0 3.1 3.2 3.3 3.4] [--length 0.6] [--out DIR]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

import anyio

from host.run.runner import RunOptions, run_program
from host.run.tracking import recovery_after_hold

PROGRAM = '<move_strides direction="forward" times="8"/>'


def one(link: str, start: float, length: float, out: Path, bound: float) -> tuple[float, float | None, float, float]:
    opts = RunOptions(program=PROGRAM, out=out, lockstep=False, link=link, faults=f"cut={start:g}+{length:g}")
    report = anyio.run(run_program, opts, backend="asyncio")
    if {c.outcome for c in report.calls} != {"done"}:
        raise SystemExit(f"{link} cut={start:g}+{length:g}: the run did not complete: {[c.outcome for c in report.calls]}")
    resumed, held, rec = recovery_after_hold(out, bound, not_before_s=start)
    walk = report.calls[0]
    if walk.start is None or walk.end is None or not walk.start < resumed - held < resumed < walk.end:
        raise SystemExit(f"{link} cut={start:g}+{length:g}: the hold ({resumed - held:.3f}-{resumed:.3f} s) "
                         f"is not inside the walk ({walk.start}-{walk.end} s)")
    return held, rec.seconds, rec.peak_deg, rec.after_deg


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--links", nargs="*", default=["pty", "can:slcan:pty"])
    ap.add_argument("--starts", type=float, nargs="*", default=[3.0, 3.1, 3.2, 3.3, 3.4])
    ap.add_argument("--length", type=float, default=0.6, help="cut length, s (default 0.6)")
    ap.add_argument("--bound", type=float, default=3.0, help="tracking bound, deg (default 3)")
    ap.add_argument("--out", type=Path, help="keep each run's folder (logs, summary) under this directory")
    args = ap.parse_args()
    print(f"{'link':15s} {'cut':9s} {'held s':>7s} {'recover s':>9s} {'peak deg':>8s} {'then max':>8s}")
    with tempfile.TemporaryDirectory(prefix="bench_recovery_") as scratch:
        tmp = args.out or Path(scratch)
        for link in args.links:
            times: list[float] = []
            for k, start in enumerate(args.starts):
                held, sec, peak, then = one(link, start, args.length, Path(tmp) / f"{k}_{link.replace(':', '_')}", args.bound)
                shown = "never" if sec is None else f"{sec:.3f}"
                cut = f"{start:g}+{args.length:g}"
                print(f"{link:15s} {cut:9s} {held:7.3f} {shown:>9s} {peak:8.2f} {then:8.2f}", flush=True)
                times.append(float("inf") if sec is None else sec)
            print(f"{link:15s} recovery within {args.bound:g} deg: median {statistics.median(times):.3f} s, "
                  f"max {max(times):.3f} s over {len(times)} cuts", flush=True)


if __name__ == "__main__":
    main()
