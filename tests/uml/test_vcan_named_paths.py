"""``ghostshell vcan`` shares the ``/tmp`` paths a command names, also inside a ``bash -c`` script (issue 45, item 2).

A new user ran ``ghostshell vcan -- bash -c "candump ... > /tmp/x/cap.log & ...; ghostshell run ... --out
/tmp/x/run"``: only whole arguments were looked at, so neither path was shared with the User-Mode
Linux guest (whose ``/tmp`` is a private tmpfs); the run said "artefacts in /tmp/x/run", exit 0,
and nothing appeared outside. An ``--out`` whose parent did not exist outside was lost the same way.
Now every absolute path inside an argument counts; the nearest folder of it that exists here is
shared, and a new ``/tmp/NAME`` is copied out when the command ends. One boot.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

from host.commands.vcan import _guest_only_paths, _tmp_paths
from host.tools.vcan.uml import REPO_ROOT, uml_unavailable_reason


def test_paths_inside_a_script_are_found(tmp_path: Path) -> None:
    (tmp_path / "x").mkdir()
    new = Path("/tmp") / f"gs-vcan-none-{uuid.uuid4().hex[:8]}"
    script = (f"candump -L vcan0 > {tmp_path}/x/cap.log & ghostshell run --out={tmp_path}/x/run/deep; "
              f"cp a {new}/run/f; cat /proc/net/can/stats")
    shared, copied = _tmp_paths(["bash", "-c", script, "--out", f"{tmp_path}/y/z"], Path("/"))
    assert shared == [tmp_path, tmp_path / "x"] and copied == [new]
    assert _guest_only_paths(["sh", "-c", "echo > /dev/shm/q; cat /proc/cpuinfo /run/x"], Path("/")) == ["/dev/shm/q",
                                                                                                          "/run/x"]


@pytest.mark.skipif(uml_unavailable_reason() is not None, reason=uml_unavailable_reason() or "")
@pytest.mark.timeout(240)
def test_a_bash_c_script_writes_where_it_says(tmp_path: Path) -> None:
    shared = tmp_path / "x"  # exists outside: shared while the command runs
    shared.mkdir()
    new = Path("/tmp") / f"gs-vcan-{uuid.uuid4().hex[:12]}"  # does not: copied out at the end
    script = (f"set -e; echo cap > {shared}/cap.log; mkdir -p {shared}/run/deeper; echo d > {shared}/run/deeper/f; "
              f"mkdir -p {new}/run; echo r > {new}/run/f; echo lost > /dev/shm/q")
    try:
        r = subprocess.run([sys.executable, "-m", "host", "vcan", "--ifaces", "vcan0", "--", "bash", "-c", script],
                           capture_output=True, text=True, timeout=200, cwd=REPO_ROOT)  # cwd outside /tmp
        assert r.returncode == 0, r.stdout + r.stderr
        assert (shared / "cap.log").read_text() == "cap\n" and (shared / "run/deeper/f").read_text() == "d\n"
        assert (new / "run/f").read_text() == "r\n"
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("ghostshell vcan: warning: /dev/shm/q is the User-Mode Linux "
                                                       "guest's own"), r.stderr
    finally:
        shutil.rmtree(new, ignore_errors=True)
