"""Fuzz throughput: each atheris target run by ``ghostshell fuzz``'s own code path for S seconds (prints numbers, asserts nothing).

For each target: executions and exec/s as libFuzzer reports them (its exec/s counts from process
start, so the target's imports and atheris' instrumentation are inside it), executions per CPU
second of the fuzzing process (``RUSAGE_CHILDREN``: on a shared machine the less disturbed number),
n (runs of S seconds) and the 1-minute load average before and after each run. Seeds are the
checked-in ``tests/fuzz/TARGET/{corpus,regressions}``; the corpus and logs go to a temporary folder.
Targets needing more than Python (``c-wire``, ``c-diff``: clang) are left out unless named.

    python bench/bench_fuzz.py [--seconds 30] [--runs 1] [TARGET ...]

Default targets: serial-decoder, can-decoder, board, shell, session. Exit 0, or 1 if a run crashed.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from host.commands.fuzz import run_target  # noqa: E402
from host.tools.fuzz import TARGETS  # noqa: E402

DEFAULT_TARGETS = ("serial-decoder", "can-decoder", "board", "shell", "session")


def _load() -> float:
    return os.getloadavg()[0]


def _child_cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def bench(target: str, seconds: int, run: int) -> tuple[int, dict[str, float | int | str]]:
    """One ``seconds`` run of ``target``; (libFuzzer's exit code, the row)."""
    with tempfile.TemporaryDirectory(prefix=f"bench-fuzz-{target}-") as tmp:
        load_before, cpu_before = _load(), _child_cpu_s()
        rc, st = run_target(target, seconds, Path(tmp) / "corpus", Path(tmp) / "out")
        cpu = _child_cpu_s() - cpu_before
        return rc, {
            "target": target, "run": run, "executions": st.executions, "exec/s": st.exec_per_s,
            "exec/cpu-s": round(st.executions / cpu) if cpu > 0 else 0, "cpu_s": round(cpu, 1),
            "load_before": load_before, "load_after": _load(), "crashes": len(st.crashes),
        }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("targets", nargs="*", metavar="TARGET", help=f"default: {' '.join(DEFAULT_TARGETS)}")
    ap.add_argument("--seconds", type=int, default=30, metavar="S", help="fuzzing time per run (default 30)")
    ap.add_argument("--runs", type=int, default=1, metavar="N", help="runs per target (default 1)")
    args = ap.parse_args(argv)
    targets = args.targets or list(DEFAULT_TARGETS)
    unknown = [t for t in targets if t not in TARGETS]
    if unknown or args.seconds < 1 or args.runs < 1:
        print(f"bench_fuzz: unknown target(s) {unknown}; choose from {', '.join(TARGETS)}" if unknown
              else "bench_fuzz: --seconds and --runs must be at least 1", file=sys.stderr)
        return 2
    print(f"fuzz throughput: ghostshell fuzz TARGET --seconds {args.seconds}, 1 job, n = {args.runs} per target, "
          f"{os.cpu_count()} CPUs")
    print(f"{'target':<15} {'run':>3} {'executions':>10} {'exec/s':>7} {'exec/cpu-s':>10} {'load before/after':>18}")
    failed = False
    for target in targets:
        for run in range(1, args.runs + 1):
            rc, row = bench(target, args.seconds, run)
            failed |= bool(rc or row["crashes"])
            print(f"{target:<15} {run:>3} {row['executions']:>10} {row['exec/s']:>7} {row['exec/cpu-s']:>10} "
                  f"{row['load_before']:>8.2f} / {row['load_after']:<8.2f}"
                  + (f"  FAILED (libFuzzer exit {rc}, {row['crashes']} crash(es))" if rc or row["crashes"] else ""),
                  flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
