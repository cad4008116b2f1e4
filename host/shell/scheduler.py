"""The multi-channel scheduler: parser events in, timed function calls out.

One :class:`ProgramRun` consumes the events of one LLM output stream while it is
still arriving and dispatches every call as soon as its element is complete
enough (a start-tag activates, a self-closing tag calls, text is spoken at
sentence boundaries). Built on AnyIO structured concurrency: every call is a
task in the run's task group with its own cancel scope (the element's
lifecycle), and a persistent element's function runs in a nested scope that its
reset cancels.

Scheduling rules (paper, Appendix A.4), with call ``j`` dispatched after ``i``:

* same channel: ``j`` starts after ``i`` completed (FIFO, one at a time), or once a finite
  ``i`` hands the channel over (``CallContext.hand_over``: planned ahead, still running);
* different channels: no ordering;
* main channel C0: if ``i`` is on C0, ``j`` waits for ``i`` (global blocking).
  Interpretation: if ``j`` is on C0 it also waits for *every* earlier call
  (a barrier), so ``<a/><wait><b/></wait>`` runs ``b`` after ``a``.
* ancestors are exempt: ``j`` never waits for an element that encloses it (it
  waits for that element's *activation* instead). Without this a child of
  ``<wait>`` or of a persistent parent on the same channel would deadlock. A
  descendant on its active ancestor's channel therefore runs at once and the
  ancestor's :class:`~host.shell.context.CallContext` reports ``overridden``
  while it runs.
* "completed" for a non-empty element means: its end-tag arrived, all its
  children completed, its persistent run was cancelled and its reset hook
  returned. So on one channel a reset always finishes before the next call
  starts.

Scopes (issue 19): ``<wait>`` and ``<async>`` take ``until`` and ``timeout``.

* ``until="all"`` (the default, the paper's meaning): the scope ends when all its
  children have ended.
* ``until="any"``: the first direct child to end (``done``, ``failed`` or, a scope,
  ``timeout``; a child cancelled from outside does not count) ends the scope: every call still pending
  under it is cancelled through the lifecycle tree (persistent ones are reset), and
  children that arrive later in the stream are cancelled before they start.
  ``CallRecord.ended_by`` names that child.
* ``timeout="S"``: S seconds after the scope starts, on the shell's clock (slept
  with ``Shell(sleep=...)``, the board clock in real runs), the scope ends the same
  way; its outcome is then ``timeout`` (``ended_by`` ``"timeout"``), else ``done``.
* The scope's ``end`` is the moment it ended; it still *completes* (what is written
  after it may start) only when its end-tag arrived and every cancelled child has
  stopped, so nothing after it overlaps what it cancelled.
* A bad ``until``/``timeout`` (see :func:`host.shell.mapper.map_scope`) fails the
  scope with one line; like any failed start-tag it still scopes its children, as a
  plain scope (``until="all"``, no timeout). On a self-closing ``<wait/>`` the
  attributes are checked but have nothing to act on (a warning says so).

``<RUN id="skill"/>`` is an element: the skill's calls are its children (paths
``RUN[0]/...``), it completes when they have, and cancelling it cancels them. It
has no channel of its own (like a group), so its calls are scheduled exactly as if
they were written in its place.

Failures are local: a call whose function raises (or whose element cannot be
mapped) is recorded ``failed`` with the error, and its children and siblings
still run (a failed start-tag still scopes its children and is reset).
"""

from __future__ import annotations

import itertools
import re
from collections.abc import AsyncIterable, Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import anyio

from host.shell.cleanups import Cleanups
from host.shell.context import CallContext
from host.shell.mapper import MappingError, map_element, map_scope, split_sync
from host.shell.limits import TurnLimits
from host.shell.parser import (
    EmptyTag,
    EndTag,
    Event,
    FunctionTokenParser,
    ParseError,
    ParseWarning,
    StartTag,
    Text,
)
from host.shell.policy import Policy, PolicyError
from host.shell.registry import Registry
from host.shell.skill_recorder import MAX_SKILL_DEPTH, SkillRecorder, warning_text
from host.shell.skills import SkillError, SkillStore, end_tag, start_tag, text
from host.shell.timeline import CallRecord, Observation, RunResult, Timeline
from host.shell.types import MAIN_CHANNEL, FunctionSpec
from host.speech.sentences import SentenceSplitter


class RunSettings(Protocol):
    """What a run takes from its shell (:class:`host.shell.shell.Shell` has it; see its docstring).

    A protocol rather than ``Shell`` itself: the shell module builds on this one.
    """

    @property
    def registry(self) -> Registry: ...
    @property
    def mode(self) -> str: ...
    @property
    def strict(self) -> bool: ...
    @property
    def text_first_class(self) -> bool: ...
    @property
    def clock(self) -> Callable[[], float] | None: ...
    @property
    def sleep(self) -> Callable[[float], Awaitable[None]] | None: ...
    @property
    def skills(self) -> SkillStore: ...
    @property
    def limits(self) -> TurnLimits: ...
    @property
    def policy(self) -> Policy | None: ...
    @property
    def parser_class(self) -> type[FunctionTokenParser]: ...

MODES = ("async-first", "sync-first")
#: deepest element nesting the shell runs (deeper elements fail; their children attach above)
MAX_DEPTH = 64

#: Longest a reset hook may take before it is abandoned (seconds on the run's clock).
RESET_TIMEOUT = 5.0

#: Tag-like markup that must never reach speech in lenient mode: ``<name ...>``, ``</name>``,
#: ``<!...>``, ``<?...>`` (a ``<`` directly followed by a name start, ``/``, ``!`` or ``?`` and closed
#: by ``>``, or a ``<`` glued to a word), ``I <3 you`` and ``a < b`` stay text, and the residue of a
#: broken tag (``"/>``).
_MARKUP = re.compile(r"<\s*[/!?]?\s*[^\W\d][^<>]*>|<[/!?]?[^\W\d][^\s<>]*|[\"']?[ \t]*/>")

__all__ = ["MAX_DEPTH", "MAX_SKILL_DEPTH", "MODES", "RESET_TIMEOUT", "ProgramRun", "RunSettings"]


@dataclass(eq=False)
class _Call:
    id: int
    record: CallRecord
    kind: str  # "fn" | "builtin" (wait, async) | "group" (a failed start-tag) | "run" (<RUN>)
    spec: FunctionSpec | None
    args: dict[str, Any]
    channel: str | None
    home: str | None
    parent: _Call | None
    persistent: bool
    scope: anyio.CancelScope = field(default_factory=anyio.CancelScope)
    run_scope: anyio.CancelScope | None = None
    deps: list[_Call] = field(default_factory=list)
    activated: anyio.Event = field(default_factory=anyio.Event)
    completed: anyio.Event = field(default_factory=anyio.Event)
    handed_over: anyio.Event = field(default_factory=anyio.Event)  # the channel's next call may start
    subtree_done: anyio.Event = field(default_factory=anyio.Event)
    open_children: int = 0
    closed: bool = False
    started: bool = False
    ok: bool = False
    reason: str | None = None
    error: str | None = None
    ctx: CallContext | None = None
    until: str = "all"  # a scope: "all" | "any"
    timeout: float | None = None  # a scope: seconds on the shell's clock
    ending: str | None = None  # a scope that ended early: "any" | "timeout"
    cut_at: float | None = None  # when it ended (seconds since the run's start)

    def ancestors(self) -> list[_Call]:
        out, p = [], self.parent
        while p is not None:
            out.append(p)
            p = p.parent
        return out


@dataclass(eq=False)
class _Frame:
    name: str
    call: _Call | None  # None for the root and for transparent frames (<RUN>...</RUN>)
    path: str
    async_ctx: bool
    counts: dict[str, int] = field(default_factory=dict)


class ProgramRun:
    """The state of one run; created by :class:`~host.shell.shell.Shell`."""

    def __init__(self, shell: RunSettings) -> None:
        self.registry = shell.registry
        self.mode = shell.mode
        self.strict = shell.strict
        self.text_first_class = shell.text_first_class
        self.clock: Callable[[], float] = shell.clock or anyio.current_time
        self.sleep: Callable[[float], Awaitable[None]] = getattr(shell, "sleep", None) or anyio.sleep
        self.skills = shell.skills
        self.timeline = Timeline()
        self.observations: list[Observation] = []
        self.error: Exception | None = None
        self.interrupted = False
        self.t0 = 0.0
        self._ids = itertools.count()
        self._pending: dict[int, _Call] = {}
        self._by_channel: dict[str | None, dict[int, _Call]] = {}  # pending calls per channel, in order
        self._stack: list[_Frame] = [_Frame("", None, "", self.mode == "async-first")]
        self._text = SentenceSplitter()
        self._text_fed = False  # text reached the splitter since its last flush (else flushing is a no-op)
        self._tg: anyio.abc.TaskGroup | None = None
        self._consumer = anyio.CancelScope()
        self._stopped = False
        self._warned_no_speech = False
        self._executed: list[tuple[str, _Call | None]] = []  # the reply as executed (see executed_text)
        self._skills = SkillRecorder(self.skills, self._observe, self._executed)  # <SAVE> and <RUN>
        self.limits: TurnLimits = getattr(shell, "limits", None) or TurnLimits()
        self.policy = getattr(shell, "policy", None)
        self._text_chars = 0  # characters of text this turn
        self._calls = 0  # elements this turn
        self._refused_calls = 0  # elements refused for exceeding max_calls
        self._full_channels: set[str | None] = set()  # channels whose queue overflowed (reported once)
        self._parser_class: type[FunctionTokenParser] = getattr(shell, "parser_class", FunctionTokenParser)
        self._cleanups = Cleanups()  # the shielded resets running now (abort_cleanups cuts them short)
        #: the elements the shell itself interprets (``host.shell.types.BUILTINS``) -> how each starts; any
        #: other name is a function (:meth:`_start_call`)
        self._elements: dict[str, Callable[[str, dict[str, str], bool], None]] = {
            "SAVE": lambda _name, attrs, empty: self._skills.start(attrs, empty),
            "RUN": lambda _name, attrs, empty: self._run_skill(attrs, empty),
            "wait": self._start_scope,
            "async": self._start_scope,
        }

    # ------------------------------------------------------------------ API
    async def run(self, chunks: AsyncIterable[str]) -> RunResult:
        """Consume ``chunks``, dispatching calls as events complete; return when every call ended."""
        self.t0 = self.clock()
        parser = self._parser_class(strict=self.strict)
        async with anyio.create_task_group() as tg:
            self._tg = tg
            with self._consumer:
                try:
                    aiter_ = chunks.__aiter__()
                    try:
                        async for chunk in aiter_:
                            self._feed(parser.feed(chunk))
                            if self._stopped:
                                break
                    finally:
                        await _aclose(aiter_)
                    if not self._stopped:
                        self._feed(parser.close())
                        self._end_of_stream()
                except ParseError as exc:
                    self._abort(exc, "parse error")
                except Exception as exc:  # the LLM stream itself failed (network, provider error)
                    self._abort(exc, "the output stream failed")
        self._tg = None
        return self.result()

    @property
    def save_failures(self) -> int:
        """``<SAVE>`` elements that saved nothing (the run's outcome is then failed)."""
        return self._skills.failures

    def result(self) -> RunResult:
        """The run's result so far (complete once :meth:`run` returned)."""
        return RunResult(self.timeline, self.observations, self.t0, self.error, self.interrupted,
                         self.executed_text(), self.save_failures)

    def executed_text(self) -> str:
        """The reply as it was executed: dispatched elements (reconstructed) and the sentences
        whose speech started; elements still open at an interruption are closed. Sentences that
        were cut before they were spoken and text after the cut are left out (only what the
        user saw and heard belongs in the conversation history)."""
        parts = [p for p, call in self._executed if call is None or call.record.start is not None]
        return "".join(parts).strip()

    def interrupt(self, channels: list[str] | tuple[str, ...] | set[str] | None = None) -> int:
        """Cancel running and queued calls (all, or those on ``channels``); return how many.

        With ``channels=None`` the rest of the stream is not dispatched either
        and every open element is closed. Active parents hit by the interrupt
        are reset (their reset hook runs, shielded).
        """
        if channels is None:
            self.interrupted = True
            self._stop("interrupted")
            return self._cancel(lambda c: True, "interrupted")
        chans = set(channels)
        return self._cancel(lambda c: c.channel in chans, "interrupted")

    # ------------------------------------------------------------ internals
    def now(self) -> float:
        """Seconds since the run started, on the run's clock (rounded to 1 ns)."""
        return round(self.clock() - self.t0, 9)

    def _observe(self, kind: str, message: str, path: str | None = None) -> None:
        self.observations.append(Observation(kind, message, path, self.now()))  # type: ignore[arg-type]

    def _stop(self, reason: str) -> None:
        self._stopped = True
        self._consumer.cancel()
        self._text, self._text_fed = SentenceSplitter(), False
        self._skills.drop()
        while len(self._stack) > 1:
            f = self._stack.pop()
            self._executed.append((end_tag(f.name), None))
            if f.call is not None:
                self._close(f.call)

    def _cancel(self, pred: Callable[[_Call], bool], reason: str) -> int:
        hit = [c for c in self._pending.values() if pred(c)]
        for c in hit:
            c.reason = c.reason or reason
            c.scope.cancel()
        return len(hit)

    def _abort(self, exc: Exception, what: str) -> None:
        """End the run: nothing more is dispatched, pending calls are cancelled, parents reset."""
        self.error = exc
        self._observe("error", f"{what}: {exc}; dispatch stopped")
        self._stop("cancelled")
        self._cancel(lambda c: True, "cancelled")

    def _end_of_stream(self) -> None:
        self._flush_text()
        if self._refused_calls:
            self._observe("error", f"{self._refused_calls} element(s) refused in all: more than "
                                   f"{self.limits.max_calls} calls in one turn")
        self._skills.end_of_stream()
        while len(self._stack) > 1:  # lenient parsers close these; be safe anyway
            f = self._stack.pop()
            self._executed.append((end_tag(f.name), None))
            if f.call is not None:
                self._close(f.call)

    # -- events --------------------------------------------------------------
    def _feed(self, events: list[Event]) -> None:
        for ev in events:
            if self._stopped:
                return
            self._event(ev)

    def _event(self, ev: Event) -> None:
        """One parser event: kept for the reply as executed, recorded (inside ``<SAVE>``) or dispatched."""
        if not self._skills.stack and isinstance(ev, (StartTag, EmptyTag, EndTag)):
            if self._skills.recording is None:
                self._flush_text()  # sentences before the tag come first
            self._keep(ev)
        if self._skills.recording is not None:
            self._skills.record(ev)
            return
        match ev:
            case Text(text=data):
                self._text_in(data)
            case ParseWarning():  # the commonest event of malformed output: matched before the tags
                self._observe("warning", warning_text(ev))
            case StartTag(name=name, attrs=attrs, refused=str(why)) | EmptyTag(name=name, attrs=attrs, refused=str(why)):
                self._flush_text()  # a malformed call (duplicated attribute): refused, its children still scoped
                self._mapping_failed(name, dict(attrs), f"<{name}> refused: {why}", isinstance(ev, EmptyTag))
            case StartTag(name=name, attrs=attrs) | EmptyTag(name=name, attrs=attrs):
                self._flush_text()
                self._start(name, dict(attrs), empty=isinstance(ev, EmptyTag))
            case EndTag(name=name):
                self._flush_text()
                self._end(name)

    def _keep(self, ev: StartTag | EmptyTag | EndTag) -> None:
        match ev:
            case EmptyTag(name=name, attrs=attrs):
                self._executed.append((start_tag(name, dict(attrs), empty=True), None))
            case StartTag(name=name, attrs=attrs):
                self._executed.append((start_tag(name, dict(attrs)), None))
            case EndTag(name=name) if self._skills.recording is not None or len(self._stack) > 1:
                self._executed.append((end_tag(name), None))

    # -- text -------------------------------------------------------------------
    def _text_in(self, data: str) -> None:
        room = self.limits.max_text_chars - self._text_chars
        if len(data) > room:
            if room > 0 or self._text_chars == self.limits.max_text_chars:
                self._observe("error", f"more than {self.limits.max_text_chars} characters of text in one turn; "
                                       "the rest is not spoken")
                self._text_chars += 1  # reported once
            data = data[: max(0, room)]
        self._text_chars += len(data)
        if not data:
            return
        self._text_fed = True
        for seg in self._text.feed(data):
            self._speak(seg)

    def _flush_text(self) -> None:
        """Speak what the splitter holds (called before every element; a no-op unless text came since the last)."""
        if not self._text_fed:  # a flushed splitter holds nothing: flushing it again returns nothing
            return
        self._text_fed = False
        for seg in self._text.flush():
            self._speak(seg)

    def _speak(self, segment: str) -> None:
        if not self.strict and _MARKUP.search(segment):  # lenient: markup is never spoken
            cleaned = " ".join(_MARKUP.sub(" ", segment).split())
            self._observe("warning", f"markup in text not spoken: {segment[:80]!r}")
            if not cleaned.strip(" \t\n\"'/<>"):
                return
            segment = cleaned
        spec = self.registry.speech
        frame = self._stack[-1]
        if spec is None:
            if not self._warned_no_speech:
                self._warned_no_speech = True
                self._observe("warning", "text is not spoken: no speech function is mounted")
            return
        if self.text_first_class or not frame.async_ctx:
            channel = MAIN_CHANNEL
        else:
            channel = spec.channel
        if self._queue_full(channel):
            return
        call = self._new_call(spec.name, "fn", spec, {"text": segment}, channel, spec.channel, persistent=False)
        if not self._skills.stack:  # sentences of one text run are joined by a space (the splitter drops it)
            sep = " " if self._executed and self._executed[-1][1] is not None else ""
            self._executed.append((sep + text(segment), call))

    def _queue_full(self, channel: str | None) -> bool:
        """True (and reported once per channel) when ``channel`` already has the maximum of pending calls."""
        if len(self._by_channel.get(channel, {})) < self.limits.max_queued_per_channel:
            return False
        if channel not in self._full_channels:
            self._full_channels.add(channel)
            self._observe("error", f"channel {channel!r} already has {self.limits.max_queued_per_channel} queued "
                                   "calls; further calls there are refused until it drains")
        return True

    # -- elements ------------------------------------------------------------
    def _start(self, name: str, attrs: dict[str, str], *, empty: bool) -> None:
        frame = self._stack[-1]
        if len(self._stack) > MAX_DEPTH:  # hostile or runaway output: refuse, keep the stream in step
            self._record_failure(name, attrs, f"<{name}> is nested deeper than {MAX_DEPTH} elements; refused", empty)
            if not empty:
                self._stack.append(_Frame(name, None, frame.path, frame.async_ctx, frame.counts))
            return
        if self._calls >= self.limits.max_calls:  # runaway output: refuse, count, keep the stream in step
            if not self._refused_calls:
                self._observe("error", f"more than {self.limits.max_calls} calls in one turn; <{name}> and "
                                       "every later element are refused")
            self._refused_calls += 1
            if not empty:
                self._stack.append(_Frame(name, None, frame.path, frame.async_ctx, frame.counts))
            return
        self._calls += 1
        big = next((k for k, v in attrs.items() if len(v) > self.limits.max_attr_chars), None)
        if big is not None:
            self._mapping_failed(name, {k: v[:64] for k, v in attrs.items()},
                                 f"<{name}> attribute {big!r} has {len(attrs[big])} characters; the limit is "
                                 f"{self.limits.max_attr_chars}", empty)
            return
        self._elements.get(name, self._start_call)(name, attrs, empty)

    def _start_scope(self, name: str, attrs: dict[str, str], empty: bool) -> None:
        """``<wait>`` or ``<async>``: a main-channel element that scopes its children."""
        frame = self._stack[-1]
        try:
            args, ignored = map_scope(name, attrs, self.limits.max_scope_timeout_s)
        except MappingError as exc:
            self._scope_failed(name, attrs, str(exc), empty)
            return
        if ignored:
            self._observe("warning", f"<{name}> takes only until and timeout; ignored {sorted(ignored)}")
        if empty and args:
            self._observe("warning", f"<{name}/> has no children: {' and '.join(sorted(args))} has no effect")
        call = self._new_call(name, "builtin", None, args, MAIN_CHANNEL, None, persistent=not empty)
        call.until, call.timeout = args.get("until", "all"), args.get("timeout")
        if not empty:
            self._stack.append(_Frame(name, call, call.record.path, name == "async" or frame.async_ctx))

    def _start_call(self, name: str, attrs: dict[str, str], empty: bool) -> None:
        """An element naming a function: mapped, checked by the policy and the channel's queue, dispatched."""
        frame = self._stack[-1]
        try:
            mapped = map_element(self.registry, name, attrs)
        except MappingError as exc:
            self._mapping_failed(name, attrs, str(exc), empty)
            return
        spec = mapped.spec
        channel = MAIN_CHANNEL if (mapped.sync or not frame.async_ctx) else spec.channel
        if self.policy is not None:
            try:
                self.policy.check(spec, mapped.args, self.clock())  # absolute: the ledger spans turns
            except PolicyError as exc:  # refused before anything reaches the robot
                self._mapping_failed(name, attrs, str(exc), empty)
                return
        if self._queue_full(channel):
            self._mapping_failed(name, attrs, f"<{name}> refused: channel {channel!r} already has "
                                              f"{self.limits.max_queued_per_channel} queued calls", empty)
            return
        call = self._new_call(name, "fn", spec, mapped.args, channel, spec.channel, persistent=not empty)
        if not empty:
            self._stack.append(_Frame(name, call, call.record.path, frame.async_ctx))

    def _record_failure(self, name: str, attrs: dict[str, str], message: str, empty: bool) -> CallRecord:
        """A failed element on the timeline, with the error as an observation."""
        path = self._path(self._stack[-1], name)
        rec = CallRecord(next(self._ids), name, None, dict(attrs), path, not empty, self.now())
        rec.outcome, rec.error, rec.end = "failed", message, rec.dispatch
        self.timeline.records.append(rec)
        self._observe("error", message, path)
        return rec

    def _mapping_failed(self, name: str, attrs: dict[str, str], message: str, empty: bool) -> None:
        frame = self._stack[-1]
        rec = self._record_failure(name, attrs, message, empty)
        path = rec.path
        if not empty:  # still scope the children, as a plain group
            try:
                _, sync = split_sync(name, attrs)
            except MappingError:
                sync = False
            call = self._spawn(rec, "group", None, {}, MAIN_CHANNEL if sync else None, None, frame, persistent=True)
            call.error = message
            self._stack.append(_Frame(name, call, path, frame.async_ctx))

    def _scope_failed(self, name: str, attrs: dict[str, str], message: str, empty: bool) -> None:
        """A refused ``<wait>``/``<async>``: failed on the timeline; a start-tag still scopes its
        children as a plain scope of its kind would (main channel, ``until="all"``, no timeout)."""
        frame = self._stack[-1]
        rec = self._record_failure(name, attrs, message, empty)
        if not empty:
            call = self._spawn(rec, "group", None, {}, MAIN_CHANNEL, None, frame, persistent=True)
            call.error = message
            self._stack.append(_Frame(name, call, rec.path, name == "async" or frame.async_ctx))

    def _end(self, name: str) -> None:
        if len(self._stack) == 1:
            self._observe("warning", f"end-tag </{name}> closes nothing; ignored")
            return
        frame = self._stack.pop()
        if frame.call is not None:
            self._close(frame.call)

    def _run_skill(self, attrs: dict[str, str], empty: bool) -> None:
        """``<RUN id=.../>``: an element (no channel) whose children are the skill's calls; a
        ``<RUN>`` start-tag also scopes what it encloses, after the skill's calls."""
        frame = self._stack[-1]
        sid = attrs.get("id", attrs.get("name", ""))
        try:
            events = self._skills.program(sid)
        except (SkillError, ParseError) as exc:
            path = self._path(frame, "RUN")
            rec = CallRecord(next(self._ids), "RUN", None, {"id": sid}, path, False, self.now())
            rec.start = rec.end = rec.dispatch
            rec.outcome, rec.error = "failed", str(exc)
            self.timeline.records.append(rec)
            self._observe("error", f"<RUN id={sid!r}/>: {exc}", path)
            if not empty:
                self._stack.append(_Frame("RUN", None, frame.path, frame.async_ctx, frame.counts))
            return
        call = self._new_call("RUN", "run", None, {"id": sid}, None, None, persistent=True)
        self._stack.append(_Frame("RUN", call, call.record.path, frame.async_ctx))
        depth = len(self._stack)
        with self._skills.expanding(sid):
            for ev in events:
                if self._stopped:
                    break
                self._event(ev)
            self._flush_text()
        if self._stopped:  # _stop closed every open element, this RUN included
            return
        while len(self._stack) > depth:  # cannot happen for a strict-parsed program
            self._end(self._stack[-1].name)
        if empty:
            self._end("RUN")

    # -- dispatch ---------------------------------------------------------------
    def _path(self, frame: _Frame, name: str) -> str:
        i = frame.counts.get(name, 0)
        frame.counts[name] = i + 1
        return f"{frame.path}/{name}[{i}]" if frame.path else f"{name}[{i}]"

    def _new_call(
        self,
        name: str,
        kind: str,
        spec: FunctionSpec | None,
        args: dict[str, Any],
        channel: str | None,
        home: str | None,
        *,
        persistent: bool,
    ) -> _Call:
        frame = self._stack[-1]
        rec = CallRecord(next(self._ids), name, channel, args, self._path(frame, name), persistent, self.now())
        self.timeline.records.append(rec)
        return self._spawn(rec, kind, spec, args, channel, home, frame, persistent=persistent)

    def _spawn(
        self,
        rec: CallRecord,
        kind: str,
        spec: FunctionSpec | None,
        args: dict[str, Any],
        channel: str | None,
        home: str | None,
        frame: _Frame,
        *,
        persistent: bool,
    ) -> _Call:
        parent = next((f.call for f in reversed(self._stack) if f.call is not None), None)
        call = _Call(rec.id, rec, kind, spec, args, channel, home, parent, persistent)
        call.deps = self._dependencies(call, channel)
        self._pending[call.id] = call
        self._by_channel.setdefault(channel, {})[call.id] = call
        if parent is not None:
            parent.open_children += 1
        if any(a.ending is not None for a in call.ancestors()):  # its scope already ended
            call.reason = "cancelled"
            call.scope.cancel()
        assert self._tg is not None
        self._tg.start_soon(self._run_element if persistent else self._run_leaf, call)
        return call

    def _dependencies(self, call: _Call, channel: str | None) -> list[_Call]:
        """The pending calls ``call`` must wait for (never its own ancestors).

        A main-channel call waits for every pending call (the barrier); any call
        waits for pending main-channel calls. On its own channel a call waits
        for the latest pending call there, plus that call's pending same-channel
        ancestors (which it does not wait for itself): the latest call already
        waits for everything earlier, so this is the whole channel, found in
        time bounded by the nesting depth instead of the queue length.
        """
        ancestors = {id(a) for a in call.ancestors()}
        if channel == MAIN_CHANNEL:
            return [p for p in self._pending.values() if id(p) not in ancestors]
        deps = [p for p in self._by_channel.get(MAIN_CHANNEL, {}).values() if id(p) not in ancestors]
        if channel is None:
            return deps
        tail = next((p for p in reversed(self._by_channel.get(channel, {}).values()) if id(p) not in ancestors), None)
        if tail is not None:
            deps.append(tail)
            deps += [a for a in tail.ancestors()
                     if a.channel == channel and a.id in self._pending and id(a) not in ancestors]
        return deps

    async def _await_deps(self, c: _Call) -> None:
        if c.parent is not None:
            await c.parent.activated.wait()
        for d in c.deps:  # a finite call on the same channel may hand over before it completes
            handover = d.channel == c.channel and c.channel != MAIN_CHANNEL and not d.persistent
            await (d.handed_over if handover else d.completed).wait()
        c.deps.clear()

    def _mark_start(self, c: _Call) -> None:
        c.started = True
        c.record.start = self.now()
        if c.spec is not None:  # created before children can start, so they can mark it overridden
            c.ctx = CallContext(
                c.spec.name, c.channel or "", c.home or "", c.args, c.record.path, c.id, c.persistent
            )
            c.ctx._hand_over = c.handed_over

    async def _invoke(self, c: _Call) -> None:
        assert c.spec is not None and c.ctx is not None
        ctx = c.ctx
        overridden = [a for a in c.ancestors() if a.ctx is not None and a.home is not None and a.home == c.home and not a.completed.is_set()]
        for a in overridden:
            a.ctx._enter_override()  # type: ignore[union-attr]
        handed = {c.spec.call_param: ctx} if c.spec.call_param else {}
        try:
            result = await c.spec.impl(**c.args, **handed)
        except Exception as exc:  # a failing function fails its call only
            # a ValueError is the function refusing its arguments: its message is the one line; any other
            # exception is a bug in the function, and its class name helps whoever reads the line
            c.error = str(exc) if isinstance(exc, ValueError) and str(exc) else f"{type(exc).__name__}: {exc}"
        else:
            c.record.result = result
            if result is not None:
                self._observe("result", f"{c.spec.name} returned {result!r}", c.record.path)
        finally:
            for a in overridden:
                a.ctx._exit_override()  # type: ignore[union-attr]

    async def _run_leaf(self, c: _Call) -> None:
        try:
            with c.scope:
                await self._await_deps(c)
                self._mark_start(c)
                if c.spec is not None:
                    await self._invoke(c)
                c.ok = True
        finally:
            self._finish(c)

    async def _persistent(self, c: _Call) -> None:
        assert c.run_scope is not None
        with c.run_scope:
            await self._invoke(c)

    async def _run_element(self, c: _Call) -> None:
        try:
            with c.scope:
                await self._await_deps(c)
                self._mark_start(c)
                c.activated.set()
                if c.spec is not None:
                    c.run_scope = anyio.CancelScope()
                    async with anyio.create_task_group() as tg:
                        tg.start_soon(self._persistent, c)
                        await c.subtree_done.wait()
                        c.run_scope.cancel()
                elif c.timeout is not None:
                    async with anyio.create_task_group() as tg:
                        tg.start_soon(self._scope_timer, c)
                        await c.subtree_done.wait()
                        tg.cancel_scope.cancel()
                else:
                    await c.subtree_done.wait()
                c.ok = True
        finally:
            c.activated.set()  # children of an element cancelled before activation may proceed
            if c.kind == "run" and not c.ok:  # a skill's calls belong to its RUN
                self._cancel(lambda d: c in d.ancestors(), c.reason or "cancelled")
            try:
                if c.started and c.spec is not None and c.spec.reset is not None:
                    await self._reset(c)
                if not c.subtree_done.is_set():  # channel interrupt: children elsewhere still run
                    await c.subtree_done.wait()
            finally:
                self._finish(c)

    async def _scope_timer(self, c: _Call) -> None:
        """End the scope ``c`` once its timeout has passed on the shell's clock."""
        assert c.timeout is not None
        try:
            await self.sleep(c.timeout)
        except Exception as exc:  # the clock's source failed (e.g. the link): the scope fails, its calls go on
            c.error = c.error or f"timeout clock failed: {type(exc).__name__}: {exc}"
            return
        self._end_scope(c, "timeout", "timeout")

    def _end_scope(self, c: _Call, why: str, by: str) -> None:
        """The scope ``c`` ends now (``why``: ``any`` or ``timeout``): cancel every call pending under it."""
        if c.ending is not None or c.subtree_done.is_set():
            return
        c.ending, c.cut_at, c.record.ended_by = why, self.now(), by
        n = self._cancel(lambda d: c in d.ancestors(), "cancelled")
        attrs = "".join(f' {k}="{v:g}"' if isinstance(v, float) else f' {k}="{v}"' for k, v in c.args.items())
        what = (f"timed out after {c.timeout:g} s" if why == "timeout"
                else f"ended when its child {by} ended")
        cancelled = f"; {n} call(s) under it cancelled" if n else ""
        self._observe("info", f"<{c.record.function}{attrs}> {what}{cancelled}", c.record.path)

    async def _reset(self, c: _Call) -> None:
        assert c.spec is not None and c.spec.reset is not None
        ctx = c.ctx
        assert ctx is not None
        ctx.phase = "reset"
        if self._cleanups.aborted:  # stopped at once: the call keeps its interruption as its outcome
            return
        handed = {c.spec.reset_call_param: ctx} if c.spec.reset_call_param else {}
        with self._cleanups.shielded(RESET_TIMEOUT) as (shield, timeout):
            try:
                await c.spec.reset(**handed)
            except Exception as exc:
                c.error = c.error or f"reset failed: {type(exc).__name__}: {exc}"
        if timeout.cancelled_caught and not shield.cancel_called:
            c.error = c.error or f"reset timed out after {RESET_TIMEOUT:g}s"

    def abort_cleanups(self) -> None:
        """Stop at once (a second Ctrl-C): the resets running now are cut short and later ones skipped,
        instead of each getting its shielded ``RESET_TIMEOUT`` (their calls keep the interruption as
        their outcome: the stop was asked for). The caller cancels the run itself; this only lifts the
        shields that would outlive it."""
        self._cleanups.abort()

    def _close(self, c: _Call) -> None:
        c.closed = True
        if c.open_children == 0:
            c.subtree_done.set()

    def _finish(self, c: _Call) -> None:
        rec = c.record
        rec.end = self.now()
        if c.error is not None:
            rec.outcome, rec.error = "failed", c.error
            if c.kind != "group":
                self._observe("error", f"{rec.function} failed: {c.error}", rec.path)
        elif c.ok:
            rec.outcome = "timeout" if c.ending == "timeout" else "done"
            if c.cut_at is not None:  # a scope that ended early: its end is the cut
                rec.end = c.cut_at
        else:
            rec.outcome = c.reason or "cancelled"  # type: ignore[assignment]
        if not c.started and rec.outcome != "failed":
            rec.end = None
        self._pending.pop(c.id, None)
        self._by_channel.get(c.channel, {}).pop(c.id, None)
        if c.parent is not None and c.parent.until == "any" and rec.outcome in ("done", "failed", "timeout"):
            self._end_scope(c.parent, "any", rec.path)  # before the events below wake its siblings
        c.activated.set()
        c.handed_over.set()
        c.completed.set()
        if c.parent is not None:
            c.parent.open_children -= 1
            if c.parent.closed and c.parent.open_children == 0:
                c.parent.subtree_done.set()


async def _aclose(it: Any) -> None:
    """Close the async iterator ``it`` if it has ``aclose``, shielded (also when the run is cancelled).

    An async generator that has finished (``ag_frame`` is None) has nothing left to close: its
    ``aclose`` would return at once, so neither it nor the shielded scope is needed.
    """
    aclose = getattr(it, "aclose", None)
    if aclose is None or getattr(it, "ag_frame", True) is None:
        return
    with anyio.CancelScope(shield=True):
        await aclose()
