"""The fuzz targets: replay every seed and regression input, run each target briefly under libFuzzer."""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

from host.tools.fuzz import TARGETS
from host.tools.fuzz.libfuzzer import parse_output

atheris = pytest.importorskip("atheris", reason="the fuzz extra is not installed (pip install -e '.[fuzz]')")

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent


def _inputs(target: str) -> list[Path]:
    return sorted(p for sub in ("corpus", "regressions") for p in (HERE / target / sub).glob("*") if p.is_file())


@pytest.mark.parametrize("target", list(TARGETS))
def test_corpus_and_regressions_replay(target: str) -> None:
    """Every checked-in input (seeds from real runs' frame logs, the minimised campaign corpus, and every
    crash ever found) passes. A C target replays its whole corpus in one process (``replay``)."""
    files = _inputs(target)
    assert files, f"tests/fuzz/{target} has no inputs"
    module = importlib.import_module(TARGETS[target].module)
    if hasattr(module, "replay"):
        module.replay(files)
        return
    one_input = module.load(False)
    for p in files:
        one_input(p.read_bytes())


def test_regressions_fail_without_the_fix() -> None:
    """The partial-camera-image regression input really breaks an invariant when the fix is undone."""
    from host.tools.fuzz.link_receive import load
    from host.link.camera import CameraAssembler

    fixed = CameraAssembler.on_chunk

    def old_on_chunk(self: CameraAssembler, msg) -> tuple[int, bytes] | None:  # type: ignore[no-untyped-def]
        parts = self.parts.get(msg.request_id)
        seq = self.seqs.get(msg.request_id)
        if parts is None or seq is None:
            return None
        parts[msg.index] = msg.data
        if len(parts) >= msg.total:
            return seq, b"".join(parts[i] for i in range(msg.total) if i in parts)
        return None

    one_input = load(False)
    data = (HERE / "session" / "regressions" / "partial-camera-image").read_bytes()
    CameraAssembler.on_chunk = old_on_chunk  # type: ignore[method-assign]
    try:
        with pytest.raises(AssertionError, match="partial image"):
            one_input(data)
    finally:
        CameraAssembler.on_chunk = fixed  # type: ignore[method-assign]
    one_input(data)


@pytest.mark.parametrize("target", list(TARGETS))
def test_cli_fuzzes_each_target_briefly(target: str, tmp_path: Path) -> None:
    """``ghostshell fuzz TARGET --seconds 1`` (the least it takes) runs libFuzzer, finds no crash and reports its
    numbers (the seconds are libFuzzer's ``-max_total_time``, all CPU: 11 targets at 2 s were 22 of the file's ~32 s)."""
    proc = subprocess.run(
        [sys.executable, "-m", "host.cli", "fuzz", target, "--seconds", "1", "--out", str(tmp_path / "out"),
         "--corpus", str(tmp_path / "corpus")],
        cwd=tmp_path, capture_output=True, text=True, timeout=120, check=False,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert f"{target}: no crash" in proc.stdout
    stats = parse_output((tmp_path / "out" / "fuzz.log").read_text())
    assert stats.executions > 0 and stats.coverage > 0
    assert f"{stats.executions} executions" in proc.stdout
    assert stats.peak_rss_mb is not None and stats.peak_rss_mb < 1024  # under the default --rss-limit-mb
    assert f"RSS {stats.rss_start_mb} -> {stats.rss_end_mb} MB" in proc.stdout


def test_cli_rss_limit_reaches_libfuzzer(tmp_path: Path) -> None:
    """A process above ``--rss-limit-mb`` is libFuzzer's out-of-memory failure (the target itself takes ~45 MB)."""
    proc = subprocess.run(
        [sys.executable, "-m", "host.cli", "fuzz", "serial-decoder", "--seconds", "30", "--rss-limit-mb", "10",
         "--out", str(tmp_path / "out"), "--corpus", str(tmp_path / "corpus")],
        cwd=tmp_path, capture_output=True, text=True, timeout=120, check=False,
    )
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "serial-decoder: FAILED" in proc.stdout
    assert "out-of-memory" in (tmp_path / "out" / "fuzz.log").read_text()


def test_cli_lists_targets() -> None:
    proc = subprocess.run([sys.executable, "-m", "host.cli", "fuzz", "--list"], capture_output=True, text=True,
                          timeout=60, check=True)
    assert [line.split()[0] for line in proc.stdout.splitlines()] == list(TARGETS)


def test_parse_output_reports_a_crash() -> None:
    log = (
        "#2\tINITED cov: 25 ft: 25 corp: 1/1b exec/s: 0 rss: 84Mb\n"
        " === Uncaught Python exception: ===\nAssertionError: ESTOP did not win\nTraceback (most recent call last):\n"
        '  File "x.py", line 1, in one_input\n'
        "==1== ERROR: libFuzzer: fuzz target exited\n"
        "artifact_prefix='/tmp/o/'; Test unit written to /tmp/o/crash-abc123\n"
        "Done 7 runs in 1 second(s)\n"
    )
    st = parse_output(log)
    assert st.crashes == ["/tmp/o/crash-abc123"]
    assert "ESTOP did not win" in st.traceback
    assert st.executions == 7 and st.seconds == 1 and st.coverage == 25


def test_parse_output_reports_resident_memory() -> None:
    log = (
        "INFO: seed corpus: files: 13 min: 1469b max: 1481b total: 19142b rss: 87Mb\n"
        "#14\tINITED cov: 304 ft: 521 corp: 9/13251b exec/s: 0 rss: 88Mb\n"
        "#512\tpulse  cov: 355 ft: 1661 corp: 115/129Kb lim: 1481 exec/s: 21 rss: 95Mb\n"
        "#1434\tDONE   cov: 371 ft: 1911 corp: 186/195Kb lim: 1481 exec/s: 23 rss: 93Mb\n"
        "Done 1434 runs in 61 second(s)\n"
        "stat::peak_rss_mb:              98\n"
    )
    st = parse_output(log)
    assert (st.rss_start_mb, st.rss_end_mb, st.peak_rss_mb) == (88, 93, 98)
    assert st.summary().endswith("corpus 186 inputs, RSS 88 -> 93 MB (peak 98 MB)")
    assert "RSS" not in parse_output("#17533: cov: 246 ft: 262 corp: 79 exec/s 762\n").summary()  # -fork lines
