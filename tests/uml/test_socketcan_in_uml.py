"""Run ``tests/socketcan`` on a real Linux kernel with vcan, inside one User-Mode Linux boot.

One boot for the whole directory (python start-up over hostfs is the cost, not the boot; the
whole directory takes about a minute inside, three paper-task runs included). The
inner pytest writes JUnit XML into the run dir; this test fails with the inner failures' text
if anything failed, errored or was skipped (inside UML every prerequisite exists, so a skip
there is a bug, not noise).
"""

from __future__ import annotations

import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from support.uml import REPO_ROOT, default_env, run_in_uml, socketcan_skip_reason

pytestmark = pytest.mark.skipif(socketcan_skip_reason() is not None, reason=socketcan_skip_reason() or "")

#: Interfaces the inner tests use; sch_tbf lets them shape vcan1 like a real 1 Mbit/s controller.
VCANS = ("vcan0", "vcan1")
EXTRA_MODULES = ("sch_tbf",)


def _junit_summary(path: Path) -> tuple[dict[str, int], list[str]]:
    root = ET.parse(path).getroot()
    suites = [root] if root.tag == "testsuite" else list(root.iter("testsuite"))
    totals = {k: sum(int(s.get(k, 0)) for s in suites) for k in ("tests", "failures", "errors", "skipped")}
    problems = []
    for case in root.iter("testcase"):
        for child in case:
            if child.tag in ("failure", "error", "skipped"):
                name = f"{case.get('classname')}::{case.get('name')}"
                problems.append(f"{child.tag.upper()} {name}: {child.get('message', '')}\n{(child.text or '')[-2500:]}")
    return totals, problems


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_socketcan_suite_passes_inside_uml(tmp_path: Path) -> None:
    junit = tmp_path / "junit.xml"
    result = run_in_uml(
        [
            sys.executable, "-m", "pytest", str(REPO_ROOT / "tests" / "socketcan"),
            "-q", "-p", "no:cacheprovider", "-o", "addopts=--import-mode=importlib",
            f"--junitxml={junit}", f"--basetemp={tmp_path / 'basetemp'}",
        ],
        run_dir=tmp_path,
        env=default_env({"GHOSTSHELL_IN_UML": "1"}),
        vcans=VCANS,
        extra_modules=EXTRA_MODULES,
        timeout=600,
    )
    assert junit.exists(), f"inner pytest wrote no JUnit XML\n{result.describe()}"
    totals, problems = _junit_summary(junit)
    assert result.returncode == 0 and not problems, "\n\n".join([result.describe(), *problems])
    assert totals["tests"] > 0 and totals["skipped"] == 0, totals
