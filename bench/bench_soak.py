"""Soak: many consecutive ``ghostshell run`` processes across robots, tasks, links, clocks and load; counts hangs.

Issue 41 ("timing you can trust on any robot and any load"): a run must end, whatever happens, with its
summary.json. Each run is a real ``ghostshell run`` subprocess (its own board, link and artefacts) of a
random task: CoCo's paper tasks (``--task N``, N in 1..30) or the arm's (``--robot arm --task N``,
robots/arm/tasks.json), over a random link: the pty (default), SLCAN on a pty (``--link can:slcan:pty``),
or python-can's virtual bus (``--link can:virtual:soak``: ``run`` refuses it at once with status 2, a
board subprocess cannot join an in-process bus, docs/guides/can.md; counted as ``refused``). Most runs are
lockstep (quick), ``--realtime-share`` of them realtime; every other run has a CPU hog on every core
(``bench/bench_latency.py``'s :func:`cpu_load`).

Every run has a wall timeout (``--timeout-s``): then it gets one SIGTERM (a first Ctrl-C: it must stop
within ~15 s with its summary), and SIGKILL ``--grace-s`` later. Printed per run: its case, exit status,
outcome, wall time, the summary's lag p99 and watchdog trips. At the end: how many runs, **hangs** (a run
that reached its timeout and left no summary.json), runs with a summary, timed-out runs that still wrote
one, the outcomes and exit statuses, wall-time percentiles, each with its n. A clean run's folder is
deleted (disk stays bounded); a hang's or any other outcome's is kept under ``--out``.

    nice python bench/bench_soak.py -n 200                 # ~1 h on 2 cores
    python bench/bench_soak.py -n 20 --realtime-share 0.5 --seed 3 --out /tmp/soak
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bench_latency import cpu_load

ROOT = Path(__file__).resolve().parent.parent
GHOSTSHELL = [sys.executable, "-m", "host"]
#: (robot, task ids): CoCo's paper tasks and the arm's (robots/arm/tasks.json)
TASKS: dict[str, range] = {"coco": range(1, 31), "arm": range(1, 16)}
#: link -> weight
LINKS: dict[str, float] = {"pty": 0.6, "can:slcan:pty": 0.3, "can:virtual:soak": 0.1}


@dataclass
class Case:
    """One run to make."""

    i: int
    robot: str
    task: int
    link: str
    lockstep: bool
    load: bool

    def argv(self, out: Path) -> list[str]:
        robot = [] if self.robot == "coco" else ["--robot", self.robot]
        return [*GHOSTSHELL, "run", *robot, "--task", str(self.task), "--link", self.link,
                "--lockstep" if self.lockstep else "--realtime", "--no-live", "--no-plots", "--out", str(out)]

    def label(self) -> str:
        return (f"{self.robot:<4} task {self.task:>2}  {self.link:<16} {'lockstep' if self.lockstep else 'realtime'}"
                f"{' +load' if self.load else '      '}")


@dataclass
class Result:
    """What one run did: ``status`` (None: killed), ``summary`` (None: none written), wall seconds."""

    case: Case
    status: int | None
    wall_s: float
    timed_out: bool
    summary: dict[str, Any] | None

    @property
    def hang(self) -> bool:
        return self.timed_out and self.summary is None

    @property
    def outcome(self) -> str:
        if self.summary is not None:
            return str(self.summary.get("outcome"))
        if self.status == 2:
            return "refused"
        return "hang" if self.hang else "no summary"


def cases(n: int, seed: int, realtime_share: float, links: dict[str, float]) -> list[Case]:
    """``n`` random cases (seeded); every other one under load."""
    rng = random.Random(seed)
    names, weights = list(links), list(links.values())
    out = []
    for i in range(n):
        robot = rng.choice(["coco", "coco", "arm"])
        out.append(Case(i, robot, rng.choice(TASKS[robot]), rng.choices(names, weights)[0],
                        rng.random() >= realtime_share, load=i % 2 == 1))
    return out


def run_one(case: Case, out: Path, timeout_s: float, grace_s: float) -> Result:
    """Run ``case`` into ``out``: SIGTERM once at ``timeout_s``, SIGKILL (its process group) ``grace_s`` later."""
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    log = open(out.with_suffix(".log"), "wb")
    t0 = time.monotonic()
    with log, (cpu_load(os.cpu_count() or 1) if case.load else nullcontext()):
        proc = subprocess.Popen(case.argv(out), stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                cwd=ROOT, env=env, start_new_session=True)
        timed_out = False
        try:
            try:
                status: int | None = proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                timed_out = True
                proc.send_signal(signal.SIGTERM)  # one signal, to the process alone: a first Ctrl-C
                try:
                    status = proc.wait(grace_s)
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
                    status = None
        except BaseException:  # Ctrl-C on the soak: the run (and its board) must not outlive it
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
            raise
    wall = time.monotonic() - t0
    summary = None
    try:
        summary = json.loads((out / "summary.json").read_text())
    except (OSError, ValueError):
        pass
    return Result(case, status, wall, timed_out, summary)


def line(r: Result, n: int) -> str:
    timing = (r.summary or {}).get("extra", {}).get("timing") or {}
    lag = timing.get("lag") or {}
    p99 = lag.get("p99_ms")
    trips = timing.get("watchdog_trips")
    return (f"[{r.case.i + 1:>4}/{n}] {r.case.label()}  status {r.status!s:>4}  {r.outcome:<11} {r.wall_s:6.1f} s"
            f"{'  TIMEOUT' if r.timed_out else ''}"
            + (f"  lag p99 {p99:.1f} ms" if isinstance(p99, (int, float)) else "")
            + (f"  trips {trips}" if isinstance(trips, int) else ""))


def report(results: list[Result]) -> list[str]:
    n = len(results)
    walls = np.asarray([r.wall_s for r in results]) if results else np.zeros(1)
    hangs = [r for r in results if r.hang]
    lines = [f"runs: {n}",
             f"hangs (timed out, no summary.json): {len(hangs)}"
             + (": " + "; ".join(f"#{r.case.i + 1} {r.case.label().strip()}" for r in hangs) if hangs else ""),
             f"runs with summary.json: {sum(r.summary is not None for r in results)}",
             f"timed out but wrote a summary after the SIGTERM: {sum(r.timed_out and r.summary is not None for r in results)}",
             "outcomes: " + ", ".join(f"{k} {v}" for k, v in Counter(r.outcome for r in results).most_common()),
             "exit statuses: " + ", ".join(f"{k} {v}" for k, v in Counter(str(r.status) for r in results).most_common()),
             f"wall s: p50 {np.percentile(walls, 50):.1f}  p99 {np.percentile(walls, 99):.1f}  max {walls.max():.1f}  (n={n})"]
    for load in (False, True):
        timings = [((r.summary or {}).get("extra", {}).get("timing") or {}) for r in results if r.case.load == load]
        lags: list[float] = [t["lag"]["p99_ms"] for t in timings
                             if isinstance((t.get("lag") or {}).get("p99_ms"), (int, float))]
        trips: list[int] = [t["watchdog_trips"] for t in timings if isinstance(t.get("watchdog_trips"), int)]
        if lags:
            lines.append(f"{'under load' if load else 'no load   '}: per-run lag p99 median {np.median(lags):.1f} ms, "
                         f"worst {max(lags):.1f} ms (n={len(lags)}); watchdog trips total {sum(trips)} in "
                         f"{sum(t > 0 for t in trips)} of {len(trips)} runs")
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("-n", type=int, default=200, help="runs (default 200)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--realtime-share", type=float, default=0.2, help="share of realtime runs (default 0.2)")
    ap.add_argument("--timeout-s", type=float, default=240.0, help="wall seconds per run before its SIGTERM (default 240)")
    ap.add_argument("--grace-s", type=float, default=30.0, help="wall seconds after the SIGTERM before SIGKILL (default 30)")
    ap.add_argument("--links", default=",".join(LINKS), help=f"comma-separated links (default {','.join(LINKS)})")
    ap.add_argument("--out", default=None, help="keep failed runs' folders here (default: a temporary folder)")
    ap.add_argument("--json", default=None, metavar="FILE", help="write every run's result as JSON")
    ap.add_argument("--max-wall-s", type=float, default=None,
                    help="start no new run after this many wall seconds (the counts cover the runs made)")
    args = ap.parse_args()
    if args.n < 1 or not 0 <= args.realtime_share <= 1 or not args.timeout_s > 0:
        ap.error("need -n >= 1, 0 <= --realtime-share <= 1 and --timeout-s > 0")
    links = {k: LINKS.get(k, 0.1) for k in args.links.split(",") if k}
    root = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="soak-"))
    root.mkdir(parents=True, exist_ok=True)
    todo = cases(args.n, args.seed, args.realtime_share, links)
    print(f"soak: {args.n} runs, seed {args.seed}, realtime share {args.realtime_share:g}, every other run with a "
          f"CPU hog on each of {os.cpu_count()} cores, timeout {args.timeout_s:g} s + {args.grace_s:g} s; "
          f"load average at start {os.getloadavg()[0]:.1f}; folders in {root}", flush=True)
    results: list[Result] = []
    started = time.monotonic()
    try:
        for case in todo:
            if args.max_wall_s is not None and time.monotonic() - started > args.max_wall_s:
                print(f"--max-wall-s {args.max_wall_s:g}: stopping after {len(results)} of {args.n} runs", flush=True)
                break
            out = root / f"run_{case.i + 1:04d}"
            r = run_one(case, out, args.timeout_s, args.grace_s)
            results.append(r)
            print(line(r, args.n), flush=True)
            clean = r.outcome == "done" and r.status == 0 and not r.timed_out
            if clean or r.outcome == "refused":
                shutil.rmtree(out, ignore_errors=True)
                out.with_suffix(".log").unlink(missing_ok=True)
    except KeyboardInterrupt:
        print(f"stopped after {len(results)} runs", flush=True)
    print("\n".join(report(results)), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps([{"case": r.case.__dict__, "status": r.status, "wall_s": r.wall_s,
                                                 "timed_out": r.timed_out, "outcome": r.outcome}
                                                for r in results], indent=1))
    return 1 if any(r.hang for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
