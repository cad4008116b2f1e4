"""Under pytest-xdist, files run longest first (the files with realtime tests before them unless the
realtime lock runs in background mode).

The suite runs with ``--dist loadfile``: a file is one work unit, handed to whichever worker runs
low. xdist's default queue order puts files with many tests first (``--loadscope-reorder``), so a
file of three long tests (SocketCAN in User-Mode Linux, ~100 s) or one (the type check, ~40 s) went
last and ran on one worker while the other had nothing left: ~100 s of a 1 000-s run on one core.
Longest-processing-time-first ordering (Graham 1969: within 4/3 of the best makespan) starts the long
files first and leaves short ones to fill the end. ``pyproject.toml`` turns xdist's reorder off
(``--no-loadscope-reorder``) so the queue keeps the order this hook gives the collection.

Outside the lock's background mode a ``realtime`` test runs alone (tests/support/realtime_lock.py): it
waits until the other workers' current tests end, however long (the SocketCAN run in UML is one 84-s test). The 18 files with
realtime tests therefore go first, longest first among themselves, while both workers run such
files and each one's other tests are short; the LPT order of the rest follows. A simulation of the
two-worker schedule with the lock, from one run's per-test times (n = 1 run of 2 076 tests, 1 617 s
of test time, 167 s of it realtime): xdist's order 995 s (that run took 1 000 s), longest first 973 s,
realtime files first 914 s; the bound ((1 617 - 167) / 2 + 167) is 892 s.

In the lock's background mode (ordinary tests go on beside a realtime one, at nice 19) nothing
idles for a realtime test, so every file goes by weight alone: the same simulation on two later runs'
times (n = 2 runs, 2 213 tests each, with the ordinary worker at 0.7x speed during a
realtime test) gave 662 and 719 s for longest first against 687 and 728 s for realtime files first.

The durations are data: ``tests/durations.json`` maps a test file (relative to the repository) to
the seconds its tests took in a run of the suite (made on two workers; the sum of the JUnit ``time`` of its tests, setup
and teardown included). A file not in it weighs :data:`DEFAULT_S_PER_TEST` per test. Remake the
table after adding or moving heavy tests::

    .venv/bin/python -m pytest -n 3 --dist loadfile --junitxml=/tmp/junit.xml
    .venv/bin/python tests/support/file_order.py /tmp/junit.xml > tests/durations.json

Only xdist workers reorder (they must all collect the same order, and do: the hook is a pure
function of the collection); a one-process run keeps pytest's order.
"""

from __future__ import annotations

import json
import sys
import xml.etree.ElementTree as ET
from collections import Counter
from collections.abc import Collection
from pathlib import Path

import pytest

#: the table, next to the tests it describes (relative to the run's root folder)
DURATIONS = Path("tests") / "durations.json"
#: the marker of a test whose board runs on the wall clock (tests/support/realtime_lock.py)
REALTIME = "realtime"
#: seconds per test of a file the table does not know (about the suite's median file rate)
DEFAULT_S_PER_TEST = 0.3


def load_durations(path: Path) -> dict[str, float]:
    """``{"tests/x/test_y.py": seconds}``; empty when the file is missing or unreadable or holds a
    value that is not a number (the order is then by test count: collection never fails over it)."""
    try:
        table = json.loads(path.read_text())
        return {str(k): float(v) for k, v in table.items()} if isinstance(table, dict) else {}
    except (OSError, ValueError, TypeError):  # unreadable, not JSON, a value that is not a number
        return {}


def file_of(nodeid: str) -> str:
    """The test file of a node id (``tests/a/test_b.py::test_c[1]`` -> ``tests/a/test_b.py``)."""
    return nodeid.split("::", 1)[0]


def run_order(nodeids: list[str], durations: dict[str, float], first: Collection[str] = ()) -> list[str]:
    """``nodeids`` grouped by file: the files in ``first`` (those with realtime tests), then the others,
    each group by descending weight (measured seconds, else :data:`DEFAULT_S_PER_TEST` per test);
    ties and each file's own tests keep their collection order."""
    counts = Counter(file_of(n) for n in nodeids)
    first_seen = {f: i for i, f in reversed(list(enumerate(file_of(n) for n in nodeids)))}

    def key(f: str) -> tuple[bool, float, int]:
        return f not in first, -durations.get(f, DEFAULT_S_PER_TEST * counts[f]), first_seen[f]

    rank = {f: r for r, f in enumerate(sorted(counts, key=key))}
    return sorted(nodeids, key=lambda n: rank[file_of(n)])  # stable: a file's tests keep their order


def _background_mode() -> bool:
    """True if the realtime lock (tests/support/realtime_lock.py) runs in background mode in this worker."""
    lock_module = sys.modules.get("support.realtime_lock")
    lock = getattr(lock_module, "_lock", None)
    return bool(getattr(lock, "background", False))


def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config, items: list[pytest.Item]) -> None:
    if getattr(config, "workerinput", None) is None:  # not an xdist worker
        return
    realtime = {file_of(it.nodeid) for it in items if it.get_closest_marker(REALTIME) is not None}
    if _background_mode():
        realtime = set()
    ids = run_order([it.nodeid for it in items], load_durations(config.rootpath / DURATIONS), realtime)
    order = {n: i for i, n in enumerate(ids)}
    items.sort(key=lambda it: order[it.nodeid])


def durations_from_junit(xml_path: Path, root: Path) -> dict[str, float]:
    """Seconds per test file from a JUnit XML report (pytest's ``--junitxml``): the ``time`` of its
    test cases summed, keyed by the file's path relative to ``root``, largest first."""
    totals: Counter[str] = Counter()
    for case in ET.parse(xml_path).iter("testcase"):
        parts = (case.get("classname") or "").split(".")
        for cut in range(len(parts), 0, -1):  # tests.a.test_b[.Class] -> tests/a/test_b.py
            candidate = "/".join(parts[:cut]) + ".py"
            if (root / candidate).is_file():
                totals[candidate] += float(case.get("time") or 0.0)
                break
    return {f: round(s, 1) for f, s in totals.most_common()}


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: file_order.py JUNIT_XML   (prints tests/durations.json)")
    repo = Path(__file__).resolve().parents[2]
    print(json.dumps(durations_from_junit(Path(sys.argv[1]), repo), indent=1))
