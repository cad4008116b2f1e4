"""An MCP tool's JSON Schema (``inputSchema``) as the shell's typed parameters.

Pure functions, no I/O: :func:`tool_interface` turns a tool's input schema and description into
:class:`~host.shell.types.Param` s (the same annotations robot stubs use, so the mapper's checks
are literally the same) plus a docstring; :func:`function_names` and :func:`attribute_names` map
tool and property names onto valid, unique XML names.

================================================  ============================================
JSON Schema (one property)                        shell parameter type
================================================  ============================================
``"type": "string"``                              ``str``
``"maxLength": n``                                ``Annotated[str, MaxLen(n)]``
``"type": "integer"`` / ``"number"``              ``int`` / ``float``
``"minimum"``/``"maximum"``                       ``Annotated[..., Interval(ge=, le=)]``
``"exclusiveMinimum"``/``"exclusiveMaximum"``     ``Interval(gt=, lt=)`` (integers: ``ge=n+1``/``le=n-1``;
                                                  draft-4 booleans too)
``"type": "boolean"``                             ``bool``
``"enum": [...]`` / ``"const"`` (scalars)         ``Literal[...]`` (a ``null`` member: ``| None``)
``["T", "null"]``, ``anyOf``/``oneOf`` with null  ``T | None`` (the attribute ``null`` or ``none``)
``anyOf``/``oneOf`` of scalars                    ``A | B`` (the mapper tries them in order)
``"type": "array"`` of scalars, ``maxItems``      ``list[T]``, ``Annotated[list[T], MaxLen(n)]``: the
                                                  attribute is a JSON array, e.g. ``'["a", "b"]'``
``{}`` / ``true`` (any value)                     ``str`` (sent as text)
``$ref`` to ``#/...`` in the same schema          resolved (at most ``MAX_REF_DEPTH`` deep)
``allOf`` with one schema                         that schema
``default``                                       the parameter's default (shown; the shell sends only
                                                  what the element gives, the server applies defaults)
``description``                                   a line of the function's docstring
``minLength``, ``pattern``, ``format``,           described in the docstring, checked by the server
``minItems``, ``uniqueItems``, ``multipleOf``
================================================  ============================================

Not expressible as an attribute (raise :class:`Unsupported` naming the construct): an object
(nested properties), an array of objects or arrays, a tuple array (``prefixItems``), ``anyOf``/
``oneOf`` with such an alternative, ``allOf`` of several schemas, ``not``/``if``, a ``$ref``
outside the schema or deeper than ``MAX_REF_DEPTH``, a root schema that is not an object.
A *required* parameter of that kind skips the tool; an *optional* one is left out of the
function (the tool still works without it) with a note.
"""

from __future__ import annotations

import inspect
import math
import re
import typing
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Annotated, Any, Literal, Union

from annotated_types import Interval, MaxLen

from host.shell.types import SYNC_ATTR, Param
from host.shell.xml_names import is_name

#: longest tool description kept in the prompt (characters)
MAX_DESCRIPTION = 1500
#: longest parameter description kept in the prompt (characters)
MAX_PARAM_DESCRIPTION = 300
#: deepest chain of ``$ref`` followed
MAX_REF_DEPTH = 8

_SCALARS: dict[str, type] = {"string": str, "integer": int, "number": float, "boolean": bool}
_UNCHECKED = ("minLength", "pattern", "format", "minItems", "uniqueItems", "multipleOf")


class Unsupported(Exception):
    """A schema construct the mapper cannot express; the message names it (``"an object ..."``)."""


@dataclass(frozen=True)
class ToolInterface:
    """A tool's parameters as the shell declares them."""

    params: tuple[Param, ...]
    wire: dict[str, str]  # attribute name -> the tool's property name
    doc: str
    notes: tuple[str, ...]  # parameters left out or renamed


def clip(text: str, limit: int) -> str:
    """``text`` with runs of whitespace kept, cut to ``limit`` characters (``…`` marks a cut)."""
    text = text.strip()
    return text if len(text) <= limit else text[: limit - 1].rstrip() + "…"


class _Resolver:
    """Local ``$ref`` resolution (``#/$defs/X``, ``#/definitions/X``, any JSON pointer into the root)."""

    def __init__(self, root: dict[str, Any]) -> None:
        self.root = root

    def deref(self, schema: Any) -> Any:
        for _ in range(MAX_REF_DEPTH + 1):
            if not isinstance(schema, dict) or "$ref" not in schema:
                return schema
            ref = schema["$ref"]
            if not isinstance(ref, str) or not ref.startswith("#"):
                raise Unsupported(f"a $ref to {str(ref)[:60]!r} outside the tool's schema")
            target: Any = self.root
            for part in filter(None, ref[1:].split("/")):
                part = part.replace("~1", "/").replace("~0", "~")
                if not isinstance(target, dict) or part not in target:
                    raise Unsupported(f"a $ref to {ref[:60]!r}, which the schema does not define")
                target = target[part]
            rest = {k: v for k, v in schema.items() if k != "$ref"}  # siblings (description, default) win
            schema = {**target, **rest} if isinstance(target, dict) else target
        raise Unsupported(f"$ref chains deeper than {MAX_REF_DEPTH}")


def _scalar_literal(values: list[Any], what: str) -> tuple[Any, bool]:
    """``Literal[values]`` (``null`` removed) and whether ``null`` was among them."""
    if not values:
        raise Unsupported(f"an empty {what}")
    if any(isinstance(v, (dict, list)) for v in values):
        raise Unsupported(f"an {what} with non-scalar values")
    nullable = any(v is None for v in values)
    rest = tuple(v for v in values if v is not None)
    if not rest:
        raise Unsupported(f"an {what} allowing only null")
    return Literal[rest], nullable  # type: ignore[valid-type]


def _bounds(s: dict[str, Any], base: type) -> Any:
    """``Interval`` for the numeric keywords of ``s`` (None without any)."""
    lo, hi = s.get("minimum"), s.get("maximum")
    xlo, xhi = s.get("exclusiveMinimum"), s.get("exclusiveMaximum")
    ge = le = gt = lt = None
    if isinstance(xlo, bool):  # draft 4: a flag on minimum
        gt, lo = (lo, None) if xlo else (None, lo)
    elif isinstance(xlo, (int, float)):
        gt = xlo
    if isinstance(xhi, bool):
        lt, hi = (hi, None) if xhi else (None, hi)
    elif isinstance(xhi, (int, float)):
        lt = xhi
    ge = lo if isinstance(lo, (int, float)) and not isinstance(lo, bool) else None
    le = hi if isinstance(hi, (int, float)) and not isinstance(hi, bool) else None
    if base is int:  # integers: every bound inclusive and integral (the same check, a plainer prompt)
        cands_lo = [math.ceil(ge)] if ge is not None else []
        cands_lo += [math.floor(gt) + 1] if gt is not None else []
        cands_hi = [math.floor(le)] if le is not None else []
        cands_hi += [math.ceil(lt) - 1] if lt is not None else []
        ge, le = (max(cands_lo) if cands_lo else None), (min(cands_hi) if cands_hi else None)
        gt = lt = None
    if ge is None and le is None and gt is None and lt is None:
        return None
    return Interval(gt=gt, ge=ge, lt=lt, le=le)


def _annotation(res: _Resolver, schema: Any, depth: int = 0) -> tuple[Any, list[str]]:
    """The shell annotation for one property schema, and docstring notes on unchecked constraints."""
    ann: Any
    if depth > MAX_REF_DEPTH:
        raise Unsupported(f"a schema nested deeper than {MAX_REF_DEPTH}")
    s = res.deref(schema)
    if s is True or s == {} or (isinstance(s, dict) and not (set(s) - {"description", "title", "default",
                                                                      "examples", "$comment"})):
        return str, ["any JSON value, sent as text"]
    if not isinstance(s, dict):
        raise Unsupported("a schema that allows no value" if s is False else f"a schema {str(s)[:40]!r}")
    for kw in ("not", "if", "prefixItems"):
        if kw in s:
            raise Unsupported("a tuple array (prefixItems)" if kw == "prefixItems" else f"'{kw}'")
    if "allOf" in s:
        subs = s["allOf"]
        if not isinstance(subs, list) or len(subs) != 1:
            raise Unsupported(f"'allOf' of {len(subs) if isinstance(subs, list) else '?'} schemas")
        merged = {**res.deref(subs[0]), **{k: v for k, v in s.items() if k != "allOf"}}
        return _annotation(res, merged, depth + 1)
    notes = [f"{kw} {s[kw]!r} (checked by the server)" for kw in _UNCHECKED if kw in s]
    if "const" in s or "enum" in s:
        values = [s["const"]] if "const" in s else s["enum"]
        lit, nullable = _scalar_literal(list(values) if isinstance(values, list) else [], "enum")
        return (typing.Optional[lit] if nullable else lit), notes
    for kw in ("anyOf", "oneOf"):
        if kw in s:
            alts = s[kw] if isinstance(s[kw], list) else []
            anns: list[Any] = []
            nullable = False
            for alt in alts:
                a = res.deref(alt)
                if isinstance(a, dict) and a.get("type") == "null":
                    nullable = True
                    continue
                try:
                    alt_ann, more = _annotation(res, a, depth + 1)
                except Unsupported as exc:
                    raise Unsupported(f"'{kw}' with {exc} as an alternative") from None
                anns.append(alt_ann)
                notes += more
            if not anns:
                raise Unsupported(f"'{kw}' allowing only null")
            if any(typing.get_origin(a) is list for a in anns) and len(anns) > 1:
                raise Unsupported(f"'{kw}' mixing an array with other types")
            union = anns[0] if len(anns) == 1 else Union[tuple(anns)]
            return (typing.Optional[union] if nullable else union), notes
    t = s.get("type")
    nullable = False
    if isinstance(t, list):
        nullable = "null" in t
        kinds = [k for k in t if k != "null"]
        if len(kinds) != 1:
            if kinds and all(k in _SCALARS for k in kinds):
                union = Union[tuple(_scalar(s, _SCALARS[k]) for k in kinds)]
                return (typing.Optional[union] if nullable else union), notes
            raise Unsupported(f"a type list {t!r}")
        t = kinds[0]
    if t is None:
        t = "object" if "properties" in s else "array" if "items" in s else None
        if t is None:
            return str, ["any JSON value, sent as text"]
    if t == "object":
        raise Unsupported("an object (nested properties cannot be an XML attribute)")
    if t == "array":
        items = res.deref(s.get("items", {}))
        item_t = items.get("type") if isinstance(items, dict) else None
        if item_t == "object" or (isinstance(items, dict) and "properties" in items):
            raise Unsupported("an array of objects")
        if item_t == "array" or (isinstance(items, dict) and "items" in items):
            raise Unsupported("an array of arrays")
        try:
            item_ann, more = _annotation(res, items, depth + 1)
        except Unsupported as exc:
            raise Unsupported(f"an array of items that are {exc}") from None
        ann = list[item_ann]  # type: ignore[valid-type]
        if isinstance(s.get("maxItems"), int):
            ann = Annotated[ann, MaxLen(s["maxItems"])]
        notes = ["a JSON array, e.g. [\"a\", \"b\"] or [1, 2]"] + notes + more
        return (typing.Optional[ann] if nullable else ann), notes
    if t == "null":
        raise Unsupported("a parameter that can only be null")
    if t not in _SCALARS:
        raise Unsupported(f"of unknown type {str(t)[:30]!r}")
    ann = _scalar(s, _SCALARS[t])
    for m in typing.get_args(ann)[1:]:  # exclusive bounds, which the XML format's range hint cannot show
        if getattr(m, "gt", None) is not None:
            notes.insert(0, f"greater than {m.gt:g}")
        if getattr(m, "lt", None) is not None:
            notes.insert(0, f"less than {m.lt:g}")
    return (typing.Optional[ann] if nullable else ann), notes


def _scalar(s: dict[str, Any], base: type) -> Any:
    if base in (int, float):
        rng = _bounds(s, base)
        return base if rng is None else Annotated[base, rng]
    if base is str and isinstance(s.get("maxLength"), int):
        return Annotated[str, MaxLen(s["maxLength"])]
    return base


_BAD_NAME_CHARS = re.compile(r"[^\w.\-]+|:", re.UNICODE)


def _xml_part(text: str, fallback: str) -> str:
    """``text`` with every run of characters an XML name cannot hold (and ``:``) made ``_``."""
    out = _BAD_NAME_CHARS.sub("_", text).strip("_.-") or fallback
    out = re.sub(r"\.{2,}", ".", out)
    return out


def _unique(name: str, taken: set[str]) -> str:
    out, i = name, 2
    while out in taken:
        out, i = f"{name}_{i}", i + 1
    taken.add(out)
    return out


def function_names(module: str, tools: Iterable[str]) -> dict[str, tuple[str, str | None]]:
    """Tool name -> (element name ``module.tool``, note or None when it had to be changed).

    Names that are already valid claim themselves first, so a renamed tool never takes a valid
    tool's name (``get forecast!`` -> ``weather.get_forecast_2`` when ``get_forecast`` exists).
    """
    tools = list(dict.fromkeys(tools))
    taken: set[str] = set()
    out: dict[str, tuple[str, str | None]] = {}
    valid = [t for t in tools if is_name(f"{module}.{t}") and ":" not in t and t == _xml_part(t, t)]
    for t in valid:
        out[t] = (_unique(f"{module}.{t}", taken), None)
    for t in tools:
        if t in out:
            continue
        name = _unique(f"{module}.{_xml_part(t, 'tool')}", taken)
        out[t] = (name, f"MCP tool {t[:60]!r} is called <{name}> here (its name is not an XML name)")
    return {t: out[t] for t in tools}


def attribute_names(props: Iterable[str]) -> dict[str, tuple[str, str | None]]:
    """Property name -> (attribute name, note or None): XML names, never the reserved ``sync``."""
    props = list(props)
    taken = {SYNC_ATTR}
    out: dict[str, tuple[str, str | None]] = {}
    for p in props:
        if is_name(p) and ":" not in p and p != SYNC_ATTR:
            out[p] = (_unique(p, taken), None)
    for p in props:
        if p in out:
            continue
        fixed = _xml_part(p, "arg")
        if not is_name(fixed):
            fixed = "_" + fixed
        if fixed == SYNC_ATTR:
            fixed = f"{SYNC_ATTR}_"
        name = _unique(fixed, taken)
        why = "sync is the shell's own attribute" if p == SYNC_ATTR else "not an XML name"
        out[p] = (name, f"parameter {p[:40]!r} is the attribute {name}= here ({why})")
    return out


def tool_interface(schema: Any, description: str | None) -> ToolInterface:
    """The parameters and docstring for a tool; raises :class:`Unsupported` naming what cannot be
    expressed (a required parameter, or the schema as a whole)."""
    if not isinstance(schema, dict):
        raise Unsupported("an input schema that is not a JSON object")
    res = _Resolver(schema)
    root = res.deref(schema)
    if not isinstance(root, dict) or root.get("type", "object") != "object":
        raise Unsupported(f"an input schema of type {root.get('type') if isinstance(root, dict) else root!r}")
    for kw in ("anyOf", "oneOf", "allOf", "not", "if", "patternProperties", "dependentSchemas"):
        if kw in root:
            raise Unsupported(f"'{kw}' at the top of its input schema")
    props = root.get("properties") or {}
    if not isinstance(props, dict):
        raise Unsupported("'properties' that are not an object")
    req = root.get("required")
    required = {r for r in req if isinstance(r, str)} if isinstance(req, list) else set()
    missing = sorted(required - set(props))
    if missing:
        raise Unsupported(f"required parameter(s) {', '.join(missing)} without a schema")
    names = attribute_names(props)
    params: list[Param] = []
    wire: dict[str, str] = {}
    notes: list[str] = []
    doc_lines: list[str] = []
    for prop, ps in props.items():
        attr, rename = names[prop]
        try:
            ann, extra = _annotation(res, ps)
        except Unsupported as exc:
            if prop in required:
                raise Unsupported(f"parameter {prop!r} is {exc}") from None
            notes.append(f"optional parameter {prop!r} left out: it is {exc}")
            continue
        if rename:
            notes.append(rename)
            extra = [f"the tool's parameter {prop!r}"] + extra
        sd = res.deref(ps)
        sd = sd if isinstance(sd, dict) else {}
        desc = sd.get("description") or ""  # not "title": generated schemas title every property
        text = "; ".join(x for x in [clip(str(desc), MAX_PARAM_DESCRIPTION), *extra] if x)
        if text:
            doc_lines.append(f"    {attr}: {text}")
        if prop in required:
            default: Any = inspect.Parameter.empty
        else:
            default = sd.get("default")
        params.append(Param(attr, ann, default))
        wire[attr] = prop
    params.sort(key=lambda p: not p.required)  # required first, as a Python signature lists them
    doc = clip(description or "", MAX_DESCRIPTION)
    if doc_lines:
        doc = (doc + "\n" if doc else "") + "Args:\n" + "\n".join(doc_lines)
    return ToolInterface(tuple(params), wire, doc, tuple(notes))
