"""The mapper: element -> (function, typed arguments).

:func:`map_element` is the paper's M(E) = (F, theta): it resolves the element
name on the registry and converts every attribute string with T(v)
(:func:`convert_value`) to the declared parameter type (``list[T]``: a JSON array
whose items are converted with T; exclusive bounds: ``annotated_types`` ``gt``/``lt``).
:func:`map_scope` does the same for the attributes of the scope elements ``<wait>`` and
``<async>`` (``until``, ``timeout``), which name no function. Errors are
:class:`MappingError` subclasses whose messages are meant for the LLM's next
turn. (Streamed text becomes speech segments through
:class:`host.speech.sentences.SentenceSplitter`, used by the scheduler.)
"""

from __future__ import annotations

import difflib
import enum
import json
import math
import types
import typing
from dataclasses import dataclass
from typing import Annotated, Any, Literal, Union

from host.shell.registry import Registry, UnknownFunction
from host.shell.types import SYNC_ATTR, FunctionSpec, Param, as_range


class MappingError(ValueError):
    """An element that cannot be mapped to a call."""


class UnknownFunctionError(MappingError):
    """The element names no mounted function."""


class UnknownParameter(MappingError):
    """An attribute names no parameter of the function."""


class MissingParameter(MappingError):
    """A required parameter has no attribute."""


class BadValue(MappingError):
    """An attribute value cannot be converted to the declared type."""


class OutOfRange(BadValue):
    """A numeric value outside the declared :class:`Range`."""


_TRUE = {"true", "1", "yes", "on"}
_FALSE = {"false", "0", "no", "off"}
_NONE = {"none", "null"}


def convert_value(value: str, annotation: Any, *, where: str = "value") -> Any:
    """T(v): convert the attribute string ``value`` to ``annotation``; raises :class:`BadValue`."""
    origin = typing.get_origin(annotation)
    if origin is Annotated:
        base, *meta = typing.get_args(annotation)
        out = convert_value(value, base, where=where)
        for m in meta:
            rng = as_range(m)
            # a bound that depends on another argument (``out_of_range``, e.g. a joint's own range) is
            # checked by map_args with every argument: its ge/le alone would name another joint's range
            if rng is not None and out is not None and not (rng.lo <= out <= rng.hi) and not hasattr(m, "out_of_range"):
                raise OutOfRange(f"{where}={value!r} is out of range [{rng.lo:g}, {rng.hi:g}]")
            _check_exclusive(m, out, where, value)
            _check_length(m, out, where)
        return out
    if origin is list:  # a JSON array of scalars, e.g. labels='["a", "b"]' (MCP tools' array parameters)
        return _convert_list(value, annotation, where)
    if origin is Literal:
        options = typing.get_args(annotation)
        for opt in options:
            if str(opt) == value or (isinstance(opt, bool) and value.lower() == str(opt).lower()):
                return opt
        key = _normal(value)  # "Flattened back", "flattened-back" -> "flattened_back"
        for opt in options:
            if isinstance(opt, str) and _normal(opt) == key:
                return opt
        valid = ", ".join(repr(str(o)) for o in options)
        close = difflib.get_close_matches(key, [str(o) for o in options], n=3, cutoff=0.6)
        hint = f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else ""
        raise BadValue(f"{where}={value!r} is not one of {valid}{hint}")
    if origin in (Union, types.UnionType):
        args = typing.get_args(annotation)
        if type(None) in args and value.strip().lower() in _NONE:
            return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return convert_value(value, a, where=where)
            except BadValue as exc:
                errors.append(str(exc))
        raise BadValue("; ".join(errors) or f"{where}={value!r} has no valid type")
    if annotation is Any or annotation is str:
        return value
    if annotation is bool:
        v = value.strip().lower()
        if v in _TRUE:
            return True
        if v in _FALSE:
            return False
        raise BadValue(f"{where}={value!r} is not a boolean (use true or false)")
    if annotation in (int, float) and value.strip().endswith("%"):
        value = value.strip()[:-1]  # "-20%": a percentage given with its sign, as TTS APIs write it
    if annotation is int:
        try:
            return int(value.strip())
        except ValueError:
            try:
                f = float(value)
            except ValueError:
                f = math.nan
            if math.isfinite(f) and f.is_integer():
                return int(f)
            raise BadValue(f"{where}={value!r} is not an integer") from None
    if annotation is float:
        try:
            f = float(value.strip())
        except ValueError:
            raise BadValue(f"{where}={value!r} is not a number") from None
        if not math.isfinite(f):
            raise BadValue(f"{where}={value!r} is not a finite number")
        return f
    if isinstance(annotation, type) and issubclass(annotation, enum.Enum):
        for member in annotation:
            if value == member.name or value == str(member.value):
                return member
        valid = ", ".join(repr(m.name) for m in annotation)
        raise BadValue(f"{where}={value!r} is not one of {valid}")
    raise BadValue(f"{where}: unsupported parameter type {annotation!r}")


def _normal(value: str) -> str:
    return "_".join(value.strip().casefold().replace("-", " ").split())


def _convert_list(value: str, annotation: Any, where: str) -> list[Any]:
    """``list[T]``: the attribute is a JSON array; every item is converted with T(v) as ``str(item)``."""
    (item_type,) = typing.get_args(annotation) or (str,)
    try:
        items = json.loads(value)
    except ValueError:
        items = None
    if not isinstance(items, list):
        raise BadValue(f"{where}={value[:40]!r} is not a JSON array (write e.g. [\"a\", \"b\"] or [1, 2])")
    return [convert_value(x if isinstance(x, str) else json.dumps(x), item_type, where=f"{where}[{i}]")
            for i, x in enumerate(items)]


def _check_exclusive(meta: Any, value: Any, where: str, raw: str) -> None:
    """Exclusive bounds: ``annotated_types`` ``Gt``/``Lt`` (or an ``Interval`` with ``gt``/``lt``)."""
    if value is None or isinstance(value, (str, list)):
        return
    gt, lt = getattr(meta, "gt", None), getattr(meta, "lt", None)
    if gt is not None and not value > gt:
        raise OutOfRange(f"{where}={raw!r} is out of range: it must be greater than {gt:g}")
    if lt is not None and not value < lt:
        raise OutOfRange(f"{where}={raw!r} is out of range: it must be less than {lt:g}")


def _check_length(meta: Any, value: Any, where: str) -> None:
    """String bounds: ``max_bytes`` (UTF-8 bytes, e.g. ``MaxUtf8Bytes``) and ``annotated_types`` MaxLen/Len;
    for a list, MaxLen bounds its number of items."""
    if isinstance(value, list):
        max_items = getattr(meta, "max_length", None)
        if isinstance(max_items, int) and len(value) > max_items:
            raise BadValue(f"{where} has {len(value)} items; at most {max_items} allowed")
        return
    if not isinstance(value, str):
        return
    max_bytes = getattr(meta, "max_bytes", None)
    if isinstance(max_bytes, int) and len(value.encode("utf-8")) > max_bytes:
        raise BadValue(f"{where}={value[:40]!r} is {len(value.encode('utf-8'))} bytes of UTF-8; at most "
                       f"{max_bytes} allowed (use a shorter name)")
    max_len = getattr(meta, "max_length", None)
    if isinstance(max_len, int) and len(value) > max_len:
        raise BadValue(f"{where}={value[:40]!r} is {len(value)} characters; at most {max_len} allowed")


@dataclass(frozen=True)
class MappedCall:
    """M(E): the resolved function, its typed arguments and the ``sync`` flag."""

    spec: FunctionSpec
    args: dict[str, Any]
    sync: bool = False


def split_sync(name: str, attrs: dict[str, str]) -> tuple[dict[str, str], bool]:
    """Remove the reserved ``sync`` attribute; return the rest and its boolean value."""
    if SYNC_ATTR not in attrs:
        return attrs, False
    rest = {k: v for k, v in attrs.items() if k != SYNC_ATTR}
    return rest, convert_value(attrs[SYNC_ATTR], bool, where=f"<{name}> {SYNC_ATTR}")


def map_args(spec: FunctionSpec, attrs: dict[str, str]) -> dict[str, Any]:
    """Convert ``attrs`` to keyword arguments of ``spec`` (defaults left to the function)."""
    out: dict[str, Any] = {}
    known = {p.name: p for p in spec.params}
    for key, raw in attrs.items():
        p: Param | None = known.get(key)
        if p is None:
            close = difflib.get_close_matches(key, list(known), n=3, cutoff=0.5)
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            params = ", ".join(known) or "none"
            raise UnknownParameter(f"<{spec.name}> has no parameter {key!r} (parameters: {params}){hint}")
        out[key] = convert_value(raw, p.annotation, where=f"<{spec.name}> {key}")
    missing = [p.name for p in spec.params if p.required and p.name not in out]
    if missing:
        raise MissingParameter(f"<{spec.name}> is missing required parameter(s): {', '.join(missing)}")
    for p in spec.params:  # bounds that depend on other arguments: ``out_of_range(value, args) -> why | None``
        meta = typing.get_args(p.annotation)[1:] if typing.get_origin(p.annotation) is Annotated else ()
        for m in meta:
            check = getattr(m, "out_of_range", None)
            why = check(out[p.name], out) if callable(check) and out.get(p.name) is not None else None
            if why:
                raise OutOfRange(f"<{spec.name}> {p.name}={attrs[p.name]!r} is out of range {why}")
    return out


def map_element(registry: Registry, name: str, attrs: dict[str, str]) -> MappedCall:
    """Resolve ``name`` and convert ``attrs``; raises a :class:`MappingError`."""
    try:
        spec = registry.resolve(name)
    except UnknownFunction as exc:
        raise UnknownFunctionError(str(exc)) from None
    rest, sync = split_sync(name, attrs)
    return MappedCall(spec, map_args(spec, rest), sync)


#: the values of a scope's ``until`` attribute (MOSShell's ``flow`` is not supported)
SCOPE_UNTIL = ("all", "any")
#: the attributes a scope element takes
SCOPE_ATTRS = ("until", "timeout")


def map_scope(name: str, attrs: dict[str, str], max_timeout_s: float) -> tuple[dict[str, Any], list[str]]:
    """Typed ``until``/``timeout`` of the scope element ``<name>``, and the other attribute names.

    ``until`` is ``"all"`` (the default) or ``"any"``; ``timeout`` a finite number of seconds
    above 0 and at most ``max_timeout_s``. Only the attributes given are returned. Raises a
    :class:`MappingError` (one line naming what is accepted).
    """
    args: dict[str, Any] = {}
    if "until" in attrs:
        raw = attrs["until"]
        try:
            args["until"] = convert_value(raw, Literal["all", "any"], where=f"<{name}> until")
        except BadValue as exc:
            note = " (until=\"flow\" is not supported)" if _normal(raw) == "flow" else ""
            raise BadValue(f"{exc}{note}") from None
    if "timeout" in attrs:
        raw = attrs["timeout"]
        t = convert_value(raw, float, where=f"<{name}> timeout")
        if not 0 < t <= max_timeout_s:
            raise OutOfRange(f"<{name}> timeout={raw!r} is out of range: seconds, more than 0 and at most "
                             f"{max_timeout_s:g}")
        args["timeout"] = t
    return args, [k for k in attrs if k not in SCOPE_ATTRS]
