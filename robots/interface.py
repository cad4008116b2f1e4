"""Function interfaces as plain Python stubs: what a robot package declares and the LLM sees.

A robot's interface module (``interface = "MODULE"`` in its robot.toml) declares one or more
*vocabularies*: ``VOCABULARIES: dict[vocabulary, dict[module name, class]]``. Each class holds
stubs, methods with type hints, defaults, ranges (``annotated_types`` constraints), a docstring
and no body, marked with :func:`stub` to say which channel runs them and which *behaviour*
implements them (with renamed parameters and pinned arguments). A behaviour is either one of the
robot's motion generators (its behaviours module, plus the generic ``pose`` and ``joint_move``) or
a peripheral behaviour the host implements over the wire (:data:`PERIPHERAL_BEHAVIOURS`).

:func:`build_interface` adds the generic module ``joints`` (:mod:`robots.generic`) to every
vocabulary and leaves out stubs whose peripheral the robot lacks (no camera: no ``capture``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import ModuleType
from typing import Annotated, Any

from robots.datatypes import RobotData, RobotDataError
from robots.generic import generic_module
from robots.stubs import StubInfo, class_stubs, stub, stub_info

__all__ = [
    "Interface",
    "MaxUtf8Bytes",
    "NAME_BYTES",
    "Name",
    "PERIPHERAL_BEHAVIOURS",
    "StubInfo",
    "build_interface",
    "class_stubs",
    "stub",
    "stub_info",
]

#: behaviours the host implements over the wire -> the peripheral they need (robot.toml [peripherals])
PERIPHERAL_BEHAVIOURS: dict[str, str] = {
    "face_emo": "screen",  # SCREEN: an expression on the face screen
    "play_bgm": "speaker",  # SPEAKER: background music
    "speech_role": "speaker",  # the voice of the following speech
    "capture": "camera",  # CAMERA_CAPTURE: a photo as an observation
}


@dataclass(frozen=True)
class MaxUtf8Bytes:
    """A string bound in bytes of UTF-8 (the wire limit of the board's name fields)."""

    max_bytes: int


#: longest voice or music name, in UTF-8 bytes (``protocol.codec.MAX_NAME_BYTES``)
NAME_BYTES = 32
#: an open set of names in any language: voices, music clips
Name = Annotated[str, MaxUtf8Bytes(NAME_BYTES)]


@dataclass(frozen=True)
class Interface:
    """A robot's vocabularies: vocabulary -> module name -> class of stubs (the generic ``joints`` included).

    ``default``: the vocabulary a prompt shows unless told otherwise; ``channel_docs``: one line per
    channel for the prompt; ``left_out``: stubs dropped because a peripheral is absent (name -> why).
    """

    vocabularies: Mapping[str, Mapping[str, type]]
    default: str
    channel_docs: Mapping[str, str] = field(default_factory=dict)
    left_out: Mapping[str, str] = field(default_factory=dict)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.vocabularies)

    def stubs(self, vocabulary: str | None = None) -> dict[str, tuple[Callable[..., Any], StubInfo]]:
        """All stubs of a vocabulary: name -> (function, mapping info)."""
        vocab = self.default if vocabulary is None else vocabulary
        try:
            modules = self.vocabularies[vocab]
        except KeyError:
            raise ValueError(f"unknown vocabulary {vocab!r}; choose one of {sorted(self.vocabularies)}") from None
        out: dict[str, tuple[Callable[..., Any], StubInfo]] = {}
        for cls in modules.values():
            for name, fn in class_stubs(cls).items():
                out[name] = (fn, stub_info(fn))  # type: ignore[assignment]
        return out


def build_interface(robot: RobotData, module: ModuleType | None) -> Interface:
    """The robot's interface: its module's vocabularies (or one empty ``default``) plus ``joints``,
    stubs needing an absent peripheral left out, every stub's behaviour checked to exist."""
    where = robot.root / f"{robot.interface_module}.py" if robot.interface_module else robot.root / "robot.toml"
    declared = getattr(module, "VOCABULARIES", None) if module is not None else {robot.default_vocabulary: {}}
    if not isinstance(declared, Mapping) or not declared:
        raise RobotDataError(f"{where}: needs VOCABULARIES = {{vocabulary: {{module: class}}}}")
    if robot.default_vocabulary not in declared:
        raise RobotDataError(f"{robot.root / 'robot.toml'}: default_vocabulary {robot.default_vocabulary!r} is not one "
                             f"of {where.name}'s vocabularies ({', '.join(declared)})")
    present = {"camera": robot.peripherals.camera is not None, "screen": robot.peripherals.screen,
               "speaker": robot.peripherals.speaker}
    behaviours = robot.behaviours
    joints = generic_module(robot)
    left_out: dict[str, str] = {}
    vocabularies: dict[str, dict[str, type]] = {}
    for vocab, modules in declared.items():
        kept: dict[str, type] = {}
        for mod_name, cls in modules.items():
            stubs = class_stubs(cls)
            keep = {}
            for name, fn in stubs.items():
                info = stub_info(fn)
                assert info is not None
                need = PERIPHERAL_BEHAVIOURS.get(info.behaviour)
                if need is not None and not present[need]:
                    left_out[name] = f"needs a {need}"
                    continue
                if need is None and info.behaviour not in behaviours:
                    raise RobotDataError(f"{where}: stub {cls.__name__}.{name} names behaviour {info.behaviour!r}, "
                                         "which neither the robot's behaviours module nor the host implements")
                keep[name] = fn
            if keep:
                kept[mod_name] = cls if len(keep) == len(stubs) else \
                    type(cls.__name__, (), {"__doc__": cls.__doc__, "__module__": cls.__module__, **keep})
        if "joints" in kept:
            raise RobotDataError(f"{where}: the module name 'joints' is the generic functions' (pose, joint_move)")
        kept["joints"] = joints
        vocabularies[vocab] = kept
    docs = {name: c.doc for name, c in robot.channels.items()}
    docs.setdefault("joints", "whole-robot moves to named poses and single-joint moves (every servo)")
    own_docs = getattr(module, "CHANNELS", None) if module is not None else None
    if isinstance(own_docs, Mapping):
        docs.update({str(k): str(v) for k, v in own_docs.items()})
    return Interface(vocabularies, robot.default_vocabulary, docs, left_out)
