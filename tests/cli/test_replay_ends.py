"""``ghostshell replay`` ends on any recorded folder (reported: two folders it waited on for good).

Real commands in real processes: the run that records, the run a signal stops while it starts
(:func:`support.cliproc.start_while_starting`: the host's handshake waits on a pty no board
answers, so the signal lands while starting with no race), and the replay. A folder that cannot be
replayed is refused in one line, exit 2, before a board starts; one that can ends with exit 0.
"""

from __future__ import annotations

import json
import shutil
import signal
from pathlib import Path

import pytest

from support.cliproc import Cli, start, start_while_starting
from support.realtime_lock import realtime_part_done

pytestmark = pytest.mark.timeout(240)


def _finish(cli: Cli, timeout: float = 120.0) -> tuple[int, list[str]]:
    rc = cli.wait(timeout)
    return rc, [ln for ln in cli.stderr.splitlines() if ln.strip()]


def _record(tmp_path: Path, *extra: str) -> Path:
    out = tmp_path / "run"
    rc, err = _finish(start(["run", "--task", "26", "--no-live", "--out", str(out), *extra], tmp_path / "run_logs"))
    assert rc == 0, err
    return out


def test_a_run_replayed_on_another_robot_is_refused_before_a_board_starts(tmp_path: Path) -> None:
    run = _record(tmp_path, "--lockstep")
    assert json.loads((run / "summary.json").read_text())["extra"]["robot"] == "coco"
    out = tmp_path / "replay"
    rc, err = _finish(start(["replay", str(run), "--robot", "arm", "--out", str(out)], tmp_path / "a"))
    assert rc == 2 and len(err) == 1, err
    assert "recorded on robot 'coco'" in err[0] and "'arm'" in err[0], err
    assert not out.exists()  # nothing started, nothing written
    # the same log without its summary.json: the servo frames themselves give the mismatch away
    bare = tmp_path / "bare"
    bare.mkdir()
    shutil.copy(run / "host_frames.jsonl", bare)
    rc, err = _finish(start(["replay", str(bare), "--robot", "arm", "--out", str(out)], tmp_path / "b"))
    assert rc == 2 and len(err) == 1 and "that robot 'arm' (6 servos) lacks" in err[0], err
    assert not out.exists()


def test_a_run_stopped_while_starting_has_nothing_to_replay(tmp_path: Path) -> None:
    run = tmp_path / "run"
    cli = start_while_starting(["run", "--task", "26", "--no-live", "--out", str(run)], tmp_path / "run_logs")
    cli.ctrl_c(signal.SIGINT)
    assert cli.wait() == 130, cli.stderr
    assert (run / "host_frames.jsonl").exists()  # the HELLO, nothing that moves the robot
    out = tmp_path / "replay"
    rc, err = _finish(start(["replay", str(run), "--out", str(out)], tmp_path / "r"))
    assert rc == 2 and len(err) == 1 and err[0].startswith("ghostshell replay: nothing to replay:"), err
    assert not out.exists()


@pytest.mark.realtime
def test_a_realtime_run_replays_to_its_last_report(tmp_path: Path) -> None:
    run = _record(tmp_path, "--realtime")
    realtime_part_done()  # the realtime run (and its board) has ended; the replays are lockstep
    out = tmp_path / "replay"
    rc, err = _finish(start(["replay", str(run), "--out", str(out)], tmp_path / "r"))
    assert rc == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["base_end"] is not None and summary["original_base_end"] is not None, summary
    assert summary["board_time_s"] > 5.0, summary  # task 26 lasts ~5.5 board seconds
    # a realtime board runs on by itself: a log whose host stopped sending at 2 s while the board went
    # on reporting (its frames after 2 s left out) is replayed up to the board's last report, too
    cut = tmp_path / "cut"
    cut.mkdir()
    lines = (run / "host_frames.jsonl").read_text().splitlines()
    kept = [ln for ln in lines if not ('"dir":"tx"' in ln and '"SERVO_FRAME"' in ln
                                       and json.loads(ln)["fields"]["apply_at_us"] > 2_000_000)]
    assert len(kept) < len(lines)
    (cut / "host_frames.jsonl").write_text("\n".join(kept) + "\n")
    rc, err = _finish(start(["replay", str(cut), "--out", str(tmp_path / "replay_cut")], tmp_path / "c"))
    assert rc == 0, err
    cut_summary = json.loads((tmp_path / "replay_cut" / "summary.json").read_text())
    assert cut_summary["board_time_s"] > 5.0, cut_summary  # the original board's last report, not 2 s
