"""``--mount-mcp`` as a user types it: an MCP tool's result comes back as an observation, and one
reply drives two robots on two boards (the second robot's shell mounted through ``ghostshell mcp``)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from host.cli import main as cli_main

SERVER = Path(__file__).resolve().parents[1] / "support" / "weather_server.py"


def test_run_returns_the_tools_result_as_an_observation(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    rc = cli_main(["run", "--lockstep", "--no-live", "--out", str(out), "--mount-mcp", f"weather=python {SERVER}",
                   "--xml", '<weather.get_forecast city="Lisbon" days="2"/>'])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "weather.get_forecast returned 'Lisbon: sunny, 21 C for 2 day(s)'" in printed
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"] == "done"
    assert any("Lisbon: sunny" in o for o in summary["extra"]["observations"])


def test_a_server_that_cannot_start_is_a_usage_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = cli_main(["run", "--lockstep", "--no-live", "--out", str(tmp_path / "run"),
                   "--mount-mcp", f"weather=python {SERVER} --fail-start", "--xml", '<head_act action="nod"/>'])
    err = capsys.readouterr().err
    assert rc == 2
    assert len(err.strip().splitlines()) == 1 and "weather" in err and "Traceback" not in err


def test_one_reply_drives_two_robots_each_on_its_own_board(tmp_path: Path) -> None:
    """CoCo nods while the mounted shell's desk arm (another robot, another board, another process:
    ``ghostshell mcp --robot arm``) waves and points: both timelines show every call done, the arm's on
    its own board clock."""
    out, remote = tmp_path / "local", tmp_path / "remote"
    rc = cli_main(["run", "--lockstep", "--no-live", "--out", str(out),
                   "--mount-mcp", f"arm=ghostshell mcp --robot arm --lockstep --out {remote}",
                   "--xml", '<head_act action="nod" duration="1.5"/><arm.wave/><arm.point_at target="red_cube"/>'])
    assert rc == 0
    local = json.loads((out / "timeline.json").read_text())["calls"]
    assert {(c["function"], c["outcome"]) for c in local} == {
        ("head_act", "done"), ("arm.wave", "done"), ("arm.point_at", "done")}
    nod = next(c for c in local if c["function"] == "head_act")
    wave = next(c for c in local if c["function"] == "arm.wave")
    assert wave["start"] < nod["end"]  # the arm waved while CoCo was still nodding
    turns = sorted(p for p in remote.iterdir() if p.name.startswith("turn_"))
    remote_calls = [c for t in turns for c in json.loads((t / "timeline.json").read_text())["calls"]]
    assert [(c["function"], c["outcome"]) for c in remote_calls] == [("wave", "done"), ("point_at", "done")]
    assert all(c["start"] is not None and c["end"] > c["start"] for c in remote_calls)  # board-measured there
    assert json.loads((turns[0] / "summary.json").read_text())["extra"]["robot"] == "arm"
    assert json.loads((out / "summary.json").read_text())["extra"]["robot"] == "coco"
