"""A robot's behaviours executed over the link: the shell's executor for the real (emulated) robot.

One implementation per behaviour. Motion behaviours (the robot's behaviours module and the generic
``pose``/``joint_move``, :attr:`robots.description.Robot.behaviours`) ask for a trajectory that
starts where the motion's servos are planned to be, place it on the frame grid and complete when telemetry shows
its last frame applied. As a parent element (persistent) they loop until reset;
reset and interruption FLUSH the channel's buffered frames and start a smooth
return (reset) or a smooth stop (interruption of a finite call) at the cut.
Face, speech, music and camera (:data:`robots.interface.PERIPHERAL_BEHAVIOURS`) go over the same
link as peripheral messages timed on the board clock; they complete when the board clock passes
their end.

Calls on one motion channel flow into each other: a finite motion is planned
to start at the previous one's planned end (on the frame grid, so the gap is
below one frame period and nothing stops in between). To make that possible a
finite motion hands its channel over to the shell (``CallContext.hand_over``)
once board time is within :data:`HANDOVER_LEAD_US` plus the lookahead of its
planned end; its own ``done`` still waits for telemetry to confirm its last
frame. An interruption cancels the calls queued on the channel, and each
cancelled motion cuts its own segment (planned-ahead ones included).

Every call's board-measured start and end are kept by element path in
:attr:`RobotRuntime.board_times` for the run's timeline.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import anyio
import numpy as np

from host.motion.mixer import Mixer, Segment
from host.motion.streamer import GRID_PERIOD_US, LOOKAHEAD_US, FrameLink, FrameStreamer
from host.shell.cleanups import Cleanups
from host.shell.context import RunningCall
from protocol.messages import (
    ScreenCommand,
    ScreenTarget,
    SoundKind,
    SpeakerAction,
    SpeakerCommand,
)
from protocol.framing import encode_frame
from robots.description import Robot
from robots.motion import JointLimits, ease_in, transition

#: How long (board µs) before the streamer's horizon reaches a motion's planned end the next
#: call on its channel is let in, so that it is planned before that frame is sent.
HANDOVER_LEAD_US = 200_000
#: Wall seconds an interrupted motion's shielded stop (FLUSH, the stop's frames, its end) may take.
#: It runs while the call is being cancelled, i.e. possibly after the session's pump, silence watchdog
#: and board-time bound are gone: without a deadline a stop waiting on the frame lock or on telemetry
#: that no longer comes kept the turn (and the run's summary) from ever ending. Above the stop's own
#: worst case on a lossy link: the FLUSH's 6 attempts of 1 s, then up to 5 s for its end.
STOP_TIMEOUT_S = 12.0


class RobotLink(FrameLink, Protocol):
    """The link operations the runtime uses (see :class:`host.runtime.link.ClientLink`)."""

    async def send_peripheral(self, msg: ScreenCommand | SpeakerCommand) -> None: ...

    async def capture(self, width: int, height: int) -> bytes: ...


@dataclass
class Voice:
    """Settings from ``speech_role``."""

    role: str = "robot"
    emotion: str = "neutral"
    speech_rate: float = 0.0  # signed percentage offset from normal (-50..100)
    loudness_rate: float = 0.0  # signed percentage offset from normal (-50..100)

    @property
    def rate_factor(self) -> float:
        """Speaking rate as a factor of normal (``1 + speech_rate / 100``)."""
        return max(0.1, 1.0 + self.speech_rate / 100.0)

    @property
    def loudness_factor(self) -> float:
        """Loudness as a factor of normal (``1 + loudness_rate / 100``)."""
        return max(0.0, 1.0 + self.loudness_rate / 100.0)


def warm_up_behaviours(robot: Robot) -> int:
    """Plan every motion behaviour of ``robot`` once from its rest pose with its defaults and drop the plans.

    A behaviour's first call pays one-time costs (CoCo's gaits read their calibration file, NumPy
    takes its first path through each function): ~10 ms for the first ``rotate`` of a process,
    measured on the token -> servo path of that call (``bench/bench_latency.py``). A session calls it
    once, before its link connects: it is CPU work that holds the event loop (tens of ms, more on a
    busy machine), and once the link is up a stalled loop sends no heartbeat, so the board's watchdog
    would trip. A behaviour that needs arguments, or refuses its defaults, is skipped (planned when
    called). Returns how many were planned.
    """
    rest = np.asarray(robot.pose(robot.rest_pose))
    planned = 0
    for fn in robot.behaviours.values():
        try:
            ease_in(fn(rest.copy()))
        except Exception:  # noqa: BLE001 - a robot's own code; it is called for real later
            continue
        planned += 1
    return planned


class RobotRuntime:
    """Implements every behaviour of ``robot``'s interface on a board behind ``link``."""

    def __init__(self, robot: Robot, link: RobotLink, run_dir: Path, *, initial: np.ndarray,
                 speech_synth: Callable[..., Any] | None = None, period_us: int = GRID_PERIOD_US,
                 lookahead_us: int = LOOKAHEAD_US, voices: tuple[str, ...] | None = None,
                 clips: tuple[str, ...] | None = None, sparse: bool = False) -> None:
        self.robot = robot
        self.limits = JointLimits.of_robot(robot)
        self.link = link
        self.run_dir = run_dir
        self.mixer = Mixer(initial)
        # sparse: grid frames carry only the servos that move (a slow line: FrameStreamer.sparse)
        self.streamer = FrameStreamer(link, self.mixer, period_us=period_us, lookahead_us=lookahead_us, sparse=sparse)
        self.voice = Voice()
        #: the speech engine's voices; another role falls back to "robot" with a note
        self.voices = voices if voices is not None else robot.peripherals.voices
        #: the music clips on the robot (None: the board plays any name)
        self.clips = clips if clips is not None else robot.peripherals.clips
        self.board_times: dict[str, list[float | None]] = {}
        self.captures: list[Path] = []
        self._active: dict[int, Segment] = {}  # element id -> the looping segment of a persistent call
        self._last: dict[str, Segment] = {}  # channel -> its last finite segment (where the next one starts)
        self._rest = np.asarray(robot.pose(robot.rest_pose))
        self._speech_synth = speech_synth
        self._cleanups = Cleanups()  # the shielded stops of cancelled calls (abort_cleanups cuts them short)
        #: behaviour name -> its implementation: the peripherals, then the robot's motions (which win a name clash)
        self.behaviours: dict[str, Behaviour] = {
            "face_emo": FaceBehaviour(self), "play_bgm": MusicBehaviour(self), "capture": CaptureBehaviour(self),
            "speech_role": SpeechRoleBehaviour(self), **{name: MotionBehaviour(self, name) for name in robot.behaviours},
        }

    def warm_up(self) -> int:
        """:func:`warm_up_behaviours` of this runtime's robot."""
        return warm_up_behaviours(self.robot)

    # -- helpers -------------------------------------------------------------------------------
    def _start_due(self, msg: ScreenCommand | SpeakerCommand) -> int:
        """Board time a peripheral command sent now starts at (see ``FrameStreamer.start_due_us``)."""
        return self.streamer.start_due_us(len(encode_frame(msg, 0)) + 4)  # + 4: a larger start time's varint

    def _mark(self, call: RunningCall, start: float | None = None, end: float | None = None) -> None:
        """Keep ``call``'s board-measured start (the first one given) and end (seconds) by its path."""
        rec = self.board_times.setdefault(call.path, [None, None])
        if start is not None and rec[0] is None:
            rec[0] = start
        if end is not None:
            rec[1] = end

    def board_now_s(self) -> float:
        """The board clock in seconds (the shell's timeline clock)."""
        return self.streamer.board_now_us() * 1e-6

    async def sleep(self, seconds: float) -> None:
        """Sleep on the board clock (works in lockstep, where wall time means nothing)."""
        await self.streamer.wait_board_time(self.streamer.board_now_us() + int(seconds * 1e6))

    # -- the Performer protocol used by host.runtime.binding ------------------------------------
    def _servos(self, channel: str, seg: Segment) -> tuple[int, ...]:
        """The servos a cut on ``channel`` affects: the channel's (robot.toml), else the segment's own."""
        c = self.robot.channels.get(channel)
        return c.servos if c is not None else tuple(int(i) for i in seg.motion.servos)

    async def perform(self, behaviour: str, channel: str, args: dict[str, Any], call: RunningCall) -> Any:
        """Run one behaviour call (the shell calls this with typed arguments and the call's context);
        raises ValueError for a behaviour :attr:`behaviours` has no implementation of."""
        impl = self.behaviours.get(behaviour)
        if impl is None:
            raise ValueError(f"no implementation for behaviour {behaviour!r} on channel {channel!r}")
        return await impl.perform(call, channel, args)

    async def reset(self, behaviour: str, channel: str, call: RunningCall) -> None:
        """End a persistent call: smooth return (motion), neutral face, music stop; nothing for the others."""
        impl = self.behaviours.get(behaviour)
        if impl is not None:
            await impl.reset(call, channel)

    async def speak(self, text: str, call: RunningCall) -> str:
        """Say one sentence at once: PLAY when a start would be due (``start_due_us``; with a generous bound
        on its length), synthesise meanwhile, then a STOP timed at start + the synthesised duration."""
        from host.speech.tts import estimate_duration_s

        payload = text.encode("utf-8")[:200].decode("utf-8", "ignore")
        volume = int(max(0, min(100, 70 * self.voice.loudness_factor)))
        bound_s = 2.0 * estimate_duration_s(text, self._rate_wpm()) + 2.0
        play = SpeakerCommand(SpeakerAction.PLAY, SoundKind.SPEECH, 0, int(bound_s * 1000), volume, text=payload)
        start = self._start_due(play)
        await self.link.send_peripheral(dataclasses.replace(play, start_at_us=start))
        async with self._stop_on_cancel(call, SpeakerCommand(SpeakerAction.STOP, SoundKind.SPEECH, 0, 0, 0)):
            duration = min(await self._speech_duration(text), bound_s)
            end = start + int(duration * 1e6)
            await self.link.send_peripheral(SpeakerCommand(SpeakerAction.STOP, SoundKind.SPEECH, end, 0, 0))
            await self.streamer.wait_board_time(start)
            self._mark(call, start=start * 1e-6)
            await self.streamer.wait_board_time(end)
        self._mark(call, end=end * 1e-6)
        return f"said {text!r} ({duration:.2f} s)"

    @contextlib.asynccontextmanager
    async def _stop_on_cancel(self, call: RunningCall, stop: ScreenCommand | SpeakerCommand) -> AsyncIterator[None]:
        """If the call is cancelled (interrupted), stop its peripheral at the next frame time."""
        try:
            yield
        except anyio.get_cancelled_exc_class():
            if not self._cleanups.aborted:
                with self._cleanups.shielded(5):
                    now = self._start_due(stop)
                    await self.link.send_peripheral(dataclasses.replace(stop, start_at_us=now))
                    self._mark(call, end=now * 1e-6)
            raise

    def abort_cleanups(self) -> None:
        """Stop at once (a second Ctrl-C): the smooth stops of cancelled motions (shielded for
        ``STOP_TIMEOUT_S``) and the peripheral stops of cancelled calls (5 s) running now are cut short,
        and later ones skipped. The caller cancels the calls themselves."""
        self._cleanups.abort()

    # -- behaviours ----------------------------------------------------------------------------
    def _rate_wpm(self) -> int:
        return int(175 * self.voice.rate_factor)

    async def _speech_duration(self, text: str) -> float:
        if self._speech_synth is None:
            from host.speech import synthesize_async

            self._speech_synth = synthesize_async
        rate = self._rate_wpm()
        async with self.streamer.busy():  # synthesis takes wall time; a lockstep board waits for it at a report
            utt = await self._speech_synth(text, self.run_dir / "speech", rate_wpm=rate)
        return float(utt.duration_s)

    def _plan_start(self, channel: str) -> tuple[int | None, int | None]:
        """Where a new finite motion on ``channel`` starts: (start on the frame grid, time whose
        targets it starts from), the previous segment's planned end while that is still ahead."""
        last = self._last.get(channel)
        end = None if last is None or last.release_us is not None else last.end_us
        if end is None or self.streamer.grid(end) < self.streamer.first_free_us:
            return None, None
        return self.streamer.grid(end), end

    async def _stop(self, call: RunningCall, seg: Segment, channel: str) -> None:
        """Interrupted finite motion: flush and settle smoothly where it is."""
        if seg.first_frame_us is None:  # planned ahead and not sent yet: just drop it
            self.mixer.cancel(seg)
            return
        servos = self._servos(channel, seg)
        new = await self.streamer.cut([seg], servos, lambda q: transition(q, q, servos, self.limits),
                                      label="stop")
        if new is not None:
            with anyio.move_on_after(5):
                self._mark(call, end=await self.streamer.wait_ended(new))

    async def _show(self, call: RunningCall, msg: ScreenCommand | SpeakerCommand) -> int:
        """Send a peripheral command timed at the next start due, wait for that board time and mark it as
        ``call``'s start; returns it (board µs)."""
        start = self._start_due(msg)
        await self.link.send_peripheral(dataclasses.replace(msg, start_at_us=start))
        await self.streamer.wait_board_time(start)
        self._mark(call, start=start * 1e-6)
        return start

    async def _end_at(self, call: RunningCall, stop: ScreenCommand | SpeakerCommand, end: int) -> None:
        """Wait until board time ``end`` (µs), sending ``stop`` if the call is interrupted; mark its end."""
        async with self._stop_on_cancel(call, stop):
            await self.streamer.wait_board_time(end)
        self._mark(call, end=end * 1e-6)

    async def _end_now(self, call: RunningCall, stop: ScreenCommand | SpeakerCommand) -> None:
        """A persistent peripheral call's reset: ``stop`` at the next start due; its end is marked then."""
        t = self._start_due(stop)
        await self.link.send_peripheral(dataclasses.replace(stop, start_at_us=t))
        await self.streamer.wait_board_time(t)
        self._mark(call, end=t * 1e-6)


class Behaviour(Protocol):
    """One behaviour's implementation in :attr:`RobotRuntime.behaviours`: ``perform`` runs a call (a persistent
    one until it is cancelled), ``reset`` ends a persistent one."""

    async def perform(self, call: RunningCall, channel: str, args: dict[str, Any]) -> str: ...

    async def reset(self, call: RunningCall, channel: str) -> None: ...


async def _hold_if_persistent(call: RunningCall) -> None:
    """An instantaneous behaviour used as a parent element stays active until it is reset."""
    if call.persistent:
        await anyio.sleep_forever()


@dataclass
class MotionBehaviour:
    """A motion behaviour of the robot (``robot.behaviours[name]``): planned from where its servos are
    planned to be, flowing on from the previous call on its channel; persistent: loops until reset."""

    rt: RobotRuntime
    name: str

    async def perform(self, call: RunningCall, channel: str, args: dict[str, Any]) -> str:
        rt, persistent = self.rt, call.persistent
        at_us, from_us = rt._plan_start(channel)
        if at_us is None:  # a fresh start: as soon as the link allows, from rest (minimum-jerk start)
            start = rt.streamer.planned_targets(rt.streamer.start_due_us())
            motion = ease_in(rt.robot.behaviours[self.name](start, persistent=persistent, **args))
            seg = await rt.streamer.start_now(motion, label=call.path)
        else:  # flowing on from the previous call on this channel
            start = rt.streamer.planned_targets(from_us)
            motion = rt.robot.behaviours[self.name](start, persistent=persistent, **args)
            seg = rt.streamer.add(motion, label=call.path, start_us=at_us)
        if persistent:
            rt._last.pop(channel, None)
            rt._active[call.element_id] = seg
            rt._mark(call, start=await rt.streamer.wait_started(seg))
            await anyio.sleep_forever()
        rt._last[channel] = seg
        try:
            rt._mark(call, start=await rt.streamer.wait_started(seg))
            planned_end = seg.end_us
            if planned_end is not None:
                await rt.streamer.wait_board_time(planned_end - rt.streamer.lookahead_us - HANDOVER_LEAD_US)
                call.hand_over()
            end = await rt.streamer.wait_ended(seg)
        except anyio.get_cancelled_exc_class():
            if rt._cleanups.aborted:  # stopped at once: no smooth stop to wait for
                rt._mark(call, end=rt.board_now_s())
                raise
            with rt._cleanups.shielded(STOP_TIMEOUT_S) as (shield, scope):
                await rt._stop(call, seg, channel)
            if scope.cancelled_caught or shield.cancel_called:
                rt._mark(call, end=rt.board_now_s())
            raise
        rt._mark(call, end=end)
        return f"{self.name} done"

    async def reset(self, call: RunningCall, channel: str) -> None:
        """Smooth return to the rest pose from where the looping segment is cut."""
        rt = self.rt
        seg = rt._active.pop(call.element_id, None)
        if seg is None:
            return
        servos = rt._servos(channel, seg)
        rest = rt._rest[list(servos)]
        new = await rt.streamer.cut([seg], servos, lambda q: transition(q, rest, servos, rt.limits),
                                    label=f"{call.path}:reset")
        if new is not None:
            rt._mark(call, end=await rt.streamer.wait_ended(new))


_NEUTRAL_FACE = ScreenCommand(ScreenTarget.FACE, "neutral", 0, 0)


@dataclass
class FaceBehaviour:
    """``face_emo``: show an expression for ``duration`` s (persistent: until reset, then neutral)."""

    rt: RobotRuntime

    async def perform(self, call: RunningCall, channel: str, args: dict[str, Any]) -> str:
        duration = 0.0 if call.persistent else float(args.get("duration", 2.0))
        start = await self.rt._show(call, ScreenCommand(ScreenTarget.FACE, str(args["emo"]), 0, int(duration * 1000)))
        await _hold_if_persistent(call)
        await self.rt._end_at(call, _NEUTRAL_FACE, start + int(duration * 1e6))
        return f"face {args['emo']} shown for {duration:g} s"

    async def reset(self, call: RunningCall, channel: str) -> None:
        await self.rt._end_now(call, _NEUTRAL_FACE)


@dataclass
class MusicBehaviour:
    """``play_bgm``: play a clip for ``duration`` s (persistent: until reset, then STOP)."""

    rt: RobotRuntime
    #: element id -> the clip a persistent call is playing (its reset stops that one)
    playing: dict[int, str] = field(default_factory=dict)

    async def perform(self, call: RunningCall, channel: str, args: dict[str, Any]) -> str:
        rt = self.rt
        duration = 0.0 if call.persistent else float(args.get("duration") or 5.0)
        name = str(args.get("name", "happy"))  # UTF-8 byte bound checked by the mapper
        note = ""
        if rt.clips is not None and name not in rt.clips:
            note = f"; note: this robot has no clip {name!r}, played 'happy' instead (clips: {', '.join(rt.clips)})"
            name = "happy"
        start = await rt._show(call, SpeakerCommand(SpeakerAction.PLAY, SoundKind.CLIP, 0, int(duration * 1000),
                                                    int(args.get("volume", 60)), name=name))
        if call.persistent:
            self.playing[call.element_id] = name
            await anyio.sleep_forever()
        await rt._end_at(call, SpeakerCommand(SpeakerAction.STOP, SoundKind.CLIP, 0, 0, 0, name=name),
                         start + int(duration * 1e6))
        return f"music {name!r} played for {duration:g} s{note}"

    async def reset(self, call: RunningCall, channel: str) -> None:
        name = self.playing.pop(call.element_id, "")
        await self.rt._end_now(call, SpeakerCommand(SpeakerAction.STOP, SoundKind.CLIP, 0, 0, 0, name=name))


@dataclass
class CaptureBehaviour:
    """``capture``: a camera frame saved as ``capture_<n>.png`` in the run directory."""

    rt: RobotRuntime

    async def perform(self, call: RunningCall, channel: str, args: dict[str, Any]) -> str:
        rt = self.rt
        rt._mark(call, start=rt.board_now_s())
        png = await rt.link.capture(160, 120)
        path = rt.run_dir / f"capture_{len(rt.captures) + 1}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(png)
        rt.captures.append(path)
        rt._mark(call, end=rt.board_now_s())
        await _hold_if_persistent(call)
        return f"photo saved to {path.name} ({len(png)} bytes)"

    async def reset(self, call: RunningCall, channel: str) -> None:
        return None


@dataclass
class SpeechRoleBehaviour:
    """``speech_role``: the :class:`Voice` later speech uses (an unknown role falls back to "robot")."""

    rt: RobotRuntime

    async def perform(self, call: RunningCall, channel: str, args: dict[str, Any]) -> str:
        rt = self.rt
        role = str(args.get("role", "robot"))
        note = ""
        if role not in rt.voices:
            note = f"; note: this robot has no voice {role!r}, using 'robot' (voices: {', '.join(rt.voices)})"
            role = "robot"
        rt.voice = Voice(**{**args, "role": role})
        t = rt.board_now_s()
        rt._mark(call, t, t)
        await _hold_if_persistent(call)
        v = rt.voice
        return (f"voice {v.role!r}, emotion {v.emotion!r}, rate {v.speech_rate:+g}%, loudness "
                f"{v.loudness_rate:+g}%{note}")

    async def reset(self, call: RunningCall, channel: str) -> None:
        return None
