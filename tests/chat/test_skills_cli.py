"""Skills persist across separate ``ghostshell run --xml-file`` processes, as a new user would try it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

NAME = "morning routine ☀"


def ghostshell(*args: str, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "host", *args], capture_output=True, text=True, encoding="utf-8",
                          env=env, timeout=180)


def test_save_in_one_run_then_run_it_in_the_next(tmp_path: Path) -> None:
    lib = tmp_path / "lib" / "skills.json"
    env = {**os.environ, "GHOSTSHELL_SKILLS": str(lib)}  # the library the user never names on the command line
    files = {
        "first": '<head_act action="nod" duration="1"/>',
        "second": f'<SAVE name="{NAME}" description="nod then wave"><head_act action="nod" duration="1"/>'
                  '<wave times="1"/></SAVE>',
        "third": f'<RUN id="{NAME}"/>',
    }
    outs = {}
    for stem, program in files.items():
        (tmp_path / f"{stem}.xml").write_text(program, encoding="utf-8")
        outs[stem] = ghostshell("run", "--xml-file", str(tmp_path / f"{stem}.xml"), "--lockstep", "--no-live",
                                "--out", str(tmp_path / stem), env=env)
        assert outs[stem].returncode == 0, outs[stem].stderr + outs[stem].stdout
    assert f"skill {NAME!r} saved" in outs["second"].stdout
    calls = json.loads((tmp_path / "third" / "timeline.json").read_text(encoding="utf-8"))["calls"]
    ran = [(c["function"], c["outcome"]) for c in calls]
    assert ("head_act", "done") in ran and ("wave", "done") in ran, ran

    listed = ghostshell("skills", "list", env=env)
    assert listed.returncode == 0 and NAME in listed.stdout and "nod then wave" in listed.stdout
    shown = ghostshell("skills", "--skills", str(lib), "show", NAME, env=env)
    assert '<wave times="1"/>' in shown.stdout
    assert ghostshell("skills", "rm", NAME, env=env).returncode == 0
    missing = ghostshell("skills", "show", NAME, env=env)
    assert missing.returncode == 2 and "unknown skill" in missing.stderr  # bad input: the exit-code table
