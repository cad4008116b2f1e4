"""``ghostshell replay``: a recorded lockstep run fed into a fresh lockstep board ends where the original ended."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import pytest

from host.cli import main as cli_main
from host.run.replay import ReplayError, read_host_to_board, replay
from protocol.framelog import iter_records
from protocol.messages import Advance, Hello, ServoFrame

from .conftest import run_e2e

pytestmark = pytest.mark.timeout(120)


def _servo_frames_received(path: Path) -> list[str]:
    with open(path, encoding="utf-8") as f:
        return [r["raw"] for r in iter_records(f) if r["dir"] == "rx" and r.get("type") == "SERVO_FRAME"]


def test_replay_ends_where_the_original_run_ended(tmp_path: Path) -> None:
    run = run_e2e('<move_forward times="1"/>', tmp_path / "run", task_label="walk")
    original = run.report.summary.base_end
    assert math.dist(original[:2], run.report.summary.base_start[:2]) > 0.01  # the robot really walked

    sent = list(read_host_to_board(tmp_path / "run" / "host_frames.jsonl"))
    assert isinstance(sent[0][2], Hello) and sent[0][1] == 0
    assert sum(isinstance(m, ServoFrame) for _, _, m in sent) > 50

    out = tmp_path / "replay"
    assert cli_main(["replay", str(tmp_path / "run"), "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["messages"] == len(sent)
    end = summary["base_end"]
    assert math.dist(end[:2], original[:2]) * 1000 <= 1.0, (end, original)
    assert abs(end[2] - original[2]) < 0.5
    assert summary["base_end_error_mm"] is not None and summary["base_end_error_mm"] <= 1.0
    assert (out / "joints.png").stat().st_size > 10_000
    # the replayed board received byte-identical servo frames, in the same order (the original board
    # was stopped with the host's last frames possibly still in flight: its log may end a few frames early)
    replayed = _servo_frames_received(out / "board_frames.jsonl")
    received = _servo_frames_received(tmp_path / "run" / "board_frames.jsonl")
    assert replayed[:len(received)] == received
    assert len(replayed) - len(received) <= 10
    assert len(replayed) == sum(isinstance(m, ServoFrame) for _, _, m in sent)


def test_replay_of_the_boards_own_log_ends_where_the_original_run_ended(tmp_path: Path) -> None:
    """The board's serial log holds the host's messages as ``rx`` records (the host's holds them as ``tx``):
    ``replay`` takes them from either, as docs/guides/faults.md tells a user to after a faulted run. Found by
    a new user: the board's log was refused as "nothing to replay"."""
    run = run_e2e('<move_forward times="1"/>', tmp_path / "run", task_label="walk")
    board_log = tmp_path / "run" / "board_frames.jsonl"
    received = list(read_host_to_board(board_log))
    assert isinstance(received[0][2], Hello)
    frames = [m for _, _, m in received if isinstance(m, ServoFrame)]
    assert len(frames) > 50 and len(frames) == len(_servo_frames_received(board_log))

    out = tmp_path / "replay"
    assert cli_main(["replay", str(board_log), "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["messages"] == len(received)
    original = run.report.summary.base_end
    assert summary["original_base_end"] == original  # the last SIM_STATE the board sent, from its own log
    assert summary["base_end_error_mm"] is not None and summary["base_end_error_mm"] <= 1.0


def test_replay_refuses_what_it_cannot_read(tmp_path: Path) -> None:
    with pytest.raises(ReplayError, match="no host frame log"):
        replay(tmp_path, tmp_path / "out")
    (tmp_path / "x.pcap").write_bytes(b"")
    with pytest.raises(ReplayError, match=r"unknown log format .\.pcap."):
        list(read_host_to_board(tmp_path / "x.pcap"))
    empty = tmp_path / "host_frames.jsonl"
    empty.write_text("")
    with pytest.raises(ReplayError, match="no host-to-board messages"):
        replay(empty, tmp_path / "out")
    assert cli_main(["replay", str(tmp_path / "missing.jsonl")]) == 2  # bad input: the exit-code table
    text = tmp_path / "text.log"  # a CAN log's name, not a CAN log (found by a fresh-user review)
    text.write_text("hello world\nnot a log\n")
    with pytest.raises(ReplayError, match=r"text\.log:1 is not a candump -L line"):
        list(read_host_to_board(text))
    assert cli_main(["replay", str(text), "--out", str(tmp_path / "r")]) == 2


def _host_log(path: Path, *msgs: object) -> Path:
    """A host frame log (JSON Lines) of ``msgs`` sent in order."""
    from protocol import framelog
    from protocol.framing import Frame, encode_frame
    from protocol.messages import MsgType

    lines = []
    for seq, msg in enumerate(msgs):
        raw = encode_frame(msg, seq)  # type: ignore[arg-type]
        t = MsgType.ADVANCE if isinstance(msg, Advance) else MsgType.SERVO_FRAME
        lines.append(framelog.to_line(framelog.record("tx", 1.0 + seq, raw, Frame(seq, t, msg, raw))))  # type: ignore[arg-type]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_replay_refuses_a_log_of_a_board_that_was_already_running(tmp_path: Path) -> None:
    """A run on a board you started (or a second run on one) begins seconds into the board's time. The
    replay's fresh board ran to that time without a frame, latched its watchdog fault, refused every
    frame, and after 30 s said "the board did not reach board time 6.040 s": refused at once now. A
    lockstep log (ADVANCEs) may start within 1 s of board time 0, a realtime one within 10 s."""
    frame = ServoFrame(apply_at_us=3_064_000, mask=0x0FFF, targets=(0.0,) * 12)
    lockstep = _host_log(tmp_path / "lockstep.jsonl", Advance(3_064_000), frame)
    with pytest.raises(ReplayError, match=r"first frame is due at board time 3\.064 s, so it was recorded on a board "
                                          r"that had been running before the run"):
        replay(lockstep, tmp_path / "out")
    assert not (tmp_path / "out").exists()  # refused before any board started
    assert cli_main(["replay", str(lockstep), "--out", str(tmp_path / "out2")]) == 2
    late = ServoFrame(apply_at_us=14_450_000, mask=0x0FFF, targets=(0.0,) * 12)
    with pytest.raises(ReplayError, match=r"board time 14\.450 s"):
        replay(_host_log(tmp_path / "realtime.jsonl", late), tmp_path / "out3")


def test_replay_refuses_to_write_over_the_recording_it_replays(tmp_path: Path) -> None:
    """``replay runs/x --out runs/x`` (or ``replay runs/replay`` with the default ``--out``) wrote the
    replay's host_frames.jsonl, board log and summary over the run it read: the recording was lost.
    Found by a new user. Refused now, before any board starts, and the recording is unchanged."""
    run = tmp_path / "run"
    run.mkdir()
    log = _host_log(run / "host_frames.jsonl", Advance(20_000), ServoFrame(20_000, 0x0FFF, (0.0,) * 12))
    (run / "summary.json").write_text('{"robot": "coco"}\n')
    before = {p.name: p.read_bytes() for p in run.iterdir()}
    for source in (run, log):
        with pytest.raises(ReplayError, match=r"over the recording's host_frames\.jsonl, summary\.json; give another "
                                              r"folder with --out DIR"):
            replay(source, run)
        assert cli_main(["replay", str(source), "--out", str(run)]) == 2
    assert {p.name: p.read_bytes() for p in run.iterdir()} == before
    # ... nor through a link: a symbolic link to the log (its own folder is elsewhere), a hard link to it
    (tmp_path / "elsewhere").mkdir()
    sym = tmp_path / "elsewhere" / "hf.jsonl"
    sym.symlink_to(log)
    hard = tmp_path / "elsewhere" / "host_frames.jsonl"
    os.link(log, hard)
    for source, out in ((sym, run), (hard, tmp_path / "elsewhere"), (log, tmp_path / "elsewhere")):
        with pytest.raises(ReplayError, match=r"over the recording's host_frames\.jsonl"):
            replay(source, out)
    assert {p.name: p.read_bytes() for p in run.iterdir()} == before
