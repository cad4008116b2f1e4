"""Declarations shared by the registry, mapper, prompt and scheduler.

A shell function is an ``async def`` with type hints and a docstring. Parameters
may be ``int``, ``float``, ``bool``, ``str``, ``Literal[...]``, an ``Enum``,
``Optional[...]`` of those, or ``Annotated[int | float, Range(lo, hi)]``.
:func:`shell_function` attaches shell options (aliases, reset hook, speech) to a
callable or to an interface stub; :class:`FunctionSpec` is the resolved,
mountable form.
"""

from __future__ import annotations

import inspect
import typing
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

from host.shell.context import CallContext, context_param

#: Name of the main channel C0.
MAIN_CHANNEL = "main"

#: Element names the shell itself interprets; modules may not declare them.
BUILTINS = frozenset({"wait", "async", "SAVE", "RUN"})

#: Reserved attribute putting any element's call on the main channel.
SYNC_ATTR = "sync"

AsyncFn = Callable[..., Awaitable[Any]]


@dataclass(frozen=True)
class Range:
    """Inclusive value range for a numeric parameter: ``Annotated[float, Range(0, 10)]``."""

    lo: float
    hi: float

    def __repr__(self) -> str:
        return f"Range({_num(self.lo)}, {_num(self.hi)})"


def as_range(meta: Any) -> Range | None:
    """``meta`` as a :class:`Range`: a Range itself, or an ``annotated_types`` bound.

    Interfaces that may not import the shell (robot descriptions) declare ranges
    with the neutral ``annotated_types`` package (``Interval(ge=0, le=10)``,
    ``Ge``/``Le``); both spellings mean the same to the mapper and the prompt.
    """
    if isinstance(meta, Range):
        return meta
    lo = getattr(meta, "ge", None)
    hi = getattr(meta, "le", None)
    if lo is None and hi is None:
        return None
    return Range(float("-inf") if lo is None else lo, float("inf") if hi is None else hi)


def _num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else repr(float(x))


@dataclass(frozen=True)
class FunctionOptions:
    """Options set with :func:`shell_function`."""

    name: str | None = None
    aliases: tuple[str, ...] = ()
    reset: AsyncFn | str | None = None
    speech: bool = False


_OPTS_ATTR = "__ghostshell__"


def shell_function(
    fn: Any = None,
    *,
    name: str | None = None,
    aliases: tuple[str, ...] | list[str] = (),
    reset: AsyncFn | str | None = None,
    speech: bool = False,
) -> Any:
    """Decorate a function (or interface stub) with shell options.

    ``aliases`` are extra element names for the same implementation; ``reset`` is
    an async hook (or the name of an implementation method) awaited, without
    arguments, when an element of this function is reset (its end-tag lifecycle
    ends, or it is interrupted); ``speech=True`` marks the function that plain
    text maps to (it must take one ``text: str`` parameter).
    """

    def apply(f: Any) -> Any:
        setattr(f, _OPTS_ATTR, FunctionOptions(name, tuple(aliases), reset, speech))
        return f

    return apply(fn) if fn is not None else apply


def options_of(fn: Any) -> FunctionOptions:
    """Shell options attached to ``fn`` (defaults when undecorated)."""
    return getattr(fn, _OPTS_ATTR, None) or FunctionOptions()


@dataclass(frozen=True)
class Param:
    """One declared parameter of a shell function."""

    name: str
    annotation: Any
    default: Any = inspect.Parameter.empty

    @property
    def required(self) -> bool:
        """True when the parameter has no default."""
        return self.default is inspect.Parameter.empty


@dataclass(frozen=True)
class FunctionSpec:
    """A mounted function: its interface (name, params, doc) bound to an implementation."""

    name: str
    module: str
    channel: str
    impl: AsyncFn
    params: tuple[Param, ...]
    doc: str = ""
    reset: AsyncFn | None = None
    speech: bool = False
    aliases: tuple[str, ...] = ()
    interface: Any = None
    #: the parameter of ``impl`` / ``reset`` that receives the call's :class:`CallContext` (None: it takes none)
    call_param: str | None = None
    reset_call_param: str | None = None

    def param(self, name: str) -> Param | None:
        """The parameter called ``name``, or None."""
        for p in self.params:
            if p.name == name:
                return p
        return None


def params_of(stub: Any) -> tuple[Param, ...]:
    """Read the declared parameters of ``stub`` (``self`` and a :class:`CallContext` parameter dropped,
    hints resolved with extras)."""
    sig = inspect.signature(stub)
    try:
        hints = typing.get_type_hints(stub, include_extras=True)
    except Exception as exc:  # unresolvable forward reference
        raise TypeError(f"cannot resolve type hints of {getattr(stub, '__qualname__', stub)!r}: {exc}") from exc
    out: list[Param] = []
    for p in sig.parameters.values():
        if p.name == "self" or p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD) or hints.get(p.name) is CallContext:
            continue
        if p.kind is p.POSITIONAL_ONLY:
            raise TypeError(f"{stub.__qualname__}: positional-only parameter {p.name!r} cannot be an attribute")
        out.append(Param(p.name, hints.get(p.name, str), p.default))
    return tuple(out)


@dataclass
class Module:
    """A named group of functions on one channel, mountable on a :class:`Registry`.

    Build one with :meth:`from_functions` (plain async callables) or :meth:`bind`
    (an abstract interface class whose stubs are shown to the LLM, bound to a
    concrete implementation object at mount time: dependency injection).
    """

    name: str
    functions: list[FunctionSpec] = field(default_factory=list)
    channel: str = ""
    doc: str = ""
    hidden: bool = False  # callable, but left out of the prompt (e.g. a second vocabulary)

    def __post_init__(self) -> None:
        if not self.channel:
            self.channel = self.name
        if self.channel == MAIN_CHANNEL:
            raise ValueError(f"module {self.name!r}: channel name {MAIN_CHANNEL!r} is reserved for C0")

    @classmethod
    def from_functions(cls, name: str, *fns: AsyncFn, channel: str | None = None, doc: str = "") -> Module:
        """A module whose interface and implementation are the same callables."""
        ch = channel or name
        specs = [_spec(fn, fn, None, name, ch) for fn in fns]
        return cls(name, specs, ch, doc)

    @classmethod
    def bind(cls, name: str, interface: type, implementation: Any, channel: str | None = None) -> Module:
        """Bind the public stubs of ``interface`` to same-named methods of ``implementation``.

        A reset hook is taken from the stub's ``shell_function(reset=...)`` (a
        callable or a method name) or, failing that, an implementation method
        called ``reset_<name>``.
        """
        ch = channel or name
        specs: list[FunctionSpec] = []
        for attr, stub in vars(interface).items():
            if attr.startswith("_") or not callable(stub):
                continue
            target = getattr(implementation, attr, None)
            if target is None or not callable(target):
                raise TypeError(f"module {name!r}: implementation {type(implementation).__name__} lacks {attr!r}")
            specs.append(_spec(stub, target, implementation, name, ch))
        return cls(name, specs, ch, inspect.getdoc(interface) or "")


    @classmethod
    def interface_only(cls, name: str, interface: type, channel: str | None = None) -> Module:
        """The stubs of ``interface`` with no implementation (calls raise NotImplementedError).

        For rendering prompts from an interface that lives where ``host`` cannot
        be imported (``robots/``); mount a :meth:`bind` module to execute.
        """

        class _Unbound:
            def __getattr__(self, attr: str) -> Any:
                async def missing(*_: Any, **__: Any) -> None:
                    raise NotImplementedError(f"{name}.{attr} has no implementation bound")

                return missing

        ch = channel or name
        specs = [
            _spec(stub, getattr(_Unbound(), attr), None, name, ch)
            for attr, stub in vars(interface).items()
            if not attr.startswith("_") and callable(stub)
        ]
        return cls(name, specs, ch, inspect.getdoc(interface) or "")


def _spec(stub: Any, impl: AsyncFn, owner: Any, module: str, channel: str) -> FunctionSpec:
    opts = options_of(stub)
    fname = opts.name or stub.__name__
    if not inspect.iscoroutinefunction(impl):
        raise TypeError(f"{module}.{fname}: implementation must be an async def")
    reset: Any = opts.reset
    if isinstance(reset, str):
        reset = getattr(owner, reset, None) if owner is not None else None
        if reset is None:
            raise TypeError(f"{module}.{fname}: reset hook {opts.reset!r} not found")
    if reset is None and owner is not None:
        reset = getattr(owner, f"reset_{fname}", None)
    if reset is not None and not inspect.iscoroutinefunction(reset):
        raise TypeError(f"{module}.{fname}: reset hook must be an async def")
    params = params_of(stub)
    if opts.speech and not any(p.name == "text" for p in params):
        raise TypeError(f"{module}.{fname}: a speech function needs a 'text: str' parameter")
    return FunctionSpec(
        name=fname,
        module=module,
        channel=channel,
        impl=impl,
        params=params,
        doc=inspect.getdoc(stub) or "",
        reset=reset,
        speech=opts.speech,
        aliases=opts.aliases,
        interface=stub,
        call_param=context_param(impl),
        reset_call_param=context_param(reset) if reset is not None else None,
    )
