"""Re-run the project's benchmark figures and print them as one table.

    python bench/run_all.py            # the figures as quoted (tens of minutes: ~5 min per 30 realtime tasks)
    python bench/run_all.py --quick    # every figure once, small: a smoke run of the benches (a few minutes)
    python bench/run_all.py --only board fuzz   # some benchmarks only (board, latency, fuzz, cfirmware)

Each figure comes from one benchmark run as a subprocess (its full output is kept in ``--log-dir``, default
a temporary folder, and echoed with ``--verbose``); the table gives, per figure: the value, n (what the
benchmark says it measured), the command, and the machine's 1-minute load average (``os.getloadavg``) when
that command started, on how many cores. Benchmarks never assert; a benchmark that fails gives a row
``FAILED (exit N)`` and the others still run. This script itself exits 0, or 1 when any benchmark failed.

Figures:

* ``bench/bench_board.py --robot coco --lockstep-only``: lockstep real-time factor of the board core
  (wall and CPU), over a pty, and the kernels' CPU time per tick (median of 7 rounds, load-independent-ish);
* ``bench/bench_latency.py`` token -> servo p50/p99 over every paper task 3 times (~290 calls; twice gave 196),
  realtime over a pty: quiet (as the machine is), ``--load`` (a busy loop per core), ``--baud 115200``;
* ``bench/bench_fuzz.py`` when that file exists (every line of its output that names an n);
* ``bench/bench_cfirmware.py --skip-fuzz``: the firmware image sizes (and its tick cost, lockstep speed).
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "bench"


@dataclass
class Row:
    """One figure of the table."""

    figure: str
    value: str
    n: str
    command: str
    load: float


Parser = Callable[[str], list[tuple[str, str, str]]]  # output -> [(figure, value, n)]


def parse_board(out: str) -> list[tuple[str, str, str]]:
    rows = []
    m = re.search(r"lockstep core \(([^)]*)\), (\S+).*?: (\d+) ticks in .*?real-time factor ([\d.]+)x \(CPU time .*?, ([\d.]+)x", out)
    if m:
        rows.append((f"lockstep core {m.group(2)} kernel, real-time factor (wall / CPU)", f"{m.group(4)}x / {m.group(5)}x",
                     f"{m.group(3)} ticks"))
    m = re.search(r"lockstep over pty .*?= ([\d.]+)x real time \((\d+) TELEMETRY.*?CPU time .*?= ([\d.]+)x", out)
    if m:
        rows.append(("lockstep board over pty, real-time factor (wall / board CPU)", f"{m.group(1)}x / {m.group(3)}x",
                     f"{m.group(2)} reports"))
    for m in re.finditer(r"kernels A/B, (\w+): CPU per tick min ([\d.]+) us \((\d+)x.*?median ([\d.]+) us \((\d+)x\), n = ([^\n]+)", out):
        rows.append((f"lockstep CPU per tick, {m.group(1)} kernel (median; min)", f"{m.group(4)} us = {m.group(5)}x; "
                     f"{m.group(2)} us", m.group(6).strip()))
    return rows


def parse_latency(label: str) -> Parser:
    def parse(out: str) -> list[tuple[str, str, str]]:
        rows = []
        for name in ("motion, immediate: token -> servo", "peripheral, immediate: token -> start",
                     "motion, all: ready -> servo", "peripheral, all: ready -> start"):
            m = re.search(re.escape(name) + r"\s+n=\s*(\d+)\s+p50=\s*([\d.-]+)\s+p99=\s*([\d.-]+)\s+max=\s*([\d.-]+)", out)
            if m:
                rows.append((f"latency {label}: {name}", f"p50 {m.group(2)} / p99 {m.group(3)} / max {m.group(4)} ms",
                             m.group(1)))
        return rows
    return parse


def parse_cfirmware(out: str) -> list[tuple[str, str, str]]:
    rows = []
    for line in out.splitlines():
        if line.startswith("size ("):
            head, _, value = line.partition("): ")
            rows.append((head + ")", value.strip(), "1 build"))
        elif line.startswith(("tick cost (", "lockstep speed (")):
            head, _, value = line.partition("): ")
            n = re.search(r"n=(\d+[^,)]*)", head)
            rows.append((re.sub(r",? ?n=\d+[^,)]*", "", head) + ")", value.strip(), n.group(1) if n else "?"))
    return rows


def parse_generic(out: str) -> list[tuple[str, str, str]]:
    """Every output line naming an n (``n=123`` / ``n = 123``): figure before the first ':' ."""
    rows = []
    for line in out.splitlines():
        m = re.search(r"\bn\s*=\s*(\d[\w ]*)", line)
        if m and ":" in line:
            head, _, value = line.partition(":")
            rows.append((head.strip(), value.strip()[:70], m.group(1).strip()))
    return rows


def plan(quick: bool) -> list[tuple[list[str], Parser]]:
    """(argv after the interpreter, parser) of every benchmark run."""
    py = ["bench/bench_latency.py"]
    lat_sel = ["--tasks", "1,5,12,23"] if quick else ["--repeat", "3"]  # 30 tasks x 3: ~290 calls (x 2 gave 196)
    runs: list[tuple[list[str], Parser]] = [
        # --quick: one round of 2 simulated seconds (the full run is 3 rounds of 10: ~25 s of a CI worker)
        (["bench/bench_board.py", "--robot", "coco", "--lockstep-only"] + (["--rounds", "1", "--sim-seconds", "2"] if quick else []),
         parse_board),
        (py + lat_sel, parse_latency("quiet")),
        (py + lat_sel + ["--load"], parse_latency("--load")),
        (py + lat_sel + ["--baud", "115200"], parse_latency("115200 baud")),
    ]
    if (BENCH / "bench_fuzz.py").exists():
        runs.append((["bench/bench_fuzz.py"] + (["--quick"] if quick and _takes(BENCH / "bench_fuzz.py", "--quick") else []),
                     parse_generic))
    runs.append((["bench/bench_cfirmware.py", "--skip-fuzz"] + (["--seconds", "2", "--repeat", "1"] if quick else []),
                 parse_cfirmware))
    return runs


#: the benchmarks :func:`plan` runs, by the name ``--only`` takes (the script's stem without ``bench_``)
BENCHMARKS = ("board", "latency", "fuzz", "cfirmware")


def _name(argv: list[str]) -> str:
    return Path(argv[0]).stem.removeprefix("bench_")


def _takes(script: Path, option: str) -> bool:
    return option in script.read_text(encoding="utf-8", errors="replace")


def run(argv: list[str], parser: Parser, log_dir: Path, verbose: bool) -> list[Row]:
    cmd = " ".join(argv)
    load = os.getloadavg()[0]
    t0 = time.monotonic()
    print(f"[run_all] {cmd} (1-min load {load:.2f}) ...", file=sys.stderr, flush=True)
    proc = subprocess.run([sys.executable, *argv], cwd=ROOT, capture_output=True, text=True,
                          env=dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")))
    log = log_dir / (Path(argv[0]).stem + "_" + re.sub(r"\W+", "_", " ".join(argv[1:]))[:60] + ".txt")
    log.write_text(proc.stdout + "\n--- stderr ---\n" + proc.stderr, encoding="utf-8")
    if verbose:
        print(proc.stdout, file=sys.stderr)
    print(f"[run_all]   {time.monotonic() - t0:.0f} s, exit {proc.returncode}, output in {log}", file=sys.stderr, flush=True)
    rows = [Row(f, v, n, cmd, load) for f, v, n in parser(proc.stdout)]
    if proc.returncode != 0 or not rows:
        tail = (proc.stderr.strip().splitlines() or ["no output"])[-1][:80]
        rows.append(Row(f"{Path(argv[0]).name}", f"FAILED (exit {proc.returncode})" if proc.returncode else
                        "no figure found in its output", "-", cmd, load))
        rows[-1].value += f": {tail}"
    return rows


def table(rows: list[Row]) -> str:
    cols = [("figure", [r.figure for r in rows]), ("value", [r.value for r in rows]), ("n", [r.n for r in rows]),
            ("command", [r.command for r in rows]), ("load@start", [f"{r.load:.2f}" for r in rows])]
    widths = [max(len(h), *(len(v) for v in vs)) for h, vs in cols]
    lines = ["  ".join(h.ljust(w) for (h, _), w in zip(cols, widths, strict=True))]
    lines.append("  ".join("-" * w for w in widths))
    for i in range(len(rows)):
        lines.append("  ".join(vs[i].ljust(w) for (_, vs), w in zip(cols, widths, strict=True)))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small runs of every benchmark (a smoke run, minutes)")
    ap.add_argument("--log-dir", default=None, help="where each benchmark's full output goes (default: a temporary folder)")
    ap.add_argument("--verbose", action="store_true", help="echo each benchmark's output to stderr")
    ap.add_argument("--only", nargs="+", choices=BENCHMARKS, metavar="NAME",
                    help=f"run these benchmarks only ({', '.join(BENCHMARKS)})")
    args = ap.parse_args(argv)
    log_dir = Path(args.log_dir) if args.log_dir else Path(tempfile.mkdtemp(prefix="bench_run_all_"))
    log_dir.mkdir(parents=True, exist_ok=True)
    rows: list[Row] = []
    try:
        for argv_, parser in plan(args.quick):
            if args.only and _name(argv_) not in args.only:
                continue
            rows += run(argv_, parser, log_dir, args.verbose)
    except KeyboardInterrupt:
        signal.signal(signal.SIGINT, signal.SIG_DFL)  # a further Ctrl-C ends the process: no traceback, no hang
        print("[run_all] interrupted; the figures so far:", file=sys.stderr)
        print(table(rows))
        return 130
    print(f"benchmark figures ({'--quick' if args.quick else 'full'}), {os.cpu_count()} cores; "
          f"load = 1-min load average when the command started; outputs in {log_dir}")
    print(table(rows))
    return 1 if any(r.value.startswith(("FAILED", "no figure")) for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
