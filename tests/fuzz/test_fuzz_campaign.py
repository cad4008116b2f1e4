"""What a fuzz campaign relies on: ``--runs`` runs exactly N inputs in all with ``--jobs``, Ctrl-C stops a
run with its exact count, ``--minimise`` keeps the coverage in fewer inputs, a C corpus replays in one process."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from host.commands.fuzz import run_shares
from host.tools.fuzz.libfuzzer import parse_output

pytest.importorskip("atheris", reason="the fuzz extra is not installed (pip install -e '.[fuzz]')")

ROOT = Path(__file__).resolve().parents[2]


def _units(log: Path) -> int:
    """libFuzzer's exact count of one process (``-print_final_stats=1``)."""
    return sum(int(line.split()[-1]) for line in log.read_text().splitlines()
               if line.startswith("stat::number_of_executed_units:"))


@pytest.mark.parametrize(("runs", "jobs", "shares"), [(10, 3, [4, 3, 3]), (1_000_000, 2, [500_000, 500_000]),
                                                      (1, 2, [1]), (7, 1, [7])])
def test_run_shares_sum_exactly(runs: int, jobs: int, shares: list[int]) -> None:
    assert run_shares(runs, jobs) == shares and sum(shares) == runs


def test_runs_with_jobs_runs_exactly_that_many_inputs(tmp_path: Path) -> None:
    """libFuzzer's ``-fork`` checks ``-runs`` only when a child job ends (30 000 asked, 46 704 run): two
    processes with shares of ``-runs`` run exactly the count asked, and the total is printed."""
    proc = subprocess.run(
        [sys.executable, "-m", "host.cli", "fuzz", "serial-decoder", "--runs", "3001", "--jobs", "2", "--quiet",
         "--out", str(tmp_path / "out"), "--corpus", str(tmp_path / "corpus")],
        cwd=tmp_path, capture_output=True, text=True, timeout=300, check=False,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "serial-decoder: 3001 inputs run in all, 2 job(s)" in proc.stdout
    assert [_units(tmp_path / "out" / f"fuzz-job{k}.log") for k in (1, 2)] == [1501, 1500]
    assert parse_output((tmp_path / "out" / "fuzz-job1.log").read_text()).executions == 1501


def test_ctrl_c_stops_every_job_with_its_exact_count(tmp_path: Path) -> None:
    """SIGINT to ``ghostshell fuzz``: each libFuzzer process is stopped with SIGTERM and prints its count
    (atheris answers a SIGINT with a bare KeyboardInterrupt, no count); exit 130, the sum printed."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "host.cli", "fuzz", "serial-decoder", "--runs", "100000000", "--jobs", "2",
         "--out", str(tmp_path / "out"), "--corpus", str(tmp_path / "corpus")],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    assert proc.stdout is not None
    started: set[str] = set()
    for line in proc.stdout:  # both processes fuzzing: libFuzzer's signal handlers are installed
        if line.lstrip().startswith("[job") and "#" in line:
            started.add(line.split()[0])
        if len(started) == 2:
            break
    proc.send_signal(signal.SIGINT)
    rest = proc.stdout.read()
    assert proc.wait(timeout=120) == 130, rest
    total = sum(_units(tmp_path / "out" / f"fuzz-job{k}.log") for k in (1, 2))
    assert total > 0
    assert f"serial-decoder: interrupted after {total} inputs of 100000000, no crash" in rest


def test_parse_output_reads_the_exact_count_of_an_interrupted_run() -> None:
    log = (
        "#13985\tREDUCE cov: 27 ft: 89 corp: 24/381b lim: 80 exec/s: 3496 rss: 46Mb L: 42/42 MS: 2 ChangeBinInt-\n"
        "==19353== libFuzzer: run interrupted; exiting\n"
        "stat::number_of_executed_units: 15324\n"
        "stat::average_exec_per_sec:     3831\n"
        "stat::peak_rss_mb:              46\n"
    )
    st = parse_output(log)
    assert st.interrupted and st.executions == 15324 and st.exec_per_s == 3831 and not st.crashes


def test_c_replay_names_the_failing_input(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """A corpus replayed in one process still fails, naming the input the binary stopped at."""
    from firmware_sim.cfirmware import libfuzzer

    fake = tmp_path / "target"  # a libFuzzer binary's way: "Running: FILE", a non-zero exit on a bad input
    fake.write_text('#!/bin/sh\nfor f; do echo "Running: $f" >&2; case $f in *bad*) exit 1;; esac; done\n')
    fake.chmod(0o755)
    monkeypatch.setattr(libfuzzer, "binary", lambda kind: fake)
    good, bad = tmp_path / "good", tmp_path / "bad"
    libfuzzer.replay_files("fuzz-c-wire", "c-wire", [good])
    with pytest.raises(AssertionError, match=f"c-wire: input {bad}"):
        libfuzzer.replay_files("fuzz-c-wire", "c-wire", [good, bad, good])



@pytest.mark.parametrize("target", ["serial-decoder", "c-diff"])
def test_minimise_keeps_the_coverage_in_fewer_inputs(target: str, tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """``--minimise`` (libFuzzer ``-merge=1``) over the checked-in corpus and a campaign's corpus (here: the
    same inputs again) keeps at least the old corpus's edges in fewer files, and the result replaces
    the checked-in corpus. c-diff's ``__main__`` once handed libFuzzer its ``.py`` path as argv[0], which
    the merge's inner process cannot execute: it merged nothing."""
    import shutil

    import host.commands.fuzz as fuzz
    from host.tools.fuzz import TARGETS

    root = tmp_path / "seeds"
    shutil.copytree(ROOT / "tests" / "fuzz" / target / "corpus", root / target / "corpus")
    campaign = tmp_path / "campaign"
    shutil.copytree(ROOT / "tests" / "fuzz" / target / "corpus", campaign)
    old = subprocess.run([sys.executable, "-m", TARGETS[target].module, "-runs=0", str(campaign)],
                         capture_output=True, text=True, timeout=300, check=True, cwd=ROOT)
    old_stats = parse_output(old.stdout + old.stderr)
    monkeypatch.setattr(fuzz, "SEEDS_ROOT", root)
    before, after, stats = fuzz.minimise(target, [campaign], tmp_path / "work")
    kept = sorted((root / target / "corpus").iterdir())
    assert before == 2 * len(list(campaign.iterdir())) and after == len(kept) and 0 < after < before
    assert all(p.name.startswith("min-") for p in kept)
    assert old_stats.coverage > 0 and stats.coverage >= old_stats.coverage
