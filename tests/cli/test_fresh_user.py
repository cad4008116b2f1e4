"""Fresh-user leftovers (issue 17): one error prefix, a --robots-dir that does not exist, --xml-file -.

Each is a real ``python -m host ...`` (or ``python -m firmware_sim``) process, as a user runs it."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.timeout(180)


def _run(*argv: str, module: str = "host", stdin: str = "", timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", module, *argv], input=stdin, capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT)


def _printed_prefixes() -> list[str]:
    """Every ``print(...)`` in host/commands and host/cli.py whose text starts with "ghostshell" (file:line)."""
    found = []
    for path in [*sorted((ROOT / "host" / "commands").glob("*.py")), ROOT / "host" / "cli.py"]:
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "print" and node.args:
                first = node.args[0]
                head = first.values[0] if isinstance(first, ast.JoinedStr) and first.values else first
                if isinstance(head, ast.Constant) and str(head.value).startswith("ghostshell"):
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    return found


def test_every_error_line_goes_through_one_function() -> None:
    assert _printed_prefixes() == []  # host.commands.errors.print_error writes "ghostshell COMMAND: ..."


@pytest.mark.parametrize("command", ["run", "demo", "chat"])
def test_run_demo_and_chat_name_themselves(command: str, tmp_path: Path) -> None:
    """Their shared checks (host.commands.run.check_run_args) printed a bare "ghostshell:"."""
    extra = ("--xml", "<x/>") if command == "run" else ()
    r = _run(command, "--vocabulary", "nope", "--out", str(tmp_path / "o"), *extra)
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith(f"ghostshell {command}: --vocabulary 'nope':"), r.stderr


@pytest.mark.parametrize("argv", [("run", "--xml", "<x/>"), ("robots", "list"), ("robots", "show", "coco"),
                                  ("prompt",), ("render", "RUN"), ("replay", "RUN")])
def test_a_robots_dir_that_does_not_exist_is_a_usage_error(argv: tuple[str, ...], tmp_path: Path) -> None:
    missing = tmp_path / "no-such-robots"
    args = [a if a != "RUN" else str(tmp_path) for a in argv]
    r = _run(*args, "--robots-dir", str(missing))
    assert r.returncode == 2, (r.returncode, r.stderr)
    last = r.stderr.strip().splitlines()[-1]
    assert "--robots-dir" in last and f"{missing}: no such folder" in last, r.stderr
    assert "Traceback" not in r.stderr


def test_the_board_refuses_a_robots_dir_that_does_not_exist(tmp_path: Path) -> None:
    r = _run("--link", "pty", "--robots-dir", str(tmp_path / "nope"), module="firmware_sim")
    assert r.returncode == 2 and f"{tmp_path / 'nope'}: no such folder" in r.stderr, r.stderr


def test_a_robots_dir_that_is_a_file_is_a_usage_error(tmp_path: Path) -> None:
    f = tmp_path / "robots.txt"
    f.write_text("x", encoding="utf-8")
    r = _run("robots", "list", "--robots-dir", str(f))
    assert r.returncode == 2 and f"{f} is not a folder" in r.stderr, r.stderr


def test_xml_file_dash_reads_the_program_from_stdin(tmp_path: Path) -> None:
    out = tmp_path / "run"
    r = _run("run", "--xml-file", "-", "--lockstep", "--no-live", "--out", str(out), stdin='<head_act action="nod"/>\n')
    assert r.returncode == 0, r.stderr[-2000:]
    calls = json.loads((out / "timeline.json").read_text())["calls"]
    assert [c["function"] for c in calls] == ["head_act"] and calls[0]["outcome"] == "done"


def test_xml_file_dash_with_nothing_on_stdin_is_a_usage_error(tmp_path: Path) -> None:
    r = _run("run", "--xml-file", "-", "--out", str(tmp_path / "run"), stdin="  \n")
    assert r.returncode == 2
    assert r.stderr.strip().splitlines()[-1].startswith("ghostshell run: --xml-file - (standard input) is empty"), r.stderr
    assert not (tmp_path / "run").exists()
