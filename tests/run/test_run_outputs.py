"""A run's outputs (issue 45 items 2-5): the console timeline on the board clock as timeline.json and
timeline.png, timeline.json's floats rounded to the microsecond, legends beside the plots (never over a
curve) and summary.json's final joint angles."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from host.cli import main as cli_main
from host.run import artefacts
from host.run.artefacts import BoardCall, calls_table
from robots.registry import load_robot


def _floats(v: Any) -> list[float]:
    if isinstance(v, float):
        return [v]
    if isinstance(v, dict):
        return [f for x in v.values() for f in _floats(x)]
    if isinstance(v, list):
        return [f for x in v for f in _floats(x)]
    return []


def test_the_console_table_is_on_the_board_clock_and_says_so() -> None:
    calls = [BoardCall("joint_move", "joints", {"deg": 45.0}, "joint_move[0]", 1.31, 2.33, "done")]
    header, row = calls_table(calls, t0=0.7).splitlines()
    assert "board time" in header and "0.70" in header
    assert row.split()[:2] == ["1.31", "2.33"]  # not 0.61 / 1.63: relative to the turn's start


def test_timeline_json_rounds_its_floats_to_the_microsecond(tmp_path: Path) -> None:
    calls = [BoardCall("nod", "head", {"duration": 0.1 + 0.2}, "nod[0]", 0.9239999999999999, 1.3099999999999998,
                       "done")]
    artefacts.write_timeline_json(tmp_path / "timeline.json", calls, t0=0.7000000000000001)
    doc = json.loads((tmp_path / "timeline.json").read_text(encoding="utf-8"))
    assert (doc["t0"], doc["calls"][0]["start"], doc["calls"][0]["end"]) == (0.7, 0.924, 1.31)
    assert doc["calls"][0]["args"]["duration"] == 0.3


def test_a_lockstep_run_prints_writes_and_summarises_on_one_clock(tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """The desk arm's shoulder swings into the table: the console rows give timeline.json's board
    times, timeline.json has no float past 6 decimals (1.3099999999999998 before), summary.json has the
    angles it ended at (the shoulder at ~37 deg, stopped by the table short of 45)."""
    out = tmp_path / "run"
    assert cli_main(["run", "--robot", "arm", "--lockstep", "--no-live", "--no-plots", "--out", str(out),
                     "--xml", '<joint_move joint="shoulder_lift" deg="45" duration="1"/>']) == 0
    printed = capsys.readouterr().out.splitlines()
    header = next(i for i, line in enumerate(printed) if line.lstrip().startswith("start"))
    assert "board time" in printed[header]
    row = printed[header + 1].split()
    text = (out / "timeline.json").read_text(encoding="utf-8")
    doc = json.loads(text)
    call = doc["calls"][0]
    assert (float(row[0]), float(row[1])) == (round(call["start"], 2), round(call["end"], 2))
    assert f"{doc['t0']:.2f}" in printed[header]
    assert not re.findall(r"\d\.\d{7,}", text), "a float with more than 6 decimals"
    assert all(round(f, 6) == f for f in _floats(doc))

    s = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    final = s["final_joints_deg"]
    assert list(final) == list(load_robot("arm").servos.names)
    assert 30.0 < final["shoulder_lift"] < 44.0  # the table stopped it short of 45
    assert final["wrist_flex"] == pytest.approx(80.0, abs=3.0) and final["gripper"] == pytest.approx(10.0, abs=1.5)


def _no_overlap(fig: Any) -> None:
    renderer = fig.canvas.get_renderer()
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
    assert legends, "no legend drawn"
    for ax in fig.axes:
        leg = ax.get_legend()
        if leg is None:
            continue
        box, area = leg.get_window_extent(renderer), ax.get_window_extent(renderer)
        assert not box.overlaps(area), f"the legend {box} covers the data area {area}"
        assert fig.bbox.contains(box.x0, box.y0) and fig.bbox.contains(box.x1, box.y1), "the legend is cut off"


def test_the_joints_plot_legends_leave_the_curves_clear(tmp_path: Path) -> None:
    arm = load_robot("arm")
    t = np.linspace(0.0, 3.0, 300)
    q = np.radians(np.stack([80.0 * np.sin(t * (i + 1)) for i in range(arm.servo_count)], axis=1))
    fig = artefacts.plot_joints(tmp_path / "joints.png", t, q, arm.servos.names, (t, q),
                                groups=artefacts.joint_groups(arm))
    _no_overlap(fig)
    many = [f"servo_{i}_long_name" for i in range(30)]  # one panel of 30: three legend columns
    fig = artefacts.plot_joints(tmp_path / "many.png", t, np.zeros((len(t), 30)), many)
    _no_overlap(fig)


def test_the_timeline_plot_legend_leaves_the_bars_clear(tmp_path: Path) -> None:
    calls = [BoardCall(f"f{i}", ch, {}, f"f{i}[0]", 0.1 * i, 0.1 * i + 2.0, outcome)
             for i, (ch, outcome) in enumerate([("arm", "done"), ("gripper", "failed"), ("speech", "cancelled"),
                                                ("arm", "interrupted"), ("gripper", "timeout")])]
    _no_overlap(artefacts.plot_timeline(tmp_path / "timeline.png", calls, title="t"))
