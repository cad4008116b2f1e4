"""Every command of docs/getting-started.md, run as written, in the page's order.

The page's fenced ``sh`` blocks are parsed; each line that is not blank or a comment is one command,
run with ``bash -c`` exactly as written (its trailing comment included) in a scratch copy of the
checkout's root: a folder whose entries are symlinks to the repository's top-level files and
folders, plus ``.venv`` linking to the venv this test runs in (``sys.prefix``), so
``.venv/bin/ghostshell`` is the installed console script and ``runs/`` lands in the scratch folder,
not in the checkout. Each command is one test case; later commands use what earlier ones wrote
(``replay runs/demo-task-26``), so the cases share the folder and run in order.

Two commands are not run here, because CI runs them itself and running them from a test would be
wrong: ``bash .ci/setup`` (it installed the environment this test runs in; re-running it would
reinstall the project into the venv under the running suite) and ``.venv/bin/python -m pytest``
(this test is part of that suite). For those the test checks that ``.ci/run`` runs each exactly as
the page writes it. Every command must exit 0 with no traceback on stderr; the commands in
:data:`CHECKS` also leave what the page says they leave.
"""

from __future__ import annotations

import importlib.metadata
import json
import re
import tomllib
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from support.cliproc import wait_until
from support.realtime_lock import realtime_part_done

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "getting-started.md"

#: commands CI runs itself (.ci/run), with the reason they do not run inside the test suite
RUN_BY_CI = {
    "bash .ci/setup": "installed the environment this suite runs in (.ci/run runs it first)",
    ".venv/bin/python -m pytest -n 3 --dist loadfile": "the test suite this test is part of (.ci/run runs it after setup)",
}


def page_commands() -> list[str]:
    """Every command line of the page's ``sh`` blocks, in order."""
    commands = []
    for block in re.findall(r"^```sh\n(.*?)^```", PAGE.read_text(encoding="utf-8"), re.S | re.M):
        for line in block.splitlines():
            if line.strip() and not line.lstrip().startswith("#"):
                assert not line.rstrip().endswith("\\"), f"one command per line: {line!r}"
                commands.append(line.rstrip())
    return commands


def realtime(command: str) -> bool:
    """A run on a realtime board (the CLI's default clock): under xdist it is marked realtime
    (tests/support/realtime_lock.py)."""
    return any(f"ghostshell {c}" in command for c in ("demo", "run", "chat")) and "--lockstep" not in command


def bare(command: str) -> str:
    """The command without its trailing comment."""
    return re.split(r"\s+#", command, maxsplit=1)[0].strip()


Result = subprocess.CompletedProcess[str]


def _summary(folder: str) -> Callable[[Path, Result], None]:
    def check(cwd: Path, r: Result) -> None:
        summary = json.loads((cwd / "runs" / folder / "summary.json").read_text(encoding="utf-8"))
        assert summary["outcome"] == "done", summary
        assert summary["outcomes"]["done"] > 0 and summary["outcomes"]["failed"] == 0, summary
    return check


def _demo(cwd: Path, r: Result) -> None:
    _summary("demo-task-26")(cwd, r)
    assert "demo task 26: done; 11 calls" in r.stdout, r.stdout
    video = cwd / "runs" / "demo-task-26" / "run.mp4"
    assert video.is_file() and video.stat().st_size > 10_000, "no run.mp4"


def _ls(cwd: Path, r: Result) -> None:
    for name in ("timeline.json", "timeline.png", "joints.png", "summary.json", "run.mcap", "run.mp4"):
        assert name in r.stdout.split(), r.stdout


def _decode(cwd: Path, r: Result) -> None:
    lines = r.stdout.splitlines()
    assert len(lines) == 3 and all(" SERVO_FRAME " in ln for ln in lines), r.stdout


def _can(cwd: Path, r: Result) -> None:
    _summary("task-26")(cwd, r)
    assert (cwd / "runs" / "task-26" / "host_frames.log").is_file(), "no candump log: not a CAN run"


def _replay(cwd: Path, r: Result) -> None:
    summary = json.loads((cwd / "runs" / "replay" / "summary.json").read_text(encoding="utf-8"))
    assert "base_end" in summary, summary
    assert "apart" in r.stdout, r.stdout


#: what a command must leave besides exit status 0 (keyed by the command without its comment)
CHECKS: dict[str, Callable[[Path, Result], None]] = {
    ".venv/bin/ghostshell demo": _demo,
    "ls runs/demo-task-26/": _ls,
    ".venv/bin/ghostshell log decode runs/demo-task-26/host_frames.jsonl --type SERVO_FRAME | head -n 3": _decode,
    """.venv/bin/ghostshell run --xml 'Hello!<head_act action="nod"/><wave/>' --lockstep""": _summary("program"),
    ".venv/bin/ghostshell run --task 26 --link can:slcan:pty --lockstep": _can,
    ".venv/bin/ghostshell replay runs/demo-task-26": _replay,
    ".venv/bin/ghostshell prompt --format xml | head -n 20": lambda cwd, r: (
        None if len(r.stdout.splitlines()) == 20 and "function tokens" in r.stdout else pytest.fail(r.stdout)),
    """.venv/bin/ghostshell dsbc '<a x="1"><b/><c/></a><d/>' '<a x="2"><c/></a>'""": lambda cwd, r: (
        None if "DSBC = 0.5625" in r.stdout else pytest.fail(r.stdout)),
    ".venv/bin/ghostshell robots list": lambda cwd, r: (
        None if re.search(r"^coco\s+12\s", r.stdout, re.M) else pytest.fail(r.stdout)),
}


TIMEOUT_S = 540


def _run(command: str, cwd: Path, tmp_path: Path) -> Result:
    return subprocess.run(["bash", "-c", command], cwd=cwd, capture_output=True, text=True, timeout=TIMEOUT_S,
                          stdin=subprocess.DEVNULL)


def _run_realtime(command: str, cwd: Path, tmp_path: Path) -> Result:
    """:func:`_run` for a command whose run is realtime: the run's ``summary.json`` is written after its
    board has stopped (:func:`host.run.runner.run_program`), and what the command does after that (the
    demo renders ``run.mp4``) needs no machine to itself, so from then on the other workers run their
    ordinary tests beside it (tests/support/realtime_lock.py). Output goes to files, read at the end."""
    before = set(cwd.glob("runs/*/summary.json"))
    out, err = tmp_path / "stdout", tmp_path / "stderr"
    deadline = time.monotonic() + TIMEOUT_S
    with open(out, "wb") as o, open(err, "wb") as e:
        proc = subprocess.Popen(["bash", "-c", command], cwd=cwd, stdout=o, stderr=e, stdin=subprocess.DEVNULL)
        try:
            wait_until(lambda: proc.poll() is not None or bool(set(cwd.glob("runs/*/summary.json")) - before),
                       "the run writes its summary.json", timeout=TIMEOUT_S)
            realtime_part_done()
            returncode = proc.wait(max(0.0, deadline - time.monotonic()))
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    return subprocess.CompletedProcess(proc.args, returncode, out.read_text(errors="replace"),
                                       err.read_text(errors="replace"))


@pytest.fixture(scope="module")
def checkout(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A scratch folder that looks like the checkout's root, with ``.venv`` the running venv."""
    venv = Path(sys.prefix)
    if not (venv / "bin" / "ghostshell").exists():
        pytest.fail(f"no ghostshell console script in {venv}/bin: run the tests from the venv .ci/setup makes")
    cwd = tmp_path_factory.mktemp("checkout")
    for entry in ROOT.iterdir():
        if entry.name not in {".venv", "runs", "site", ".git"}:
            (cwd / entry.name).symlink_to(entry)
    (cwd / ".venv").symlink_to(venv)
    return cwd


def test_the_page_has_the_commands_the_checks_name() -> None:
    commands = [bare(c) for c in page_commands()]
    assert commands[0] == "bash .ci/setup" and commands[1] == ".venv/bin/ghostshell demo", commands[:2]
    missing = [c for c in [*CHECKS, *RUN_BY_CI] if c not in commands]
    assert not missing, f"commands checked here but no longer on the page: {missing}"


@pytest.mark.parametrize("command", [c for c in page_commands() if bare(c) in RUN_BY_CI], ids=bare)
def test_ci_runs_the_commands_this_test_skips(command: str) -> None:
    ci_run = [ln.strip() for ln in (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()]
    assert bare(command) in ci_run, f"{bare(command)!r} ({RUN_BY_CI[bare(command)]}) is not a line of .ci/run"


def test_setup_already_ran() -> None:
    """What ``bash .ci/setup`` installs is here: the project and every extra it names."""
    setup = (ROOT / ".ci" / "setup").read_text(encoding="utf-8")
    extras = re.search(r"pip install -q -e '\.\[([a-z,]+)\]'", setup)
    assert extras, "no `pip install -e '.[...]'` line in .ci/setup"
    assert "docs" in extras[1].split(","), "the docs extra (mkdocs-material) is not installed by .ci/setup"
    optional = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["optional-dependencies"]
    missing = []
    for extra in extras[1].split(","):
        for requirement in optional[extra]:
            name = re.split(r"[<>=!~\[; ]", requirement, maxsplit=1)[0]
            try:
                importlib.metadata.version(name)
            except importlib.metadata.PackageNotFoundError:
                missing.append(f"{name} ({extra})")
    assert not missing, f"not installed, so .ci/setup did not run here: {missing}"


@pytest.mark.timeout(600)
@pytest.mark.parametrize("command", [pytest.param(c, marks=pytest.mark.realtime) if realtime(c) else c
                                     for c in page_commands() if bare(c) not in RUN_BY_CI],
                         ids=lambda c: bare(c)[:70])
def test_command_as_written(command: str, checkout: Path, tmp_path: Path) -> None:
    r = (_run_realtime if realtime(command) else _run)(command, checkout, tmp_path)
    why = f"{command}\n--- exit {r.returncode}\n--- stdout (tail)\n{r.stdout[-4000:]}\n--- stderr (tail)\n{r.stderr[-3000:]}"
    assert r.returncode == 0, why
    assert "Traceback" not in r.stderr, why
    check = CHECKS.get(bare(command))
    if check is not None:
        check(checkout, r)
