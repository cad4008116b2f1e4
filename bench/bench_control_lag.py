"""Control-path lag of realtime runs: the host event loop's scheduling delay and the board's watchdog trips.

Every frame, confirmation and token of a run goes through the host's one event loop; work that holds it
(recording, plotting) delays all of them, and past the board's watchdog (200 ms) the servos are held.
Each run's summary.json has ``extra.timing`` (:meth:`host.run.robot_session.RobotSession.timing`): the lag a
task sleeping 5 ms sees (p50/p99/max over the turn, :mod:`host.run.loop_lag`), frames late, watchdog
trips and the recording's drops. This runs ``ghostshell run`` (realtime, a real board subprocess, run.mcap
recorded) ``-n`` times for each case and prints those numbers per run, then per case the median of the
runs' p99 and the worst max, with n:

* ``coco-26``: CoCo's task 26 (music, ears, nods, a walk; ~26 s);
* ``arm-12``: the arm's task 12 (pick and place while speaking);
* ``mesh``: a 6-servo arm with 13 binary STL meshes (~100k triangles) behind an ``<include>``
  (``tests/support/mesh_robot.py``): home pose, then a 1-s joint move. The recording of its meshes used
  to run on the event loop (2 watchdog trips per run).

    python bench/bench_control_lag.py [-n 3] [--load] [--cases coco-26,arm-12,mesh] [--out DIR]

``--load``: a busy-loop subprocess per core meanwhile (``bench/bench_latency.py``'s :func:`cpu_load`).
Numbers depend on the machine and its load; they are printed, never asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import numpy as np

from bench_latency import cpu_load

ROOT = Path(__file__).resolve().parent.parent
MESH_PROGRAM = '<pose name="home"/><joint_move joint="shoulder_pan" deg="30" duration="1"/>'


def case_argv(name: str, mesh_robots: Path | None) -> list[str]:
    """The ``ghostshell run`` arguments of a case (without --out)."""
    if name == "coco-26":
        return ["--task", "26"]
    if name == "arm-12":
        return ["--robot", "arm", "--task", "12"]
    if name == "mesh":
        assert mesh_robots is not None
        return ["--robots-dir", str(mesh_robots), "--robot", "mesh_arm", "--xml", MESH_PROGRAM]
    raise SystemExit(f"unknown case {name!r}: coco-26, arm-12 or mesh")


def mesh_robot(folder: Path) -> Path:
    """The mesh arm's robots folder (tests/support/mesh_robot.py ``write_mesh_arm``)."""
    sys.path.insert(0, str(ROOT / "tests"))
    from support.mesh_robot import write_mesh_arm

    return Path(write_mesh_arm(folder))


def run_once(argv: list[str], out: Path, timeout_s: float) -> tuple[int | None, float, dict[str, Any] | None]:
    """One realtime run into ``out``: (exit status or None on timeout, wall s, summary.json or None)."""
    cmd = [sys.executable, "-m", "host", "run", *argv, "--realtime", "--no-live", "--no-plots", "--out", str(out)]
    t0 = time.monotonic()
    with open(out.with_suffix(".log"), "wb") as log:
        try:
            status: int | None = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT, timeout=timeout_s,
                                                env=dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))).returncode
        except subprocess.TimeoutExpired:
            status = None
    wall = time.monotonic() - t0
    try:
        return status, wall, json.loads((out / "summary.json").read_text())
    except (OSError, ValueError):
        return status, wall, None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("-n", type=int, default=3, help="runs per case (default 3)")
    ap.add_argument("--cases", default="coco-26,arm-12,mesh", help="comma-separated: coco-26, arm-12, mesh")
    ap.add_argument("--load", action="store_true", help="a CPU hog (busy-loop subprocess) on every core meanwhile")
    ap.add_argument("--timeout-s", type=float, default=300.0, help="wall seconds per run (default 300)")
    ap.add_argument("--out", default=None, help="the runs' folders (default: a temporary folder)")
    args = ap.parse_args()
    if args.n < 1:
        ap.error("-n must be >= 1")
    root = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="control-lag-"))
    root.mkdir(parents=True, exist_ok=True)
    names = [c for c in args.cases.split(",") if c]
    mesh = mesh_robot(root / "mesh_robot") if "mesh" in names else None
    hogs = os.cpu_count() or 1
    print(f"control-path lag, realtime, n={args.n} per case; "
          f"{f'under --load: {hogs} busy-loop processes' if args.load else 'no added load'}; "
          f"load average at start {os.getloadavg()[0]:.1f}; runs in {root}", flush=True)
    rows: dict[str, list[dict[str, Any]]] = {}
    with cpu_load(hogs) if args.load else nullcontext():
        for name in names:
            argv = case_argv(name, mesh)
            for i in range(args.n):
                out = root / f"{name}_{i + 1}"
                status, wall, summary = run_once(argv, out, args.timeout_s)
                timing = ((summary or {}).get("extra") or {}).get("timing") or {}
                lag = timing.get("lag") or {}
                rows.setdefault(name, []).append({**lag, "trips": timing.get("watchdog_trips"),
                                                  "late": timing.get("frames_late"),
                                                  "dropped": timing.get("recording_dropped")})
                print(f"{name:<8} run {i + 1}: status {status}  outcome {(summary or {}).get('outcome')}  wall {wall:5.1f} s  "
                      f"lag p50 {lag.get('p50_ms')} p99 {lag.get('p99_ms')} max {lag.get('max_ms')} ms (n={lag.get('n')})  "
                      f"watchdog trips {timing.get('watchdog_trips')}  frames late {timing.get('frames_late')}  "
                      f"recording drops {timing.get('recording_dropped')}", flush=True)
    print("\nper case (runs with a summary):")
    for name, runs in rows.items():
        p99 = [r["p99_ms"] for r in runs if isinstance(r.get("p99_ms"), (int, float))]
        mx = [r["max_ms"] for r in runs if isinstance(r.get("max_ms"), (int, float))]
        trips = [r["trips"] for r in runs if isinstance(r.get("trips"), int)]
        if not p99:
            print(f"  {name:<8} no summary with timing (n=0 of {len(runs)})")
            continue
        print(f"  {name:<8} lag p99 median {np.median(p99):.2f} ms, max worst {max(mx):.2f} ms; watchdog trips "
              f"{sum(trips)} total, in {sum(t > 0 for t in trips)} of {len(trips)} runs (n={len(p99)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
