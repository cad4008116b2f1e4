"""The User-Mode Linux harness itself: exit status, captured output, environment, interfaces,
private /tmp, job timeout; module resolution. Two short boots (~2 s each)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from support.uml import (
    BASE_MODULES,
    UmlError,
    module_paths,
    run_in_uml,
    socketcan_skip_reason,
    uml_modules_dir,
    uml_unavailable_reason,
)

needs_uml = pytest.mark.skipif(uml_unavailable_reason() is not None, reason=uml_unavailable_reason() or "")

SCRIPT = r"""
set -e
echo "out:$GS_MARK"
echo "err:$GS_MARK" >&2
cat /sys/class/net/vcan0/mtu /sys/class/net/vcan1/mtu /sys/class/net/vcan0/operstate
test -e /dev/ptmx && test -d /dev/pts
touch /tmp/gs-private-probe
ls "$RUN_DIR/job.json"
exit 3
"""


@needs_uml
def test_job_status_output_env_and_interfaces(tmp_path: Path) -> None:
    result = run_in_uml(
        ["sh", "-c", SCRIPT.replace("$RUN_DIR", str(tmp_path))],
        run_dir=tmp_path,
        env={"PATH": "/usr/sbin:/usr/bin:/sbin:/bin", "GS_MARK": "xyz"},
        vcans=("vcan0", "vcan1"),
        timeout=60,
    )
    assert result.returncode == 3, result.describe()
    assert result.stdout.split() == ["out:xyz", "72", "72", "unknown", f"{tmp_path}/job.json"]
    assert result.stderr.strip() == "err:xyz"
    assert "vcan: Virtual CAN interface driver" in result.console
    assert not Path("/tmp/gs-private-probe").exists()  # the guest's /tmp is its own
    assert json.loads((tmp_path / "job.json").read_text())["vcans"] == ["vcan0", "vcan1"]


@needs_uml
def test_job_killed_at_its_timeout_keeps_its_output(tmp_path: Path) -> None:
    result = run_in_uml(["sh", "-c", "echo started; exec sleep 600"], run_dir=tmp_path, timeout=2, fd=False)
    assert result.returncode == 124, result.describe()
    assert result.stdout == "started\n"
    assert "timeout" in result.stderr
    assert result.seconds < 60


@needs_uml
def test_modules_resolve_with_dependencies_first() -> None:
    modules = uml_modules_dir()
    assert modules is not None
    names = [p.name for p in module_paths([*BASE_MODULES, "sch_tbf"], modules)]
    assert names.index("can.ko") < names.index("can-raw.ko")
    assert names.index("can-dev.ko") < names.index("vcan.ko")
    assert "sch_tbf.ko" in names and all((modules / "kernel").exists() for _ in names)
    with pytest.raises(UmlError, match="no-such-module"):
        module_paths(["no-such-module"], modules)


def test_skip_reason_names_what_is_missing(monkeypatch: pytest.MonkeyPatch) -> None:
    import support.uml as uml

    monkeypatch.setattr(uml, "UML_KERNEL", Path("/nonexistent/linux.uml"))
    monkeypatch.setattr(uml, "native_vcan", lambda name="vcan0": False)
    reason = socketcan_skip_reason()
    assert reason is not None and "vcan0" in reason and "/nonexistent/linux.uml" in reason


def _leftover_run_dirs(root: Path) -> list[str]:
    return sorted(p.name for p in root.glob("uml_run_*"))


@needs_uml
def test_command_line_removes_its_temporary_run_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    import tempfile

    from host.cli import main

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # mkdtemp's folder: only this test's files there
    assert main(["vcan", "--uml", "--classic", "--timeout", "30", "--", "sh", "-c", "echo hi; exit 3"]) == 3
    out, err = capsys.readouterr()
    assert out == "hi\n" and "sh exited 3" in err
    assert _leftover_run_dirs(tmp_path) == []


def test_command_line_removes_its_temporary_run_dir_on_failure(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    import tempfile

    import support.uml as uml
    from host.cli import main

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.setattr(uml, "UML_KERNEL", Path("/nonexistent/linux.uml"))  # UML cannot start
    assert main(["vcan", "--uml", "--", "true"]) == 125
    err = capsys.readouterr().err
    assert "/nonexistent/linux.uml" in err and len(err.strip().splitlines()) == 1
    assert _leftover_run_dirs(tmp_path) == []
    kept = tmp_path / "kept"
    kept.mkdir()
    assert main(["vcan", "--uml", "--run-dir", str(kept), "--", "true"]) == 125
    assert kept.is_dir()  # a folder the user named is the user's
