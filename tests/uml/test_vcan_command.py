"""``ghostshell vcan`` as a user runs it (issue 16, item 5), in one User-Mode Linux boot.

One boot runs a script in a fresh ``/tmp`` folder (shared without ``--keep``) that streams a line,
waits for a file this test creates once it has *seen* that line (so the output reached the terminal
while the command ran), checks the interfaces and ``tc``'s token bucket (``sch_tbf`` loaded), and
runs ``ghostshell vcan`` again inside: there the kernel has vcan, so it runs its command directly,
after creating an interface it lacks (deleted afterwards). The exit status comes back; the
temporary run folder is gone afterwards.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from host.tools.vcan.uml import uml_unavailable_reason

pytestmark = [pytest.mark.skipif(uml_unavailable_reason() is not None, reason=uml_unavailable_reason() or ""),
              pytest.mark.timeout(300)]

SCRIPT = r"""
set -e
echo "ready"
while [ ! -e "$1/go" ]; do sleep 0.05; done
ip -br link show vcan0 | grep -q UP
ip -br link show vcan1 | grep -q UP
tc qdisc replace dev vcan1 root tbf rate 16kbit burst 32 limit 160 && echo "tbf ok"
ghostshell vcan --ifaces vcan0 -- sh -c 'echo "inner: vcan0 there"'
ghostshell vcan --ifaces vcan7 -- sh -c 'ip -br link show vcan7 | grep -q UP && echo "inner: vcan7 created"'
if ip link show vcan7 2>/dev/null; then echo "vcan7 left behind"; exit 9; fi
exit 7
"""


def test_vcan_streams_shares_tmp_returns_the_status_and_cleans_up(tmp_path: Path) -> None:
    work = tmp_path / "work"  # under /tmp: the guest sees it because the command names it
    work.mkdir()
    script = work / "job.sh"
    script.write_text(SCRIPT)
    temp = tmp_path / "temp"  # ghostshell vcan's own temporary folder (TMPDIR): no run folder left in it
    temp.mkdir()
    env = dict(os.environ, TMPDIR=str(temp))
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])  # ghostshell inside
    proc = subprocess.Popen([sys.executable, "-m", "host", "vcan", "--", "sh", str(script), str(work)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    assert proc.stdout is not None
    first = proc.stdout.readline()
    assert first == "ready\n", first + (proc.stderr.read() if proc.stderr else "")
    (work / "go").touch()  # only now may the job go on: "ready" was streamed while it ran
    rest, err = proc.communicate(timeout=240)
    assert proc.returncode == 7, rest + err
    assert rest.splitlines() == ["tbf ok", "inner: vcan0 there", "inner: vcan7 created"], rest + err
    assert "sh exited 7" in err.splitlines()[-1], err
    assert sorted(p.name for p in temp.glob("uml_run_*")) == []  # the guest's files removed without any flag


def test_vcan_refuses_what_it_cannot_run() -> None:
    r = subprocess.run([sys.executable, "-m", "host", "vcan", "--", "no-such-command-anywhere"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 127 and r.stderr.strip() == "ghostshell vcan: no-such-command-anywhere: command not found"
