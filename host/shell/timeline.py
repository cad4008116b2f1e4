"""What a run did: one :class:`CallRecord` per call plus observations for the LLM.

Times are seconds relative to the run's start on the shell's clock (``t0`` is
the absolute start). ``start`` is None for a call that never began (mapping
error, or cancelled while queued).

A scope (``<wait>``/``<async>``) records the ``until``/``timeout`` it was given in
``args``; its outcome is ``done`` when its children ended as ``until`` asks and
``timeout`` when its timeout ended it; ``end`` is the moment it ended (its cancelled
children's own ``end`` says when each of them stopped), and ``ended_by`` names the
child whose end ended an ``until="any"`` scope (``"timeout"`` for a timeout).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, Literal

Outcome = Literal["pending", "done", "failed", "cancelled", "interrupted", "timeout"]


@dataclass
class CallRecord:
    """One call's life on the timeline."""

    id: int
    function: str
    channel: str | None
    args: dict[str, Any]
    path: str
    persistent: bool
    dispatch: float
    start: float | None = None
    end: float | None = None
    outcome: Outcome = "pending"
    error: str | None = None
    result: Any = None
    ended_by: str | None = None  # a scope: the path of the child that ended it, or "timeout"

    @property
    def duration(self) -> float | None:
        """``end - start`` when both are known."""
        return None if self.start is None or self.end is None else self.end - self.start


@dataclass(frozen=True)
class Observation:
    """Something the LLM should hear about on its next turn."""

    kind: Literal["result", "error", "warning", "info"]
    message: str
    path: str | None = None
    time: float | None = None

    def __str__(self) -> str:
        where = f" {self.path}" if self.path else ""
        return f"[{self.kind}{where}] {self.message}"


@dataclass
class Timeline:
    """The records of one run in dispatch order."""

    records: list[CallRecord] = field(default_factory=list)

    def __iter__(self) -> Iterator[CallRecord]:
        return iter(self.records)

    def __len__(self) -> int:
        return len(self.records)

    def find(self, function: str, **args: Any) -> list[CallRecord]:
        """Records of ``function`` whose args include ``args``."""
        return [r for r in self.records if r.function == function and all(r.args.get(k) == v for k, v in args.items())]

    def one(self, function: str, **args: Any) -> CallRecord:
        """The single record of ``function`` matching ``args`` (AssertionError otherwise)."""
        found = self.find(function, **args)
        if len(found) != 1:
            raise AssertionError(f"expected one {function} {args}, found {len(found)}")
        return found[0]

    def by_path(self, path: str) -> CallRecord:
        """The record with element path ``path``."""
        for r in self.records:
            if r.path == path:
                return r
        raise KeyError(path)

    def table(self) -> str:
        """A plain-text table of the records (for logs and the CLI)."""
        rows = ["  start     end  channel  outcome      path  args"]
        for r in self.records:
            s = "   -  " if r.start is None else f"{r.start:6.2f}"
            e = "   -  " if r.end is None else f"{r.end:6.2f}"
            rows.append(f"{s}  {e}  {r.channel or '-':7}  {r.outcome:11}  {r.path}  {r.args}{'  ' + r.error if r.error else ''}"
                        f"{'  ended by ' + r.ended_by if r.ended_by else ''}")
        return "\n".join(rows)


@dataclass
class RunResult:
    """Timeline, observations and the parse error (if any) of one run."""

    timeline: Timeline
    observations: list[Observation]
    t0: float
    error: Exception | None = None
    interrupted: bool = False
    executed_text: str = ""  # the reply as executed (ProgramRun.executed_text)
    save_failures: int = 0  # <SAVE> elements that saved nothing (empty/invalid name, unwritable library)

    def observation_text(self) -> str:
        """Observations rendered one a line, for the LLM's next turn."""
        return "\n".join(str(o) for o in self.observations)
