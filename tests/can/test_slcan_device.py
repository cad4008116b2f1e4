"""The board's SLCAN (Lawicel) adapter side, and python-can's slcan formatting against it."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.can.slcan import MAX_LINE, SlcanDevice, format_frame
from protocol.can import CanFrame


def test_commands_and_frames() -> None:
    d = SlcanDevice()
    ev, reply = d.feed(b"C\rS8\rV\rN\rF\r\rO\r")
    assert reply == b"\r\rV1013\rNGHST\rF00\r\r\r" and d.is_open and d.bitrate_code == "S8"
    ev, reply = d.feed(b"t0818" + b"0011223344556677" + b"\rd0819" + b"00" * 12 + b"\rr0818\rT000000811AA\r")
    frames = [e.frame for e in ev]
    assert frames[0] == CanFrame(0x081, bytes.fromhex("0011223344556677"))
    assert frames[1] == CanFrame(0x081, bytes(12), is_fd=True)
    assert frames[2] is not None and frames[2].is_remote and frames[2].data == b""
    assert frames[3] is not None and frames[3].is_extended_id and frames[3].data == b"\xaa"
    assert reply == b"z\rz\rz\rZ\r"


def test_refusals_answer_bell_and_count() -> None:
    d = SlcanDevice()
    _, reply = d.feed(b"t0811AA\r")  # channel closed
    assert reply == b"\a" and d.errors == 1
    d.feed(b"O\r")
    for bad in (b"t08", b"t0819" + b"00" * 9, b"t0812AA", b"tXYZ1AA", b"t8001AA", b"Q", b"S8", "é".encode()):
        _, reply = d.feed(bad + b"\r")
        assert reply == b"\a", bad
    _, reply = d.feed(b"t" + b"1" * (MAX_LINE + 10) + b"\rt0810\r")
    assert reply == b"\az\r"  # an overlong line is dropped, the next one is fine


def test_format_matches_python_can_parser() -> None:
    # python-can's slcan parses our lines: the same code path as a real adapter's output
    for f in (CanFrame(0x481, bytes(range(8))), CanFrame(0x081, bytes(32), is_fd=True), CanFrame(0x000, b"")):
        line = format_frame(f).decode()
        assert line.endswith("\r")
        d = SlcanDevice()
        d.feed(b"O\r")
        ev, _ = d.feed(line.encode())
        assert ev[0].frame == f


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(max_size=200), max_size=20))
def test_never_raises_and_stays_bounded(chunks: list[bytes]) -> None:
    d = SlcanDevice()
    d.feed(b"O\r")
    for c in chunks:
        d.feed(c)
        assert len(d._line) <= MAX_LINE
