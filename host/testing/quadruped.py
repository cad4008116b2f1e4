"""A small example interface of a quadruped with ears, a head and a face, with a simulated implementation.

Used by the shell tests as fake functions of known duration, and by ``ghostshell prompt --interface
host.testing.quadruped:modules`` to show the shell's prompt without a robot. Each module is an abstract
interface (stubs with hints and docstrings: what the LLM sees) bound by
dependency injection to :class:`SimulatedQuadruped`, whose methods just
``await anyio.sleep(seconds)`` and log what they did. Durations (seconds):

* finite calls: ``duration`` if given, else ``times`` x per-repetition time,
  else the default in :data:`DEFAULT_SECONDS`; ``speak`` takes 0.1 s per character,
  ``rotate`` 1 s per 90 degrees, ``run_distance`` 1 s per 10 cm;
* persistent calls (start-tag elements) loop that action (or hold the posture)
  until reset; reset hooks take :attr:`SimulatedQuadruped.reset_seconds` (0 by default).
"""

from __future__ import annotations

from typing import Annotated, Literal

import anyio

from host.shell.context import CallContext
from host.shell.types import Module, Range, shell_function

Emotion = Literal[
    "smile", "happy", "very_happy", "sad", "very_sad", "calm", "surprise", "angry",
    "frustrated", "very_frustrated", "wink", "wink_left", "wink_right",
]
Direction = Literal["forward", "backward", "left", "right"]

DEFAULT_SECONDS: dict[str, float] = {
    "stand": 1.0, "sit": 1.0, "push_up": 2.0, "wave": 2.0, "chest_expansion_exercise": 3.0,
    "fly_rub_hands": 2.0, "body_lean": 1.0, "wriggle": 2.0, "single_leg_knock": 0.5, "shake_ass": 1.0,
    "creep": 2.0, "move_forward": 2.0, "move_strides": 1.0, "shake_like_dog": 2.0,
    "head_act": 1.0, "head_pose": 0.5, "shake_ear": 1.0, "ear_state": 0.5, "face_emo": 1.0,
    "play_bgm": 5.0, "capture": 0.5,
}


class Body:
    """Whole-body postures and motions (legs)."""

    async def stand(self, posture: Literal["normal", "forward", "backward"] = "normal") -> None:
        """Stand up in a posture. As a parent element the posture is held until its children finish."""

    async def sit(self, style: Literal["normal", "dog"] = "normal") -> None:
        """Sit down."""

    async def push_up(self, times: Annotated[int, Range(1, 20)] = 2, duration: float | None = None) -> None:
        """Do push-ups (``times`` repetitions, or for ``duration`` seconds)."""

    async def wave(self) -> None:
        """Wave a front leg."""

    async def chest_expansion_exercise(self) -> None:
        """Do a chest expansion exercise."""

    async def fly_rub_hands(self) -> None:
        """Rub the front paws together like a fly."""

    async def body_lean(self, direction: Literal["left", "right"]) -> None:
        """Lean (shrug) the body to one side and back."""

    async def run_distance(self, distance: Annotated[float, Range(1, 500)]) -> None:
        """Walk straight ahead ``distance`` centimetres."""

    async def rotate(self, angle: Annotated[float, Range(-720, 720)] = 360) -> None:
        """Rotate in place by ``angle`` degrees (positive: left, negative: right)."""

    async def wriggle(self, duration: Annotated[float, Range(0.5, 30)] = 2) -> None:
        """Wriggle the whole body."""

    async def single_leg_knock(self, leg: Literal[1, 2, 3, 4], times: Annotated[int, Range(1, 10)] = 1) -> None:
        """Tap the ground with one leg (1 front right, 2 front left, 3 back left, 4 back right)."""

    async def shake_ass(self, speed: Annotated[int, Range(1, 100)] = 50, times: Annotated[int, Range(1, 20)] = 1) -> None:
        """Shake the butt. As a parent element it keeps shaking until its children finish."""

    async def creep(self, direction: Direction = "forward", speed: Annotated[int, Range(1, 100)] = 50) -> None:
        """Creep low along the ground."""

    async def move_forward(self) -> None:
        """Walk forward. As a parent element it keeps walking until its children finish."""

    async def move_strides(self, direction: Direction = "forward", times: Annotated[int, Range(1, 20)] = 1) -> None:
        """Take ``times`` strides in ``direction`` (1 s each)."""

    async def shake_like_dog(self) -> None:
        """Shake the whole body like a wet dog. As a parent element it shakes until its children finish."""


class Head:
    """Head motions."""

    async def head_act(self, action: Literal["nod", "shake"] = "nod", duration: float | None = None) -> None:
        """Nod or shake the head once (or for ``duration`` seconds; as a parent element, until its children finish)."""

    async def head_pose(
        self, yaw: Annotated[float, Range(-90, 90)] = 0, pitch: Annotated[float, Range(-30, 30)] = 0
    ) -> None:
        """Turn the head to an absolute pose in degrees (negative yaw: right)."""


class Ears:
    """Ear motions."""

    async def shake_ear(self, duration: Annotated[float, Range(0.2, 30)] = 1) -> None:
        """Shake (flap) both ears."""

    async def ear_state(self, state: Literal["relaxed", "inquisitive", "alert", "droopy"]) -> None:
        """Hold the ears in an expressive state."""


class Face:
    """The face screen."""

    async def face_emo(self, emo: Emotion, duration: Annotated[float, Range(0.2, 60)] = 1) -> None:
        """Show an emotion (or eye wink) on the face screen for ``duration`` seconds."""


class Speech:
    """Text to speech."""

    @shell_function(speech=True)
    async def speak(self, text: str) -> None:
        """Say ``text`` aloud. Plain text in your output is spoken with this function."""


class Bgm:
    """Background music."""

    async def play_bgm(self, name: str = "default", duration: Annotated[float, Range(1, 600)] | None = None) -> None:
        """Play background music (a 5 s clip, or ``duration`` seconds; as a parent element, until its children finish)."""


class Camera:
    """The nose camera."""

    async def capture(self) -> str:
        """Take a photo; returns its file name."""
        raise NotImplementedError("interface stub: Module.bind routes calls to the implementation")


class SimulatedQuadruped:
    """Implements every example interface by sleeping for a known time and logging."""

    def __init__(self, reset_seconds: float = 0.0) -> None:
        self.reset_seconds = reset_seconds
        self.log: list[tuple[float, str, str]] = []  # (time, function, event)
        self.photos = 0

    async def _act(self, ctx: CallContext, name: str, seconds: float, hold: float | None = None) -> None:
        self.log.append((anyio.current_time(), name, "start"))
        if ctx.persistent:
            if hold is not None:  # reach the posture, then hold it
                await anyio.sleep(hold)
                await anyio.sleep_forever()
            while True:
                await anyio.sleep(seconds)
                await ctx.wait_not_overridden()
        await anyio.sleep(seconds)
        self.log.append((anyio.current_time(), name, "end"))

    async def _reset(self, name: str) -> None:
        await anyio.sleep(self.reset_seconds)
        self.log.append((anyio.current_time(), name, "reset"))

    def __getattr__(self, attr: str):  # reset_<name> hooks for every function
        if attr.startswith("reset_") and attr[6:] in DEFAULT_SECONDS:
            name = attr[6:]

            async def reset() -> None:
                await self._reset(name)

            return reset
        raise AttributeError(attr)

    async def stand(self, call: CallContext, posture: str = "normal") -> None:
        await self._act(call, "stand", DEFAULT_SECONDS["stand"], hold=DEFAULT_SECONDS["stand"])

    async def sit(self, call: CallContext, style: str = "normal") -> None:
        await self._act(call, "sit", DEFAULT_SECONDS["sit"])

    async def push_up(self, call: CallContext, times: int = 2, duration: float | None = None) -> None:
        await self._act(call, "push_up", duration if duration is not None else times * 1.0)

    async def wave(self, call: CallContext) -> None:
        await self._act(call, "wave", DEFAULT_SECONDS["wave"])

    async def chest_expansion_exercise(self, call: CallContext) -> None:
        await self._act(call, "chest_expansion_exercise", DEFAULT_SECONDS["chest_expansion_exercise"])

    async def fly_rub_hands(self, call: CallContext) -> None:
        await self._act(call, "fly_rub_hands", DEFAULT_SECONDS["fly_rub_hands"])

    async def body_lean(self, call: CallContext, direction: str) -> None:
        await self._act(call, "body_lean", DEFAULT_SECONDS["body_lean"])

    async def run_distance(self, call: CallContext, distance: float) -> None:
        await self._act(call, "run_distance", distance / 10.0)

    async def rotate(self, call: CallContext, angle: float = 360) -> None:
        await self._act(call, "rotate", abs(angle) / 90.0)

    async def wriggle(self, call: CallContext, duration: float = 2) -> None:
        await self._act(call, "wriggle", duration)

    async def single_leg_knock(self, call: CallContext, leg: int, times: int = 1) -> None:
        await self._act(call, "single_leg_knock", times * DEFAULT_SECONDS["single_leg_knock"])

    async def shake_ass(self, call: CallContext, speed: int = 50, times: int = 1) -> None:
        await self._act(call, "shake_ass", times * 50.0 / speed)

    async def creep(self, call: CallContext, direction: str = "forward", speed: int = 50) -> None:
        await self._act(call, "creep", DEFAULT_SECONDS["creep"])

    async def move_forward(self, call: CallContext) -> None:
        await self._act(call, "move_forward", DEFAULT_SECONDS["move_forward"])

    async def move_strides(self, call: CallContext, direction: str = "forward", times: int = 1) -> None:
        await self._act(call, "move_strides", times * DEFAULT_SECONDS["move_strides"])

    async def shake_like_dog(self, call: CallContext) -> None:
        await self._act(call, "shake_like_dog", DEFAULT_SECONDS["shake_like_dog"])

    async def head_act(self, call: CallContext, action: str = "nod", duration: float | None = None) -> None:
        await self._act(call, "head_act", duration if duration is not None else DEFAULT_SECONDS["head_act"])

    async def head_pose(self, call: CallContext, yaw: float = 0, pitch: float = 0) -> None:
        await self._act(call, "head_pose", DEFAULT_SECONDS["head_pose"])

    async def shake_ear(self, call: CallContext, duration: float = 1) -> None:
        await self._act(call, "shake_ear", duration)

    async def ear_state(self, call: CallContext, state: str) -> None:
        await self._act(call, "ear_state", DEFAULT_SECONDS["ear_state"], hold=DEFAULT_SECONDS["ear_state"])

    async def face_emo(self, call: CallContext, emo: str, duration: float = 1) -> None:
        await self._act(call, "face_emo", duration)

    async def speak(self, call: CallContext, text: str) -> None:
        await self._act(call, "speak", 0.1 * len(text))

    async def play_bgm(self, call: CallContext, name: str = "default", duration: float | None = None) -> None:
        await self._act(call, "play_bgm", duration if duration is not None else DEFAULT_SECONDS["play_bgm"])

    async def capture(self, call: CallContext) -> str:
        await self._act(call, "capture", DEFAULT_SECONDS["capture"])
        self.photos += 1
        return f"photo{self.photos}.jpg"


INTERFACES: dict[str, type] = {
    "body": Body, "head": Head, "ears": Ears, "face": Face, "speech": Speech, "bgm": Bgm, "camera": Camera,
}


def modules(impl: SimulatedQuadruped | None = None) -> list[Module]:
    """The example modules, each interface bound to ``impl`` (a fresh :class:`SimulatedQuadruped` by default)."""
    impl = impl if impl is not None else SimulatedQuadruped()
    return [Module.bind(name, iface, impl) for name, iface in INTERFACES.items()]
