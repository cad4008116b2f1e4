"""``ghostshell run --no-plots``: the JSON artefacts and frame logs without timeline.png / joints.png,
and without importing matplotlib (batch runs on a machine that only wants the data). The default
draws both (checked on the CLI by tests/cli/test_ctrl_c.py and tests/docs/test_getting_started.py)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

#: runs the CLI in a fresh interpreter and says whether matplotlib got imported
PROBE = ("import sys; from host.cli import main; rc = main(sys.argv[1:]); "
         "print('matplotlib imported:', 'matplotlib' in sys.modules); sys.exit(rc)")


def _run(out: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", PROBE, "run", "--xml", '<head_act action="nod"/>', "--lockstep",
                           "--out", str(out), *extra], capture_output=True, text=True, timeout=120)


def test_no_plots_writes_the_json_artefacts_only(tmp_path: Path) -> None:
    r = _run(tmp_path / "run", "--no-plots")
    assert r.returncode == 0, r.stderr
    out = tmp_path / "run"
    assert json.loads((out / "summary.json").read_text(encoding="utf-8"))["outcome"] == "done"
    assert (out / "timeline.json").is_file() and (out / "host_frames.jsonl").is_file()
    assert not (out / "timeline.png").exists() and not (out / "joints.png").exists()
    assert "matplotlib imported: False" in r.stdout, r.stdout
    assert "timeline.png" not in r.stdout.split("artefacts in", 1)[-1]  # the artefact line lists what exists

