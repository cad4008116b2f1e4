"""The native function-calling ablation: tool definitions, native execution, the pattern judge.

* :func:`tool_schemas` turns the mounted stubs into provider tool definitions:
  JSON Schema (draft 2020-12 subset the providers accept) from the type hints —
  ``Literal``/``Enum`` -> ``enum``, ``int``/``float``/``bool``/``str`` -> the JSON
  type, ``Annotated[.., Range(lo, hi)]`` or ``annotated_types`` bounds ->
  ``minimum``/``maximum``, defaults -> ``default``, parameters without one ->
  ``required``. The speech function is not a tool: speech is the text part.
* :func:`native_program` is how native function calling executes a reply: after
  the response, the text part is spoken, then the tool calls are dispatched in
  the order given. ``parallel`` (default, like parallel tool calls): all at once
  after the speech, calls for different modules run together and calls for one
  module queue in order (``TEXT<wait>calls</wait>``); ``sequential``: each call
  to completion before the next (a ``<wait>`` per call). Either way there is no
  nesting and no overlap of speech and motion: the structure a flat
  ``tool_calls`` array beside a separate text field has.
* :func:`judge` checks a board-measured timeline against an expected pattern, in the atoms a
  robot's ablation module defines (:func:`judge_words`)
  (the task data's ``expected``): ``A -> B`` (B starts after A ended, no overlap),
  ``A || B`` (their intervals overlap), parentheses, and ``outer{a, b}`` for
  lifecycle-scoped termination (outer runs while every inner call runs and stops
  within :data:`SCOPE_S` after the last one ends).
"""

from __future__ import annotations

import enum
import json
import re
import typing
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Literal
from xml.sax.saxutils import escape, quoteattr

from host.shell.registry import Registry
from host.shell.types import FunctionSpec, as_range
from robots.description import Robot
from robots.registry import load_robot

#: "A -> B": B may start this much before A's measured end (one telemetry period + grid)
SEQ_TOL_S = 0.05
#: "A || B": the intervals must share at least this much time
OVERLAP_MIN_S = 0.1
#: "outer{inner}": outer may stop at most this long after the last inner call ended
SCOPE_S = 1.5


# -- tool definitions ----------------------------------------------------------------------
def json_schema(annotation: Any) -> dict[str, Any]:
    """JSON Schema for one parameter annotation (see the module docstring)."""
    base: Any = annotation
    metas: tuple[Any, ...] = ()
    if typing.get_origin(annotation) is typing.Annotated:
        base, *rest = typing.get_args(annotation)
        metas = tuple(rest)
    schema: dict[str, Any]
    if typing.get_origin(base) is Literal:
        values = list(typing.get_args(base))
        kinds = {type(v) for v in values}
        schema = {"enum": values}
        if kinds <= {str}:
            schema["type"] = "string"
        elif kinds <= {int}:
            schema["type"] = "integer"
    elif isinstance(base, type) and issubclass(base, enum.Enum):
        schema = {"type": "string", "enum": [m.value for m in base]}
    elif base is bool:
        schema = {"type": "boolean"}
    elif base is int:
        schema = {"type": "integer"}
    elif base is float:
        schema = {"type": "number"}
    else:
        schema = {"type": "string"}
    for meta in metas:
        r = as_range(meta)
        if r is not None:
            if r.lo != float("-inf"):
                schema["minimum"] = r.lo
            if r.hi != float("inf"):
                schema["maximum"] = r.hi
    return schema


def function_schema(spec: FunctionSpec) -> dict[str, Any]:
    """``{"type": "object", "properties": ..., "required": [...]}`` for one function."""
    props: dict[str, Any] = {}
    required: list[str] = []
    for p in spec.params:
        s = json_schema(p.annotation)
        if p.required:
            required.append(p.name)
        elif isinstance(p.default, (str, int, float, bool)):
            s["default"] = p.default.value if isinstance(p.default, enum.Enum) else p.default
        props[p.name] = s
    out: dict[str, Any] = {"type": "object", "properties": props}
    if required:
        out["required"] = required
    return out


def tool_schemas(registry: Registry, provider: str) -> list[dict[str, Any]]:
    """Tool definitions for every visible, non-speech function, in the provider's format.

    ``provider``: ``"openai"`` (``{"type": "function", "function": {name, description,
    parameters}}``) or ``"anthropic"`` (``{name, description, input_schema}``).
    """
    tools: list[dict[str, Any]] = []
    for module in registry.modules():
        if module.hidden:
            continue
        for spec in module.functions:
            if spec.speech:
                continue
            desc = (spec.doc or spec.name).strip().splitlines()[0]
            schema = function_schema(spec)
            if provider == "anthropic":
                tools.append({"name": spec.name, "description": desc, "input_schema": schema})
            elif provider == "openai":
                tools.append({"type": "function", "function": {"name": spec.name, "description": desc,
                                                               "parameters": schema}})
            else:
                raise ValueError(f"no tool format for provider {provider!r} (openai, anthropic)")
    return tools


@dataclass(frozen=True)
class ToolCall:
    """One native tool call: the function's ``name`` and its ``arguments`` (decoded JSON object)."""

    name: str
    arguments: dict[str, Any]


def parse_arguments(raw: str | dict[str, Any] | None) -> dict[str, Any]:
    """A tool call's arguments: a JSON object string (OpenAI) or an object (Anthropic).
    Raises ValueError with the reason on malformed JSON or a non-object."""
    if raw is None or raw == "":
        return {}
    value = json.loads(raw) if isinstance(raw, str) else raw
    if not isinstance(value, dict):
        raise ValueError(f"tool arguments must be a JSON object, got {type(value).__name__}")
    return value


def _attr(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    return str(v)


#: how the native tool calls of one response run (see the module docstring)
NATIVE_EXEC = ("parallel", "sequential")


def native_program(text: str, calls: Iterable[ToolCall], execution: str = "parallel") -> str:
    """The function-token program that executes a native reply the native way: the text
    spoken first, then the calls in the order given (``execution``: parallel or sequential)."""
    if execution not in NATIVE_EXEC:
        raise ValueError(f"native execution {execution!r}; valid: {', '.join(NATIVE_EXEC)}")
    out = [escape(text.strip())] if text.strip() else []
    tags = [f"<{c.name}" + "".join(f" {k}={quoteattr(_attr(v))}" for k, v in c.arguments.items()) + "/>"
            for c in calls]
    if execution == "sequential":
        out += [f"<wait>{t}</wait>" for t in tags]
    elif tags:
        out.append("<wait>" + "".join(tags) + "</wait>")
    return "".join(out)


# -- the judge -----------------------------------------------------------------------------
@dataclass(frozen=True)
class Interval:
    """One call on the board clock: ``function``, ``args``, ``start``/``end`` in seconds."""

    function: str
    args: dict[str, Any]
    start: float
    end: float


@dataclass(frozen=True)
class JudgeWords:
    """A robot's words for the judge (its ablation module, robot.toml ``[data] ablation_judge``):
    ``atoms`` name -> predicate on an :class:`Interval`; ``call_atom(base, args) -> (predicate, check)``
    for shorthands with arguments; ``lifecycle`` task id -> the pattern ``nested lifecycle`` means."""

    atoms: dict[str, Callable[[Interval], bool]]
    call_atom: Callable[[str, list[str]], tuple[Callable[[Interval], bool], Callable[[Interval], bool]]]
    lifecycle: dict[int, str]


def judge_words(robot: Robot | None = None) -> JudgeWords:
    """``robot``'s judge words (default robot when None); ValueError when the robot has no ablation judge."""
    bot = load_robot() if robot is None else robot
    path = bot.data.get("ablation_judge")
    if path is None:
        raise ValueError(f"{bot.name} has no native-call ablation (robot.toml [data] ablation_judge)")
    mod = bot.module(path.stem)
    return JudgeWords(dict(mod.ATOMS), mod.call_atom, dict(getattr(mod, "LIFECYCLE_PATTERNS", {})))


#: the data's shorthand with arguments -> an atom with a check on the measured call
_CALL_RE = re.compile(r"^(\w+)\(([^)]*)\)$")


def expected_pattern(task_id: int, expected: str, words: JudgeWords | None = None) -> str:
    """The judge's pattern for an ablation task (``nested lifecycle`` spelled out)."""
    lifecycle = (words or judge_words()).lifecycle
    return lifecycle.get(task_id, expected) if expected.strip() == "nested lifecycle" else expected


@dataclass(frozen=True)
class Verdict:
    """``passed`` and a one-line ``reason`` naming the first violated relation."""

    passed: bool
    reason: str


class _Fail(Exception):
    pass


def _tokens(pattern: str) -> list[str]:
    return re.findall(r"->|\|\||[(){},]|\w+\([^)]*\)|\w+", pattern)


class _Judge:
    def __init__(self, calls: Sequence[Interval], words: JudgeWords) -> None:
        self.calls = sorted(calls, key=lambda c: (c.start, c.end))
        self.used: set[int] = set()
        self.words = words

    def atom(self, name: str, after: float) -> tuple[float, float]:
        check: Callable[[Interval], bool] = lambda c: True
        atoms = self.words.atoms
        m = _CALL_RE.match(name)
        if m:
            base, argtext = m.group(1), [a.strip() for a in m.group(2).split(",") if a.strip()]
            pred, check = self.words.call_atom(base, argtext)
        else:
            if name not in atoms:
                raise ValueError(f"unknown pattern atom {name!r}; known: {', '.join(atoms)}")
            pred = atoms[name]
        for i, c in enumerate(self.calls):
            if i in self.used or c.start < after - SEQ_TOL_S:
                continue
            if pred(c) and check(c):
                self.used.add(i)
                return c.start, c.end
        if any(pred(c) and check(c) for c in self.calls):
            raise _Fail(f"{name} does not start after {after:.2f} s")
        raise _Fail(f"no {name} call in the timeline")

    # pattern := seq ; seq := par ('->' par)* ; par := unit ('||' unit)* ; unit := '(' seq ')' | atom ['{' list '}']
    def parse(self, tokens: list[str], after: float) -> tuple[float, float]:
        self.toks, self.pos = tokens, 0
        span = self.seq(after)
        if self.pos != len(tokens):
            raise ValueError(f"unexpected {tokens[self.pos]!r} in pattern")
        return span

    def peek(self) -> str | None:
        return self.toks[self.pos] if self.pos < len(self.toks) else None

    def take(self) -> str:
        tok = self.toks[self.pos]
        self.pos += 1
        return tok

    def seq(self, after: float) -> tuple[float, float]:
        start, end = self.par(after)
        while self.peek() == "->":
            self.take()
            s2, e2 = self.par(end)
            if s2 < end - SEQ_TOL_S:
                raise _Fail(f"step starting at {s2:.2f} s overlaps the previous one (ends {end:.2f} s)")
            end = max(end, e2)
        return start, end

    def par(self, after: float) -> tuple[float, float]:
        spans = [self.unit(after)]
        while self.peek() == "||":
            self.take()
            spans.append(self.unit(after))
        if len(spans) > 1:
            lo, hi = max(s for s, _ in spans), min(e for _, e in spans)
            if hi - lo < OVERLAP_MIN_S:
                raise _Fail(f"parallel parts do not overlap (shared {max(hi - lo, 0):.2f} s)")
        return min(s for s, _ in spans), max(e for _, e in spans)

    def unit(self, after: float) -> tuple[float, float]:
        tok = self.take()
        if tok == "(":
            span = self.seq(after)
            if self.take() != ")":
                raise ValueError("unbalanced parentheses in pattern")
            return span
        outer = self.atom(tok, after)
        if self.peek() == "{":
            self.take()
            inner: list[tuple[float, float]] = []
            names: list[str] = []
            while True:
                nxt = self.peek()
                if nxt is not None and nxt in self.words.atoms:
                    names.append(nxt)
                inner.append(self.unit(outer[0]))
                t = self.take()
                if t == "}":
                    break
                if t != ",":
                    raise ValueError("expected , or } in pattern")
            first, last = min(s for s, _ in inner), max(e for _, e in inner)
            for name in names:  # "saying hello 3 times": every repeat inside the scope counts
                for c in self.calls:
                    atoms = self.words.atoms
                    if name in atoms and atoms[name](c) and outer[0] - SEQ_TOL_S <= c.start <= outer[1]:
                        last = max(last, c.end)
            if outer[0] > first + SEQ_TOL_S or outer[1] < last - SEQ_TOL_S:
                raise _Fail(f"{tok} ({outer[0]:.2f}-{outer[1]:.2f} s) does not span its scoped calls "
                            f"({first:.2f}-{last:.2f} s)")
            if outer[1] > last + SCOPE_S:
                raise _Fail(f"{tok} keeps running {outer[1] - last:.2f} s after its scoped calls ended")
        return outer


def judge(expected: str, calls: Sequence[Interval], words: JudgeWords | None = None) -> Verdict:
    """Judge a board-measured timeline against ``expected`` (see the module docstring) in ``words``
    (default: the default robot's). Calls that never started or never ended are ignored. Raises
    ValueError on a bad pattern."""
    j = _Judge([c for c in calls if c.start is not None and c.end is not None], words or judge_words())
    try:
        j.parse(_tokens(expected), float("-inf"))
    except _Fail as f:
        return Verdict(False, str(f))
    return Verdict(True, "ok")


def intervals_from_timeline(calls: Iterable[Any]) -> list[Interval]:
    """:class:`Interval` list from run calls (``BoardCall`` objects or timeline.json dicts);
    failed calls and structural elements (``wait``/``async``) are dropped."""
    out = []
    for c in calls:
        d = c if isinstance(c, dict) else c.__dict__
        if d.get("outcome") == "failed" or d.get("function") in ("wait", "async"):
            continue
        if d.get("start") is None or d.get("end") is None:
            continue
        out.append(Interval(d["function"], dict(d.get("args") or {}), float(d["start"]), float(d["end"])))
    return out
