"""Link fault model: a fault spec, a seeded fault injector over wire units, a sequence-gap detector.

Pure (no I/O, no threads, no clocks: callers pass times in seconds), so the same model drives the
serial and the CAN transports of both ends and the tests. A *wire unit* is whatever one write puts
on the wire: a serial frame (``bytes``, COBS + delimiter) or a CAN frame
(:class:`protocol.can.frame.CanFrame`).

Spec syntax (``--faults``), comma-separated, each key at most once::

    drop=P          lose the unit                         P in [0, 1]
    corrupt=P       flip one random bit of its data       (serial: the CRC must catch it;
                                                            CAN: the controller's CRC would turn
                                                            it into a loss, the model lets it
                                                            through to test the layers above)
    dup=P           deliver it twice
    reorder=P       hold it back until after the next unit (or ``REORDER_HOLD_S``)
    truncate=P      cut its data short at a random length (serial: delimiter lost too)
    delay=MEAN[±J]  add MEAN ms (uniform ±J ms) latency; "+-" may replace "±";
                    MEAN + J <= MAX_DELAY_MS (250); jitter also reorders units
    cut=START+LEN   from START s after the first unit, for LEN s, nothing gets through

Example: ``drop=0.01,corrupt=0.01,dup=0.005,reorder=0.005``. Each direction gets its own injector
seeded from ``(seed, direction)``, so a run is reproducible and both directions are independent.
Faults are drawn in the order cut, drop, truncate, corrupt, dup, reorder, delay; one unit may get
several (e.g. corrupted and duplicated).
"""

from __future__ import annotations

import dataclasses
import difflib
import heapq
import itertools
import math
import random
from collections import Counter, deque
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

__all__ = ["MAX_DELAY_MS", "FaultInjector", "FaultSpec", "FaultSpecError", "GapDetector", "REORDER_HOLD_S"]

#: longest a reordered unit waits for a successor before it is released anyway (seconds)
REORDER_HOLD_S = 0.05
#: largest one-way delay (mean + jitter, ms) a spec may ask for: at 250 ms a realtime run still ends
#: ``done`` (the board HOLDs while the host's connect-time TIME_SYNC exchanges, one round trip each,
#: leave it without messages); at 900 ms the board latched a watchdog fault before the program began,
#: at 1 000 ms the link never came up (n = 1 each, quiet)
MAX_DELAY_MS = 250.0
#: a value each key takes, for the "needs a value" error
_EXAMPLES = {"delay": "delay=80±20 (ms)", "cut": "cut=3+1.5 (s)"}

_PROB_KEYS = ("drop", "corrupt", "dup", "reorder", "truncate")
_KEYS = (*_PROB_KEYS, "delay", "cut")

U = TypeVar("U")


class FaultSpecError(ValueError):
    """A ``--faults`` spec that cannot be parsed; the message names the item and the fix."""


@dataclass(frozen=True)
class FaultSpec:
    """Parsed fault spec; probabilities in [0, 1], delay and jitter in ms, cut in seconds."""

    drop: float = 0.0
    corrupt: float = 0.0
    dup: float = 0.0
    reorder: float = 0.0
    truncate: float = 0.0
    delay_ms: float = 0.0
    jitter_ms: float = 0.0
    cut: tuple[float, float] | None = None  # (start s, length s)

    @property
    def active(self) -> bool:
        """True when the spec injects anything at all."""
        return any(getattr(self, k) for k in _PROB_KEYS) or self.delay_ms > 0 or self.jitter_ms > 0 or self.cut is not None

    @classmethod
    def parse(cls, text: str) -> FaultSpec:
        """Parse ``drop=0.01,corrupt=0.01,...``; raises :class:`FaultSpecError` naming the bad item."""
        values: dict[str, Any] = {}
        text = text.strip()
        if not text or text.lower() == "none":
            return cls()
        for item in text.split(","):
            item = item.strip()
            if not item:
                raise FaultSpecError(f"empty item in fault spec {text!r} (two commas?)")
            key, sep, val = item.partition("=")
            key, val = key.strip().lower(), val.strip()
            if not sep or not val:
                raise FaultSpecError(f"fault {item!r} needs a value, e.g. {_EXAMPLES.get(key, 'drop=0.01')}")
            if key not in _KEYS:
                near = difflib.get_close_matches(key, _KEYS, n=1)
                hint = f"; did you mean {near[0]}?" if near else ""
                raise FaultSpecError(f"unknown fault {key!r} (known: {', '.join(_KEYS)}){hint}")
            if key in values or (key == "delay" and "delay_ms" in values):
                raise FaultSpecError(f"fault {key!r} given twice")
            if key in _PROB_KEYS:
                p = _number(key, val)
                if not 0.0 <= p <= 1.0:
                    raise FaultSpecError(f"{key}={val}: a probability must be in [0, 1]")
                values[key] = p
            elif key == "delay":
                mean, jitter = _split_pm(val)
                if jitter is not None and not jitter:
                    raise FaultSpecError(f"delay={val}: a jitter after '±' is missing, e.g. delay=80±20")
                values["delay_ms"], values["jitter_ms"] = _number("delay", mean), _number("delay jitter", jitter or "0")
                if values["delay_ms"] < 0 or values["jitter_ms"] < 0:
                    raise FaultSpecError(f"delay={val}: mean and jitter must be >= 0 ms")
                if values["jitter_ms"] > values["delay_ms"]:
                    raise FaultSpecError(f"delay={val}: jitter larger than the mean would make negative delays")
                if values["delay_ms"] + values["jitter_ms"] > MAX_DELAY_MS:
                    raise FaultSpecError(f"delay={val}: mean + jitter must be <= {MAX_DELAY_MS:g} ms (the link's "
                                         "handshake, clock sync and the board's 200 ms watchdog expect round trips "
                                         "well under a second)")
            else:
                start, plus, length = val.partition("+")
                if not plus:
                    raise FaultSpecError(f"cut={val}: expected START+LENGTH in seconds, e.g. cut=3+1.5")
                s, n = _number("cut start", start), _number("cut length", length)
                if s < 0 or n <= 0:
                    raise FaultSpecError(f"cut={val}: START must be >= 0 s and LENGTH > 0 s")
                values["cut"] = (s, n)
        return cls(**values)

    def __str__(self) -> str:
        parts = [f"{k}={getattr(self, k):g}" for k in _PROB_KEYS if getattr(self, k)]
        if self.delay_ms or self.jitter_ms:
            parts.append(f"delay={self.delay_ms:g}" + (f"±{self.jitter_ms:g}" if self.jitter_ms else ""))
        if self.cut is not None:
            parts.append(f"cut={self.cut[0]:g}+{self.cut[1]:g}")
        return ",".join(parts) or "none"

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (for ``summary.json``)."""
        d = dataclasses.asdict(self)
        d["spec"] = str(self)
        return d


def _number(what: str, text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise FaultSpecError(f"{what}: {text!r} is not a number") from None
    if not math.isfinite(v):
        raise FaultSpecError(f"{what}: {text!r} is not a finite number")
    return v


def _split_pm(text: str) -> tuple[str, str | None]:
    """``MEAN±JITTER`` -> (mean, jitter); (text, None) without a ``±`` / ``+-``."""
    for sep in ("±", "+-"):
        if sep in text:
            a, _, b = text.partition(sep)
            return a.strip(), b.strip()
    return text, None


def _data_of(unit: Any) -> bytes:
    return bytes(unit) if isinstance(unit, (bytes, bytearray)) else bytes(unit.data)


def _with_data(unit: U, data: bytes) -> U:
    if isinstance(unit, (bytes, bytearray)):
        return data  # type: ignore[return-value]
    return dataclasses.replace(unit, data=data)  # type: ignore[type-var]


class FaultInjector(Generic[U]):
    """Seeded faults on one direction of a link.

    ``push(unit, now_s)`` hands a unit to the wire at time ``now_s`` (seconds, any monotonic
    origin); ``pop_due(now_s)`` returns the units that reach the far end by ``now_s``, in arrival
    order; ``next_due()`` is the earliest pending arrival time (None when nothing is in flight).
    Units are ``bytes`` or any frozen dataclass with a ``data: bytes`` field (a CAN frame).
    Counters: ``units_in``, ``units_out``, ``injected`` (per fault kind).
    """

    def __init__(self, spec: FaultSpec, seed: int = 0, direction: str = "tx") -> None:
        self.spec = spec
        self.direction = direction
        self.rng = random.Random(f"ghostshell-faults:{seed}:{direction}")
        self.units_in = 0
        self.units_out = 0
        self.injected: Counter[str] = Counter()
        self._t0: float | None = None
        self._heap: list[tuple[float, int, U]] = []
        self._order = itertools.count()
        self._held: tuple[float, U] | None = None  # a reordered unit waiting for its successor

    def push(self, unit: U, now_s: float) -> None:
        """Send ``unit`` at ``now_s``; it arrives (possibly changed, twice, late or never) via :meth:`pop_due`."""
        spec, rng = self.spec, self.rng
        self.units_in += 1
        if self._t0 is None:
            self._t0 = now_s
        if spec.cut is not None:
            start = self._t0 + spec.cut[0]
            if start <= now_s < start + spec.cut[1]:
                self.injected["cut"] += 1
                return
        if spec.drop and rng.random() < spec.drop:
            self.injected["drop"] += 1
            return
        data = _data_of(unit)
        if spec.truncate and data and rng.random() < spec.truncate:
            self.injected["truncate"] += 1
            unit = _with_data(unit, data[: rng.randrange(len(data))])
            data = _data_of(unit)
        if spec.corrupt and data and rng.random() < spec.corrupt:
            self.injected["corrupt"] += 1
            bit = rng.randrange(len(data) * 8)
            flipped = bytearray(data)
            flipped[bit // 8] ^= 1 << (bit % 8)
            unit = _with_data(unit, bytes(flipped))
        copies = 1
        if spec.dup and rng.random() < spec.dup:
            self.injected["dup"] += 1
            copies = 2
        t = now_s + self._delay_s()
        if self._held is not None:  # the held unit goes right after this one
            held_t, held = self._held
            self._held = None
            self._schedule(max(t, held_t), unit, copies)
            self._schedule(max(t, held_t), held, 1)
            return
        if spec.reorder and rng.random() < spec.reorder:
            self.injected["reorder"] += 1
            self._held = (t, unit)
            if copies == 2:
                self._schedule(t, unit, 1)
            return
        self._schedule(t, unit, copies)

    def _delay_s(self) -> float:
        s = self.spec
        if not s.delay_ms and not s.jitter_ms:
            return 0.0
        return max(0.0, s.delay_ms + self.rng.uniform(-s.jitter_ms, s.jitter_ms)) / 1000.0

    def _schedule(self, t: float, unit: U, copies: int) -> None:
        for _ in range(copies):
            heapq.heappush(self._heap, (t, next(self._order), unit))

    def pop_due(self, now_s: float) -> list[U]:
        """Units arriving by ``now_s``, in arrival order (a held reordered unit is released after
        :data:`REORDER_HOLD_S` without a successor)."""
        if self._held is not None and now_s >= self._held[0] + REORDER_HOLD_S:
            t, held = self._held
            self._held = None
            self._schedule(t + REORDER_HOLD_S, held, 1)
        out: list[U] = []
        while self._heap and self._heap[0][0] <= now_s:
            out.append(heapq.heappop(self._heap)[2])
        self.units_out += len(out)
        return out

    def next_due(self) -> float | None:
        """Earliest time a pending unit arrives, or None."""
        times = [self._heap[0][0]] if self._heap else []
        if self._held is not None:
            times.append(self._held[0] + REORDER_HOLD_S)
        return min(times) if times else None

    @property
    def in_flight(self) -> int:
        return len(self._heap) + (self._held is not None)

    def summary(self) -> dict[str, Any]:
        """What was injected on this direction (for ``summary.json``)."""
        return {"direction": self.direction, "units_in": self.units_in, "units_out": self.units_out,
                "injected": {k: self.injected.get(k, 0) for k in ("cut", *_PROB_KEYS)}}


class GapDetector:
    """Counts lost, duplicated and out-of-order 16-bit sequence numbers of one direction.

    ``feed(seq)`` returns how many sequence numbers were skipped before ``seq`` (0 when it is the
    next one). A sequence number behind the highest seen (within half the 16-bit range) is counted
    as ``late`` (reordered or duplicated) and, if it filled a gap, taken back off ``lost``. Memory
    is bounded: only the last ``window`` missing numbers are remembered.

    ``restart_from(seq)`` starts counting afresh at a point in the sender's numbering (a handshake
    reply): the last :data:`RECENT` numbers fed are replayed, so the units that overtook that point
    (a fixed CAN frame passing a slow ISO-TP transfer) still count as received.
    """

    #: numbers fed that :meth:`restart_from` can replay (units that may overtake the restart point)
    RECENT = 64

    def __init__(self, window: int = 1024, first: int | None = None) -> None:
        self.window = window
        self._recent: deque[int] = deque(maxlen=self.RECENT)
        #: with ``first`` (the sequence a sender starts at, e.g. 0) a loss of the very first units counts too
        self.highest: int | None = None if first is None else (first - 1) & 0xFFFF
        self.lost = 0
        self.late = 0
        self.received = 0
        self._missing: dict[int, None] = {}

    def restart_from(self, seq: int) -> None:
        """Count from ``seq`` on, as a fresh detector seeded with ``seq`` would, and replay (in arrival
        order) the numbers among the last :data:`RECENT` fed that lie after ``seq`` (within ``RECENT``):
        they arrived before the restart point was known. Numbers before ``seq`` then arrive as late,
        never as lost; a sender that restarted its numbering (a new board) leaves nothing behind."""
        seq &= 0xFFFF
        recent = [s for s in self._recent if 0 < (s - seq) & 0xFFFF <= self.RECENT]
        self.highest, self.lost, self.late, self.received = seq, 0, 0, 1
        self._missing.clear()
        self._recent.clear()
        self._recent.append(seq)
        for s in recent:
            self.feed(s)

    def new_sender(self) -> None:
        """Forget the numbering (a new sender starts its own at the next number fed) and keep the
        totals: a board's ``seq_gaps`` counts over its whole life, as its other link counters do."""
        self.highest = None
        self._missing.clear()
        self._recent.clear()

    def feed(self, seq: int) -> int:
        seq &= 0xFFFF
        self.received += 1
        self._recent.append(seq)
        if self.highest is None:
            self.highest = seq
            return 0
        ahead = (seq - self.highest) & 0xFFFF
        if ahead == 0 or ahead >= 0x8000:  # not newer: a duplicate or a late (reordered) unit
            self.late += 1
            if seq in self._missing:
                del self._missing[seq]
                self.lost -= 1
            return 0
        gap = ahead - 1
        # a number missing a lap (65 536 numbers) ago and not yet evicted: that unit stays lost, and its
        # entry goes, so ``_missing`` stays in arrival order (``settled_lost`` walks it from the end)
        self._missing.pop(seq, None)
        # the last ``window`` skipped numbers, in order: (highest + 1 + k) & 0xFFFF for k in range(lo, gap),
        # as at most two runs of consecutive numbers (before and after the wrap) added in C, not per number
        lo = max(0, gap - self.window)
        if gap - lo >= self.window:  # the new run alone fills the window: every older entry would be evicted
            self._missing.clear()
        first = (self.highest + 1 + lo) & 0xFFFF
        end = first + gap - lo
        self._missing.update(dict.fromkeys(range(first, min(end, 0x10000))))
        if end > 0x10000:
            self._missing.update(dict.fromkeys(range(end - 0x10000)))
        excess = len(self._missing) - self.window
        if excess > 0:  # the oldest, in one pass (``next(iter(d))`` per key rescans the deleted slots: quadratic)
            for old in list(itertools.islice(self._missing, excess)):
                del self._missing[old]
        self.lost += gap
        self.highest = seq
        return gap

    def settled_lost(self, depth: int) -> int:
        """``lost`` without the missing numbers within ``depth`` of the highest: those may still be in
        flight on a link that reorders (over CAN an ISO-TP transfer is overtaken by the fixed frames sent
        during it), so a number counts as lost once ``depth`` later ones have arrived. O(``depth``)."""
        pending = 0
        if self.highest is not None:
            for m in reversed(self._missing):
                if (self.highest - m) & 0xFFFF > depth:
                    break
                pending += 1
        return self.lost - pending

