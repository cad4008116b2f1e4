"""Lockstep identity under disturbance (prints numbers, asserts nothing).

Per robot (CoCo, the arm, the mesh arm of ``tests/support/mesh_robot.py``): one quiet
``ghostshell run --lockstep`` of a short program, then ``--runs`` disturbed runs of the same program,
each with a CPU hog per core, the host process SIGSTOPped 0.25 s every 0.5 s, and the host's control
path stalled at random (``GHOSTSHELL_STALLS=seed=<run>,p=<p>,max_s=<max_s>``, :mod:`host.motion.stalls`).
A disturbed run counts as identical when the board received the same messages and sent the same reports
up to the earlier end, and ended in the same TELEMETRY/SIM_STATE (:mod:`tests.support.lockstep_identity`).
Prints ``n identical / n runs`` per robot, the wall seconds of the runs and the first difference of
every run that differs.

Run: ``nice .venv/bin/python bench/bench_lockstep_identity.py [--runs 20] [--robot coco --robot arm ...]
[--p 0.05] [--max-s 1.0] [--firmware python|c]`` (MUJOCO_GL=egl). About 15-40 s a disturbed run on 2 loaded cores.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.support.lockstep_identity import compare, run_lockstep  # noqa: E402
from tests.support.mesh_robot import write_mesh_arm  # noqa: E402

XML = {
    "coco": 'Hello, I nod. <head_act action="nod" duration="1"/><wave/><head_act action="shake"/>',
    "arm": '<pose name="home"/><joint_move joint="shoulder_pan" deg="30" duration="1"/>'
           '<joint_move joint="elbow_flex" deg="20" duration="0.5"/>',
    "mesh_arm": '<pose name="home"/><joint_move joint="shoulder_pan" deg="30" duration="1"/>'
                '<joint_move joint="elbow_flex" deg="20" duration="0.5"/>',
}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=20, help="disturbed runs per robot (default 20)")
    ap.add_argument("--robot", action="append", choices=sorted(XML), help="robots (default: all three)")
    ap.add_argument("--p", type=float, default=0.05, help="stall probability at each stall point (default 0.05)")
    ap.add_argument("--max-s", type=float, default=1.0, help="longest stall, wall seconds (default 1.0)")
    ap.add_argument("--firmware", choices=("python", "c"), default="python",
                    help="the emulated board's firmware (default python; c: the C firmware and its MuJoCo plant)")
    ap.add_argument("--keep", type=Path, default=None, help="keep the run folders here (default: a temp folder)")
    args = ap.parse_args()
    if args.runs < 1 or not 0 <= args.p <= 1 or args.max_s < 0:
        print("error: --runs must be >= 1, --p in 0..1, --max-s >= 0", file=sys.stderr)
        return 2
    robots = args.robot or ["coco", "arm", "mesh_arm"]
    with tempfile.TemporaryDirectory(prefix="bench_lockstep_identity_") as tmp:
        base = args.keep or Path(tmp)
        base.mkdir(parents=True, exist_ok=True)
        for robot in robots:
            if robot == "mesh_arm":
                robot_args = ["--robots-dir", str(write_mesh_arm(base / "mesh")), "--robot", "mesh_arm"]
            else:
                robot_args = ["--robot", robot]
            robot_args += ["--firmware", args.firmware]
            t0 = time.monotonic()
            quiet = run_lockstep(base / robot / "quiet", XML[robot], robot_args)
            quiet_s = time.monotonic() - t0
            if quiet.proc.returncode != 0:
                print(f"{robot}: the quiet run failed (exit {quiet.proc.returncode}): {quiet.proc.stderr.strip()[-300:]}")
                continue
            same, walls, stops, failed = 0, [], [], 0
            for i in range(args.runs):
                t0 = time.monotonic()
                run = run_lockstep(base / robot / f"disturbed_{i:02d}", XML[robot], robot_args, disturb=True,
                                   stalls=f"seed={i},p={args.p},max_s={args.max_s}")
                walls.append(time.monotonic() - t0)
                stops.append(run.stops)
                if run.proc.returncode != 0:
                    failed += 1
                    print(f"  {robot} run {i}: exit {run.proc.returncode}: {run.proc.stderr.strip()[-200:]}")
                    continue
                verdict = compare(quiet.record, run.record)
                if verdict == "identical":
                    same += 1
                else:
                    print(f"  {robot} run {i}: {verdict[:300]}")
            print(f"{robot} ({args.firmware}): {same} identical / {args.runs} disturbed runs ({failed} failed); quiet run "
                  f"{quiet_s:.1f} s wall, board time {quiet.record.end_us / 1e6:.2f} s, "
                  f"{quiet.record.counts().get('ServoFrame', 0)} frames; disturbed wall s median "
                  f"{statistics.median(walls):.1f} max {max(walls):.1f}; SIGSTOPs per run median "
                  f"{statistics.median(stops):.0f}; stalls p={args.p} max_s={args.max_s}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
