"""Eval scaling: ``ghostshell eval --llm ground-truth`` wall time with 1 and N workers (prints numbers, asserts nothing).

Each round runs the sweep once per setting in the same order (``--workers 1``, ``--workers 2``, ...,
then ``--ray ADDRESS`` if given), each a fresh ``python -m host eval ... --quiet`` into its own
folder, so the settings are paired and interleaved (w1, w2, w1, w2, ...): on a shared machine the load
moves between rounds, and a ratio of two runs far apart says little. Per run it prints the wall time,
the CPU seconds of the command and its children (host worker processes and boards; a Ray cluster's
workers are not its children, so not counted), ``/proc/loadavg`` before it and the micro/macro line;
then per setting the median and the speed-up of each setting over ``--workers 1``, round by round and
of the medians.

Run: ``MUJOCO_GL=egl .venv/bin/python bench/bench_eval.py [--rounds 2] [--workers 1,2] [--tasks 1-30]
[--no-plots] [--ray ADDRESS]``. The 30 paper tasks, 1 trial: ~20-40 s a run on 2 cores.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _loadavg() -> str:
    try:
        return " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return "?"


def _children_cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_once(out: Path, tasks: str, extra: list[str]) -> tuple[float, float, str, int]:
    """One sweep: (wall s, CPU s of it and its children, its micro/macro line, exit status)."""
    cmd = [sys.executable, "-m", "host", "eval", "--llm", "ground-truth", "--trials", "1", "--tasks", tasks,
           "--quiet", "--out", str(out), *extra]
    cpu0 = _children_cpu_s()
    t0 = time.monotonic()
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, stdin=subprocess.DEVNULL)
    wall = time.monotonic() - t0
    line = next((ln for ln in r.stdout.splitlines() if ln.startswith("micro")), r.stderr.strip()[-200:])
    return wall, _children_cpu_s() - cpu0, line, r.returncode


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=2, help="runs of each setting, interleaved (default 2)")
    ap.add_argument("--workers", default="1,2", help="worker counts, comma-separated (default 1,2)")
    ap.add_argument("--tasks", default="1-30", help="eval --tasks (default 1-30, the paper's tasks)")
    ap.add_argument("--no-plots", action="store_true", help="pass --no-plots (no timeline/joints plots per run)")
    ap.add_argument("--ray", default=None, metavar="ADDRESS",
                    help="also run on this Ray cluster each round, with the largest --workers in flight")
    ap.add_argument("--keep", type=Path, default=None, help="keep the eval folders here (default: a temp folder)")
    args = ap.parse_args()
    try:
        counts = [int(w) for w in args.workers.split(",")]
    except ValueError:
        counts = []
    if args.rounds < 1 or not counts or min(counts) < 1:
        print("error: --rounds >= 1 and --workers a list of whole numbers >= 1 (e.g. 1,2)", file=sys.stderr)
        return 2
    settings = [(f"w{w}", ["--workers", str(w)]) for w in counts]
    if args.ray:
        settings.append((f"ray w{max(counts)}", ["--workers", str(max(counts)), "--ray", args.ray]))
    plots = ["--no-plots"] if args.no_plots else []
    walls: dict[str, list[float]] = {name: [] for name, _ in settings}
    print(f"eval --llm ground-truth --tasks {args.tasks} --trials 1{' --no-plots' if plots else ''}; "
          f"{os.cpu_count()} CPUs; {args.rounds} round(s)")
    with tempfile.TemporaryDirectory(prefix="bench_eval_") as tmp:
        base = args.keep or Path(tmp)
        for k in range(args.rounds):
            for name, extra in settings:
                load = _loadavg()
                out = base / f"r{k}-{re.sub(r'[^a-z0-9]+', '-', name)}"
                wall, cpu, line, status = run_once(out, args.tasks, extra + plots)
                walls[name].append(wall)
                print(f"round {k + 1} {name:>8}: {wall:6.1f} s wall, {cpu:6.1f} CPU-s, load {load}, exit {status}: {line}",
                      flush=True)
    ref = walls[settings[0][0]]
    print(f"after: load {_loadavg()}")
    for name, _ in settings:
        w = walls[name]
        ratios = ", ".join(f"{a / b:.2f}" for a, b in zip(ref, w))
        print(f"{name:>8}: median {statistics.median(w):.1f} s (n = {len(w)}); speed-up over {settings[0][0]} "
              f"round by round {ratios}, of the medians {statistics.median(ref) / statistics.median(w):.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
