"""The robot line of a chat observation (what the LLM reads after its turn) says when the pose is unknown.

Over a line too slow for the board's reports (``--baud 57600`` for CoCo) no SIM_STATE reaches the host,
and the turn's summary has zeros for the base pose and tilt: told as "upright, moved 0.00 m" the LLM
would take a walk that happened for one that did not."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

from host.chat.observations import telemetry_line


def _turn(**extra: Any) -> Any:
    summary = SimpleNamespace(base_start=[0.0, 0.0, 0.0], base_end=[0.12, 0.01, 2.0], fell=False,
                              max_tilt_deg=3.1, extra=extra)
    return SimpleNamespace(summary=summary)


def test_a_turn_with_reports_tells_the_pose() -> None:
    assert telemetry_line(_turn(base_reports=150)).startswith("robot: upright, max tilt 3.1 deg; base moved 0.12 m")
    assert telemetry_line(_turn()).startswith("robot: upright")  # a summary from before the count


def test_a_turn_without_a_report_says_the_pose_is_unknown() -> None:
    line = telemetry_line(_turn(base_reports=0))
    assert line == "robot: pose unknown (no SIM_STATE report reached the host)"
    assert "moved" not in line and "upright" not in line
