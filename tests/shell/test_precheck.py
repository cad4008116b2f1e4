"""A program known in full is checked element by element before it runs (host.shell.precheck)."""

from __future__ import annotations

import pytest

from host.runtime.binding import signature_registry
from host.shell.precheck import refuse_program
from robots.registry import load_robot


@pytest.fixture(scope="module")
def arm_registry():
    return signature_registry(load_robot("arm"))


def test_a_late_out_of_range_argument_is_refused_with_where_and_the_joints_own_range(arm_registry) -> None:
    why = refuse_program('<pose name="home"/>\n<joint_move joint="elbow_flex" deg="500" duration="1"/>', arm_registry, 600)
    assert why is not None and why.startswith("line 2, column 1: <joint_move> deg='500' is out of range")
    assert "for joint elbow_flex" in why and "\n" not in why


@pytest.mark.parametrize("program, what", [
    ('<joint_move joint="elbow_flex" deg="ten"/>', "deg"),
    ('<joint_move joint="elbow_flex" deg="5" speed="2"/>', "speed"),
    ('<wait timeout="9999"><pose name="home"/></wait>', "timeout"),
    ('<pose name="nowhere"/>', "nowhere"),
])
def test_bad_values_unknown_parameters_and_scope_timeouts_are_refused(arm_registry, program: str, what: str) -> None:
    why = refuse_program(program, arm_registry, 600)
    assert why is not None and what in why


def test_good_programs_unknown_names_and_skills_pass(arm_registry) -> None:
    ok = '<pose name="home"/><wait><joint_move joint="elbow_flex" deg="5" duration="1"/></wait>'
    assert refuse_program(ok, arm_registry, 600) is None
    # a name the registry does not know may be a mounted MCP tool; SAVE/RUN are skills: checked as the run goes
    assert refuse_program('<weather_now city="Oslo"/><RUN skill="x"/><SAVE name="s"><pose name="home"/></SAVE>',
                          arm_registry, 600) is None
    assert refuse_program("just words <unclosed", arm_registry, 600) is None


def test_nesting_deeper_than_the_scheduler_takes_is_refused_before_anything_runs(arm_registry) -> None:
    """The scheduler refuses an element with MAX_DEPTH open elements around it, one failure at a time as the
    stream goes (a new user's 3 000-deep ``<wait>`` ran into the 120 s board-time bound, 1 731 calls failed,
    exit 1); a program known in full is refused at once, at the first such element, and one level less runs."""
    from host.shell.scheduler import MAX_DEPTH

    def nested(n: int) -> str:
        return "<wait>" * n + '<pose name="home"/>' + "</wait>" * n

    assert refuse_program(nested(MAX_DEPTH - 1), arm_registry, 600) is None
    why = refuse_program(nested(MAX_DEPTH), arm_registry, 600)
    assert why is not None and why.endswith(f"<pose> is nested deeper than {MAX_DEPTH} elements"), why
    why = refuse_program(nested(3000), arm_registry, 600)
    assert why is not None and f"<wait> is nested deeper than {MAX_DEPTH}" in why and len(why) < 120, why
