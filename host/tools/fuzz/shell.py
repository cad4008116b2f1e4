"""Fuzz target ``shell``: fuzzed text in fuzzed chunks through the real shell (parser, mapper, scheduler).

Input layout (atheris ``FuzzedDataProvider``): byte 0 picks strict (even) or lenient (odd) parsing, the
last 4 bytes seed the chunking, the bytes between are the LLM output (UTF-8, errors replaced). A seed
file is therefore ``b"\\x00" + program + 4 bytes`` (see ``host.tools.fuzz.seeds``).

Each input runs once, through :class:`host.shell.shell.Shell` on Trio's ``MockClock`` (virtual time)
with the default robot's vocabulary bound to a recorder, and the Shell's own stream parser is watched
(:func:`watched_parser`, the Shell's ``parser_class``). Checked on every input:

1. the parse (:class:`host.shell.parser.FunctionTokenParser`, the pieces the Shell was given): only
   :class:`ParseError` (strict) escapes the parser (the Shell would report anything else as "the
   output stream failed"; here it is raised), and it stays dead afterwards; tags nest properly;
   held-back input stays under ``MAX_TOKEN`` after every piece; :func:`host.shell.mapper.map_element`
   raises only :class:`MappingError` on every start or empty tag, and every argument it maps
   satisfies its annotation (:func:`host.tools.fuzz.validate.conforms`). Should the Shell stop reading
   before the end (its run aborted), the rest of the pieces are fed to the same parser here;
2. the run: no exception escapes it, and every call that reaches an implementation has exactly the
   declared parameters, each one conforming.

Throughput (measured exec/s, with command, n and load: docs/guides/fuzzing.md#throughput): when
fuzzing, the Shell runs in one Trio run in guest mode on the fuzzing thread (:class:`GuestLoop`: no
thread hand-off, one task that runs each call at its first tick; ``load(False)`` uses the threaded
:class:`TrioLoop`, one Trio loop kept for the process); coverage instruments ``host.shell`` and
``host.speech`` only, with real stack sizes (:mod:`host.tools.fuzz.stackdepth`); start-up's objects are
frozen out of the garbage collector (:func:`host.tools.fuzz.harness.run_atheris`). The parser checks read
the Shell's parse (instrumented: that is the input's coverage) instead of parsing the input a second
time; the watch reads ``pending``, and probes a dead parser's ``feed``, with that source compiled
without coverage hooks. Each distinct (element, attributes) is mapped once per process (mapped and
checked for real the first time, so a failure reproduces from its input alone); the registry works
out an unknown name's did-you-mean (``difflib``) once per name. No check is sampled (every Nth input)
or deferred to the end of a run: every check above runs on every input. What is left is the code
under test: the instrumented parser and the scheduler's task per call (anyio on Trio).
"""

from __future__ import annotations

import inspect
import math
import threading
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any

from host.tools.fuzz.serial_decoder import chunks as byte_chunks

if TYPE_CHECKING:
    from host.shell.parser import Event, FunctionTokenParser, ParseError

__all__ = ["GuestLoop", "ParseWatch", "TrioLoop", "load", "watched_parser"]

#: element names whose did-you-mean, and elements whose mapping, are remembered (each; then it starts again)
MAX_REMEMBERED = 4096


class TrioLoop:
    """One Trio run on a ``MockClock`` (autojump: virtual time) in a daemon thread, kept for the process.

    ``trio.run`` costs 1.2-1.6 ms to set up and tear down (runner, I/O manager, system nursery) on
    this machine, more than the shell's own work for most inputs; :meth:`run` instead hands an async
    function to the running loop (``trio.from_thread.run``, ~50 us) and returns its result or raises
    its exception in the caller's thread. Virtual time carries on from input to input (the shell's
    timeline is relative to its run's start; a scope ``timeout`` is relative too).
    """

    def __init__(self) -> None:
        import threading

        import trio
        from trio.testing import MockClock

        self._trio = trio
        started = threading.Event()
        box: list[trio.lowlevel.TrioToken] = []
        # autojump only while a call runs: with a threshold of 0 an idle loop polls epoll without
        # a timeout, a busy loop that takes half a core (and the GIL) from the fuzzer between inputs
        self.clock = MockClock(autojump_threshold=math.inf)

        async def serve() -> None:
            box.append(trio.lowlevel.current_trio_token())
            started.set()
            await trio.sleep_forever()

        thread = threading.Thread(target=trio.run, args=(serve,), kwargs={"clock": self.clock},
                                  name="fuzz-shell-trio", daemon=True)
        thread.start()
        started.wait()
        self.token = box[0]

    def run(self, afn: Callable[..., Awaitable[Any]], *args: Any) -> Any:
        """``await afn(*args)`` in the loop; its result, or its exception raised here."""
        return self._trio.from_thread.run(self._virtual_time, afn, *args, trio_token=self.token)

    async def _virtual_time(self, afn: Callable[..., Awaitable[Any]], *args: Any) -> Any:
        self.clock.autojump_threshold = 0  # in the loop's thread: the setter tells the running loop
        try:
            return await afn(*args)
        finally:
            self.clock.autojump_threshold = math.inf


class GuestLoop:
    """One Trio run on a ``MockClock`` in *guest mode* on the caller's thread, kept for the process.

    :class:`TrioLoop` hands each input to a Trio thread and waits for its answer: two thread wake-ups
    per input and the GIL passed back and forth. Here Trio runs as a guest
    (``trio.lowlevel.start_guest_run``) of a "host loop" that is just :meth:`run` pumping Trio's
    callbacks on the calling thread until the submitted function has finished; between calls
    nothing runs (the next pending callback waits in the queue), so the clock can autojump at all
    times (threshold 0): with a MockClock and no runnable task, Trio never waits on I/O in guest
    mode and never starts its I/O thread. Trio leaves the process's SIGINT handler and wakeup fd
    alone (libFuzzer's). One per thread (:meth:`shared`): a thread holds one Trio run at a time, and
    while the guest run lives its thread counts as inside it (``trio.run`` there fails), so only the
    fuzzing process uses it; ``load(False)`` (pytest, which runs other Trio code on its thread) keeps
    :class:`TrioLoop`.

    A submitted function is run by the run's one task (:meth:`_serve`), which between calls waits in
    a checkpoint for :meth:`run` to leave it the next one: the first Trio tick of a call runs it.
    (Handing it over through ``TrioToken.run_sync_soon`` and starting a task for it took three
    ticks, with a write and two reads on Trio's wake-up socket.) The task is runnable between calls,
    so the run is never idle there (no autojump, no I/O wait), but nothing pumps it then either.
    """

    def __init__(self) -> None:
        import queue
        import signal

        import outcome
        import trio
        from trio.testing import MockClock

        self._outcome = outcome
        self._checkpoint = trio.lowlevel.checkpoint
        self.clock = MockClock(autojump_threshold=0)
        self._callbacks: queue.SimpleQueue[Callable[[], object]] = queue.SimpleQueue()
        self._result: Any = None
        #: the call :meth:`_serve` runs next: (function, its arguments), or ``_STOP``
        self._job: tuple[Callable[..., Awaitable[Any]], tuple[Any, ...]] | None = None
        self._token: trio.lowlevel.TrioToken | None = None

        def ended(result: Any) -> None:  # closed, or the guest run itself failed: reported from run()
            self._result = result if isinstance(result, outcome.Error) else outcome.Error(RuntimeError("trio ended"))
            self._token = None

        main = threading.current_thread() is threading.main_thread()
        sigint = signal.getsignal(signal.SIGINT) if main else None
        trio.lowlevel.start_guest_run(
            self._serve, run_sync_soon_threadsafe=self._callbacks.put,
            run_sync_soon_not_threadsafe=self._callbacks.put,
            done_callback=ended, clock=self.clock, host_uses_signal_set_wakeup_fd=True,
        )
        if main and signal.getsignal(signal.SIGINT) is not sigint:  # trio's KeyboardInterrupt handler: not here
            signal.signal(signal.SIGINT, sigint)
        while self._token is None and self._result is None:
            self._callbacks.get()()
        if self._result is not None:
            self._result.unwrap()

    _per_thread = threading.local()

    @classmethod
    def shared(cls) -> GuestLoop:
        """The calling thread's guest run (one per thread: Trio runs one run per thread at a time)."""
        loop: GuestLoop | None = getattr(cls._per_thread, "loop", None)
        if loop is None or loop._token is None:
            loop = cls._per_thread.loop = cls()
        return loop

    def run(self, afn: Callable[..., Awaitable[Any]], *args: Any) -> Any:
        """``await afn(*args)`` in the guest run; its result, or its exception raised here."""
        if self._token is None:
            raise RuntimeError("the guest Trio run has ended")
        self._result = None
        self._job = (afn, args)
        get = self._callbacks.get
        while self._result is None:
            get()()
        result, self._result = self._result, None
        return result.unwrap()

    def close(self) -> None:
        """End the guest run (its task returns; the run ends on this thread)."""
        if self._token is None:
            return
        self._result = None
        self._job = _STOP
        while self._result is None:
            self._callbacks.get()()
        self._result = None
        if getattr(self._per_thread, "loop", None) is self:
            del self._per_thread.loop

    async def _serve(self) -> None:
        """The run's task: run each call :meth:`run` leaves in ``_job`` and keep its outcome."""
        import trio

        self._token = trio.lowlevel.current_trio_token()
        checkpoint, acapture = self._checkpoint, self._outcome.acapture
        while True:
            job = self._job
            if job is None:
                await checkpoint()
                continue
            self._job = None
            if job is _STOP:
                return
            self._result = await acapture(job[0], *job[1])


async def _stop() -> None:
    """Never called: the marker that tells :meth:`GuestLoop._serve` to return."""


#: ``GuestLoop._job`` value that ends the run
_STOP: tuple[Callable[..., Awaitable[Any]], tuple[Any, ...]] = (_stop, ())


@dataclass
class ParseWatch:
    """What one watched parser (:func:`watched_parser`) did: ``events`` it returned (with a
    ``ParseError``'s events), pieces ``fed`` (calls of ``feed``), whether it was ``closed``, the
    ``error`` it raised (a ``ParseError``), any other exception it raised (``failure``), and the most
    input it held back after a ``feed`` (``held``, characters)."""

    events: list[Event] = field(default_factory=list)
    fed: int = 0
    closed: bool = False
    error: ParseError | None = None
    failure: Exception | None = None
    held: int = 0


def watched_parser(
    base: type[FunctionTokenParser], pending: Callable[[FunctionTokenParser], str], made: list[Any]
) -> type[FunctionTokenParser]:
    """A subclass of ``base`` whose instances keep a :class:`ParseWatch` (``.watch``) and append
    themselves to ``made``; ``pending(parser)`` reads the held-back input (the property's source
    without coverage hooks when fuzzing). Parsing itself is ``base``'s, unchanged."""
    from host.shell.parser import ParseError

    class Watched(base):  # type: ignore[valid-type,misc]
        def __init__(self, strict: bool = True) -> None:
            super().__init__(strict)
            self.watch = ParseWatch()
            made.append(self)

        def feed(self, text: str) -> list[Event]:
            self.watch.fed += 1
            events = self._watched(super().feed, text)
            self.watch.held = max(self.watch.held, len(pending(self)))
            return events

        def close(self) -> list[Event]:
            self.watch.closed = True
            return self._watched(super().close)

        def _watched(self, step: Callable[..., list[Event]], *args: str) -> list[Event]:
            watch = self.watch
            try:
                events = step(*args)
            except ParseError as e:
                watch.error = e
                watch.events += e.events
                raise
            except Exception as e:
                watch.failure = e
                raise
            watch.events += events
            return events

    return Watched


def load(instrument: bool = False) -> Callable[[bytes], None]:
    """Import the shell (instrumented when ``instrument``) and return the one-input function."""
    if instrument:
        from host.tools.fuzz.harness import instrument_only

        with instrument_only(["host.shell", "host.speech"]):
            import host.shell.shell  # noqa: F401
    import atheris  # type: ignore[import-not-found,unused-ignore]

    from host.tools.fuzz.harness import without_hooks
    from host.tools.fuzz.validate import conforms
    from host.shell.mapper import MappingError, map_element
    from host.shell.parser import MAX_TOKEN, EmptyTag, EndTag, Event, FunctionTokenParser, ParseError, StartTag
    from host.shell.registry import Registry, UnknownFunction
    from host.shell.shell import Shell
    from host.shell.types import Module, params_of, shell_function
    from robots.interface import class_stubs, stub_info
    from robots.registry import load_robot

    robot = load_robot()  # the default robot's default vocabulary (the seeds are its tasks)
    vocabulary = robot.interface.vocabularies[robot.interface.default]

    calls: list[tuple[str, dict[str, Any]]] = []
    params: dict[str, dict[str, Any]] = {}

    def recorder(name: str) -> Callable[..., Any]:
        async def call(**kwargs: Any) -> None:
            calls.append((name, kwargs))

        return call

    @shell_function(speech=True)
    async def speak(text: str) -> None:
        """Say ``text``."""
        calls.append(("speak", {"text": text}))

    modules = [Module.from_functions("speak", speak, channel="speech")]
    for module_name, iface in vocabulary.items():
        stubs = class_stubs(iface)
        impl = SimpleNamespace(**{n: recorder(n) for n in stubs})
        channel = stub_info(next(iter(stubs.values()))).channel  # type: ignore[union-attr]
        view = type(iface.__name__, (), {"__doc__": iface.__doc__, **stubs})
        modules.append(Module.bind(module_name, view, impl, channel=channel))
        for n, f in stubs.items():
            params[n] = {p.name: p.annotation for p in params_of(f)}
    class FuzzRegistry(Registry):
        """The registry, with an unknown name's did-you-mean (``difflib``, a tenth of an input) worked
        out once per name: the answer depends on the name and the mounted functions only, and no
        mount changes here; found for real the first time a name appears (so per input alone)."""

        unknown: dict[str, list[str]] = {}

        def resolve(self, name: str):  # type: ignore[no-untyped-def]
            known = self.unknown.get(name)
            if known is not None:
                raise UnknownFunction(name, list(known))
            try:
                return super().resolve(name)
            except UnknownFunction as e:
                if len(self.unknown) >= MAX_REMEMBERED:
                    self.unknown.clear()
                self.unknown[name] = list(e.suggestions)
                raise

    registry = FuzzRegistry(modules)
    loop: GuestLoop | TrioLoop = GuestLoop.shared() if instrument else TrioLoop()
    # the Shell's stream parser, watched; its pending and a dead-parser probe run without coverage hooks
    plain = without_hooks(FunctionTokenParser) if instrument else FunctionTokenParser
    made: list[Any] = []
    pending = vars(plain)["pending"].fget  # the property's getter

    class WatchedShell(Shell):
        parser_class = watched_parser(FunctionTokenParser, pending, made)

    # (element name, attributes) already mapped and checked: map_element is a function of them and the
    # (fixed) registry; a new element is mapped and checked for real
    mapped_ok: set[tuple[str, tuple[tuple[str, str], ...]]] = set()

    def parsed(pieces: list[str], strict: bool) -> list[Event]:
        """The events of the Shell's parse of ``pieces``, its parser's invariants checked."""
        assert len(made) == 1, f"the Shell made {len(made)} watched stream parsers, not 1"
        p = made[0]
        w: ParseWatch = p.watch
        if w.error is None and w.failure is None:  # the run stopped reading early: the rest, here
            try:
                for piece in pieces[w.fed:]:
                    p.feed(piece)
                if not w.closed:
                    p.close()
            except Exception:  # kept in the watch, checked below
                pass
        if w.failure is not None:
            raise w.failure  # only ParseError may escape the parser
        assert w.held <= MAX_TOKEN + 16, f"parser holds {w.held} characters"
        if w.error is not None:
            assert strict, f"lenient parser raised {w.error}"
            try:
                plain.feed(p, "x")
            except ParseError:
                pass
            else:
                raise AssertionError("a dead strict parser accepted more input")
        return w.events

    def check_events(events: list[Event]) -> None:
        """Tags nest; every start or empty tag maps (or fails with MappingError) to conforming args."""
        stack: list[str] = []
        for ev in events:
            if isinstance(ev, StartTag):
                stack.append(ev.name)
            elif isinstance(ev, EndTag):
                assert stack and stack[-1] == ev.name, f"end-tag {ev.name} does not close {stack}"
                stack.pop()
            if isinstance(ev, (StartTag, EmptyTag)):
                key = (ev.name, tuple(ev.attrs.items()))
                if key in mapped_ok:
                    continue
                try:
                    mapped = map_element(registry, ev.name, dict(ev.attrs))
                except MappingError:
                    mapped = None
                if mapped is not None:
                    for k, v in mapped.args.items():
                        ann = mapped.spec.param(k)
                        assert ann is not None and conforms(v, ann.annotation), f"<{ev.name}> {k}={v!r} mapped"
                if len(mapped_ok) >= MAX_REMEMBERED:
                    mapped_ok.clear()
                mapped_ok.add(key)

    def one_input(data: bytes) -> None:
        fdp = atheris.FuzzedDataProvider(data)
        strict = not fdp.ConsumeBool()  # byte 0 even -> strict
        seed = fdp.ConsumeIntInRange(0, 2**32 - 1) if fdp.remaining_bytes() >= 4 else 0
        text = fdp.ConsumeBytes(fdp.remaining_bytes()).decode("utf-8", "replace")
        pieces = [b.decode("utf-8", "replace") for b in byte_chunks(text.encode(), seed, 64)]
        pieces = [p for p in pieces if p]
        calls.clear()
        made.clear()
        # the loop's MockClock: what anyio.current_time reads, without the backend and run lookups
        shell = WatchedShell(registry, strict=strict, clock=loop.clock.current_time)
        loop.run(shell.run_text, pieces)
        check_events(parsed(pieces, strict))
        for name, kwargs in calls:
            if name == "speak":
                assert isinstance(kwargs["text"], str)
                continue
            declared = params[name]
            assert set(kwargs) <= set(declared), f"{name} got undeclared {set(kwargs) - set(declared)}"
            for k, v in kwargs.items():
                assert conforms(v, declared[k]), f"{name}({k}={v!r}) reached the implementation"
            assert all(k in kwargs for k, a in declared.items() if _required(name, k)), f"{name} missing args"

    required: dict[tuple[str, str], bool] = {}
    for module_name, iface in vocabulary.items():
        for n, f in class_stubs(iface).items():
            for p in inspect.signature(f).parameters.values():
                required[(n, p.name)] = p.default is inspect.Parameter.empty and p.name != "self"

    def _required(name: str, param: str) -> bool:
        return required.get((name, param), False)

    return one_input


if __name__ == "__main__":
    from host.tools.fuzz.harness import run_atheris

    run_atheris(load, "host.tools.fuzz.shell")
