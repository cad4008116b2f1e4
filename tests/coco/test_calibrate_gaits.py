"""CoCo's gait calibration (``python -m robots.coco.calibrate_gaits --check``) still runs against the
checked-in gait.toml and prints its accuracy table (its numbers are printed, never asserted)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path


def test_calibration_check_runs(tmp_path: Path) -> None:
    root = Path(__file__).resolve().parents[2]
    r = subprocess.run([sys.executable, "-m", "robots.coco.calibrate_gaits", "--check"], cwd=root,
                       capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip()
