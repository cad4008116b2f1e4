"""Bind a robot's interface stubs (:attr:`robots.description.Robot.interface`) to behaviours: shell modules.

Every vocabulary of the robot is mounted so the mapper accepts any of them; the one chosen for the
prompt is visible, the others are mounted hidden (callable, not shown). A name several vocabularies
declare is taken from the visible one. Each stub becomes an async function that fills the stub's
defaults, renames parameters, pins fixed arguments and hands the behaviour call, with the call's
context from the scheduler (:class:`host.shell.context.RunningCall`: element path and id, persistent,
hand-over), to a :class:`Performer` (the runtime that really moves the robot, or a fake one in tests). Plain text is
spoken only by a robot with a speaker (:func:`speech_module`).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any, Protocol

from host.shell.context import CallContext, RunningCall
from host.shell.registry import Registry
from host.shell.types import Module, shell_function
from robots.description import Robot
from robots.interface import StubInfo, class_stubs, stub_info


class Performer(Protocol):
    """What the binding needs from a runtime. ``call`` is the shell call being run (or reset)."""

    async def perform(self, behaviour: str, channel: str, args: dict[str, Any], call: RunningCall) -> Any: ...

    async def reset(self, behaviour: str, channel: str, call: RunningCall) -> None: ...

    async def speak(self, text: str, call: RunningCall) -> Any: ...


def _bound_call(stub: Callable[..., Any], info: StubInfo, performer: Performer) -> Callable[..., Any]:
    sig = inspect.signature(stub)

    async def call(shell_call: CallContext, **kwargs: Any) -> Any:
        bound = sig.bind_partial(None, **kwargs)  # None stands for the stub's self
        bound.apply_defaults()
        args = {info.rename.get(k, k): v for k, v in bound.arguments.items() if k != "self"}
        args.update(info.fixed)
        return await performer.perform(info.behaviour, info.channel, args, shell_call)

    call.__name__ = stub.__name__
    return call


def _bound_reset(info: StubInfo, performer: Performer) -> Callable[..., Any]:
    async def reset(shell_call: CallContext) -> None:
        await performer.reset(info.behaviour, info.channel, shell_call)

    return reset


def vocabulary_modules(robot: Robot, vocabulary: str, performer: Performer, *, hidden: bool = False,
                       skip: frozenset[str] = frozenset()) -> list[Module]:
    """Shell modules for one of ``robot``'s vocabularies, bound to ``performer``."""
    vocabularies = robot.interface.vocabularies
    if vocabulary not in vocabularies:
        raise ValueError(f"unknown vocabulary {vocabulary!r} for {robot.name}; choose one of {sorted(vocabularies)}")
    out: list[Module] = []
    for module_name, iface in vocabularies[vocabulary].items():
        stubs = {n: f for n, f in class_stubs(iface).items() if n not in skip}
        if not stubs:
            continue
        impl = SimpleNamespace()
        channel = ""
        for name, fn in stubs.items():
            info = stub_info(fn)
            assert info is not None
            channel = info.channel
            setattr(impl, name, _bound_call(fn, info, performer))
            setattr(impl, f"reset_{name}", _bound_reset(info, performer))
        view = type(iface.__name__, (), {"__doc__": iface.__doc__, **stubs})
        mod = Module.bind(module_name if not hidden else f"{vocabulary}:{module_name}", view, impl, channel=channel)
        mod.hidden = hidden
        out.append(mod)
    return out


def speech_module(performer: Performer) -> Module:
    """The speech channel: plain text in the stream is spoken by ``speak``."""

    @shell_function(speech=True)
    async def speak(text: str, shell_call: CallContext) -> Any:
        """Say `text` aloud (you do not call this: plain text outside tags is spoken)."""
        return await performer.speak(text, shell_call)

    return Module.from_functions("speak", speak, channel="speech", doc="the speaker")


def robot_registry(robot: Robot, performer: Performer, vocabulary: str | None = None) -> Registry:
    """A registry with ``robot`` mounted: ``vocabulary`` (default: the robot's) visible, the others hidden."""
    vocabulary = robot.interface.default if vocabulary is None else vocabulary
    visible = vocabulary_modules(robot, vocabulary, performer)
    registry = Registry([speech_module(performer)] if robot.peripherals.speaker else [])
    names: set[str] = set()
    for m in visible:
        registry.mount(m)
        names.update(s.name for s in m.functions)
    for other in robot.interface.names:
        if other != vocabulary:
            for m in vocabulary_modules(robot, other, performer, hidden=True, skip=frozenset(names)):
                registry.mount(m)
                names.update(s.name for s in m.functions)
    return registry


class _SignaturesOnly:
    """A performer for registries that are only read (prompts, tool schemas, policy checks)."""

    async def perform(self, behaviour: str, channel: str, args: dict[str, Any], call: RunningCall) -> Any:
        raise RuntimeError(f"{behaviour}: this registry lists the robot's functions; it runs nothing")

    async def reset(self, behaviour: str, channel: str, call: RunningCall) -> None:
        return None

    async def speak(self, text: str, call: RunningCall) -> Any:
        raise RuntimeError("this registry lists the robot's functions; it runs nothing")


def signature_registry(robot: Robot, vocabulary: str | None = None) -> Registry:
    """``robot``'s registry for reading only: its prompt, its tools' schemas (calls raise RuntimeError)."""
    return robot_registry(robot, _SignaturesOnly(), vocabulary)


def function_params(robot: Robot) -> dict[str, frozenset[str]]:
    """Every function ``robot``'s shell accepts (all vocabularies, aliases included) -> its parameter names
    (for checking a safety policy's names: :meth:`host.shell.policy.Policy.check_names`)."""
    registry = signature_registry(robot)
    out: dict[str, frozenset[str]] = {}
    for spec in registry.functions():
        params = frozenset(p.name for p in spec.params)
        for name in (spec.name, *spec.aliases, *registry.aliases_of(spec)):
            out[name] = params
    return out
