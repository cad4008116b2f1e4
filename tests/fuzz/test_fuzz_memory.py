"""The board fuzz target keeps memory bounded: many fuzzed inputs, the traced Python heap stays put.

Inputs are the checked-in seeds, cut and bit-flipped by a seeded ``random.Random`` (deterministic).
After a warm-up (caches, the replaced board's objects, bounded histories filling) the traced heap
(``tracemalloc``, after ``gc.collect()``) may grow by at most ``BOUND`` over ``N`` more inputs:
about 200 bytes per input, while one leaked frame, reply or event per tick or message would add
kilobytes per input. Two shapes: a fresh board per input (what libFuzzer runs) and one long-lived
board fed every input (a board process serving a link for hours: whatever it keeps must stay
bounded). The RSS creep seen under libFuzzer came from native memory tracemalloc does not see (a
new 14 MB MuJoCo arena per input fragmenting the C heap); that fix is tested in
tests/firmware/test_board_reuse.py and measured in README ("Fuzzing").
"""

from __future__ import annotations

import gc
import random
import tracemalloc
from pathlib import Path

import pytest

from firmware_sim.fuzz import load

SEEDS = Path(__file__).resolve().parent / "board" / "corpus"
WARM_UP, TRACED_WARM_UP, N = 5, 5, 30
BOUND = 8 * 1024  # bytes of traced heap growth allowed over N inputs after warm-up


def _inputs(count: int, seed: int = 0) -> list[bytes]:
    seeds = [p.read_bytes() for p in sorted(SEEDS.glob("*")) if p.is_file()]
    assert seeds, "tests/fuzz/board/corpus is empty"
    rng = random.Random(seed)
    out = []
    for i in range(count):
        s = bytearray(seeds[i % len(seeds)][: rng.randrange(300, 600)])
        for _ in range(rng.randrange(1, 16)):
            s[rng.randrange(len(s))] = rng.randrange(256)
        out.append(bytes(s))
    return out


def _growth(persistent: bool) -> int:
    """Traced heap growth (bytes) over ``N`` inputs after the warm-up."""
    one_input = load(False, persistent=persistent)
    inputs = _inputs(WARM_UP + TRACED_WARM_UP + N)
    for data in inputs[:WARM_UP]:
        one_input(data)
    tracemalloc.start(1)
    try:
        for data in inputs[WARM_UP : WARM_UP + TRACED_WARM_UP]:  # the live board's objects become traced
            one_input(data)
        gc.collect()
        before = tracemalloc.get_traced_memory()[0]
        for data in inputs[WARM_UP + TRACED_WARM_UP :]:
            one_input(data)
        gc.collect()
        return tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()


@pytest.mark.parametrize("persistent", [False, True], ids=["fresh-board-per-input", "one-long-lived-board"])
def test_board_fuzz_target_memory_stays_bounded(persistent: bool) -> None:
    grown = _growth(persistent)
    assert grown < BOUND, f"traced heap grew {grown} B over {N} inputs after warm-up (bound {BOUND} B)"
