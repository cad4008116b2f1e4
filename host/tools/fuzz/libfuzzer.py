"""Read libFuzzer's console output (as printed by atheris): progress stats, final totals, crashes.

libFuzzer reports progress lines such as ``#106452 DONE cov: 45 ft: 187 corp: 60/5029b ... exec/s:
5069 rss: 47Mb``, in ``-fork`` mode ``#17533: cov: 246 ft: 262 corp: 79 exec/s 762 ...``, then
``Done N runs in S second(s)``; a crash prints ``Test unit written to PATH`` (and atheris the Python
traceback before it); ``-print_final_stats=1`` adds ``stat::number_of_executed_units: N`` (the exact
count, printed also when SIGINT/SIGTERM stops the run: ``libFuzzer: run interrupted``, exit 72),
``stat::average_exec_per_sec: N`` and ``stat::peak_rss_mb: N``. The ``rss:`` of the first
and last progress line and the peak give the process's resident memory over the run (single-process
runs only: ``-fork`` progress lines carry no RSS). Formats: https://llvm.org/docs/LibFuzzer.html#output
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

__all__ = ["FuzzStats", "parse_output"]

_PROGRESS = re.compile(r"^#(\d+):?\s+(?:\w+\s+)?cov: (\d+) ft: (\d+) corp: (\d+)\S*.*?exec/s:? (\d+)")
_DONE = re.compile(r"^Done (\d+) runs in (\d+) second")
_RSS = re.compile(r"^#\d+.*\srss: (\d+)Mb")
_PEAK_RSS = re.compile(r"^stat::peak_rss_mb:\s*(\d+)")
_UNITS = re.compile(r"^stat::number_of_executed_units:\s*(\d+)")
_AVG_RATE = re.compile(r"^stat::average_exec_per_sec:\s*(\d+)")


@dataclass
class FuzzStats:
    """Totals of one ``ghostshell fuzz`` run; ``None`` where libFuzzer printed nothing yet."""

    executions: int = 0
    seconds: int | None = None
    exec_per_s: int = 0
    coverage: int = 0  # edges (libFuzzer "cov")
    features: int = 0  # libFuzzer "ft"
    corpus: int = 0
    rss_start_mb: int | None = None  # resident memory (MB) at the first progress line
    rss_end_mb: int | None = None  # ... at the last
    peak_rss_mb: int | None = None  # libFuzzer's final stats (or the largest rss seen)
    crashes: list[str] = field(default_factory=list)  # saved inputs
    traceback: str = ""  # the uncaught exception atheris printed, if any
    interrupted: bool = False  # libFuzzer stopped by SIGINT/SIGTERM ("run interrupted"), not by a crash

    def summary(self) -> str:
        rate = self.exec_per_s if self.exec_per_s else (self.executions // self.seconds if self.seconds else 0)
        secs = f" in {self.seconds} s" if self.seconds is not None else ""
        rss = ""
        if self.rss_start_mb is not None and self.rss_end_mb is not None:
            rss = f", RSS {self.rss_start_mb} -> {self.rss_end_mb} MB"
            if self.peak_rss_mb is not None and self.peak_rss_mb > self.rss_end_mb:
                rss += f" (peak {self.peak_rss_mb} MB)"
        return (
            f"{self.executions} executions{secs} ({rate} exec/s), coverage {self.coverage} edges / "
            f"{self.features} features, corpus {self.corpus} inputs{rss}"
        )


def parse_output(text: str) -> FuzzStats:
    """Stats, crash files and the first Python traceback found in libFuzzer/atheris output."""
    st = FuzzStats()
    lines = text.splitlines()
    for i, line in enumerate(lines):
        m = _RSS.match(line)
        if m:
            rss = int(m[1])
            st.rss_start_mb = rss if st.rss_start_mb is None else st.rss_start_mb
            st.rss_end_mb = rss
            st.peak_rss_mb = max(st.peak_rss_mb or 0, rss)
        m = _PEAK_RSS.match(line)
        if m:
            st.peak_rss_mb = int(m[1])
            continue
        m = _UNITS.match(line)  # -print_final_stats=1: the exact count, also after an interrupt
        if m:
            st.executions = max(st.executions, int(m[1]))
            continue
        m = _AVG_RATE.match(line)
        if m:  # a -fork parent runs no inputs itself: its 0 is not the run's rate
            st.exec_per_s = int(m[1]) or st.exec_per_s
            continue
        if "libFuzzer: run interrupted" in line:
            st.interrupted = True
        m = _PROGRESS.match(line)
        if m:
            st.executions = max(st.executions, int(m[1]))
            st.coverage, st.features, st.corpus = int(m[2]), int(m[3]), int(m[4])
            st.exec_per_s = int(m[5])
            continue
        m = _DONE.match(line)
        if m:
            st.executions, st.seconds = max(st.executions, int(m[1])), int(m[2])
            continue
        if "Test unit written to" in line or ("crash-" in line and "written" in line):
            path = line.rsplit(" ", 1)[-1]
            if path not in st.crashes:
                st.crashes.append(path)
        if "Uncaught Python exception" in line and not st.traceback:
            tb = []
            for follow in lines[i : i + 60]:
                tb.append(follow)
                if follow.startswith(("==", "MS:", "artifact_prefix")) and len(tb) > 1:
                    break
            st.traceback = "\n".join(tb)
    return st
