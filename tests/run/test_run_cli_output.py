"""``ghostshell run`` as a user sees it: the printed timeline is the board-measured one (as timeline.json),
a failed ``<SAVE>`` fails the run, and out-of-range numbers are refused by the parser."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from host.cli import main as cli

NODS = '<head_act action="nod"/><head_act action="nod"/><head_act action="nod"/>'


def _rows(text: str) -> list[tuple[float, float]]:
    rows = []
    for line in text.splitlines():
        parts = line.split()
        if len(parts) > 3 and parts[2] == "head":
            rows.append((float(parts[0]), float(parts[1])))
    return rows


def test_printed_timeline_is_the_board_measured_one(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "r"
    assert cli(["run", "--xml", NODS, "--lockstep", "--no-live", "--out", str(out)]) == 0
    printed = _rows(capsys.readouterr().out)
    doc = json.loads((out / "timeline.json").read_text())
    saved = [(round(c["start"], 2), round(c["end"], 2)) for c in doc["calls"]  # both on the board clock
             if c["channel"] == "head"]
    assert len(printed) == 3 and [x for r in printed for x in r] == pytest.approx([x for r in saved for x in r], abs=0.006)
    assert all(a[1] <= b[0] + 0.011 for a, b in zip(printed, printed[1:]))  # one head: back to back, no overlap


def test_summary_line_without_any_action(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli(["run", "--xml", "<wait/>", "--lockstep", "--no-live", "--out", str(tmp_path / "r")]) == 0
    text = capsys.readouterr().out
    assert "no action" in text and "None ms" not in text


@pytest.mark.parametrize("name", ["", "x" * 101])
def test_a_failed_save_fails_the_run(name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    xml = f'<SAVE name="{name}" description="d"><head_act action="nod"/></SAVE>'
    out = tmp_path / "r"
    assert cli(["run", "--xml", xml, "--lockstep", "--no-live", "--skills", str(tmp_path / "s.json"),
                "--out", str(out)]) == 1
    assert json.loads((out / "summary.json").read_text())["outcome"] == "failed"
    assert "skill not saved" in capsys.readouterr().out


def test_an_unwritable_skill_library_fails_the_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "file").write_text("not a folder")  # even root cannot create file/s.json
    xml = '<SAVE name="n" description="d"><head_act action="nod"/></SAVE>'
    assert cli(["run", "--xml", xml, "--lockstep", "--no-live", "--skills", str(tmp_path / "file" / "s.json"),
                "--out", str(tmp_path / "r")]) == 1
    assert "skill not saved" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [
    ["run", "--xml", "<nod/>", "--interrupt-at", "-1"],
    ["render", "RUN", "--workers", "0"],
])
def test_out_of_range_numbers_are_refused(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        cli(argv)
    assert e.value.code == 2 and "must be >=" in capsys.readouterr().err


def test_an_unknown_flag_is_named(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        cli(["run", "--bogus"])
    assert e.value.code == 2 and "unrecognized arguments: --bogus" in capsys.readouterr().err
    assert cli(["run", "--lockstep"]) == 2
    assert "one of the arguments --task" in capsys.readouterr().err


def test_a_bad_llm_spec_is_refused_before_the_board_starts(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli(["run", "--prompt", "nod", "--llm", "bogus", "--out", str(tmp_path / "r")]) == 2
    assert "unknown LLM spec" in capsys.readouterr().err and not (tmp_path / "r").exists()
