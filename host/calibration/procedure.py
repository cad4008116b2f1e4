"""The hand-guided calibration of a robot's real servos (``ghostshell robots calibrate``), after LeRobot's
for its SO-100/Koch arms (``MotorsBus.set_half_turn_homings`` and ``record_ranges_of_motion``).

With every servo limp (torque off for the whole procedure, and again at the end whatever happens):

1. **check the bus**: every servo of the servo table answers a ping with the model number
   ``hardware.toml`` names;
2. **reference pose** (the servo table's ``neutral``; the pose of ``poses.toml`` that equals it is
   named): ``offset_steps = present - STEP_CENTRE``; the positions are read twice, :data:`STILL_S` apart,
   and a joint that moved more than :data:`STILL_STEPS` between them (a limp joint sagging, a hand not
   yet still) is named in one warning line; the offset is taken from the later reading;
3. **direction**, one joint at a time: the user moves it a little towards its positive direction;
   ``direction = sign(raw change) * table direction`` (a change under :data:`MIN_MOVE_DEG` is refused);
4. **range**: the user moves every joint through its whole range while the present positions are read
   continuously (a second thread; :data:`POLL_S`) until Enter: ``min_steps``/``max_steps`` are the
   extremes seen.

Checks (one :class:`CalibrationError` naming servo id and name; nothing is returned): a missing servo
or wrong model, a direction change too small to tell, a range that did not move (min >= max), one that
crosses the encoder's 0/4095 wrap, one that does not overlap the joint's range
(:func:`robots.hardware.step_limits`), or one that does not contain the reference pose.

Unlike LeRobot nothing is written to the servos (no homing offset, no angle limits): the result is a
:class:`robots.hardware.Calibration` for ``calibration.toml``. Input comes through ``ask(prompt) ->
line`` (``input`` at a terminal; a test moves the joints of an emulated bus in it).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence
from typing import Protocol

from robots.datatypes import RobotDataError, Servo
from robots.description import Robot
from robots.hardware import STEP_CENTRE, STEP_MAX, Calibration, Hardware, ServoCalibration, rad_to_steps, step_limits

__all__ = ["Bus", "CalibrationError", "MIN_MOVE_DEG", "POLL_S", "STILL_S", "STILL_STEPS", "calibrate", "coverage_notes",
           "live_table", "reference_pose_name", "still_warning", "table"]

#: a direction move must change the raw position by at least this much (degrees)
MIN_MOVE_DEG = 5.0
#: the range phase reads every present position this often (seconds)
POLL_S = 0.02
HALF_TURN = (STEP_MAX + 1) // 2
#: the reference pose is read twice this far apart (seconds) ...
STILL_S = 0.2
#: ... and a joint whose two readings differ by more steps than this is still moving (a step of encoder noise is not)
STILL_STEPS = 1


class CalibrationError(Exception):
    """What the user's robot or input got wrong (one line; exit status 2)."""


class Bus(Protocol):
    def ping(self, servo_id: int) -> int | None: ...
    def torque_off(self, servo_id: int) -> bool: ...
    def position(self, servo_id: int) -> int: ...


def _who(s: Servo) -> str:
    return f"servo {s.id} ({s.name})"


def reference_pose_name(robot: Robot) -> str | None:
    """The pose of poses.toml that is the servo table's neutral (within 0.05 deg), preferring ``neutral``."""
    neutral = [s.neutral for s in robot.servos]
    names = sorted(robot.poses, key=lambda n: (n != "neutral", n))
    for name in names:
        q = robot.poses[name]
        if len(q) == len(neutral) and all(abs(a - b) <= math.radians(0.05) for a, b in zip(q, neutral)):
            return name
    return None


def _wrap(delta: int) -> int:
    """A raw position change as the shortest way round the 4096-step circle."""
    return (delta + HALF_TURN) % (2 * HALF_TURN) - HALF_TURN


def _check_bus(bus: Bus, servos: Sequence[Servo], hardware: Hardware) -> None:
    for s in servos:
        model = bus.ping(s.id)
        if model is None:
            raise CalibrationError(f"{_who(s)} does not answer a ping: check its cable, power, id and the baud rate")
        want = hardware.model_of(s)
        if model != want:
            raise CalibrationError(f"{_who(s)} reports model number {model}, hardware.toml says {want}: "
                                   "a different servo, or fix hardware.toml (model / [models])")


def _torque_off(bus: Bus, servos: Sequence[Servo]) -> list[Servo]:
    """Torque off for every servo; the ones that did not acknowledge."""
    return [s for s in servos if not bus.torque_off(s.id)]


def _positions(bus: Bus, servos: Sequence[Servo]) -> list[int]:
    return [bus.position(s.id) for s in servos]


def _deg(x: float) -> str:
    v = round(math.degrees(x))
    return f"{v:+d} deg" if v else "0 deg"


def still_warning(servos: Sequence[Servo], first: Sequence[int], second: Sequence[int], apart_s: float) -> str | None:
    """The one warning line for joints that moved between two readings of the reference pose, else None."""
    moved = [(s, _wrap(b - a)) for s, a, b in zip(servos, first, second) if abs(_wrap(b - a)) > STILL_STEPS]
    if not moved:
        return None
    which = ", ".join(f"{_who(s)} {d:+d} steps" for s, d in moved)
    return (f"warning: still moving while the reference pose was read ({which} in {apart_s:g} s): a limp joint "
            "sags unless held; hold it still in the pose (its offset is taken from the later reading)")


def _record_ranges(bus: Bus, servos: Sequence[Servo], ask: Callable[[str], str], prompt: str,
                   live: Callable[[Sequence[int], Sequence[int], Sequence[int]], None] | None,
                   poll_s: float) -> tuple[list[int], list[int]]:
    """Read every present position until ``ask`` returns; (mins, maxes). A jump of more than half a
    turn between two readings is the encoder wrapping (CalibrationError)."""
    first = _positions(bus, servos)
    mins, maxes, last = list(first), list(first), list(first)
    stop = threading.Event()
    failure: list[BaseException] = []

    def sweep() -> None:
        pos = _positions(bus, servos)
        for i, (p, s) in enumerate(zip(pos, servos)):
            if abs(p - last[i]) > HALF_TURN:
                raise CalibrationError(
                    f"{_who(s)}: its position jumped {last[i]} -> {p}, across the encoder's 0/{STEP_MAX} wrap: its range "
                    "crosses the servo's zero; remount the horn (or re-centre the servo) so the range lies inside 0..4095")
            last[i] = p
            mins[i], maxes[i] = min(mins[i], p), max(maxes[i], p)
        if live is not None:
            live(pos, mins, maxes)

    def reader() -> None:
        try:
            while not stop.is_set():
                sweep()
                stop.wait(poll_s)
        except BaseException as e:  # noqa: BLE001 - handed to the main thread
            failure.append(e)

    th = threading.Thread(target=reader, name="calibrate-ranges", daemon=True)
    th.start()
    try:
        ask(prompt)
    finally:
        stop.set()
        th.join()
    if failure:
        raise failure[0]
    sweep()  # where the joints were left
    return mins, maxes


def calibrate(robot: Robot, bus: Bus, hardware: Hardware, *, ask: Callable[[str], str],
              say: Callable[[str], None] = print,
              live: Callable[[Sequence[int], Sequence[int], Sequence[int]], None] | None = None,
              poll_s: float = POLL_S, still_s: float = STILL_S) -> Calibration:
    """Run the procedure (module docstring) on ``bus``; the calibration of every servo of ``robot``.

    ``ask(prompt)`` waits for the user (Enter); ``say`` prints a line; ``live(positions, mins, maxes)``
    is called after every reading of the range phase (servo order); ``still_s``: how far apart the reference
    pose's two readings are (:func:`still_warning`). Torque is left off."""
    servos = list(robot.servos)
    step = robot.servos.model.resolution
    _check_bus(bus, servos, hardware)
    failed = _torque_off(bus, servos)
    if failed:
        s = failed[0]
        raise CalibrationError(f"{_who(s)} did not acknowledge torque off")

    # (a) the reference pose -> offsets
    pose = reference_pose_name(robot)
    named = f"pose {pose!r} of poses.toml" if pose else "no pose of poses.toml is this one"
    joints = ", ".join(f"{s.name} {_deg(s.neutral)}" for s in servos)
    say(f"Torque is off: every servo of {robot.name} is limp; move the joints by hand.")
    say(f"1/3 reference pose: the servo table's neutral ({named}): {joints}")
    ask("Put the robot in this pose and press Enter: ")
    first = _positions(bus, servos)
    time.sleep(still_s)
    ref = _positions(bus, servos)
    warning = still_warning(servos, first, ref, still_s)
    if warning:
        say(warning)
    offsets = [p - STEP_CENTRE for p in ref]

    # (b) one joint at a time -> direction
    say("2/3 direction: one joint at a time, move it a little (5-20 deg) towards its positive direction.")
    directions: list[int] = []
    min_move = max(1, round(math.radians(MIN_MOVE_DEG) / step))
    for s in servos:
        before = bus.position(s.id)
        ask(f"  {s.name} (servo {s.id}): towards {_deg(s.max)} (its max), then press Enter: ")
        delta = _wrap(bus.position(s.id) - before)
        if abs(delta) < min_move:
            raise CalibrationError(f"{_who(s)}: it moved {abs(delta)} steps ({math.degrees(abs(delta) * step):.1f} deg), "
                                   f"too little to tell its direction (at least {MIN_MOVE_DEG:g} deg); nothing written")
        directions.append((1 if delta > 0 else -1) * s.direction)

    # (c) every joint through its range -> min/max
    say("3/3 range: move every joint slowly through its whole range, end stop to end stop.")
    mins, maxes = _record_ranges(bus, servos, ask, "Press Enter when every joint has been to both ends: ", live, poll_s)

    out: dict[str, ServoCalibration] = {}
    for i, s in enumerate(servos):
        lo, hi = mins[i], maxes[i]
        if lo >= hi:
            raise CalibrationError(f"{_who(s)}: its range {lo}..{hi} is empty (min >= max): it did not move; "
                                   "nothing written")
        cal = ServoCalibration(s.id, offsets[i], directions[i], lo, hi)
        try:
            step_limits(s, cal, step)
        except RobotDataError:
            a, b = sorted(rad_to_steps(s, cal, q, step) for q in (s.min, s.max))
            raise CalibrationError(
                f"{_who(s)}: its range {lo}..{hi} lies outside its joint range "
                f"{math.degrees(s.min):+.0f}..{math.degrees(s.max):+.0f} deg "
                f"(steps {a}..{b} from the reference pose): was it in the reference pose? nothing written") from None
        if not lo <= ref[i] <= hi:
            raise CalibrationError(f"{_who(s)}: its range {lo}..{hi} does not contain the reference pose ({ref[i]}): "
                                   "was it moved through its whole range? nothing written")
        out[s.name] = cal
    return Calibration(out)


def coverage_notes(robot: Robot, calibration: Calibration) -> list[str]:
    """Lines for servos whose calibrated range covers less than the servo table's joint range."""
    step = robot.servos.model.resolution
    notes = []
    for s in robot.servos:
        c = calibration.of(s)
        lo, hi = step_limits(s, c, step)
        q = sorted(s.neutral + c.direction * s.direction * (r - STEP_CENTRE - c.offset_steps) * step for r in (lo, hi))
        if q[0] > s.min + math.radians(1) or q[1] < s.max - math.radians(1):
            notes.append(f"{_who(s)}: goals are held to {_deg(q[0])}..{_deg(q[1])}, "
                         f"inside its joint range {_deg(s.min)}..{_deg(s.max)}")
    return notes


def table(robot: Robot, calibration: Calibration) -> list[str]:
    """The calibration as aligned lines (one per servo)."""
    rows = [("SERVO", "NAME", "OFFSET", "DIR", "MIN", "MAX")]
    for s in robot.servos:
        c = calibration.of(s)
        rows.append((str(s.id), s.name, f"{c.offset_steps:+d}", f"{c.direction:+d}", str(c.min_steps), str(c.max_steps)))
    widths = [max(len(r[k]) for r in rows) for k in range(len(rows[0]))]
    return ["  ".join(v.rjust(w) if k != 1 else v.ljust(w) for k, (v, w) in enumerate(zip(r, widths))).rstrip()
            for r in rows]


def live_table(names: Sequence[str], write: Callable[[str], None]) -> Callable[[Sequence[int], Sequence[int], Sequence[int]], None]:
    """A ``live`` for a terminal: the range table redrawn in place (ANSI cursor up), as LeRobot shows it."""
    first = [True]

    def show(pos: Sequence[int], mins: Sequence[int], maxes: Sequence[int]) -> None:
        lines = [f"{'NAME':<16} {'MIN':>5} {'POS':>5} {'MAX':>5}"]
        lines += [f"{n:<16} {lo:>5} {p:>5} {hi:>5}" for n, p, lo, hi in zip(names, pos, mins, maxes)]
        up = "" if first[0] else f"\x1b[{len(lines)}F"
        first[0] = False
        write(up + "\n".join(lines) + "\n")

    return show

