"""``ghostshell fuzz``: coverage-guided fuzzing of the protocol, the board, the shell and the link client.

``ghostshell fuzz --list`` names the targets; ``ghostshell fuzz TARGET [--seconds N] [--corpus DIR]
[--jobs N]`` runs one under atheris/libFuzzer in a subprocess (libFuzzer owns its process and exits on
the first crash), seeded from ``tests/fuzz/TARGET/{corpus,regressions}`` when the source tree is
present, and prints executions, exec/s, coverage, resident memory (RSS at the first and last
progress line) and any crash with the path of its saved input.
Needs the ``fuzz`` extra (``pip install -e '.[fuzz]'``).

Memory: libFuzzer's ``-rss_limit_mb`` (``--rss-limit-mb``, default 1024 MB; every target runs under
100 MB) turns a process that keeps growing into a reported ``out-of-memory`` failure with the input
saved, where libFuzzer's own default (2048 MB) would leave a slow leak unnoticed much longer.
``-malloc_limit_mb`` is not passed: libFuzzer enforces it through sanitizer malloc hooks, which the
plain CPython + atheris build does not have (a 300 MB allocation under ``-malloc_limit_mb=256``
passes unreported), so it would only suggest a check that does not happen.
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from host.commands.errors import print_error
from host.commands.outarg import out_dir
from host.tools.fuzz import TARGETS
from host.tools.fuzz.libfuzzer import FuzzStats, parse_output

__all__ = ["configure", "main", "run_target", "seed_dirs"]

SEEDS_ROOT = Path(__file__).resolve().parents[2] / "tests" / "fuzz"
DEFAULT_RSS_LIMIT_MB = 1024


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("target", nargs="?", metavar="TARGET", help=f"one of: {', '.join(TARGETS)}")
    parser.add_argument("--list", action="store_true", help="list the targets and what each checks")
    parser.add_argument("--seconds", type=int, default=60, metavar="N", help="fuzz for N seconds (default 60)")
    parser.add_argument("--corpus", type=out_dir, default=None, metavar="DIR",
                        help="where new interesting inputs are kept (default fuzz-out/TARGET/corpus)")
    parser.add_argument("--jobs", type=int, default=1, metavar="N", help="parallel fuzzing processes (libFuzzer -fork)")
    parser.add_argument("--out", type=out_dir, default=None, metavar="DIR",
                        help="crash inputs and the full log (default fuzz-out/TARGET)")
    parser.add_argument("--max-len", type=int, default=4096, metavar="BYTES", help="longest input (default 4096)")
    parser.add_argument("--rss-limit-mb", type=int, default=DEFAULT_RSS_LIMIT_MB, metavar="MB",
                        help=f"fail when a fuzzing process's resident memory passes MB (default {DEFAULT_RSS_LIMIT_MB})")
    parser.add_argument("--no-seeds", action="store_true", help="do not read tests/fuzz/TARGET")
    parser.add_argument("--quiet", action="store_true",
                        help="no progress (libFuzzer's lines, or on a terminal a bar with exec/s, corpus and crashes)")


def seed_dirs(target: str) -> list[Path]:
    """The checked-in seed corpus and regression inputs of ``target`` (those that exist)."""
    return [d for d in (SEEDS_ROOT / target / "corpus", SEEDS_ROOT / target / "regressions") if d.is_dir()]


def run_target(
    target: str, seconds: int, corpus: Path, out: Path, jobs: int = 1, max_len: int = 4096, seeds: bool = True,
    echo: bool | Callable[[str], None] = False, rss_limit_mb: int = DEFAULT_RSS_LIMIT_MB,
    on_stats: Callable[[FuzzStats], None] | None = None,
) -> tuple[int, FuzzStats]:
    """Fuzz ``target`` for ``seconds``; returns (libFuzzer's exit code, parsed stats). Log: ``out/fuzz.log``.

    ``echo``: print libFuzzer's progress lines (True: ``print``; or a function taking each line);
    ``on_stats``: called with the totals so far after each progress line or crash.
    """
    t = TARGETS[target]
    corpus.mkdir(parents=True, exist_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    cmd = [
        sys.executable, "-m", t.module, str(corpus), *(str(d) for d in (seed_dirs(target) if seeds else [])),
        f"-max_total_time={seconds}", f"-artifact_prefix={out}/", f"-max_len={max_len}",
        "-timeout=20", f"-rss_limit_mb={rss_limit_mb}", "-print_final_stats=1",
    ]
    if jobs > 1:
        cmd.append(f"-fork={jobs}")
    log_path = out / "fuzz.log"
    with open(log_path, "w", encoding="utf-8") as log:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, errors="replace")
        assert proc.stdout is not None
        lines: list[str] = []
        say = echo if callable(echo) else (lambda text: print(text, flush=True)) if echo else None
        so_far = FuzzStats()
        for line in proc.stdout:
            log.write(line)
            lines.append(line)
            progress_line = line.startswith("#") and ("pulse" in line or "DONE" in line or ": cov:" in line)
            if say is not None and progress_line:
                say(f"  {line.rstrip()}")
            if on_stats is not None and (line.startswith("#") or "Test unit written" in line):
                now = parse_output(line)
                if now.executions:
                    so_far.executions, so_far.exec_per_s = now.executions, now.exec_per_s
                    so_far.corpus, so_far.coverage = now.corpus, now.coverage
                so_far.crashes += now.crashes
                on_stats(so_far)
        rc = proc.wait()
    stats = parse_output("".join(lines))
    if rc and not stats.crashes and not stats.traceback:
        stats.traceback = "".join(lines[-30:])
    return rc, stats


def main(args: argparse.Namespace) -> int:
    if args.list or not args.target:
        width = max(map(len, TARGETS))
        for name, t in TARGETS.items():
            print(f"{name:<{width}}  {t.help}")
        if not args.list:
            print("\nghostshell fuzz: name a TARGET (or --list)", file=sys.stderr)
            return 2
        return 0
    if args.target not in TARGETS:
        print_error("fuzz", f"unknown target {args.target!r}; choose one of {', '.join(TARGETS)}")
        return 2
    if importlib.util.find_spec("atheris") is None:
        print_error("fuzz", "atheris is not installed; pip install -e '.[fuzz]'")
        return 2
    for option, value in (("--seconds", args.seconds), ("--jobs", args.jobs), ("--rss-limit-mb", args.rss_limit_mb),
                          ("--max-len", args.max_len)):
        if value < 1:  # the one option that is wrong (all four were named for any of them)
            print_error("fuzz", f"{option} must be at least 1, got {value}")
            return 2
    out = Path(args.out or Path("fuzz-out") / args.target)
    corpus = Path(args.corpus) if args.corpus else out / "corpus"
    seeds = [] if args.no_seeds else seed_dirs(args.target)
    for what, d in (("--corpus", corpus), ("--out", out)):
        try:
            d.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            print_error("fuzz", f"{what}: cannot create {d}: {e.strerror or e}")
            return 2
    print(f"fuzzing {args.target} for {args.seconds} s ({args.jobs} job(s)); corpus {corpus}"
          + (f", seeds {', '.join(map(str, seeds))}" if seeds else ""), flush=True)
    from host.progress import bar

    with bar(f"fuzzing {args.target}", args.seconds, quiet=args.quiet, fields=("exec/s", "corpus", "cov", "crashes")
             ) as shown:
        started = time.monotonic()

        def stats(s: FuzzStats) -> None:
            shown.update(completed=min(args.seconds, time.monotonic() - started), **{
                "exec/s": s.exec_per_s, "corpus": s.corpus, "cov": s.coverage, "crashes": len(s.crashes)})

        rc, st = run_target(args.target, args.seconds, corpus, out, args.jobs, args.max_len, not args.no_seeds,
                            echo=False if args.quiet or shown.shown else True, rss_limit_mb=args.rss_limit_mb,
                            on_stats=stats if shown.shown else None)
    print(f"{args.target}: {st.summary()}")
    if st.crashes or rc:
        if st.traceback:
            print(st.traceback)
        for c in st.crashes:
            print(f"crash input saved to {c}")
            print(f"  replay: {sys.executable} -m {TARGETS[args.target].module} {c}")
            print(f"  keep it: cp {c} tests/fuzz/{args.target}/regressions/")
        print(f"{args.target}: FAILED (libFuzzer exit {rc}); full log {out / 'fuzz.log'}")
        return 1
    print(f"{args.target}: no crash; full log {out / 'fuzz.log'}")
    return 0
