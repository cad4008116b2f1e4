"""Skills inside one run: ``<SAVE>`` recording and the programs ``<RUN>`` expands.

:class:`SkillRecorder` is the part of a :class:`host.shell.scheduler.ProgramRun` that is not scheduling:

* ``<SAVE name="n" description="d">...</SAVE>``: while a SAVE is open every parser event is
  recorded (re-serialised as markup, :func:`host.shell.skills.start_tag`), nothing is dispatched, and
  the program is saved to the :class:`~host.shell.skills.SkillStore` when its end-tag closes it. A
  self-closing ``<SAVE/>``, a SAVE never closed, and a save the store refuses (bad name, recursion,
  unwritable library) each count one failure (:attr:`SkillRecorder.failures`; the run's outcome is
  then failed) with one error observation.
* ``<RUN id="n"/>``: :meth:`SkillRecorder.program` returns the skill's parsed events, refusing
  (``SkillError``) a skill that is already being expanded (recursion) or nesting deeper than
  :data:`MAX_SKILL_DEPTH`; the scheduler dispatches them inside :meth:`SkillRecorder.expanding`.

The reply as executed (``ProgramRun.executed_text``) is a list the run owns; the recorder appends
the text of a recorded SAVE to it and removes an unfinished SAVE from it.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from host.shell.parser import EmptyTag, EndTag, Event, FunctionTokenParser, ParseWarning, StartTag, Text
from host.shell.skills import SkillError, SkillStore, end_tag, start_tag, text

#: Deepest nesting of ``<RUN>`` expansions.
MAX_SKILL_DEPTH = 16


def warning_text(ev: ParseWarning) -> str:
    """The observation line of a parser warning."""
    return f"parse warning at {getattr(ev, 'pos', '?')}: {ev.message}"


@dataclass(eq=False)
class _Recording:
    name: str
    description: str
    depth: int = 1
    parts: list[str] = field(default_factory=list)


class SkillRecorder:
    """``<SAVE>`` recording and ``<RUN>`` expansion for one run.

    ``observe(kind, message)`` reports to the run (``kind``: ``"error"``, ``"warning"``, ``"info"``);
    ``executed`` is the run's reply-as-executed list of ``(markup, call or None)``.
    """

    def __init__(self, skills: SkillStore, observe: Callable[[str, str], None],
                 executed: list[tuple[str, Any]]) -> None:
        self.skills = skills
        self._observe = observe
        self._executed = executed
        #: the open ``<SAVE>`` while one is (its events go to :meth:`record`, nothing is dispatched), else None
        self.recording: _Recording | None = None
        self._mark = 0  # index in ``executed`` of the open SAVE's start tag
        #: <SAVE> elements that saved nothing
        self.failures = 0
        #: the skills being expanded now, outermost first (a <RUN> inside a skill nests)
        self.stack: list[str] = []

    def start(self, attrs: dict[str, str], empty: bool) -> None:
        """A ``<SAVE>`` tag (its start tag already kept in ``executed``); ``<SAVE/>`` fails at once."""
        name = attrs.get("name", "")
        if empty:
            self._observe("error", f"<SAVE name={name!r}/> encloses no program; nothing saved")
            self.failures += 1
            return
        self.recording = _Recording(name, attrs.get("description", ""))
        self._mark = max(0, len(self._executed) - 1)

    def record(self, ev: Event) -> None:
        """One parser event inside the open ``<SAVE>``; its end-tag saves the program."""
        rec = self.recording
        assert rec is not None
        match ev:
            case Text(text=data):
                rec.parts.append(text(data))
                if not self.stack:
                    self._executed.append((text(data), None))
            case EmptyTag(name=name, attrs=attrs):
                rec.parts.append(start_tag(name, dict(attrs), empty=True))
            case StartTag(name=name, attrs=attrs):
                rec.depth += 1
                rec.parts.append(start_tag(name, dict(attrs)))
            case EndTag(name=name):
                rec.depth -= 1
                if rec.depth == 0:
                    self.recording = None
                    self._save(rec)
                else:
                    rec.parts.append(end_tag(name))
            case ParseWarning():
                self._observe("warning", warning_text(ev))

    def _save(self, rec: _Recording) -> None:
        existed = rec.name in self.skills
        try:
            self.skills.save(rec.name, rec.description, "".join(rec.parts))
        except (SkillError, OSError) as exc:
            self._observe("error", f"skill not saved: {exc}")
            self.failures += 1
        else:
            self._observe("info", f"skill {rec.name!r} {'replaced (a skill of that name existed)' if existed else 'saved'}")

    def drop(self) -> None:
        """The run stopped: an unfinished SAVE is not part of what was executed (nothing is saved)."""
        if self.recording is not None:
            del self._executed[self._mark:]
        self.recording = None

    def end_of_stream(self) -> None:
        """The stream ended: a SAVE still open was never closed (one failure; nothing is saved)."""
        if self.recording is not None:
            self._observe("error", f"<SAVE name={self.recording.name!r}> was never closed; skill not saved")
            self.failures += 1
            self.drop()

    def program(self, sid: str) -> list[Event]:
        """The parsed events of skill ``sid``; raises SkillError (unknown, recursive, nested deeper than
        :data:`MAX_SKILL_DEPTH`) or ParseError (a stored program that no longer parses)."""
        if sid in self.stack:
            raise SkillError(f"recursive skill: {' -> '.join([*self.stack, sid])}")
        if len(self.stack) >= MAX_SKILL_DEPTH:
            raise SkillError(f"skills nested deeper than {MAX_SKILL_DEPTH}")
        skill = self.skills.get(sid)
        p = FunctionTokenParser(strict=True)
        return p.feed(skill.program) + p.close()

    @contextlib.contextmanager
    def expanding(self, sid: str) -> Iterator[None]:
        """While the events of skill ``sid`` are dispatched (they are not kept in ``executed``)."""
        self.stack.append(sid)
        try:
            yield
        finally:
            self.stack.pop()
