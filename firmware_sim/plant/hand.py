"""A person's hand on the emulated robot (``python -m firmware_sim.plant ... --hand``): lines on the plant's
stdin move and hold its limp joints, as a hand moves a real robot whose torque is off (``ghostshell robots
calibrate``, docs/guides/calibration.md).

One command a line (joint angles in degrees, the servo table's frame: 0 is not the raw centre, the
plant's injected ``--offset``/``--reverse`` stay hidden behind the encoder as on a real servo)::

    shoulder_pan 30        hold joint shoulder_pan (or servo id 1: "1 30") at +30 deg
    pose zero              hold every joint at a pose of poses.toml ("neutral": the servo table's neutral)
    release wrist_flex     let go of one joint (it sags under gravity again); "release all": every joint
    show                   print every joint's angle and whether it is held
    help                   these lines

A held joint stays kinematically at its angle (position set, velocity zero, every control period) while its
servo's torque is off; a servo with torque on drives itself, and the hold waits until it goes off. Each
command answers one line on stdout (``hand: ...``); a bad one, one line on stderr. The lines are read by a
thread (:meth:`Hand.read`) and applied by the serve loop (:meth:`Hand.apply`), so the world is only touched
from one thread.
"""

from __future__ import annotations

import math
import queue
import sys
from collections.abc import Iterable
from typing import IO

from firmware_sim.plant.world import World

__all__ = ["HELP", "Hand"]

HELP = ("hand: NAME|ID DEG holds a joint at DEG degrees; pose NAME (poses.toml, or neutral) holds every joint; "
        "release NAME|ID|all lets go; show prints the joints")


class Hand:
    """Commands for ``world``'s joints, queued by any thread, applied by the plant's serve loop."""

    def __init__(self, world: World, out: IO[str] | None = None, err: IO[str] | None = None) -> None:
        self.world = world
        self.out, self.err = out or sys.stdout, err or sys.stderr
        self.servos = list(world.table)
        self._lines: queue.SimpleQueue[str] = queue.SimpleQueue()

    # -- input -------------------------------------------------------------------------------------
    def put(self, line: str) -> None:
        """Queue one command line (applied at the serve loop's next turn)."""
        self._lines.put(line)

    def read(self, lines: Iterable[str]) -> None:
        """Queue every line of ``lines`` (e.g. ``sys.stdin``; a thread's target) until it ends."""
        for line in lines:
            self.put(line)

    def apply(self) -> None:
        """Apply the queued commands (the serve loop calls this every turn)."""
        while True:
            try:
                line = self._lines.get_nowait()
            except queue.Empty:
                return
            try:
                said = self.command(line)
            except ValueError as e:
                print(f"hand: {e}", file=self.err, flush=True)
                continue
            if said:
                print(said, file=self.out, flush=True)

    # -- commands ----------------------------------------------------------------------------------
    def _index(self, word: str) -> int:
        for i, s in enumerate(self.servos):
            if word == s.name or word == str(s.id):
                return i
        names = ", ".join(s.name for s in self.servos)
        raise ValueError(f"no joint {word!r} (joints: {names}; or their servo ids)")

    def _held(self, i: int, q: float, asked: float) -> str:
        s = self.servos[i]
        note = f" (its range ends at {math.degrees(q):+.1f} deg)" if abs(q - asked) > 1e-9 else ""
        if self.world.servos[i].torque:
            note += " (its torque is on: held once it goes off)"
        return f"{s.name} at {math.degrees(q):+.1f} deg{note}"

    def command(self, line: str) -> str | None:
        """Apply one command line; the line to print (None for an empty line). ValueError: a bad command."""
        words = line.split("#", 1)[0].split()
        if not words:
            return None
        head = words[0].lower()
        if head in ("help", "?"):
            return HELP
        if head == "show":
            q = self.world.positions()
            return "hand: " + ", ".join(
                f"{s.name} {math.degrees(q[i]):+.1f} deg{' (held)' if i in self.world.held else ''}"
                for i, s in enumerate(self.servos))
        if head == "release":
            if len(words) != 2:
                raise ValueError(f"{line.strip()!r}: release NAME|ID|all")
            if words[1].lower() == "all":
                self.world.release()
                return "hand: released every joint"
            i = self._index(words[1])
            self.world.release(i)
            return f"hand: released {self.servos[i].name}"
        if head == "pose":
            if len(words) != 2:
                raise ValueError(f"{line.strip()!r}: pose NAME (a pose of poses.toml, or neutral)")
            robot = self.world.robot
            if words[1] in robot.poses:
                pose = list(robot.poses[words[1]])
            elif words[1] == "neutral":
                pose = [s.neutral for s in self.servos]
            else:
                raise ValueError(f"no pose {words[1]!r} (poses: {', '.join(sorted(robot.poses)) or 'none'}; or neutral)")
            held = [self._held(i, self.world.hold(i, q), q) for i, q in enumerate(pose)]
            return f"hand: pose {words[1]}: " + ", ".join(held)
        if len(words) != 2:
            raise ValueError(f"{line.strip()!r}: expected NAME DEG, pose NAME, release NAME|all or show")
        i = self._index(words[0])
        try:
            deg = float(words[1])
        except ValueError:
            raise ValueError(f"{line.strip()!r}: {words[1]!r} is not an angle in degrees") from None
        if not math.isfinite(deg):
            raise ValueError(f"{line.strip()!r}: the angle must be finite")
        asked = math.radians(deg)
        return "hand: holds " + self._held(i, self.world.hold(i, asked), asked)
