"""Realtime under load (issue 41): a task run N times per board with a CPU hog on every core.

For each board (``--firmware python|c|qemu``) the task (default 26: ears, nods, two steps, with music)
runs ``--runs`` times realtime (``ghostshell run --task T --firmware F --realtime --no-live --no-plots``)
while a busy-loop subprocess per core runs at nice 0 (``bench/bench_latency.py``'s ``cpu_load``). The
runs and the hogs keep the priority they get (the runs' boards raise their own:
:mod:`firmware_sim.priority`). Printed per board: the outcomes (``done``, ``link_lost``, ...) with n,
how many runs reported a dead servo (``stopped answering`` in the board's stderr: with a healthy plant
this must stay 0), how many said the emulation could not keep up (``realtime_behind`` in
summary.json, or the C firmware's lateness record read with :mod:`host.run.realtime_health`), and the
largest servo-bus silence and plant lag the C firmware's boards reported (ms). The 1-minute load
average at the start is printed; numbers depend on the machine and its load and are never asserted.

    python bench/bench_realtime_load.py                          # 10 runs x python, c, qemu (~15 min)
    python bench/bench_realtime_load.py --firmware qemu --runs 3 # a few QEMU runs
    python bench/bench_realtime_load.py --no-load                # the same without the hogs
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import tempfile
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_latency import cpu_load, load_1min  # noqa: E402

from host.run.realtime_health import add_realtime_behind, board_lateness  # noqa: E402


def one_run(firmware: str, task: int, out: Path, max_board_s: float) -> dict[str, Any]:
    """One ``ghostshell run``; returns ``{"outcome", "status", "dead_servo", "behind", "lateness", "wall_s"}``."""
    cmd = [sys.executable, "-m", "host", "run", "--task", str(task), "--firmware", firmware, "--realtime",
           "--no-live", "--no-plots", "--max-board-s", str(max_board_s), "--out", str(out)]
    t0 = time.monotonic()
    p = subprocess.run(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                       env=dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl")), timeout=600)
    wall = time.monotonic() - t0
    try:
        summary = json.loads((out / "summary.json").read_text())
    except (OSError, ValueError):
        summary = {"outcome": "no summary", "extra": {}}
    extra = summary.get("extra") or {}
    err = out / "board.stderr"
    text = err.read_text(errors="replace") if err.exists() else ""
    behind = extra.get("realtime_behind")
    if behind is None and add_realtime_behind(extra, err) is not None:  # a session that does not record it yet
        behind = extra["realtime_behind"]
    return {"outcome": summary.get("outcome"), "status": p.returncode, "wall_s": wall,
            "dead_servo": "stopped answering" in text or "stopped answering" in p.stderr,
            "behind": behind is not None, "lateness": board_lateness(err) or {},
            "last_line": (p.stderr.strip().splitlines() or [""])[-1][:160]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--firmware", action="append", choices=["python", "c", "qemu"],
                    help="board(s) to run (repeatable; default all three)")
    ap.add_argument("--runs", type=int, default=10, help="runs per board (default 10)")
    ap.add_argument("--task", type=int, default=26)
    ap.add_argument("--no-load", action="store_true", help="no CPU hogs")
    ap.add_argument("--max-board-s", type=float, default=60.0, help="each run's board-time bound (default 60)")
    ap.add_argument("--out", type=Path, default=Path(tempfile.gettempdir()) / "bench_realtime_load")
    ap.add_argument("--json", type=Path, default=None, help="also write every run's record here")
    args = ap.parse_args()
    if args.runs < 1:
        ap.error("--runs: must be at least 1")  # one usage line and exit status 2, as argparse refuses
    if args.max_board_s <= 0:
        ap.error("--max-board-s: must be > 0")
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        ap.error(f"--out: cannot make {args.out}: {e.strerror}")
    boards = args.firmware or ["python", "c", "qemu"]
    records: dict[str, list[dict[str, Any]]] = {}
    hogs_n = 0 if args.no_load else (os.cpu_count() or 1)
    print(f"task {args.task} realtime, {args.runs} run(s) per board on {', '.join(boards)}; "
          f"{hogs_n} busy-loop hog(s) at nice {os.nice(0)}; 1-min load average at start {load_1min():.2f} "
          f"on {os.cpu_count()} cores", flush=True)
    with cpu_load(hogs_n):
        for fw in boards:
            records[fw] = []
            for k in range(args.runs):
                rec = one_run(fw, args.task, args.out / f"{fw}-{k}", args.max_board_s)
                records[fw].append(rec)
                lat = rec["lateness"]
                print(f"  {fw} run {k + 1}: {rec['outcome']} (exit {rec['status']}, {rec['wall_s']:.0f} s)"
                      f"{'; DEAD SERVO reported' if rec['dead_servo'] else ''}"
                      f"{'; could not keep up' if rec['behind'] else ''}"
                      + (f"; bus silent max {lat.get('bus_silent_max_ms', 0)} ms, plant behind max "
                         f"{lat.get('plant_behind_max_ms', 0)} ms" if lat else ""), flush=True)
    for fw, recs in records.items():
        outcomes = Counter(str(r["outcome"]) for r in recs)
        dead = sum(r["dead_servo"] for r in recs)
        behind = sum(r["behind"] for r in recs)
        silent = [r["lateness"].get("bus_silent_max_ms", 0) for r in recs if r["lateness"]]
        print(f"{fw:<7} n={len(recs)}  outcomes {dict(outcomes)}  dead-servo reports {dead}  "
              f"'could not keep up' {behind}" + (f"  bus silent max {max(silent)} ms" if silent else ""))
    if args.json is not None:
        args.json.write_text(json.dumps(records, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
