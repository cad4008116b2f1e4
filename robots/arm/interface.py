"""The arm's function interface: the stubs an LLM sees, in one vocabulary (``default``).

Plain Python stubs (type hints, defaults, ranges as ``annotated_types`` constraints, docstrings, no
body); each names the channel that runs it and the behaviour that implements it
(:func:`robots.interface.stub`): the motion generators of :mod:`robots.arm.behaviours`, and the
peripheral behaviours the host implements (``capture`` with the wrist camera, ``play_bgm`` on the
speaker). Plain text the LLM writes is spoken (the arm has a speaker). The generic ``pose`` and
``joint_move`` (:mod:`robots.generic`) are added to the vocabulary by the loader.

Object names are the movable objects of the arm's table scene (robot.toml ``[scenes.table]``);
places add the named spots of ``places.toml`` (tests/robots/test_arm.py checks both lists against
the data). One call = one gesture: a rhythmic gesture called without ``times``/``duration`` plays
once; used as a parent element it keeps going until its children finish.
"""

from __future__ import annotations

from typing import Annotated, Literal

from annotated_types import Interval

from robots.interface import Name, stub

__all__ = ["CHANNELS", "VOCABULARIES", "ObjectName", "PlaceName"]

#: the objects on the table (the table scene's movable objects)
ObjectName = Literal["red_cube", "blue_cube"]
#: where an object can go or the gripper can point: an object, or a named spot on the table
PlaceName = Literal["red_cube", "blue_cube", "front", "left", "right"]
Seconds = Annotated[float, Interval(ge=0.0, le=120.0)]
Times = Annotated[int, Interval(ge=1, le=30)]
Volume = Annotated[int, Interval(ge=0, le=100)]

CHANNELS: dict[str, str] = {
    "arm": "the five arm joints: gestures, pointing, pick and place (one call at a time)",
    "gripper": "the gripper jaw: grip, release, snap (runs alongside the arm)",
    "speech": "the speaker, for speech (plain text you write is spoken here)",
    "bgm": "background music, mixed under speech",
    "camera": "the wrist camera at the gripper",
}


class Arm:
    """The arm (shoulder, elbow, wrist): gestures and handling the cubes on the table."""

    @stub("arm")
    def point_at(self, target: PlaceName = "red_cube") -> None:
        """Point the gripper straight down at an object or a spot on the table (front, left, right), from a
        few centimetres above it; the wrist camera then sees it."""

    @stub("arm")
    def wave(self, times: Times = 1, duration: Seconds = 0.0) -> None:
        """Raise the hand and wave side to side: one wave, `times` waves, or waves for `duration` seconds when
        it is > 0; then lower the hand back where it was."""

    @stub("arm")
    def nod(self, times: Times = 1, duration: Seconds = 0.0) -> None:
        """Nod with the wrist (the hand dips and comes back): once, `times` times, or for `duration` seconds."""

    @stub("arm")
    def shake(self, times: Times = 1, duration: Seconds = 0.0) -> None:
        """Shake the hand "no" (the wrist rolls one way and the other): once, `times` times, or for `duration`
        seconds."""

    @stub("arm")
    def pick(self, object: ObjectName = "red_cube") -> None:
        """Pick an object up from where it lies on the table and hold it a few centimetres above that spot
        (opens the gripper, reaches down, grips, lifts)."""

    @stub("arm")
    def place(self, object: ObjectName = "red_cube", on: PlaceName = "front") -> None:
        """Put the object you hold down on top of another object or on a spot of the table (front, left,
        right), let go and lift the hand."""


class Gripper:
    """The gripper's moving jaw."""

    @stub("gripper")
    def grip(self) -> None:
        """Close the gripper (squeezes whatever is between the jaws)."""

    @stub("gripper")
    def release(self) -> None:
        """Open the gripper (lets go of what it holds)."""

    @stub("gripper")
    def snap(self, times: Times = 1, duration: Seconds = 0.0) -> None:
        """Snap the jaws open and shut like a beak: once, `times` times, or for `duration` seconds."""


class Music:
    """Background music on the speaker."""

    @stub("bgm")
    def play_bgm(self, duration: Seconds = 5.0, name: Name = "happy", volume: Volume = 60) -> None:
        """Play background music `name` for `duration` seconds (as a parent: until its children finish)."""


class Camera:
    """The wrist camera."""

    @stub("camera")
    def capture(self) -> None:
        """Take a photo with the wrist camera; the image is returned as an observation."""


VOCABULARIES: dict[str, dict[str, type]] = {
    "default": {"arm": Arm, "gripper": Gripper, "bgm": Music, "camera": Camera},
}
