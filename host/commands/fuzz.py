"""``ghostshell fuzz``: coverage-guided fuzzing of the protocol, the board, the shell and the link client.

``ghostshell fuzz --list`` names the targets; ``ghostshell fuzz TARGET [--seconds N] [--runs N] [--corpus DIR]
[--jobs N]`` runs one under atheris/libFuzzer in a subprocess (libFuzzer owns its process and exits on
the first crash), seeded from ``tests/fuzz/TARGET/{corpus,regressions}`` when the source tree is
present, and prints executions, exec/s, coverage, resident memory (RSS at the first and last
progress line) and any crash with the path of its saved input.
Needs the ``fuzz`` extra (``pip install -e '.[fuzz]'``).

Jobs: ``--jobs N`` alone runs libFuzzer's ``-fork=N`` (one parent starting child jobs of growing
length, up to 300 s each). ``--runs N`` is an input count: with one job libFuzzer's ``-runs=N``; with
``-fork`` libFuzzer checks ``-runs`` only when a child job ends (and removes it from the children), so
the total overshoots by up to the jobs in flight (30 000 asked, 46 704 run in a probe). So
``--runs`` with ``--jobs N`` starts N independent libFuzzer processes instead, each with its share of
``-runs`` (the shares sum to exactly N), all on the one ``--corpus`` directory (libFuzzer's
``-reload``, once a second, gives each the others' new inputs): the total run is exactly N, the sum of
each process's ``Done K runs``, printed at the end. Each process's output goes to
``OUT/fuzz-jobK.log``; ``OUT/fuzz.log`` holds them all, each line tagged ``[jobK]``. A crash in one
process stops the others.

``--minimise`` fuzzes nothing: it merges (libFuzzer ``-merge=1 -use_counters=0``) the checked-in corpus
``tests/fuzz/TARGET/corpus`` and ``--corpus`` into the smallest set keeping every coverage edge (not
every hit-count feature: the suite replays the corpus, and the board's 1 858 campaign inputs kept 272
files by features, 47 by edges, the same 366 edges), replaces the checked-in corpus with it (files named
``min-<sha1>``) and prints the count before and after and the minimised corpus's coverage (a
``-runs=0`` replay: libFuzzer's ``cov``/``ft``).

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
import queue
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

from host.commands.errors import print_error
from host.commands.outarg import out_dir
from host.tools.fuzz import TARGETS
from host.tools.fuzz.libfuzzer import FuzzStats, parse_output

__all__ = ["configure", "main", "minimise", "run_shares", "run_target", "seed_dirs"]

SEEDS_ROOT = Path(__file__).resolve().parents[2] / "tests" / "fuzz"
DEFAULT_RSS_LIMIT_MB = 1024
INTERRUPT_WAIT_S = 30.0  # after Ctrl-C, how long the libFuzzer processes get to print their final stats


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("target", nargs="?", metavar="TARGET", help=f"one of: {', '.join(TARGETS)}")
    parser.add_argument("--list", action="store_true", help="list the targets and what each checks")
    parser.add_argument("--seconds", type=int, default=None, metavar="N",
                        help="fuzz for N seconds (default 60, or no time limit with --runs)")
    parser.add_argument("--runs", type=int, default=None, metavar="N",
                        help="stop after N inputs in all (with --jobs: N split exactly among the jobs)")
    parser.add_argument("--corpus", type=out_dir, default=None, metavar="DIR",
                        help="where new interesting inputs are kept (default fuzz-out/TARGET/corpus)")
    parser.add_argument("--jobs", type=int, default=1, metavar="N",
                        help="parallel fuzzing processes (libFuzzer -fork; with --runs, N processes on one corpus)")
    parser.add_argument("--out", type=out_dir, default=None, metavar="DIR",
                        help="crash inputs and the full log (default fuzz-out/TARGET)")
    parser.add_argument("--max-len", type=int, default=4096, metavar="BYTES", help="longest input (default 4096)")
    parser.add_argument("--rss-limit-mb", type=int, default=DEFAULT_RSS_LIMIT_MB, metavar="MB",
                        help=f"fail when a fuzzing process's resident memory passes MB (default {DEFAULT_RSS_LIMIT_MB})")
    parser.add_argument("--no-seeds", action="store_true", help="do not read tests/fuzz/TARGET")
    parser.add_argument("--minimise", action="store_true",
                        help="fuzz nothing: merge tests/fuzz/TARGET/corpus and --corpus into the smallest set with "
                             "the same edges (libFuzzer -merge=1 -use_counters=0) and make it the checked-in corpus")
    parser.add_argument("--quiet", action="store_true",
                        help="no progress (libFuzzer's lines, or on a terminal a bar with exec/s, corpus and crashes)")


def seed_dirs(target: str) -> list[Path]:
    """The checked-in seed corpus and regression inputs of ``target`` (those that exist)."""
    return [d for d in (SEEDS_ROOT / target / "corpus", SEEDS_ROOT / target / "regressions") if d.is_dir()]


def run_shares(runs: int, jobs: int) -> list[int]:
    """``runs`` inputs split among at most ``jobs`` processes: shares summing to exactly ``runs``
    (the first ones larger by one; no empty share)."""
    q, r = divmod(runs, jobs)
    return [n for n in (q + (k < r) for k in range(jobs)) if n > 0]


def _combine(per_job: list[FuzzStats]) -> FuzzStats:
    """One run's totals from its processes' stats: executions and exec/s summed, coverage, features,
    corpus and memory the largest of any process (each process sees the shared corpus), crashes all."""
    if len(per_job) == 1:
        return per_job[0]
    out = FuzzStats()
    out.executions = sum(s.executions for s in per_job)
    out.exec_per_s = sum(s.exec_per_s for s in per_job)
    secs = [s.seconds for s in per_job if s.seconds is not None]
    out.seconds = max(secs) if secs else None
    out.coverage = max(s.coverage for s in per_job)
    out.features = max(s.features for s in per_job)
    out.corpus = max(s.corpus for s in per_job)
    for name in ("rss_start_mb", "rss_end_mb", "peak_rss_mb"):
        vals = [getattr(s, name) for s in per_job if getattr(s, name) is not None]
        setattr(out, name, max(vals) if vals else None)
    out.crashes = [c for s in per_job for c in s.crashes]
    out.traceback = next((s.traceback for s in per_job if s.traceback), "")
    return out


def _is_progress(line: str) -> bool:
    return line.startswith("#") and ("pulse" in line or "DONE" in line or ": cov:" in line)


def run_target(
    target: str, seconds: int | None, corpus: Path, out: Path, jobs: int = 1, max_len: int = 4096, seeds: bool = True,
    echo: bool | Callable[[str], None] = False, rss_limit_mb: int = DEFAULT_RSS_LIMIT_MB,
    on_stats: Callable[[FuzzStats], None] | None = None, runs: int | None = None,
) -> tuple[int, FuzzStats]:
    """Fuzz ``target`` for ``seconds`` and/or ``runs`` inputs (at least one of them); returns (libFuzzer's
    exit code, the first non-zero one of any process, and the parsed stats). Log: ``out/fuzz.log``.

    ``jobs`` > 1: libFuzzer's ``-fork`` without ``runs``; with ``runs``, ``jobs`` processes on ``corpus``
    whose ``-runs`` sum to ``runs`` (module docstring), each logged to ``out/fuzz-jobK.log`` too.
    ``echo``: print libFuzzer's progress lines (True: ``print``; or a function taking each line);
    ``on_stats``: called with the totals so far after each progress line or crash.
    Ctrl-C (SIGINT): each process is asked to stop (libFuzzer prints its exact count), the stats say
    ``interrupted`` and the exit code is 130. Raises ``ValueError`` when neither ``seconds`` nor ``runs`` is given.
    """
    if seconds is None and runs is None:
        raise ValueError("give seconds or runs")
    t = TARGETS[target]
    corpus.mkdir(parents=True, exist_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    base = [
        sys.executable, "-m", t.module, str(corpus), *(str(d) for d in (seed_dirs(target) if seeds else [])),
        f"-artifact_prefix={out}/", f"-max_len={max_len}",
        "-timeout=20", f"-rss_limit_mb={rss_limit_mb}", "-print_final_stats=1",
    ]
    if seconds is not None:
        base.append(f"-max_total_time={seconds}")
    if runs is None:
        cmds = [base + ([f"-fork={jobs}"] if jobs > 1 else [])]
    else:
        cmds = [base + [f"-runs={n}"] for n in run_shares(runs, jobs)]
    say = echo if callable(echo) else (lambda text: print(text, flush=True)) if echo else None
    many = len(cmds) > 1
    # each in its own process group: a terminal's Ctrl-C reaches only this process, which stops them with
    # SIGTERM (libFuzzer then prints its final stats; atheris turns a SIGINT into a bare KeyboardInterrupt)
    procs = [subprocess.Popen(c, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, errors="replace",
                              process_group=0) for c in cmds]
    lines: list[list[str]] = [[] for _ in procs]
    so_far = [FuzzStats() for _ in procs]
    found: queue.Queue[tuple[int, str | None]] = queue.Queue()

    def read(k: int) -> None:
        stdout = procs[k].stdout
        assert stdout is not None
        for line in stdout:
            found.put((k, line))
        found.put((k, None))

    readers = [threading.Thread(target=read, args=(k,), daemon=True) for k in range(len(procs))]
    for r in readers:
        r.start()
    rcs: list[int | None] = [None] * len(procs)
    open_streams = len(procs)
    interrupted = False
    with open(out / "fuzz.log", "w", encoding="utf-8") as log:

        def pump(deadline: float | None) -> None:
            """Log, echo and count lines until every process has ended (or ``deadline``, monotonic s)."""
            nonlocal open_streams
            while open_streams:
                try:
                    k, line = found.get(timeout=None if deadline is None else max(0.0, deadline - time.monotonic()))
                except queue.Empty:
                    return
                if line is None:
                    open_streams -= 1
                    rcs[k] = procs[k].wait()
                    if rcs[k] and many and not interrupted:  # a crash (or any failure) in one process ends the run
                        for other in procs:
                            if other.poll() is None:
                                other.terminate()
                    continue
                tag = f"[job{k + 1}] " if many else ""
                log.write(tag + line)
                lines[k].append(line)
                if say is not None and _is_progress(line):
                    say(f"  {tag}{line.rstrip()}")
                if on_stats is not None and (line.startswith("#") or "Test unit written" in line):
                    now = parse_output(line)
                    mine = so_far[k]
                    if now.executions:
                        mine.executions, mine.exec_per_s = now.executions, now.exec_per_s
                        mine.corpus, mine.coverage = now.corpus, now.coverage
                    mine.crashes += now.crashes
                    on_stats(_combine(so_far))

        try:
            try:
                pump(None)
            except KeyboardInterrupt:  # Ctrl-C or SIGINT: every process prints its final stats and stops
                interrupted = True
                for proc in procs:
                    if proc.poll() is None:
                        proc.terminate()
                pump(time.monotonic() + INTERRUPT_WAIT_S)
        finally:
            for proc in procs:  # a second Ctrl-C, or an exception here: no libFuzzer process is left behind
                if proc.poll() is None:
                    proc.terminate()
                    proc.wait()
    if many:
        for k, text in enumerate(lines):
            (out / f"fuzz-job{k + 1}.log").write_text("".join(text), encoding="utf-8")
    per_job = [parse_output("".join(text)) for text in lines]
    # a process stopped because another crashed reports its runs (none of its own failure)
    crashed = next((k for k, rc in enumerate(rcs) if rc and (per_job[k].crashes or per_job[k].traceback)), None)
    rc = next((rc for rc in rcs if rc), 0) if crashed is None else rcs[crashed] or 0
    for k, st in enumerate(per_job):
        if rcs[k] and not st.crashes and not st.traceback and crashed is None and not interrupted:
            st.traceback = "".join(lines[k][-30:])
    total = _combine(per_job)
    if interrupted and crashed is None:
        total.interrupted, rc = True, 130
    return rc, total


def minimise(target: str, extra: list[Path], work: Path) -> tuple[int, int, FuzzStats]:
    """Merge ``tests/fuzz/TARGET/corpus`` and ``extra`` (libFuzzer ``-merge=1 -use_counters=0``) into the
    smallest set with the same coverage edges and make it the checked-in corpus (files ``min-<sha1>``, the SHA-1 of
    the input as libFuzzer names it). Returns (inputs before: checked-in + extra, inputs after, the
    coverage of the result from a ``-runs=0`` replay). ``work`` holds the merge's scratch and its log
    (``merge.log``, ``replay.log``). Raises ``RuntimeError`` (with the log's tail) if libFuzzer fails or
    keeps no input of a non-empty set (the checked-in corpus is then left as it was).
    """
    t = TARGETS[target]
    checked_in = SEEDS_ROOT / target / "corpus"
    sources = [d for d in (checked_in, *extra) if d.is_dir()]
    before = sum(1 for d in sources for p in d.iterdir() if p.is_file())
    merged = work / "merged"
    if merged.exists():
        shutil.rmtree(merged)
    merged.mkdir(parents=True)
    for step, cmd in (
        ("merge", [sys.executable, "-m", t.module, "-merge=1", "-use_counters=0", f"-artifact_prefix={work}/", str(merged),
                   *map(str, sources)]),
        ("replay", [sys.executable, "-m", t.module, "-runs=0", str(merged)]),
    ):
        proc = subprocess.run(cmd, capture_output=True, text=True, errors="replace", check=False)
        (work / f"{step}.log").write_text(proc.stdout + proc.stderr, encoding="utf-8")
        if proc.returncode:
            raise RuntimeError(f"libFuzzer {step} failed (exit {proc.returncode}): {(proc.stdout + proc.stderr)[-2000:]}")
    stats = parse_output(proc.stdout + proc.stderr)
    kept = sorted(p for p in merged.iterdir() if p.is_file())
    if before and not kept:  # e.g. the merge's inner process could not start: keep the corpus as it was
        raise RuntimeError(f"libFuzzer merge kept none of {before} inputs; see {work / 'merge.log'}")
    if checked_in.is_dir():
        shutil.rmtree(checked_in)
    checked_in.mkdir(parents=True)
    for p in kept:
        shutil.copyfile(p, checked_in / f"min-{p.name[:16]}")
    return before, len(kept), stats


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
    seconds = args.seconds if args.seconds is not None or args.runs is not None else 60
    for option, value in (("--seconds", seconds), ("--runs", args.runs), ("--jobs", args.jobs),
                          ("--rss-limit-mb", args.rss_limit_mb), ("--max-len", args.max_len)):
        if value is not None and value < 1:  # the one option that is wrong (all were named for any of them)
            print_error("fuzz", f"{option} must be at least 1, got {value}")
            return 2
    out = Path(args.out or Path("fuzz-out") / args.target)
    corpus = Path(args.corpus) if args.corpus else out / "corpus"
    if args.minimise:
        return _minimise(args.target, corpus, out)
    seeds = [] if args.no_seeds else seed_dirs(args.target)
    for what, d in (("--corpus", corpus), ("--out", out)):
        try:
            d.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            print_error("fuzz", f"{what}: cannot create {d}: {e.strerror or e}")
            return 2
    limit = " and ".join(x for x in (f"{args.runs} inputs" if args.runs else "", f"{seconds} s" if seconds else "") if x)
    print(f"fuzzing {args.target} for {limit} ({args.jobs} job(s)); corpus {corpus}"
          + (f", seeds {', '.join(map(str, seeds))}" if seeds else ""), flush=True)
    from host.progress import bar

    total = args.runs if args.runs is not None else seconds
    with bar(f"fuzzing {args.target}", total, quiet=args.quiet, fields=("exec/s", "corpus", "cov", "crashes")
             ) as shown:
        started = time.monotonic()

        def stats(s: FuzzStats) -> None:
            done = s.executions if args.runs is not None else time.monotonic() - started
            shown.update(completed=min(total, done), **{
                "exec/s": s.exec_per_s, "corpus": s.corpus, "cov": s.coverage, "crashes": len(s.crashes)})

        rc, st = run_target(args.target, seconds, corpus, out, args.jobs, args.max_len, not args.no_seeds,
                            echo=False if args.quiet or shown.shown else True, rss_limit_mb=args.rss_limit_mb,
                            on_stats=stats if shown.shown else None, runs=args.runs)
        wall = time.monotonic() - started
    print(f"{args.target}: {st.summary()}")
    print(f"{args.target}: {st.executions} inputs run in all, {args.jobs} job(s), {wall:.0f} s wall "
          f"({st.executions / wall if wall > 0 else 0:.0f} exec/s)")
    if st.interrupted:
        print_error("fuzz", f"{args.target}: interrupted after {st.executions} inputs"
                    + (f" of {args.runs}" if args.runs else "") + f", no crash; full log {out / 'fuzz.log'}")
        return 130
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


def _minimise(target: str, corpus: Path, out: Path) -> int:
    if not (SEEDS_ROOT / target).is_dir():
        print_error("fuzz", f"--minimise needs the source tree (tests/fuzz/{target} not found)")
        return 2
    try:
        out.mkdir(parents=True, exist_ok=True)
        before, after, st = minimise(target, [corpus] if corpus.is_dir() else [], out)
    except (OSError, RuntimeError) as e:
        print_error("fuzz", f"--minimise: {e}")
        return 1
    print(f"{target}: corpus minimised: {before} inputs -> {after} in tests/fuzz/{target}/corpus "
          f"(coverage {st.coverage} edges / {st.features} features); logs in {out}")
    return 0
