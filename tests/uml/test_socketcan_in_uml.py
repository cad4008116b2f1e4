"""The SocketCAN commands of docs/guides/can.md, run exactly as written (``ghostshell vcan -- ...``).

Where this kernel has no ``vcan0``, ``tests/socketcan`` runs here: the CAN guide's
``ghostshell vcan -- .venv/bin/python -m pytest tests/socketcan -x -q`` boots User-Mode Linux
once and runs the whole directory inside (python start-up over hostfs is the cost, not the boot;
~1-2 min, three paper-task runs included), then ``ghostshell vcan -- ghostshell run --task 26
--link 'can:socketcan:vcan0?node=2' ...`` runs a task over SocketCAN. Each command is read from the
guide's code blocks (``.venv/bin/python`` is this interpreter, ``ghostshell`` is ``python -m
host``: the checkout's venv may live elsewhere); each must exit 0, and the test suite's summary
must show nothing failed, errored or skipped (inside UML every prerequisite exists, so a skip there
is a bug, not noise).
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from support.uml import REPO_ROOT, socketcan_skip_reason

pytestmark = pytest.mark.skipif(socketcan_skip_reason() is not None, reason=socketcan_skip_reason() or "")

#: where the commands are written: the CAN guide of the docs site (the README links to it)
SOURCES = (REPO_ROOT / "docs" / "guides" / "can.md",)


def readme_vcan_commands() -> list[str]:
    """Every line of the guide's ``sh`` code blocks that starts with ``ghostshell vcan``."""
    commands = []
    text = "\n".join(p.read_text(encoding="utf-8") for p in SOURCES if p.is_file())
    for block in re.findall(r"```sh\n(.*?)```", text, re.S):
        for line in block.splitlines():
            if line.startswith("ghostshell vcan ") and "COMMAND" not in line:
                commands.append(line.split("  #", 1)[0].strip())
    return list(dict.fromkeys(commands))  # a command the guide shows twice runs once


def _argv(command: str) -> list[str]:
    argv = shlex.split(command)
    assert argv[:2] == ["ghostshell", "vcan"], command
    argv = [sys.executable, "-m", "host", *argv[1:]]
    return [sys.executable if a == ".venv/bin/python" else a for a in argv]


def test_the_readme_names_its_socketcan_commands() -> None:
    commands = readme_vcan_commands()
    assert any("-m pytest tests/socketcan" in c for c in commands), commands
    assert any("can:socketcan:vcan0" in c and "ghostshell run" in c for c in commands), commands


@pytest.mark.slow
@pytest.mark.timeout(1200)
# ``realtime`` (run at its worker's own nice value, one realtime test at a time; in background mode the other
# workers go on at nice 19): tests/socketcan/test_link_over_socketcan.py drives a realtime board, and the guest
# runs host, board and plant on one CPU. The lockstep task runs of tests/socketcan no longer need it: their ISO-TP
# timers count board time (protocol/can/isotp_link.py; before, at nice 19 beside a realtime test the guest was
# starved past the 200 ms wall-clock timers in CI: 2026-12-07, task 17, a transfer given up, 1 decode error,
# 2 gaps), and the C board's boot waits out a plant slow to answer (a dead servo 1 was reported at load 10).
@pytest.mark.realtime
@pytest.mark.parametrize("command", readme_vcan_commands())
def test_readme_socketcan_command_as_written(command: str, tmp_path: Path) -> None:
    env = dict(os.environ, GHOSTSHELL_IN_UML="1")
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])  # its ghostshell inside
    r = subprocess.run(_argv(command), cwd=REPO_ROOT, capture_output=True, text=True, timeout=1100, env=env)
    why = f"{command}\n--- exit {r.returncode}\n--- stdout (tail)\n{r.stdout[-6000:]}\n--- stderr (tail)\n{r.stderr[-3000:]}"
    assert r.returncode == 0, why
    if "pytest" in command:
        summary = [ln for ln in r.stdout.splitlines() if re.search(r"\d+ passed", ln)]
        assert summary, why
        assert not re.search(r"failed|error|skipped|deselected", summary[-1]), why
    else:
        assert re.search(r": done; 11 calls", r.stdout), why  # task 26's 11 calls, every one done
