"""Fuzz target ``serial-decoder``: arbitrary bytes, in arbitrary chunks, into the serial frame decoder.

Input layout (atheris ``FuzzedDataProvider``): 4 bytes seed the chunking, the rest is the byte stream,
so a seed file is ``4 bytes + wire bytes`` (e.g. a frame log's raw frames, see ``host.tools.fuzz.seeds``).

Invariants (an ``AssertionError`` names the one that broke):

* the decoder never raises and never holds more than ``max_frame_bytes`` undelimited bytes;
* chunking is invisible: the chunked feed yields the same frames and error kinds as one feed;
* every frame it yields re-encodes (``encode_frame(msg, seq)``) to exactly its own wire bytes;
* resync: after any input, ``0x00`` + a valid frame decodes to that frame;
* counters agree with the events (``frames_ok``, ``errors``).

Throughput: the block between two delimiters is decoded by ``protocol.framing._decode_block``, a
function of the block's bytes (and the schema) alone; most blocks of an input are the seeds' frames
again (a mutation inside a frame breaks its CRC), and decoding them (the codec, instrumented) was
most of an input's time, twice (chunked and whole). The process therefore remembers each distinct
block that passed the CRC (a frame, or an intact frame's VERSION/LENGTH/UNKNOWN_TYPE/PAYLOAD error)
with its decode result, up to :data:`MAX_REMEMBERED` (then it starts again), and each distinct
frame shown to re-encode to its own bytes; every block of the input running is remembered for that
input (the whole feed meets the chunked feed's blocks again, garbage included). Every invariant is
still checked on every input, and a new block is decoded (and a new frame re-encoded) for real the
first time it appears, so a failure reproduces from its input alone. ``FrameDecoder``'s own work
(delimiters, buffering, OVERSIZE, counters) runs in full for both feeds; the whole feed runs the
same ``FrameDecoder`` source without coverage hooks (:func:`host.tools.fuzz.harness.without_hooks`; the
chunked feed's coverage is the input's). Measured exec/s (command, n, load):
docs/guides/fuzzing.md#throughput.
"""

from __future__ import annotations

import random
from collections.abc import Callable

__all__ = ["load", "chunks"]

#: distinct intact blocks remembered (decoded; frames re-encode checked), each; a block is at most 512 B on the
#: wire, so a few MB at most
MAX_REMEMBERED = 4096


def chunks(data: bytes, seed: int, max_chunk: int = 300) -> list[bytes]:
    """Split ``data`` into pieces of pseudo-random length 0..``max_chunk`` (deterministic in ``seed``)."""
    # ``random.Random(seed).randint(0, max_chunk)`` per piece, inlined (the same numbers: randint draws
    # ``getrandbits(bit_length)`` until below the bound); randint's three Python calls per piece were a
    # few per cent of an input
    bits = random.Random(seed).getrandbits
    bound = max_chunk + 1
    k = bound.bit_length()
    out: list[bytes] = []
    i = 0
    n_data = len(data)
    while i < n_data:
        n = bits(k)
        while n >= bound:
            n = bits(k)
        out.append(data[i : i + n])
        i += n
    return out


def load(instrument: bool = False) -> Callable[[bytes], None]:
    """Import the decoder (instrumented for coverage when ``instrument``) and return the one-input function."""
    if instrument:
        from host.tools.fuzz.harness import instrument_only

        with instrument_only(["protocol.framing", "protocol.codec"]):  # not protocol.messages (declarations)
            from protocol import codec, framing  # noqa: F401
    from host.tools.fuzz.harness import without_hooks
    import atheris  # type: ignore[import-not-found,unused-ignore]

    from protocol import framing
    from protocol.codec import WireSchema
    from protocol.framing import DecodeError, DecodeErrorKind, Frame, FrameDecoder, encode_frame
    from protocol.messages import Heartbeat

    decode_block = framing._decode_block
    # the whole feed, compared with the chunked one, runs the same FrameDecoder source without coverage
    # hooks (the chunked feed's coverage is the input's); uninstrumented, it is the class itself
    WholeDecoder = without_hooks(FrameDecoder) if instrument else FrameDecoder
    decoded: dict[tuple[bytes, WireSchema], Frame | DecodeError] = {}
    # blocks failing COBS or the CRC are new garbage on every input: remembered for the input only
    NOT_REMEMBERED = frozenset((DecodeErrorKind.COBS, DecodeErrorKind.CRC))
    reencoded: set[bytes] = set()  # wire bytes of frames shown to re-encode to themselves
    probe_msg = Heartbeat(123_456)
    probe = encode_frame(probe_msg, 4242)

    this_input: dict[tuple[bytes, WireSchema], Frame | DecodeError] = {}  # every block of the input running

    def remembered(block: bytes, raw: bytes, schema: WireSchema = framing.WIRE_SCHEMA_16) -> Frame | DecodeError:
        """``_decode_block`` once per distinct valid frame, and once per distinct block of one input
        (``raw`` is always ``block + 0x00``)."""
        key = (block, schema)
        known = this_input.get(key) or decoded.get(key)
        if known is not None:
            return known
        item = decode_block(block, raw, schema)
        this_input[key] = item  # the whole feed decodes the chunked feed's blocks again: errors too
        if isinstance(item, Frame) or item.kind not in NOT_REMEMBERED:
            if len(decoded) >= MAX_REMEMBERED:
                decoded.clear()
            decoded[key] = item
        return item

    def one_input(data: bytes) -> None:
        framing._decode_block = remembered  # only while the input runs: nothing else in the process sees it
        this_input.clear()
        try:
            check(data)
        finally:
            framing._decode_block = decode_block

    def check(data: bytes) -> None:
        fdp = atheris.FuzzedDataProvider(data)
        seed = fdp.ConsumeIntInRange(0, 2**32 - 1)
        stream = fdp.ConsumeBytes(fdp.remaining_bytes())

        dec = FrameDecoder()
        events: list[Frame | DecodeError] = []
        for piece in chunks(stream, seed):
            events += dec.feed(piece)
            assert dec.pending <= dec.max_frame_bytes, f"decoder holds {dec.pending} bytes"
        whole = WholeDecoder().feed(stream)
        key = [(type(e).__name__, e.raw if isinstance(e, Frame) else e.kind) for e in events]
        key_whole = [(type(e).__name__, e.raw if isinstance(e, Frame) else e.kind) for e in whole]
        assert key == key_whole, f"chunking changed the result: {key} vs {key_whole}"
        n_frames = 0
        for e in events:
            if isinstance(e, Frame):
                n_frames += 1
                if e.raw in reencoded:
                    continue
                again = encode_frame(e.msg, e.seq)
                assert again == e.raw, f"{e.msg_type.name} seq {e.seq} re-encodes to {again.hex()}, got {e.raw.hex()}"
                if len(reencoded) >= MAX_REMEMBERED:
                    reencoded.clear()
                reencoded.add(e.raw)
        assert dec.frames_ok == n_frames
        assert dec.error_count == len(events) - n_frames
        tail = dec.feed(b"\x00" + probe)
        assert tail and isinstance(tail[-1], Frame) and tail[-1].msg == probe_msg and tail[-1].seq == 4242, (
            f"no resync at the next delimiter: {tail}"
        )

    return one_input


if __name__ == "__main__":
    from host.tools.fuzz.harness import run_atheris

    run_atheris(load, "host.tools.fuzz.serial_decoder")
