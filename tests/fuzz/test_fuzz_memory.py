"""The board fuzz target keeps memory bounded: the same fuzzed inputs twice, the traced heap stays put.

Inputs are the checked-in seeds, cut and bit-flipped by a seeded ``random.Random`` (deterministic),
after a warm-up input that fills the board's bounded histories (screen and speaker, 256 entries
each) with the largest entries the protocol allows, so later entries can only replace them. The
inputs run twice; after each input the traced heap (``tracemalloc``, after ``gc.collect()``) is
sampled, and the median difference between the second pass and the first, input by input, must
stay under ``BOUND``: a leak of L bytes per input adds about ``L * N`` (allocator free lists make
a few hundred bytes of noise). Two shapes: a fresh board per input, as libFuzzer runs it (8
inputs: catches a board kept alive per input, ~13 KB, or a leak over ~200 B per input), and one
long-lived board fed every input, as a board process serves a link for hours (16 inputs: catches
~70 B per input, one small object). Both run a warm-up pass of the same inputs first, so growth
that happens once in the process (not per input) falls before the measured passes.

The RSS creep seen under libFuzzer came from native memory tracemalloc does not see (a new 14 MB
MuJoCo arena per input fragmenting the C heap): the last test checks that the target compiles the
model and allocates ``MjData`` once, tests/firmware/test_board_reuse.py that a reused board runs
bit-for-bit as a new one; docs/guides/fuzzing.md has the RSS numbers.
"""

from __future__ import annotations

import gc
import random
import statistics
import sys
import struct
import tracemalloc
import types
from array import array
from pathlib import Path

import pytest

from firmware_sim.fuzz import load
from protocol.codec import MAX_NAME_BYTES, MAX_SPEECH_TEXT_BYTES, encode_payload, msg_type_of
from protocol.messages import Message, ScreenCommand, ScreenTarget, SoundKind, SpeakerAction, SpeakerCommand

SEEDS = Path(__file__).resolve().parent / "board" / "corpus"
N = {False: 8, True: 16}  # inputs per pass (a fresh board runs ~300 ticks per input)
BOUND = 1024  # bytes: median growth of the traced heap from the first pass to the second
FAT = "\N{GRINNING FACE}"  # 4 UTF-8 bytes, 4 bytes per character in a Python str: the largest str per wire byte


def _raw_op(msg: Message, seq: int) -> bytes:
    """Fuzz op 0 (RAW): type u8, seq u16, len u8, payload."""
    payload = encode_payload(msg)
    return struct.pack("<BBHB", 0, msg_type_of(msg), seq, len(payload)) + payload


def _fill_histories() -> bytes:
    """A fuzz input of 300 SCREEN and 300 SPEAKER commands with the longest names and text."""
    name, text = FAT * (MAX_NAME_BYTES // 4), FAT * (MAX_SPEECH_TEXT_BYTES // 4)
    out = bytearray()
    for i in range(300):
        t = 2**32 - 300 + i
        out += _raw_op(ScreenCommand(ScreenTarget(i % 3), name, t, 65535), i)
        out += _raw_op(SpeakerCommand(SpeakerAction.PLAY, SoundKind.SPEECH, t, 65535, 100, name, text), i)
    return bytes(out)


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


def _growth_per_pass(persistent: bool) -> tuple[int, list[int]]:
    """Run the inputs twice; per input, traced heap after the second pass minus after the first.

    Returns (the median of those differences in bytes, all of them). After the same input the live
    objects are the same (exactly so with a fresh board per input), so what differs is what the
    first pass left behind: a leak of L bytes per input shows as about ``L * len(inputs)``.
    """
    tracemalloc.start(1)  # before anything: a traced object replacing an untraced one would count as growth
    try:
        one_input = load(False, persistent=persistent)
        one_input(_fill_histories())
        inputs = _inputs(N[persistent])
        # a warm-up pass: the long-lived board's state settles (held frames, schedules), and one-time
        # growth anywhere in the process (a dict or cache of the interpreter resized once) happens
        # before the measured passes. Without it, CI once saw a fresh board per input "grow" 1 356 B:
        # per input [4048, 1880, 872, 1840, 1856, -528, -504, -488], a single ~2.3 KB allocation made
        # during the first measured pass at its sixth input, not a per-input leak (that shows in every
        # input's difference)
        for data in inputs:
            one_input(data)
        samples = array("q", bytes(8 * 2 * len(inputs)))  # preallocated C longs: sampling allocates nothing
        for i, data in enumerate(inputs + inputs):
            one_input(data)
            gc.collect()
            samples[i] = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    k = len(inputs)
    diffs = [samples[k + i] - samples[i] for i in range(k)]
    return int(statistics.median(diffs)), diffs


@pytest.mark.parametrize("persistent", [False, True], ids=["fresh-board-per-input", "one-long-lived-board"])
def test_board_fuzz_target_memory_stays_bounded(persistent: bool) -> None:
    grown, diffs = _growth_per_pass(persistent)
    assert grown < BOUND, (
        f"the traced heap grew {grown} B (median) over a second pass of the same {len(diffs)} inputs "
        f"(bound {BOUND} B); per input: {diffs}"
    )


def test_board_fuzz_target_compiles_the_model_and_allocates_mjdata_once() -> None:
    """Every input gets a fresh board, but on the process's one model and ``MjData`` (``Board(reuse=)``):
    a new 14 MB MuJoCo arena per input fragmented the C heap (RSS 88 -> 98 MB over a 60 s run)."""
    from robots.model import RobotModel as CocoModel, load_model  # the board compiles through robots.model

    watched = {load_model.__code__: "load_model", CocoModel.new_data.__code__: "new_data"}
    calls = {name: 0 for name in watched.values()}

    def profile(frame: types.FrameType, event: str, arg: object) -> None:
        if event == "call" and frame.f_code in watched:
            calls[watched[frame.f_code]] += 1

    one_input = load(False)
    inputs = _inputs(4, seed=2)
    sys.setprofile(profile)  # observes Python calls only; nothing is replaced
    try:
        for data in inputs:
            one_input(data)
    finally:
        sys.setprofile(None)
    assert calls == {"load_model": 1, "new_data": 1}
