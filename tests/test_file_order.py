"""The suite's file order under xdist (tests/support/file_order.py): longest files first, from the
measured table tests/durations.json, so no long file is left to run alone at the end; files with
realtime tests before them unless the realtime lock runs in background mode."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from support.file_order import DEFAULT_S_PER_TEST, DURATIONS, durations_from_junit, file_of, run_order
from support.realtime_lock import _may_lower_nice_to

REPO = Path(__file__).resolve().parent.parent


def test_files_go_longest_first_and_keep_their_tests_in_order() -> None:
    ids = ["t/a.py::x", "t/a.py::y", "t/b.py::z", "t/c.py::p", "t/c.py::q", "t/c.py::r", "t/d.py::s"]
    table = {"t/b.py": 50.0, "t/d.py": 0.1}
    # b is measured longest; c (3 unknown tests) outweighs a (2); d is measured short
    assert run_order(ids, table) == ["t/b.py::z", "t/c.py::p", "t/c.py::q", "t/c.py::r",
                                     "t/a.py::x", "t/a.py::y", "t/d.py::s"]
    same = {"t/a.py": 3.0, "t/b.py": 3.0}
    assert run_order(["t/b.py::1", "t/a.py::1", "t/b.py::2"], same) == ["t/b.py::1", "t/b.py::2", "t/a.py::1"]
    # files with realtime tests first (longest first among them), however short
    assert run_order(ids, table, first={"t/d.py", "t/a.py"}) == ["t/a.py::x", "t/a.py::y", "t/d.py::s", "t/b.py::z",
                                                                "t/c.py::p", "t/c.py::q", "t/c.py::r"]
    assert file_of("tests/x/test_y.py::test_z[a::b]") == "tests/x/test_y.py"
    assert DEFAULT_S_PER_TEST > 0


def test_a_missing_or_malformed_table_means_no_measurements(tmp_path: Path) -> None:
    from support.file_order import load_durations

    assert load_durations(tmp_path / "absent.json") == {}
    for text in ("{", "[1, 2]", '{"tests/a.py": null}', '{"tests/a.py": [1]}', '{"tests/a.py": "abc"}'):
        (tmp_path / "d.json").write_text(text)
        assert load_durations(tmp_path / "d.json") == {}, text
    (tmp_path / "d.json").write_text('{"tests/a.py": 2, "tests/b.py": "3.5"}')
    assert load_durations(tmp_path / "d.json") == {"tests/a.py": 2.0, "tests/b.py": 3.5}


def test_junit_times_sum_per_file(tmp_path: Path) -> None:
    (tmp_path / "tests" / "sub").mkdir(parents=True)
    (tmp_path / "tests" / "sub" / "test_k.py").write_text("")
    (tmp_path / "tests" / "test_m.py").write_text("")
    xml = tmp_path / "j.xml"
    xml.write_text('<testsuites><testsuite>'
                   '<testcase classname="tests.sub.test_k" name="a" time="1.25"/>'
                   '<testcase classname="tests.sub.test_k" name="b" time="2.0"/>'
                   '<testcase classname="tests.test_m.TestThing" name="c" time="4.0"/>'
                   '<testcase classname="tests.gone" name="d" time="9.0"/>'
                   '</testsuite></testsuites>')
    assert durations_from_junit(xml, tmp_path) == {"tests/test_m.py": 4.0, "tests/sub/test_k.py": 3.2}


def test_the_table_names_only_test_files_that_exist() -> None:
    table = json.loads((REPO / DURATIONS).read_text())
    assert len(table) > 100 and all(isinstance(v, (int, float)) and v >= 0 for v in table.values())
    missing = [f for f in table if not (REPO / f).is_file()]
    assert not missing, f"tests/durations.json names files that are gone (remake it: tests/support/file_order.py): {missing}"


def test_an_xdist_run_starts_realtime_files_then_the_longest(tmp_path: Path) -> None:
    """A real three-file suite under ``-n 1 --dist loadfile`` with the project's options: the short file
    with a realtime test first, then the file with one measured-long test, then the file with many
    short ones (xdist's own order runs the file with most tests first)."""
    tests = tmp_path / "tests"
    tests.mkdir()
    (tests / "conftest.py").write_text(f"import sys\nsys.path.insert(0, {str(REPO / 'tests')!r})\n"
                                       "pytest_plugins = ['support.file_order']\n")
    (tests / "test_many.py").write_text("".join(f"def test_short_{i}():\n    pass\n" for i in range(5)))
    (tests / "test_one.py").write_text("def test_long():\n    pass\n")
    (tests / "test_rt.py").write_text("import pytest\n\n@pytest.mark.realtime\ndef test_wall_clock():\n    pass\n")
    (tests / "durations.json").write_text(json.dumps({"tests/test_one.py": 100.0, "tests/test_many.py": 1.0}))
    (tmp_path / "pyproject.toml").write_text('[tool.pytest.ini_options]\naddopts = "--no-loadscope-reorder"\n'
                                            'markers = ["realtime: runs alone"]\n')
    out = subprocess.run([sys.executable, "-m", "pytest", "-n", "1", "--dist", "loadfile", "-v", "-p", "no:cacheprovider"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    ran = [line.split()[-1] for line in out.stdout.splitlines() if "PASSED" in line and "::" in line]
    assert len(ran) == 7 and ran[:2] == ["tests/test_rt.py::test_wall_clock", "tests/test_one.py::test_long"], ran
    assert all("test_many" in r for r in ran[2:])


@pytest.mark.skipif(not sys.platform.startswith("linux") or not _may_lower_nice_to(0),
                    reason="background mode needs Linux and root or CAP_SYS_NICE")
def test_in_background_mode_the_longest_file_goes_first_realtime_or_not(tmp_path: Path) -> None:
    """The same suite with the realtime lock loaded too, in background mode: weight alone decides."""
    tests = tmp_path / "tests"
    tests.mkdir()
    (tests / "conftest.py").write_text(f"import sys\nsys.path.insert(0, {str(REPO / 'tests')!r})\n"
                                       "pytest_plugins = ['support.realtime_lock', 'support.file_order']\n")
    (tests / "test_one.py").write_text("def test_long():\n    pass\n")
    (tests / "test_rt.py").write_text("import pytest\n\n@pytest.mark.realtime\ndef test_wall_clock():\n    pass\n")
    (tests / "durations.json").write_text(json.dumps({"tests/test_one.py": 100.0, "tests/test_rt.py": 1.0}))
    (tmp_path / "pyproject.toml").write_text('[tool.pytest.ini_options]\naddopts = "--no-loadscope-reorder"\n')
    env = {k: v for k, v in os.environ.items() if k != "GHOSTSHELL_TESTS_REALTIME_ALONE"}
    out = subprocess.run([sys.executable, "-m", "pytest", "-n", "1", "--dist", "loadfile", "-v", "-p", "no:cacheprovider"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=120, env=env,
                         preexec_fn=lambda: os.setpriority(os.PRIO_PROCESS, 0, 0))  # this worker may run at 19
    assert out.returncode == 0, out.stdout + out.stderr
    ran = [line.split()[-1] for line in out.stdout.splitlines() if "PASSED" in line and "::" in line]
    assert ran == ["tests/test_one.py::test_long", "tests/test_rt.py::test_wall_clock"], ran


def test_the_project_turns_xdists_reorder_off() -> None:
    import tomllib

    opts = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]["addopts"]
    assert "--no-loadscope-reorder" in opts.split()
