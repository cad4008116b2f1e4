"""A program known in full, checked element by element before any of it runs.

``refuse_program(text, registry, max_scope_timeout_s)`` maps every element of ``text`` as the
scheduler would (:func:`host.shell.mapper.map_element`; ``<wait>``/``<async>`` through
:func:`host.shell.mapper.map_scope`) and returns the first element's refusal as one line, or None.
Why: the scheduler maps an element when its last character arrives, so a bad argument late in a
``run --xml`` program used to fail only after the robot had already moved to its start pose and run
the elements before it; on a real servo bus that is a real arm moving for a program that was never
going to run. Refused here: values of the wrong type, out of their range (a joint's own range),
unknown or missing parameters. Not refused: a name the registry does not know (it may be a mounted
MCP tool or a skill, resolved when the run starts) and ``SAVE``/``RUN`` (skills), which the run
checks as it goes. Parsing is lenient (a malformed reply is the scheduler's to report).
"""

from __future__ import annotations

from host.shell.mapper import MappingError, UnknownFunctionError, map_element, map_scope
from host.shell.parser import EmptyTag, FunctionTokenParser, StartTag
from host.shell.registry import Registry

__all__ = ["refuse_program"]

_SKILLS = ("SAVE", "RUN")
_SCOPES = ("wait", "async")


def refuse_program(text: str, registry: Registry, max_scope_timeout_s: float) -> str | None:
    """The first element of ``text`` whose arguments the shell would refuse (its one-line reason,
    prefixed with where it starts: ``line 1, column 20: <joint_move> deg='500' is out of range ...``),
    or None when every element maps."""
    parser = FunctionTokenParser(strict=False)
    for ev in [*parser.feed(text), *parser.close()]:
        if not isinstance(ev, (StartTag, EmptyTag)):
            continue
        name, attrs = ev.name, dict(ev.attrs)
        if name in _SKILLS:
            continue
        try:
            if name in _SCOPES:
                map_scope(name, attrs, max_scope_timeout_s)
            else:
                map_element(registry, name, attrs)
        except UnknownFunctionError:
            continue
        except MappingError as e:
            return f"{ev.pos}: {e}"
    return None
