"""Code as prompt: render the mounted interfaces for the LLM's system prompt.

Two equivalent formats (paper, Appendix A.2): ``code`` renders Python stubs
(type hints, defaults, ranges, docstrings; bodies omitted) and ``xml`` renders
function tokens (parameters as attributes, descriptions in XML comments). Both
come with the function-token rules, the scheduling mode in force and the saved
skills. Only the registry is read, so mounting or unmounting a module changes
the next rendering.

Bounds are rendered the way the paper's stubs read, not as the annotation's
``repr``: a bounded parameter is ``duration: float = 2.0,  # 0..120 s`` (one
parameter a line when any of a stub's parameters has a bound) and its XML hint
``number 0..120 s``. :func:`bounds_text` says what a bound reads as: an inclusive
range ``lo..hi`` (``Range`` or ``annotated_types`` ``ge``/``le``; ``gt``/``lt`` as
``> x``/``< x``), a string's ``max_bytes``/``max_length``, and a unit from the
metadata's ``unit`` attribute or, for a parameter called ``duration``, seconds.
Metadata it does not know stays in an ``Annotated[...]``. Only the rendering
changes: the mapper checks the annotations as declared.
"""

from __future__ import annotations

import enum
import textwrap
from dataclasses import dataclass
import types
import typing
from typing import Annotated, Any, Literal, Union

from host.shell.registry import Registry
from host.shell.skills import SkillStore
from host.shell.types import FunctionSpec, Param, as_range

FORMATS = ("code", "xml")

RULES = """\
# Output format: function tokens
Write plain text and XML function tokens; both are executed while you are still writing.
- Call a function with a self-closing tag: <name param="value"/>. Every value is quoted; use &lt; &amp; &quot; for < & ".
- A start-tag and end-tag pair <name ...>children</name> activates the function and keeps it running
  (looping or holding) until every child has finished; then it is reset (lifecycle-scoped termination).
- Plain text outside tags is spoken aloud with {speech}.
- Tag names and parameter names are the function and parameter names below; omit a parameter to use its default.
- sync="true" on any element puts that call on the main channel (everything after it waits for it).
- <SAVE name="skill" description="what it does">program</SAVE> saves the enclosed program as a skill without
  running it; <RUN id="skill"/> runs a saved skill at that point.
- <wait> and <async> take until="all" (the default: they end when all their children have ended) or
  until="any" (the first child to end ends them and stops the others), and timeout="S" (they end after
  S seconds, stopping whatever still runs). E.g. <{scope} until="any" timeout="3"><f/><g/></{scope}> runs f and g
  and ends as soon as either has finished, after 3 s at the latest; what is written after it starts then."""

MODE_TEXT = {
    "async-first": """\
# Scheduling: Async-First
Calls on different modules run in parallel; calls on the same module run one after another.
<wait>children</wait> runs its children (in parallel across modules), waits until they all finish,
and nothing written after it starts before that. Use <wait> to say "first ... then ...".""",
    "sync-first": """\
# Scheduling: Sync-First
Every call runs on its own, one after another, in the order written.
<async>children</async> runs its children in parallel (calls on the same module still queue);
nothing written after it starts before they all finish.""",
}

TEXT_FIRST_CLASS = "Spoken text blocks: nothing written after a sentence starts before it has been said."


#: units of parameters whose metadata names none, by parameter name
UNITS = {"duration": "s"}


def _bound_note(meta: Any) -> str | None:
    """What one ``Annotated`` metadata item says, as a stub comment reads it (None: unknown)."""
    max_bytes = getattr(meta, "max_bytes", None)
    if isinstance(max_bytes, int):
        return f"any language, at most {max_bytes} bytes of UTF-8"
    max_len = getattr(meta, "max_length", None)
    if isinstance(max_len, int):
        return f"at most {max_len} characters"
    rng = as_range(meta)
    lo, hi = (rng.lo, rng.hi) if rng is not None else (float("-inf"), float("inf"))
    gt, lt = (v if isinstance(v, (int, float)) and not isinstance(v, bool) else None
              for v in (getattr(meta, "gt", None), getattr(meta, "lt", None)))
    if lo != float("-inf") and hi != float("inf") and gt is None and lt is None:
        return f"{lo:g}..{hi:g}"
    parts = []  # the lower bound first, then the upper: "> 0, <= 1000"
    if gt is not None:
        parts.append(f"> {gt:g}")
    elif lo != float("-inf"):
        parts.append(f">= {lo:g}")
    if lt is not None:
        parts.append(f"< {lt:g}")
    elif hi != float("inf"):
        parts.append(f"<= {hi:g}")
    return ", ".join(parts) if parts else None


def _split_bounds(ann: Any) -> tuple[Any, list[str]]:
    """``ann`` without the metadata :func:`_bound_note` knows (inside unions too), and the notes."""
    origin = typing.get_origin(ann)
    if origin is Annotated:
        base, *meta = typing.get_args(ann)
        notes, unknown = [], []
        for m in meta:
            note = _bound_note(m)
            if note is not None and typing.get_origin(base) is list:  # a list's length bound counts items
                note = note.replace(" characters", " items")
            (notes.append(note) if note is not None else unknown.append(m))
        base, inner = _split_bounds(base)
        return (Annotated[(base, *unknown)] if unknown else base), inner + notes  # type: ignore[return-value]
    if origin in (Union, types.UnionType):
        notes = []
        for a in typing.get_args(ann):
            notes += _split_bounds(a)[1]
        return _Stripped(tuple(_split_bounds(a)[0] for a in typing.get_args(ann))), notes
    return ann, []


@dataclass(frozen=True)
class _Stripped:
    """A union whose members lost their bounds (``typing`` would drop a duplicate member)."""

    args: tuple[Any, ...]


def bounds_text(p: Param) -> str:
    """The bounds of ``p`` as the prompt writes them (``"0..120 s"``), or an empty string."""
    notes = _split_bounds(p.annotation)[1]
    if not notes:
        return ""
    unit = next((u for u in (getattr(m, "unit", None) for m in _meta(p.annotation)) if isinstance(u, str)), None)
    unit = unit or UNITS.get(p.name)
    return "; ".join(notes) + (f" {unit}" if unit else "")


def _meta(ann: Any) -> list[Any]:
    if typing.get_origin(ann) is Annotated:
        return list(typing.get_args(ann)[1:])
    if typing.get_origin(ann) in (Union, types.UnionType):
        return [m for a in typing.get_args(ann) for m in _meta(a)]
    return []


def render_annotation(ann: Any) -> str:
    """Python source text for a parameter annotation (Enums shown as their member names)."""
    if isinstance(ann, _Stripped):
        return " | ".join("None" if a is type(None) else render_annotation(a) for a in ann.args)
    origin = typing.get_origin(ann)
    if origin is Annotated:
        base, *meta = typing.get_args(ann)
        extra = ", ".join(repr(m) for m in meta)
        return f"Annotated[{render_annotation(base)}, {extra}]" if extra else render_annotation(base)
    if origin is Literal:
        return "Literal[" + ", ".join(_lit(a) for a in typing.get_args(ann)) + "]"
    if origin in (Union, types.UnionType):
        args = typing.get_args(ann)
        return " | ".join("None" if a is type(None) else render_annotation(a) for a in args)
    if isinstance(ann, type) and issubclass(ann, enum.Enum):
        return "Literal[" + ", ".join(_lit(m.name) for m in ann) + "]"
    if isinstance(ann, type):
        return ann.__name__
    return str(ann).replace("typing.", "")


def _lit(v: Any) -> str:
    return f'"{v}"' if isinstance(v, str) else repr(v)


def _default(v: Any) -> str:
    if isinstance(v, enum.Enum):
        return f'"{v.name}"'
    if isinstance(v, str):
        return f'"{v}"'
    return repr(v)


def _value_hint(ann: Any) -> str:
    """Short description of accepted attribute values (bounds left to :func:`bounds_text`), for the XML format."""
    origin = typing.get_origin(ann)
    if origin is Annotated:
        return _value_hint(typing.get_args(ann)[0])
    if origin is Literal:
        return "one of " + ", ".join(str(a) for a in typing.get_args(ann))
    if origin in (Union, types.UnionType):
        return " or ".join(_value_hint(a) for a in typing.get_args(ann) if a is not type(None))
    if isinstance(ann, type) and issubclass(ann, enum.Enum):
        return "one of " + ", ".join(m.name for m in ann)
    if ann is bool:
        return "true or false"
    if isinstance(ann, type):
        return {"int": "integer", "float": "number", "str": "text"}.get(ann.__name__, ann.__name__)
    return str(ann)


def _placeholder(p: Param) -> str:
    origin = typing.get_origin(p.annotation)
    ann = typing.get_args(p.annotation)[0] if origin is Annotated else p.annotation
    if typing.get_origin(ann) is Literal:
        return "|".join(str(a) for a in typing.get_args(ann))
    if not p.required and p.default is not None:
        return str(p.default.name if isinstance(p.default, enum.Enum) else p.default)
    return "..." if p.required else ""


def render_stub(spec: FunctionSpec, aliases: list[str] | None = None) -> str:
    """A Python stub: ``def name(params) -> None:`` with its docstring, body omitted; when a
    parameter has bounds, one parameter a line with the bounds as a comment (``# 0..120 s``)."""
    params, notes = [], []
    for p in spec.params:
        s = f"{p.name}: {render_annotation(_split_bounds(p.annotation)[0])}"
        if not p.required:
            s += f" = {_default(p.default)}"
        params.append(s)
        notes.append(bounds_text(p))
    doc = spec.doc or "(no description)"
    if aliases:
        doc += f"\nAlso callable as: {', '.join(aliases)}."
    body = textwrap.indent('"""' + doc + '"""', "    ")
    if not any(notes):
        return f"def {spec.name}({', '.join(params)}) -> None:\n{body}"
    lines = "".join(f"    {s},{'  # ' + n if n else ''}\n" for s, n in zip(params, notes))
    return f"def {spec.name}(\n{lines}) -> None:\n{body}"


def render_xml(spec: FunctionSpec, aliases: list[str] | None = None) -> str:
    """An XML function-token template preceded by a comment describing it."""
    lines = [spec.doc or "(no description)"]
    for p in spec.params:
        req = "required" if p.required else ("optional" if p.default is None else f"default {_default(p.default)}")
        bounds = bounds_text(p)
        lines.append(f"{p.name}: {_value_hint(p.annotation)}{' ' + bounds if bounds else ''} ({req})")
    if aliases:
        lines.append(f"also callable as: {', '.join(aliases)}")
    comment = "<!-- " + "\n     ".join(line.replace("--", "- -") for line in "\n".join(lines).splitlines()) + " -->"
    attrs = "".join(f' {p.name}="{_placeholder(p)}"' for p in spec.params)
    return f"{comment}\n<{spec.name}{attrs}/>"


def render_interface(registry: Registry, format: str = "code") -> str:
    """The mounted functions, grouped by module, in ``format``."""
    if format not in FORMATS:
        raise ValueError(f"format must be one of {FORMATS}, not {format!r}")
    blocks = []
    for m in registry.modules():
        if m.hidden:
            continue
        head = f"module {m.name} (channel {m.channel})" + (f": {m.doc}" if m.doc else "")
        items = [
            (render_stub if format == "code" else render_xml)(s, registry.aliases_of(s)) for s in m.functions
        ]
        if format == "code":
            blocks.append(f"# {head}\n" + "\n\n".join(items))
        else:
            blocks.append(f"<!-- {head} -->\n" + "\n".join(items))
    if not blocks:
        return "(no functions are mounted)"
    if format == "code":
        return "```python\n" + "\n\n\n".join(blocks) + "\n```"
    return "```xml\n" + "\n\n".join(blocks) + "\n```"


def render_skills(skills: SkillStore | None) -> str:
    """The saved skills, one a line, or an empty string."""
    if skills is None or len(skills) == 0:
        return ""
    lines = ["# Saved skills (run with <RUN id=\"name\"/>)"]
    lines += [f"- {s.name}: {s.description or '(no description)'}" for s in skills.list()]
    return "\n".join(lines)


def render_prompt(
    registry: Registry,
    *,
    format: str = "code",
    mode: str = "async-first",
    text_first_class: bool = False,
    skills: SkillStore | None = None,
) -> str:
    """The whole shell part of the system prompt."""
    if mode not in MODE_TEXT:
        raise ValueError(f"mode must be one of {tuple(MODE_TEXT)}, not {mode!r}")
    speech = registry.speech
    parts = [RULES.format(speech=f"<{speech.name}>" if speech else "the speech function (none is mounted: text is not spoken)",
                          scope="async" if mode == "sync-first" else "wait")]  # the scope whose children run in parallel
    parts.append(MODE_TEXT[mode] + ("\n" + TEXT_FIRST_CLASS if text_first_class else ""))
    parts.append(f"# Available functions ({'Python stubs' if format == 'code' else 'XML function tokens'})\n"
                 + render_interface(registry, format))
    sk = render_skills(skills)
    if sk:
        parts.append(sk)
    return "\n\n".join(parts) + "\n"

