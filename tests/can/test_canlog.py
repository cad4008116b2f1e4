"""Reading CAN captures: python-can formats, every frame through the DBC, messages reassembled."""

from __future__ import annotations

from pathlib import Path

import can
import pytest

from host.commands.canlog_decode import decode_can_file
from host.link.canlog import candump_cut_line, candump_problem, iter_can_log, read_can_host_to_board
from protocol.can import CanItem, encode_fixed
from protocol.can.codec import Sender
from protocol.messages import MsgType
from protocol.testing.samples import servo_frame_12, telemetry_12


class _Sink:
    def __init__(self) -> None:
        self.parts: list[str] = []

    def write(self, s: str) -> None:
        self.parts.append(s)

    @property
    def text(self) -> str:
        return "".join(self.parts)


def _write(path: Path, frames: list[tuple[int, bytes, bool]]) -> None:
    with can.Logger(str(path)) as log:  # type: ignore[no-untyped-call]
        for i, (aid, data, fd) in enumerate(frames):
            log.on_message_received(can.Message(timestamp=1000.0 + i * 0.001, arbitration_id=aid, data=data,
                                                is_fd=fd, is_extended_id=False, channel="vcan0"))


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf"])
def test_two_nodes_in_one_capture(tmp_path: Path, suffix: str) -> None:
    frames = [(f.arbitration_id, f.data, f.is_fd) for f in encode_fixed(servo_frame_12(), 7, 1)]
    frames += [(f.arbitration_id, f.data, f.is_fd) for f in encode_fixed(servo_frame_12(5000), 9, 2)]
    frames += [(f.arbitration_id, f.data, f.is_fd) for f in encode_fixed(telemetry_12(), 3, 2, sender=Sender.BOARD)]
    path = tmp_path / f"capture{suffix}"
    _write(path, frames)
    entries = list(iter_can_log(path))
    assert len(entries) == len(frames) and all(e.dbc_name for e in entries)
    done = [(e.frame.arbitration_id & 0x7F, it.msg_type, it.seq) for e in entries for it in e.items if isinstance(it, CanItem)]
    assert done == [(1, MsgType.SERVO_FRAME, 7), (2, MsgType.SERVO_FRAME, 9), (2, MsgType.TELEMETRY, 3)]
    assert [(s, type(m).__name__) for _, s, m in read_can_host_to_board(path)] == [(7, "ServoFrame")]  # first node only
    out, err = _Sink(), _Sink()
    assert decode_can_file(str(path), out, err, node=2) == 0
    assert "SERVO_FRAME_N2" in out.text and "SERVO_FRAME_N1" not in out.text and "TELEMETRY" in out.text
    # a node the capture does not hold: one line and exit 2 (it printed nothing, said nothing and exited 0)
    out, err = _Sink(), _Sink()
    assert decode_can_file(str(path), out, err, node=5) == 2
    assert out.text == ""
    assert err.text.count("\n") == 1 and f"none of the {len(frames)} frame(s)" in err.text and "it holds node(s) 1, 2" in err.text


def test_unknown_and_partial_frames_are_reported(tmp_path: Path) -> None:
    parts = encode_fixed(servo_frame_12(), 7, 1)
    path = tmp_path / "capture.log"
    _write(path, [(0x7F0, b"\x01", False)] + [(f.arbitration_id, f.data, False) for f in parts[:2]]
           + [(f.arbitration_id, f.data, False) for f in encode_fixed(servo_frame_12(), 8, 1)])
    out, err = _Sink(), _Sink()
    assert decode_can_file(str(path), out, err) == 1
    assert "UNKNOWN" in out.text and "ERROR INCOMPLETE" in out.text and "1 not in the DBC" in err.text
    assert out.text.count("SERVO_FRAME  ") + out.text.count("SERVO_FRAME ") >= 1


def _channels(path: Path) -> dict[bool, set[str]]:
    """Channels named in a candump log, by direction (is_rx)."""
    out: dict[bool, set[str]] = {True: set(), False: set()}
    for msg in can.LogReader(str(path)):  # type: ignore[no-untyped-call]
        out[bool(msg.is_rx)].add(str(msg.channel))
    return out


def test_host_and_board_logs_name_the_slcan_channel_alike(tmp_path: Path) -> None:
    # a real lockstep board as an SLCAN adapter on a pty; the host through python-can's slcan interface
    import anyio

    from host.link import BoardClient
    from host.link.board_process import start_board

    board = start_board(["--lockstep", "--log", str(tmp_path / "board.log")], tmp_path / "board.stderr",
                        link="can:slcan:pty")
    tty = board.port

    async def talk() -> None:
        async with await BoardClient.connect(board.spec, log_path=tmp_path / "host.log", reconnect=False) as c:
            at = c.board_now_estimate()
            await c.advance(at + 40_000)
            await c.wait_for(lambda t: t.board_time_us > at, 10)  # telemetry (fixed) and SIM_STATE (ISO-TP) came

    try:
        anyio.run(talk, backend="asyncio")
    finally:
        board.stop()
    assert tty.startswith("/dev/")
    host, board_log = _channels(tmp_path / "host.log"), _channels(tmp_path / "board.log")
    assert host == {True: {tty}, False: {tty}}  # received and sent frames: the adapter's tty, as python-can opened it
    assert board_log == {True: {tty}, False: {tty}}


def test_a_capture_names_its_robot_in_caps(tmp_path: Path) -> None:
    """A 17-servo robot's capture (u32 mask, 17-servo layouts) decodes through the layouts its CAPS names,
    also after a broadcast ESTOP; the DBC view is the robot's generated one."""
    from protocol.can.ids import ESTOP_BROADCAST_ID, bulk_ids
    from protocol.can.isotp_link import IsoTpLink
    from protocol.can.layouts import can_layouts
    from protocol.can import encode_bulk
    from protocol.can.frame import CanFrame
    from protocol.messages import Caps, Estop
    from protocol.testing.samples import servo_frame_n, telemetry_n
    from host.link.canlog import log_servo_count

    t = can_layouts(17)
    caps = Caps(1, t.schema.hash, 17, 500, 64, 50, 0, True, "chain17", 0x1234)
    out: list[CanFrame] = []
    board, host = bulk_ids(1)
    iso = IsoTpLink(rxid=board, txid=host, fd=True, send=out.append)
    iso.send(encode_bulk(caps, 1, t.schema))
    iso.poll()
    assert len(out) == 1  # one CAN FD single frame
    frames = [(f.arbitration_id, f.data, True) for f in out]
    frames += [(f.arbitration_id, f.data, True) for f in encode_fixed(servo_frame_n(17), 7, 1, True, layouts=t)]
    frames += [(f.arbitration_id, f.data, True) for f in encode_fixed(Estop(), 8, 0, True)]
    assert frames[-1][0] == ESTOP_BROADCAST_ID
    frames += [(f.arbitration_id, f.data, True) for f in encode_fixed(telemetry_n(17), 2, 1, True, Sender.BOARD, t)]
    path = tmp_path / "capture.log"
    _write(path, frames)
    assert log_servo_count(path) == 17
    entries = list(iter_can_log(path))
    assert all(e.dbc_name for e in entries), [(hex(e.frame.arbitration_id), e.dbc_name) for e in entries]
    done = [it.msg for e in entries for it in e.items if isinstance(it, CanItem)]
    assert [type(m).__name__ for m in done] == ["Caps", "ServoFrame", "Estop", "Telemetry"]
    assert done[1].mask == (1 << 17) - 1 and len(done[3].positions) == 17  # type: ignore[attr-defined]


@pytest.mark.parametrize("cut_at", [1, 12, 25, -3])
def test_a_candump_cut_off_in_its_last_line_keeps_every_whole_frame(tmp_path: Path, cut_at: int) -> None:
    """A logger killed while writing (``kill -9``, a power cut) leaves a last line without its newline.
    python-can's reader failed on it (or, cut inside the data, read a shorter frame as if whole), so the
    capture was refused whole. The whole frames before it are read; the cut line is named (exit 1, as a
    .jsonl's bad line or a cut run.mcap) and never guessed at. Cut at its time stamp, its id, its data."""
    frames = [(f.arbitration_id, f.data, f.is_fd) for f in encode_fixed(servo_frame_12(), 7, 1)]
    frames += [(f.arbitration_id, f.data, f.is_fd) for f in encode_fixed(servo_frame_12(5000), 8, 1)]
    path = tmp_path / "host_frames.log"
    _write(path, frames)
    text = path.read_text()
    last = text.rstrip("\n").rsplit("\n", 1)[-1]
    cut = tmp_path / "cut.log"
    cut.write_text(text[: len(text) - 1 - len(last)] + last[:cut_at])  # the last line, cut inside it
    assert candump_problem(cut) is None and candump_cut_line(cut) == len(frames)
    assert [e.frame.data for e in iter_can_log(cut)] == [f[1] for f in frames[:-1]]
    assert [(s, type(m).__name__) for _, s, m in read_can_host_to_board(cut)] == [(7, "ServoFrame")]  # the 2nd is cut
    out, err = _Sink(), _Sink()
    assert decode_can_file(str(cut), out, err) == 1
    assert err.text.count("\n") == 1 and f"cut.log:{len(frames)} is cut off" in err.text
    assert f"skipped, {len(frames) - 1} whole frame(s) read" in err.text
    assert candump_cut_line(path) is None  # the whole capture: nothing cut
    out, err = _Sink(), _Sink()
    assert decode_can_file(str(path), out, err) == 0 and err.text == ""
