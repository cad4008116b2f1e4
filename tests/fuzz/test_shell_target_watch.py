"""The shell target checks its parser invariants on the Shell's own parse (one parse per input, not two).

Each check the separate direct parse made still fails its input: a planted fault in the parser is
caught through the Shell's watched stream parser (:func:`host.tools.fuzz.shell.watched_parser`), also when
the Shell stops reading early (the target feeds the rest itself), and the guest loop runs each call
at its first tick.
"""

from __future__ import annotations

import threading
from typing import Any

import pytest

pytest.importorskip("atheris", reason="the fuzz extra is not installed (pip install -e '.[fuzz]')")

from host.shell.parser import MAX_TOKEN, EndTag, FunctionTokenParser, ParseError  # noqa: E402

CALL = b'\x00<rotate angle="-90"/>\0\0\0\0'  # strict; one call that reaches the implementation
LENIENT = b'\x01a <3 b <rotate angle="-90"/>\0\0\0\0'


def raising(exc: Exception) -> Any:
    """A method that raises ``exc``."""

    def method(self: object, *args: object) -> Any:
        raise exc

    return method


def test_the_watched_parser_is_the_shells_stream_parser(monkeypatch: pytest.MonkeyPatch) -> None:
    from host.tools.fuzz.shell import load

    made: list[tuple[type, bool]] = []
    real = FunctionTokenParser.__init__

    def init(self: FunctionTokenParser, strict: bool = True) -> None:
        made.append((type(self), strict))
        real(self, strict)

    monkeypatch.setattr(FunctionTokenParser, "__init__", init)
    one_input = load(False)
    one_input(CALL)
    one_input(LENIENT)
    assert [strict for _, strict in made] == [True, False]  # one parse per input, the Shell's
    assert all(cls.__name__ == "Watched" for cls, _ in made)


def test_a_parser_exception_the_shell_would_swallow_is_raised(monkeypatch: pytest.MonkeyPatch) -> None:
    from host.tools.fuzz.shell import load

    one_input = load(False)
    one_input(CALL)
    real = FunctionTokenParser._scan

    def scan(self: FunctionTokenParser) -> None:
        if "rotate" in self._buf:
            raise KeyError("planted")
        real(self)

    monkeypatch.setattr(FunctionTokenParser, "_scan", scan)
    with pytest.raises(KeyError, match="planted"):  # the Shell reported it as "the output stream failed"
        one_input(CALL)


def test_a_lenient_parse_error_fails_the_input(monkeypatch: pytest.MonkeyPatch) -> None:
    from host.tools.fuzz.shell import load

    one_input = load(False)
    one_input(LENIENT)
    monkeypatch.setattr(FunctionTokenParser, "close", raising(ParseError("planted")))
    with pytest.raises(AssertionError, match="lenient parser raised"):
        one_input(LENIENT)
    with pytest.raises(AssertionError, match="dead strict parser"):  # strict: raising is fine, but close()
        one_input(CALL)  # here left the parser alive, so it accepts more input


def test_a_dead_strict_parser_must_stay_dead(monkeypatch: pytest.MonkeyPatch) -> None:
    from host.tools.fuzz.shell import load

    one_input = load(False)
    broken = b"\x00<rotate></other>\0\0\0\0"
    one_input(broken)  # a strict parse error: the parser stays dead
    monkeypatch.setattr(FunctionTokenParser, "_check_alive", lambda self: None)
    with pytest.raises(AssertionError, match="dead strict parser accepted more input"):
        one_input(broken)


def test_held_back_input_is_bounded(monkeypatch: pytest.MonkeyPatch) -> None:
    from host.tools.fuzz.shell import load

    monkeypatch.setattr(FunctionTokenParser, "pending", property(lambda self: "x" * (MAX_TOKEN + 17)))
    with pytest.raises(AssertionError, match=f"parser holds {MAX_TOKEN + 17} characters"):
        load(False)(CALL)


def test_tags_must_nest(monkeypatch: pytest.MonkeyPatch) -> None:
    from host.tools.fuzz.shell import load

    one_input = load(False)
    real = FunctionTokenParser.feed
    monkeypatch.setattr(FunctionTokenParser, "feed", lambda self, text: [*real(self, text), EndTag("stray")])
    with pytest.raises(AssertionError, match="end-tag stray does not close"):
        one_input(CALL)


def test_the_rest_is_parsed_and_checked_when_the_shell_stops_reading(monkeypatch: pytest.MonkeyPatch) -> None:
    """A scheduler failure aborts the run after the first piece's events; the parser fault is at
    ``close()``, which the Shell never reaches: the target finishes the parse and finds it."""
    import host.shell.scheduler as scheduler
    from host.tools.fuzz.shell import load

    one_input = load(False)
    closed: list[bool] = []
    real_close = FunctionTokenParser.close

    def close(self: FunctionTokenParser) -> Any:
        closed.append(True)
        return real_close(self)

    monkeypatch.setattr(scheduler.ProgramRun, "_event", raising(RuntimeError("scheduler fault")))
    monkeypatch.setattr(FunctionTokenParser, "close", close)
    one_input(CALL)  # the Shell aborted ("the output stream failed"); the target closed the parse
    assert closed == [True]
    monkeypatch.setattr(FunctionTokenParser, "close", raising(IndexError("at close")))
    with pytest.raises(IndexError, match="at close"):
        one_input(CALL)
    monkeypatch.setattr(FunctionTokenParser, "close", real_close)
    real_feed = FunctionTokenParser.feed

    def feed(self: FunctionTokenParser, text: str) -> Any:
        if "Z" in text:
            raise KeyError("in a later piece")
        return real_feed(self, text)

    monkeypatch.setattr(FunctionTokenParser, "feed", feed)
    long = b'\x00<rotate angle="-90"/>' + b"x" * 200 + b"Z\1\2\3\4"  # 4+ pieces of at most 64 bytes
    with pytest.raises(KeyError, match="in a later piece"):
        one_input(long)


def test_guest_loop_runs_a_call_at_its_first_tick() -> None:
    """No hand-over through Trio's wake-up socket and no task per call: one callback (one tick) runs
    a call that does not wait; the loop still serves call after call and ends when closed."""
    from host.tools.fuzz.shell import GuestLoop

    seen: dict[str, object] = {}

    def body() -> None:
        loop = GuestLoop.shared()

        async def answer(x: int) -> int:
            return x + 1

        loop.run(answer, 0)
        queue, ticks = loop._callbacks, [0]

        class Counting:
            def get(self) -> Any:
                ticks[0] += 1
                return queue.get()

        loop._callbacks = Counting()  # type: ignore[assignment]
        seen["answers"] = [loop.run(answer, i) for i in range(5)]
        seen["ticks"] = ticks[0]
        loop._callbacks = queue
        loop.close()
        seen["closed"] = loop._token is None

    t = threading.Thread(target=body)
    t.start()
    t.join(60)
    assert seen == {"answers": [1, 2, 3, 4, 5], "ticks": 5, "closed": True}
