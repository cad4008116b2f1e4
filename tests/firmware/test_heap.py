"""firmware_sim.gc_freeze: the board process freezes what it loaded before it serves."""

from __future__ import annotations

import subprocess
import sys


def test_freeze_heap_takes_what_is_alive_out_of_the_collectors_passes() -> None:
    # in a fresh interpreter: a frozen heap is never given back, so not in the test process
    code = ("import gc; from firmware_sim.gc_freeze import freeze_heap; keep = [[i] for i in range(1000)]; "
            "assert any(o is keep for o in gc.get_objects()); "
            "n = freeze_heap(); assert n == gc.get_freeze_count() and n >= 1000, n; "
            "assert not any(o is keep for o in gc.get_objects()), 'still walked by the passes'; "
            "later = [[1]]; assert any(o is later for o in gc.get_objects()); print(n)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert int(out.stdout) >= 1000
