"""A program known in full, checked element by element before any of it runs.

``refuse_program(text, registry, max_scope_timeout_s, strict=..., mounts=...)`` parses ``text`` as
the run will, maps every element as the scheduler would (:func:`host.shell.mapper.map_element`;
``<wait>``/``<async>`` through :func:`host.shell.mapper.map_scope`) and returns the first problem as
one line, or None. Why: the scheduler maps an element when its last character arrives, so a bad
argument late in a ``run --xml`` program used to fail only after the robot had already moved to its
start pose and run the elements before it; on a real servo bus that is a real arm moving for a
program that was never going to run. Refused here: values of the wrong type, out of their range (a
joint's own range), unknown or missing parameters; with ``strict=True`` (the run's parser is strict,
the default for scripted replay) malformed or unclosed markup (``<head_act action="nod"``, an
end-tag that closes nothing), which the strict parser would stop the run at; with ``mounts`` given
(the NAMEs of the run's ``--mount-mcp``), a name that is neither the registry's nor a mounted
module's (``NAME.TOOL``); an element nested deeper than the scheduler's ``MAX_DEPTH``. Not refused: ``SAVE``/``RUN`` (skills), which the run checks as it goes;
without ``mounts`` any unknown name (it may be a tool mounted later); with ``strict=False`` what the
lenient parser recovers from.
"""

from __future__ import annotations

from collections.abc import Collection

from host.shell.mapper import MappingError, UnknownFunctionError, map_element, map_scope
from host.shell.parser import EmptyTag, EndTag, Event, FunctionTokenParser, ParseError, StartTag
from host.shell.registry import Registry

__all__ = ["refuse_program"]

_SKILLS = ("SAVE", "RUN")
_SCOPES = ("wait", "async")


def refuse_program(text: str, registry: Registry, max_scope_timeout_s: float, *, strict: bool = False,
                   mounts: Collection[str] | None = None) -> str | None:
    """The first element of ``text`` the shell would refuse, or the first malformed markup the strict
    parser would stop at (``strict``): its one-line reason, prefixed with where it starts (``line 1,
    column 20: <joint_move> deg='500' is out of range ...``, ``line 1, column 1: stream ended inside
    tag '<head_act action="nod"'``), or None when the program parses and every element maps.
    ``mounts``: the module NAMEs whose ``NAME.TOOL`` functions will be mounted when the run starts;
    given, any other unknown name is refused (None: unknown names pass)."""
    parser = FunctionTokenParser(strict=strict)
    broken: ParseError | None = None
    try:
        events: list[Event] = parser.feed(text)
    except ParseError as e:
        events, broken = e.events, e
    if broken is None:
        try:
            events += parser.close()
        except ParseError as e:
            events, broken = events + e.events, e
    from host.shell.scheduler import MAX_DEPTH

    depth = 0  # open elements around the one in hand (the scheduler refuses one with MAX_DEPTH around it)
    for ev in events:
        if isinstance(ev, EndTag):
            depth = max(0, depth - 1)
            continue
        if not isinstance(ev, (StartTag, EmptyTag)):
            continue
        if depth >= MAX_DEPTH:  # hostile or runaway nesting: refused before anything runs, not 3 000 failures later
            return f"{ev.pos}: <{ev.name}> is nested deeper than {MAX_DEPTH} elements"
        depth += isinstance(ev, StartTag)
        name, attrs = ev.name, dict(ev.attrs)
        if name in _SKILLS:
            continue
        try:
            if name in _SCOPES:
                map_scope(name, attrs, max_scope_timeout_s)
            else:
                map_element(registry, name, attrs)
        except UnknownFunctionError as e:
            if mounts is None or name.partition(".")[0] in mounts:
                continue
            return f"{ev.pos}: {e}"
        except MappingError as e:
            return f"{ev.pos}: {e}"
    if broken is not None:
        return f"line {broken.line}, column {broken.column}: {broken.message}"
    return None
