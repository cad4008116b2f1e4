"""Events from the world that may interrupt a turn: falls, stalls, a degrading link, toppled objects,
scripted events and user messages, each handled as the policy says.

Detection (:class:`EventMonitor`, fed every TELEMETRY with the latest SIM_STATE and the host's link
counters; pure bookkeeping, no I/O):

==========  ==========================================================================================
``fall``    a floating-base robot tilts more than :data:`FALL_TILT_DEG` (45 deg) or its base drops below
            :data:`FALL_HEIGHT_FRACTION` of its height in the first report (a quadruped standing at 9 cm: 3 cm;
            any robot's own size): :func:`has_fallen`, the same test as ``summary.json``'s ``fell``;
            once per fall
``tilt``    it tilts more than :data:`TILT_DEG` (25 deg) without falling; once until it is upright again
``stall``   a servo stopped short of its target, pushing at its limit (blocked, collided, overloaded,
            a gripper closed on an object): for :data:`STALL_S` its commanded target stayed put, it
            stayed more than :data:`STALL_DEG` from it, its effort stayed at :data:`SATURATED` of its
            actuator's limit or more, pushing towards the target, and it moved slower than
            :data:`STALL_SPEED_DPS`. The same rule for every servo and every behaviour (``joint_move``,
            ``pose``, ``grip`` ...); the event names the servo, its joint, the target, the angle
            reached, the effort and the limit (:meth:`EventMonitor.stall_data`). Once per servo until it
            comes within :data:`REACHED_DEG` of a target again. The limit is the MJCF actuator's
            ``forcerange``, else the servo table's stall torque (:mod:`host.run.effort_limits`); a servo
            with neither, or reports without efforts, gets no stall event
``link``    the link lost :data:`LINK_BURST` or more messages (decode errors, re-sent requests, sequence
            gaps) within one second; at most once per :data:`LINK_QUIET_S`
``toppled`` SIM_STATE's toppled count rose (a scene object fell over)
``scripted`` a line of ``--events FILE``: ``at S: text`` (board seconds from the session start)
``user``    a user message while the robot acts (chat)
==========  ==========================================================================================

Policy (the ``[events]`` table of the ``--policy`` file, ``kind = "ignore" | "note" | "interrupt"``;
defaults :data:`DEFAULT_ACTIONS`): ``note`` puts the event into the observations of the running turn
(or the next one), ``interrupt`` also cancels the running turn through the lifecycle tree (as an
interruption does: the executed text is kept as history), and in ``chat`` the LLM is asked again at
once with the event as the observation. A fall always stops motion first, whatever the policy says
(every motion channel is interrupted: each motion settles smoothly where it is).
"""

from __future__ import annotations

import math
import re
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from host.bounded_read import MAX_EVENT_FILE, MAX_POLICY, InputTooLarge, read_capped

__all__ = ["ACTIONS", "DEFAULT_ACTIONS", "Event", "EventFileError", "EventMonitor", "EventPolicy", "KINDS",
           "ScriptedEvent", "parse_event_file", "parse_events_table"]

KINDS = ("fall", "tilt", "stall", "link", "toppled", "scripted", "user")
ACTIONS = ("ignore", "note", "interrupt")
DEFAULT_ACTIONS: dict[str, str] = {"fall": "interrupt", "tilt": "note", "stall": "note", "link": "note",
                                   "toppled": "note", "scripted": "interrupt", "user": "interrupt"}
FALL_TILT_DEG = 45.0
#: ... or its base sinks below this fraction of the height it started at
FALL_HEIGHT_FRACTION = 1 / 3
TILT_DEG = 25.0
#: a stall: more than this from the commanded target (deg; 5 encoder steps of an STS3215, 11 of its deadband) ...
STALL_DEG = 1.0
#: ... for this long (board seconds; the turn's default settle, 0.5 s, leaves room to report it) ...
STALL_S = 0.2
#: ... with the effort at this fraction of the actuator's limit or more ...
SATURATED = 0.95
#: ... and moving slower than this (deg/s; faster is catching up, not blocked)
STALL_SPEED_DPS = 5.0
#: a servo whose error falls below this has reached its target (re-arms its stall event)
REACHED_DEG = 0.5
LINK_BURST = 5
LINK_QUIET_S = 5.0
#: most events kept per session (older ones are dropped; the count stays exact)
MAX_EVENTS = 256


@dataclass(frozen=True)
class Event:
    """Something that happened to the robot: ``kind`` (:data:`KINDS`), board time (s), one line of text."""

    kind: str
    board_time_s: float
    text: str
    data: Mapping[str, Any] = field(default_factory=dict)

    def __str__(self) -> str:
        return f"{self.kind} at board time {self.board_time_s:.2f} s: {self.text}"


class EventFileError(ValueError):
    """A malformed ``--events`` file or ``[events]`` table; the message names file:line."""


@dataclass(frozen=True)
class ScriptedEvent:
    """``at S: text`` from an events file."""

    at_s: float
    text: str


_LINE = re.compile(r"^at\s+([^:]+):\s*(.*)$")
MAX_SCRIPTED = 10_000


def parse_event_file(path: str | Path) -> list[ScriptedEvent]:
    """The scripted events of ``path`` (``at S: text`` per line; ``#`` comments and blank lines skipped),
    sorted by time. :class:`EventFileError` names file:line for a bad line, an empty file, or too many."""
    p = Path(path)
    try:
        text = read_capped(p, MAX_EVENT_FILE).decode("utf-8")
    except InputTooLarge as e:
        raise EventFileError(f"{p}: {e}") from None
    except OSError as e:
        raise EventFileError(f"{p}: cannot read it ({e.strerror or e})") from None
    except UnicodeDecodeError as e:
        raise EventFileError(f"{p}: not UTF-8 text ({e.reason} at byte {e.start})") from None
    out: list[ScriptedEvent] = []
    for n, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        m = _LINE.match(line)
        if m is None:
            raise EventFileError(f"{p}:{n}: expected 'at SECONDS: text', got {line[:60]!r}")
        try:
            at = float(m.group(1))
        except ValueError:
            raise EventFileError(f"{p}:{n}: {m.group(1).strip()!r} is not a number of seconds") from None
        if not math.isfinite(at) or at < 0:
            raise EventFileError(f"{p}:{n}: the time must be a finite number of seconds >= 0, got {m.group(1).strip()}")
        what = m.group(2).strip()
        if not what:
            raise EventFileError(f"{p}:{n}: the event at {at:g} s has no text")
        out.append(ScriptedEvent(at, what[:300]))
        if len(out) > MAX_SCRIPTED:
            raise EventFileError(f"{p}:{n}: more than {MAX_SCRIPTED} events")
    if not out:
        raise EventFileError(f"{p}: no events (lines 'at SECONDS: text')")
    return sorted(out, key=lambda e: e.at_s)


def parse_events_table(doc: Mapping[str, Any], where: str = "policy") -> dict[str, str]:
    """The ``[events]`` table of a policy document merged over :data:`DEFAULT_ACTIONS`."""
    table = doc.get("events", {})
    if not isinstance(table, Mapping):
        raise EventFileError(f"{where}: [events] must be a table of kind = \"ignore\" | \"note\" | \"interrupt\"")
    actions = dict(DEFAULT_ACTIONS)
    for kind, action in table.items():
        if kind not in KINDS:
            raise EventFileError(f"{where}: [events] {kind!r} is no event kind; kinds: {', '.join(KINDS)}")
        if action not in ACTIONS:
            raise EventFileError(f"{where}: [events] {kind} = {action!r}; choose one of {', '.join(ACTIONS)}")
        actions[kind] = str(action)
    return actions


@dataclass
class EventPolicy:
    """What to do per event kind (:data:`ACTIONS`)."""

    actions: dict[str, str] = field(default_factory=lambda: dict(DEFAULT_ACTIONS))

    @classmethod
    def load(cls, path: str | Path) -> EventPolicy:
        """The ``[events]`` table of a TOML policy file (the shell's own tables are read by
        :class:`host.shell.policy.Policy`)."""
        import tomllib

        try:
            doc = tomllib.loads(read_capped(path, MAX_POLICY).decode("utf-8"))
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError, InputTooLarge) as e:
            raise EventFileError(f"policy {path}: {e}") from None
        return cls(parse_events_table(doc, f"policy {path}"))

    def action(self, kind: str) -> str:
        return self.actions.get(kind, "note")


def _tilt_deg(quat: Sequence[float]) -> float:
    w, x, y, z = quat
    n = w * w + x * x + y * y + z * z
    cos = 1.0 - 2.0 * (x * x + y * y) / n if n > 1e-12 else 1.0
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))


def _saturated(effort: float, err_deg: float, limit: tuple[float, float] | None) -> bool:
    """``effort`` (N*m) is at :data:`SATURATED` of ``limit``'s side it pushes on, towards the target
    (``err_deg`` > 0: the target lies at a larger angle)."""
    if limit is None or not math.isfinite(effort):
        return False
    lo, hi = limit
    if err_deg > 0:
        return hi > 0 and effort >= SATURATED * hi
    return lo < 0 and effort <= SATURATED * lo


def has_fallen(tilt_deg: float, z: float | None, z0: float | None) -> bool:
    """A floating base has fallen: tilted more than :data:`FALL_TILT_DEG`, or its height ``z`` (m) below
    :data:`FALL_HEIGHT_FRACTION` of ``z0``, its height at the start (None: unknown, tilt only)."""
    return tilt_deg > FALL_TILT_DEG or (z is not None and z0 is not None and z < z0 * FALL_HEIGHT_FRACTION)


class EventMonitor:
    """Turns reports into :class:`Event` s (see the module docstring); :meth:`feed` returns the new ones.

    ``names``: servo names (messages); ``floating``: the robot has a floating base (fall/tilt are
    only meaningful then); ``targets(t_us)``: the host's commanded targets at board time ``t_us``
    (the frames it sent, radians per servo), None when it sent none; ``limits``: per servo the
    ``(lo, hi)`` effort limit in N*m or None (:func:`host.run.effort_limits.effort_limits`; without
    them no stall is reported); ``joints``: the MJCF joint of each servo (default: ``names``).
    """

    def __init__(self, names: Sequence[str], floating: bool, targets: Any = None,
                 limits: Sequence[tuple[float, float] | None] | None = None,
                 joints: Sequence[str] | None = None) -> None:
        self.names = tuple(names)
        self.joints = tuple(joints) if joints is not None else self.names
        self.limits = tuple(limits) if limits is not None else ()
        self.floating = floating
        self.targets = targets
        self._fallen = False
        self._z0: float | None = None  # the base's height in the first report (m)
        self._tilted = False
        self._toppled = 0
        self._stall_since: dict[int, float] = {}
        self._stalled: set[int] = set()
        self._losses: deque[tuple[float, int]] = deque(maxlen=64)
        self._link_last = -math.inf

    def feed(self, t_s: float, positions: Sequence[float], base: tuple[Sequence[float], Sequence[float]] | None,
             toppled: int = 0, losses: int = 0, efforts: Sequence[float] | None = None,
             velocities: Sequence[float] | None = None) -> list[Event]:
        """One report at board time ``t_s``: joint positions (rad), base (position m, quaternion) if the
        board reports it, the scene's toppled count, the link's cumulative loss count, the servos'
        efforts (N*m; None: not reported, no stall) and velocities (rad/s; None: not checked)."""
        out: list[Event] = []
        if base is not None and self.floating:
            pos, quat = base
            tilt = _tilt_deg(quat)
            if self._z0 is None:
                self._z0 = float(pos[2])
            fell = has_fallen(tilt, float(pos[2]), self._z0)
            if fell and not self._fallen:
                out.append(Event("fall", t_s, f"the robot fell over (tilt {tilt:.0f} deg, base {pos[2] * 100:.1f} cm "
                                              "above the floor); motion was stopped",
                                 {"tilt_deg": round(tilt, 1), "height_m": round(float(pos[2]), 3)}))
            elif not fell and tilt > TILT_DEG and not self._tilted:
                out.append(Event("tilt", t_s, f"the robot tilts {tilt:.0f} deg", {"tilt_deg": round(tilt, 1)}))
            self._fallen = fell if fell else (self._fallen and tilt > TILT_DEG)
            self._tilted = tilt > TILT_DEG
        if toppled > self._toppled:
            out.append(Event("toppled", t_s, f"{toppled - self._toppled} scene object(s) toppled ({toppled} now)",
                             {"toppled": toppled}))
        self._toppled = max(self._toppled, toppled)
        out += self._stalls(t_s, positions, efforts, velocities)
        out += self._link(t_s, losses)
        return out

    def _stalls(self, t_s: float, positions: Sequence[float], efforts: Sequence[float] | None,
                velocities: Sequence[float] | None) -> list[Event]:
        if self.targets is None or efforts is None or not self.limits:
            return []
        now_t = self.targets(int(t_s * 1e6))
        before = self.targets(int((t_s - STALL_S) * 1e6))
        if now_t is None or before is None:
            return []
        q = np.asarray(positions, dtype=float)
        target = np.asarray(now_t, dtype=float)
        n = min(len(q), len(target), len(efforts), len(self.limits))
        err = np.degrees(target[:n] - q[:n])  # signed: where the servo has to go
        steady = np.degrees(np.abs(target[:n] - np.asarray(before, dtype=float)[:n])) < 1.0
        out = []
        for i in range(n):
            e = float(err[i])
            if not math.isfinite(e):
                continue
            if abs(e) < REACHED_DEG:
                self._stalled.discard(i)
                self._stall_since.pop(i, None)
                continue
            speed = abs(math.degrees(velocities[i])) if velocities is not None and i < len(velocities) else 0.0
            if not (steady[i] and abs(e) > STALL_DEG and speed < STALL_SPEED_DPS
                    and _saturated(float(efforts[i]), e, self.limits[i])):
                self._stall_since.pop(i, None)
                continue
            since = self._stall_since.setdefault(i, t_s)
            if t_s - since >= STALL_S - 1e-9 and i not in self._stalled:
                self._stalled.add(i)
                data = self.stall_data(i, float(target[i]), float(q[i]), float(efforts[i]), t_s - since)
                out.append(Event("stall", t_s, f"{data['servo']} stopped short of its target: at "
                                               f"{data['reached_deg']:.1f} deg, target {data['target_deg']:.1f} deg "
                                               f"({data['error_deg']:.1f} deg short), effort {data['effort_nm']:.2f} "
                                               f"N*m at its limit {data['limit_nm']:.2f} N*m for {data['for_s']:.1f} s "
                                               "(blocked or overloaded)", data))
        return out

    def stall_data(self, i: int, target: float, reached: float, effort: float, for_s: float) -> dict[str, Any]:
        """A stall event's ``data``: ``servo``, ``joint`` (names), ``target_deg``, ``reached_deg``,
        ``error_deg`` (|target - reached|), ``effort_nm``, ``limit_nm`` (the limit on the side it pushes)
        and ``for_s`` (how long it had stalled when reported); ``target``/``reached`` in radians."""
        lim = self.limits[i] if i < len(self.limits) else None
        side = (lim[1] if effort >= 0 else lim[0]) if lim is not None else math.nan
        return {"servo": self.names[i] if i < len(self.names) else f"servo {i + 1}",
                "joint": self.joints[i] if i < len(self.joints) else f"servo {i + 1}",
                "target_deg": round(math.degrees(target), 1), "reached_deg": round(math.degrees(reached), 1),
                "error_deg": round(abs(math.degrees(target - reached)), 1), "effort_nm": round(effort, 3),
                "limit_nm": round(side, 3), "for_s": round(for_s, 2)}

    def _link(self, t_s: float, losses: int) -> list[Event]:
        self._losses.append((t_s, losses))
        while self._losses and self._losses[0][0] < t_s - 1.0:
            self._losses.popleft()
        burst = losses - self._losses[0][1] if self._losses else 0
        if burst >= LINK_BURST and t_s - self._link_last >= LINK_QUIET_S:
            self._link_last = t_s
            return [Event("link", t_s, f"the link is degrading: {burst} messages lost or re-sent in the last second",
                          {"lost_per_s": burst})]
        return []
