"""Calibrate CoCo's gaits in MuJoCo and print their accuracy.

    python -m robots.coco.calibrate_gaits          # measure, rewrite robots/coco/gait.toml, print accuracy
    python -m robots.coco.calibrate_gaits --check  # only print the accuracy table for the current gait.toml

Walking: for each (speed, amplitude) in {0, 50, 100}^2 and both directions, walk 2 and 6 cycles at
full amplitude and fit ``distance = offset + per_cycle * cycles``; the yaw drift of forward and
backward walking is cancelled by a small turn-pattern trim. Turning: 2 and 8 cycles each way.
Then run_distance (10, 20, 40, -20 cm) and rotate (45, 90, 180, -90, 360 deg) are played through
the behaviour generators and measured against their targets.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

from robots.coco import gaits
from robots.coco.gaits import CALIBRATION_PATH, FORWARD, TURN_LEFT, GaitParams, load_calibration, stand_body
from robots.coco.motions import BEHAVIOURS
from robots.coco.playback import Measurement, Player

GRID = (0.0, 50.0, 100.0)
FIT_CYCLES = (2, 6)
TURN_CYCLES = (2, 8)


def simulate(p: GaitParams, cycles: int) -> Measurement:
    player = Player()
    return player.play(gaits.gait_motion(player.targets, p, cycles))


def fit(xs: tuple[int, ...], ys: list[float]) -> tuple[float, float]:
    """(offset, per_cycle) least squares."""
    per, off = np.polyfit(np.array(xs, float), np.array(ys), 1)
    return float(off), float(per)


def calibrate() -> str:
    """Measure everything and return the gait.toml text."""
    base = stand_body()
    lift = math.radians(25.0)
    # turning first (the walking trim needs degrees per cycle)
    turn = {}
    for name, sign in (("left", 1.0), ("right", -1.0)):
        p = GaitParams(gaits.TURN_PERIOD, math.radians(gaits.TURN_AMPLITUDE_DEG), lift, sign * TURN_LEFT, base)
        ys = [sign * simulate(p, n).yaw_deg for n in TURN_CYCLES]
        turn[name] = fit(TURN_CYCLES, ys)
    turn_per_rad = (turn["left"][1] + turn["right"][1]) / 2 / math.radians(gaits.TURN_AMPLITUDE_DEG)
    # yaw trim at the default speed/amplitude
    trims = {}
    for name, sign in (("forward", 1.0), ("backward", -1.0)):
        period, amp = gaits.walk_params()
        p = GaitParams(period, math.radians(amp), lift, sign * FORWARD, base)
        drift = simulate(p, 6).yaw_deg / 6  # degrees per cycle
        trims[name] = -drift / (turn_per_rad * math.radians(amp))
    walk: dict[str, list[list[float]]] = {}
    for name, sign in (("forward", 1.0), ("backward", -1.0)):
        per_rows, off_rows = [], []
        for s in GRID:
            per_row, off_row = [], []
            for a in GRID:
                period, amp = gaits.walk_params(s, a)
                p = GaitParams(period, math.radians(amp), lift, sign * FORWARD + trims[name] * TURN_LEFT, base)
                off, per = fit(FIT_CYCLES, [sign * simulate(p, n).forward_cm for n in FIT_CYCLES])
                per_row.append(round(per, 3))
                off_row.append(round(off, 3))
            per_rows.append(per_row)
            off_rows.append(off_row)
        walk[f"{name}_per_cycle"], walk[f"{name}_offset"] = per_rows, off_rows

    def grid(rows: list[list[float]]) -> str:
        return "[" + ", ".join("[" + ", ".join(f"{v:.3f}" for v in r) + "]" for r in rows) + "]"

    return "\n".join([
        "# CoCo gait calibration, measured in MuJoCo by robots/coco/calibrate_gaits.py (do not edit by hand).",
        "# travel = offset + per_cycle * cycles at full amplitude; rows: speed, columns: amplitude.",
        "",
        "[walk]",
        f"speeds = [{', '.join(f'{v:g}' for v in GRID)}]",
        f"amplitudes = [{', '.join(f'{v:g}' for v in GRID)}]",
        f"forward_per_cycle = {grid(walk['forward_per_cycle'])}  # cm",
        f"forward_offset = {grid(walk['forward_offset'])}",
        f"backward_per_cycle = {grid(walk['backward_per_cycle'])}",
        f"backward_offset = {grid(walk['backward_offset'])}",
        f"forward_trim = {trims['forward']:.5f}  # turn-pattern weight cancelling yaw drift",
        f"backward_trim = {trims['backward']:.5f}",
        "",
        "[turn]",
        f"left_per_cycle = {turn['left'][1]:.3f}  # degrees",
        f"left_offset = {turn['left'][0]:.3f}",
        f"right_per_cycle = {turn['right'][1]:.3f}",
        f"right_offset = {turn['right'][0]:.3f}",
        "",
    ])


def accuracy() -> None:
    """Play run_distance and rotate through the behaviour generators and print the errors."""
    print(f"{'behaviour':28s} {'target':>8s} {'measured':>9s} {'error':>7s} {'side':>7s} {'yaw':>7s}"
          f" {'tilt':>6s} {'time':>6s}")
    for d in (10.0, 20.0, 40.0, -20.0):
        player = Player()
        r = player.play(BEHAVIOURS["run_distance"](player.targets, distance=d))
        print(f"{'run_distance ' + f'{d:g} cm':28s} {d:8.1f} {r.forward_cm:9.1f} {100 * (r.forward_cm - d) / abs(d):6.1f}%"
              f" {r.left_cm:6.1f}cm {r.yaw_deg:6.1f}° {r.max_tilt_deg:5.1f}° {r.duration_s:5.1f}s")
    for s, a in ((0, 0), (100, 100), (100, 0), (0, 100)):
        player = Player()
        r = player.play(BEHAVIOURS["run_distance"](player.targets, distance=20.0, speed=s, amplitude=a))
        print(f"{f'run_distance 20 s={s} a={a}':28s} {20.0:8.1f} {r.forward_cm:9.1f} {100 * (r.forward_cm - 20) / 20:6.1f}%"
              f" {r.left_cm:6.1f}cm {r.yaw_deg:6.1f}° {r.max_tilt_deg:5.1f}° {r.duration_s:5.1f}s")
    for ang in (45.0, 90.0, 180.0, -90.0, 360.0):
        player = Player()
        r = player.play(BEHAVIOURS["rotate"](player.targets, angle=ang))
        print(f"{'rotate ' + f'{ang:g} deg':28s} {ang:8.1f} {r.yaw_deg:9.1f} {100 * (r.yaw_deg - ang) / abs(ang):6.1f}%"
              f" {math.hypot(r.forward_cm, r.left_cm):6.1f}cm {'':7s} {r.max_tilt_deg:5.1f}° {r.duration_s:5.1f}s")
    player = Player()
    p0, _ = player.base()
    yaw = 0.0
    for _ in range(4):
        for name, kw in (("run_distance", {"distance": 20.0}), ("rotate", {"angle": -90.0})):
            yaw += player.play(BEHAVIOURS[name](player.targets, **kw), hold_s=0.1).yaw_deg
    p1, _ = player.base()
    print(f"{'square 4x(20 cm, -90 deg)':28s} closes within {100 * math.hypot(*(p1 - p0)[:2]):.1f} cm,"
          f" heading error {yaw + 360.0:+.1f}°")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="do not recalibrate; only print the accuracy table")
    args = ap.parse_args()
    if not args.check:
        t0 = time.perf_counter()
        text = calibrate()
        CALIBRATION_PATH.write_text(text)
        load_calibration.cache_clear()
        print(f"wrote {CALIBRATION_PATH} ({time.perf_counter() - t0:.1f} s)\n")
        print(text)
    accuracy()
    return 0


if __name__ == "__main__":
    sys.exit(main())
