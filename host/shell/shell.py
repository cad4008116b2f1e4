"""The public façade: :class:`Shell` runs LLM output streams against a registry.

Example::

    shell = Shell(Registry([Module.from_functions("head", nod)]))
    result = await shell.run_text('<nod times="2"/>Hello there.')
    print(result.timeline.table())
"""

from __future__ import annotations

from collections.abc import AsyncIterable, AsyncIterator, Awaitable, Callable, Iterable

from host.shell.limits import TurnLimits
from host.shell.parser import FunctionTokenParser
from host.shell.policy import Policy
from host.shell.registry import Registry
from host.shell.scheduler import MODES, ProgramRun
from host.shell.skills import SkillStore
from host.shell.timeline import RunResult, Timeline


class Shell:
    """Parse, map, schedule and execute function-token streams.

    ``mode`` is ``"async-first"`` (default; ``<wait>`` serialises) or
    ``"sync-first"`` (everything on the main channel; ``<async>`` parallelises);
    ``strict`` selects the paper's strict parser (a parse error stops the run) or
    lenient recovery (warnings become observations); ``text_first_class`` puts
    speech on the main channel; ``clock`` is the time source for the timeline
    (default ``anyio.current_time``) and ``sleep(seconds)`` sleeps on that clock (a scope's
    ``timeout``; default ``anyio.sleep``, right for the default clock); ``skills`` is the skill memory (default: an
    in-memory store); ``limits`` caps what one turn may do (:class:`TurnLimits`); ``policy``
    refuses calls it does not allow before they are dispatched (:class:`Policy`).

    ``parser_class`` (class attribute) is the type of each run's stream parser; a subclass may watch
    the parse (the shell fuzz target checks the parser's invariants on the Shell's own parse).
    """

    parser_class: type[FunctionTokenParser] = FunctionTokenParser

    def __init__(
        self,
        registry: Registry,
        mode: str = "async-first",
        strict: bool = True,
        text_first_class: bool = False,
        clock: Callable[[], float] | None = None,
        skills: SkillStore | None = None,
        limits: TurnLimits | None = None,
        policy: Policy | None = None,
        sleep: Callable[[float], Awaitable[None]] | None = None,
    ) -> None:
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, not {mode!r}")
        self.registry = registry
        self.mode = mode
        self.strict = strict
        self.text_first_class = text_first_class
        self.clock = clock
        self.sleep = sleep
        self.skills = skills if skills is not None else SkillStore()
        self.limits = (limits or TurnLimits()).validate()
        self.policy = policy
        self._run: ProgramRun | None = None
        self._last: ProgramRun | None = None

    @property
    def timeline(self) -> Timeline | None:
        """The live timeline of the run in progress (times relative to its start), or None."""
        return None if self._run is None else self._run.timeline

    @property
    def running(self) -> bool:
        """True while a run is in progress."""
        return self._run is not None

    async def run(self, chunks: AsyncIterable[str]) -> RunResult:
        """Run one output stream; returns when every dispatched call has ended."""
        if self._run is not None:
            raise RuntimeError("a run is already in progress on this shell")
        self._run = self._last = ProgramRun(self)
        try:
            return await self._run.run(chunks)
        finally:
            self._run = None

    @property
    def last_result(self) -> RunResult | None:
        """The result of the run in progress or of the last one, as far as it got (None before the
        first run). A run cancelled from outside (e.g. its session lost the link) never returns
        its result; this is where its calls, in the state the cancellation left them, are kept."""
        return None if self._last is None else self._last.result()

    async def run_text(self, text: str | Iterable[str]) -> RunResult:
        """Run a complete program (a string, or an iterable of chunks delivered at once)."""
        return await self.run(_chunks([text] if isinstance(text, str) else list(text)))

    def interrupt(self, channels: Iterable[str] | None = None) -> int:
        """External-event interruption of the current run (see :meth:`ProgramRun.interrupt`).

        Returns the number of calls cancelled (0 when nothing runs). Call it from
        the event loop that runs the shell.
        """
        if self._run is None:
            return 0
        return self._run.interrupt(None if channels is None else tuple(channels))

    def abort_cleanups(self) -> None:
        """Cut short the current run's resets (:meth:`ProgramRun.abort_cleanups`): a forced stop, not an
        interruption. Nothing when no run is in progress."""
        if self._run is not None:
            self._run.abort_cleanups()

    def prompt(self, format: str = "code") -> str:
        """The system prompt for the mounted functions, this mode and the saved skills."""
        from host.shell.prompt import render_prompt

        return render_prompt(
            self.registry, format=format, mode=self.mode, text_first_class=self.text_first_class, skills=self.skills
        )


async def _chunks(parts: list[str]) -> AsyncIterator[str]:
    for p in parts:
        yield p
