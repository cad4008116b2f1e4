"""A program given on the command line is refused whole before any board starts (issue 45, item 1).

``ghostshell run --xml '<head_act action="nod"'`` (an unclosed tag), ``'<nosuch/>'`` (a function no
module has) or an end-tag that closes nothing used to be found by the run itself: the board started,
the robot went to its start pose, the run folder was written, exit status 1. The README says bad
input exits 2 before anything starts; the strict parser a scripted replay uses and the names the run
will have mounted are known before the board is, so :func:`host.shell.precheck.refuse_program`
checks them (each row: exit 2, one line on stderr, nothing on stdout, no run folder: the board
would have logged its frames there).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from host.runtime.binding import signature_registry
from host.shell.precheck import refuse_program
from robots.registry import load_robot

pytestmark = pytest.mark.timeout(120)

ROWS = [
    ('<head_act action="nod"', "line 1, column 1: stream ended inside tag '<head_act action=\"nod\"'"),
    ('<head_act action="nod">', "stream ended with <head_act> (opened at line 1, column 1) still open"),
    ('<head_act action="nod"/></head_act>', "line 1, column 25: end-tag </head_act> closes no open element"),
    ("<nosuch/>", "line 1, column 1: unknown function <nosuch>"),
    ('<head_act action="nod"/> and <head_act action="sideways"/>', "action='sideways' is not one of"),
    ('<head_act action="nod"/><head_act action="nod" action="nod"/>', "line 1, column 25:"),
]


@pytest.mark.parametrize("xml, says", ROWS, ids=[x for x, _ in ROWS])
def test_a_malformed_program_exits_2_before_a_board_starts(xml: str, says: str, tmp_path: Path) -> None:
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "host", "run", "--xml", xml, "--lockstep", "--no-live",
                        "--out", str(out)], capture_output=True, text=True, timeout=100, cwd=tmp_path)
    assert r.returncode == 2, r.stdout + r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ghostshell run: the program: "), r.stderr
    assert says in lines[0] and lines[0].endswith("; nothing was run"), lines[0]
    assert r.stdout == ""
    assert not out.exists(), sorted(p.name for p in out.iterdir())


@pytest.fixture(scope="module")
def coco_registry():  # type: ignore[no-untyped-def]
    return signature_registry(load_robot("coco"))


def test_lenient_recovers_what_the_run_would_and_mounted_names_pass(coco_registry) -> None:  # type: ignore[no-untyped-def]
    # --lenient: the run's parser recovers from an unclosed tag, so the check lets it through
    assert refuse_program('<head_act action="nod">', coco_registry, 600, strict=False) is None
    assert refuse_program('<head_act action="nod">', coco_registry, 600, strict=True) is not None
    # a tool of a --mount-mcp NAME is known only once the run mounts it; any other unknown name is refused
    assert refuse_program('<weather.get_forecast city="Oslo"/>', coco_registry, 600, mounts={"weather"}) is None
    why = refuse_program('<get_forecast city="Oslo"/>', coco_registry, 600, mounts={"weather"})
    assert why is not None and why.startswith("line 1, column 1: unknown function <get_forecast>")
    assert refuse_program("<nosuch/>", coco_registry, 600) is None  # no mounts given: a later mount may add it
