"""End-to-end helpers: one real board subprocess per run, lockstep over a real pty.

``run_e2e(program, out, **opts)`` runs :func:`host.run.runner.run_program`
(board ``python -m firmware_sim --link pty --lockstep``, the real BoardClient,
the shell and the scripted LLM paced on the board clock) and wraps the
:class:`~host.run.runner.RunReport` in :class:`E2ERun`, which adds look-ups
by function/arguments and readers for the board's frame log (telemetry and
the emulator's ground-truth base pose). The link client is asyncio-only, so
runs use AnyIO's asyncio backend.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import anyio
import numpy as np
import pytest

from host.run.artefacts import BoardCall, yaw_deg
from host.run.runner import RunOptions, RunReport, run_program
from protocol.framelog import iter_records
from robots.coco.tasks import load_tasks

#: the board's servo frame period (s): a call on a channel starts on this grid
FRAME_S = 0.010
#: "the same instant" on the board clock: two frame periods
SAME_S = 2 * FRAME_S
#: a call released by the previous one's end starts within this (grid + the streamer's 60 ms lookahead)
PROMPT_S = 0.15
#: speech is synthesised (espeak-ng, wall clock) before it is scheduled, and the lockstep
#: board clock keeps running meanwhile, so a sentence after a motion may start later
SPEECH_PROMPT_S = 0.6

TASKS = {i: t for i, t in load_tasks().items() if t.ground_truth}


@dataclass
class E2ERun:
    """A finished run: the report plus look-ups on the board-measured calls."""

    report: RunReport

    @property
    def calls(self) -> list[BoardCall]:
        return self.report.calls

    @property
    def out(self) -> Path:
        return self.report.out

    @property
    def t0(self) -> float:
        """Board time (s) at which the LLM stream started."""
        return self.report.board_t0

    def find(self, function: str, **args: Any) -> list[BoardCall]:
        """Calls of ``function`` whose args include ``args`` (speech text compared stripped)."""
        def match(c: BoardCall) -> bool:
            for k, v in args.items():
                got = c.args.get(k)
                if isinstance(v, str) and isinstance(got, str):
                    if got.strip() != v.strip():
                        return False
                elif got != v:
                    return False
            return True
        return [c for c in self.calls if c.function == function and match(c)]

    def one(self, function: str, **args: Any) -> BoardCall:
        found = self.find(function, **args)
        assert len(found) == 1, f"expected one {function} {args}, found {len(found)}:\n{self.table()}"
        return found[0]

    def table(self) -> str:
        """The calls relative to the run start, for assertion messages."""
        rel = lambda t: "-" if t is None else f"{t - self.t0:7.3f}"
        return "\n".join(f"  {rel(c.start)} {rel(c.end)} {c.channel or '?':7s} {c.outcome:11s} {c.path} {c.args}"
                         for c in self.calls)

    # -- the board's frame log -----------------------------------------------------------------
    @cached_property
    def _board_sent(self) -> dict[str, list[dict[str, Any]]]:
        """Fields of every message the board sent, by type, from its frame log (read once: a long task's
        log is ~5 000 JSON lines, and telemetry and the base pose were two passes over it)."""
        sent: dict[str, list[dict[str, Any]]] = {}
        with open(self.out / "board_frames.jsonl", encoding="utf-8") as f:
            for rec in iter_records(f):
                if rec["dir"] == "tx" and "type" in rec:
                    sent.setdefault(rec["type"], []).append(rec["fields"])
        return sent

    def _board_records(self, msg_type: str) -> Iterator[dict[str, Any]]:
        yield from self._board_sent.get(msg_type, [])

    def host_sent(self, msg_type: str) -> list[dict[str, Any]]:
        """Fields of every ``msg_type`` message the host sent, from its frame log."""
        with open(self.out / "host_frames.jsonl", encoding="utf-8") as f:
            return [r["fields"] for r in iter_records(f) if r["dir"] == "tx" and r.get("type") == msg_type]

    @cached_property
    def telemetry(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(board time s, positions rad [n, 12], velocities rad/s [n, 12]) as the board sent them."""
        t, q, v = [], [], []
        for f in self._board_records("TELEMETRY"):
            t.append(f["board_time_us"] * 1e-6)
            q.append(f["positions"])
            v.append(f["velocities"])
        return np.asarray(t), np.asarray(q), np.asarray(v)

    @cached_property
    def base(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Emulator ground truth: (board time s, xy m [n, 2], yaw deg [n], unwrapped)."""
        t, xy, yaw = [], [], []
        for f in self._board_records("SIM_STATE"):
            t.append(f["board_time_us"] * 1e-6)
            xy.append(f["base_pos"][:2])
            yaw.append(math.radians(yaw_deg(f["base_quat"])))
        return np.asarray(t), np.asarray(xy), np.degrees(np.unwrap(np.asarray(yaw)))

    def base_at(self, t: float) -> tuple[np.ndarray, float]:
        """Base (xy, unwrapped yaw deg) at the last SIM_STATE at or before board time ``t``."""
        times, xy, yaw = self.base
        i = max(int(np.searchsorted(times, t, side="right")) - 1, 0)
        return xy[i], float(yaw[i])

    def turned_deg(self, start: float, end: float, settle_s: float = 0.3) -> float:
        """Yaw change (deg, + = left) from ``start`` to ``end + settle_s`` (the body settles after the last frame)."""
        return self.base_at(end + settle_s)[1] - self.base_at(start)[1]

    def moved_forward_m(self, start: float, end: float, settle_s: float = 0.3) -> float:
        """Base displacement (m) along the heading it had at ``start`` (negative: backward)."""
        xy0, yaw0 = self.base_at(start)
        xy1, _ = self.base_at(end + settle_s)
        heading = np.array([math.cos(math.radians(yaw0)), math.sin(math.radians(yaw0))])
        return float(np.dot(xy1 - xy0, heading))


def mask_of(servos: Any) -> int:
    """Servo bit mask of the FLUSH/SERVO_FRAME messages."""
    return sum(1 << int(i) for i in servos)


def run_e2e(program: str, out: Path, **options: Any) -> E2ERun:
    """Run ``program`` end to end (lockstep unless told otherwise) and write the artefacts to ``out``.

    No plots unless asked (``plots=True``): the JSON artefacts and frame logs are what the checks read,
    and drawing timeline.png and joints.png costs ~0.25 s of CPU per run (measured: 6 lockstep tasks, 2 runs each way) (the suite makes ~200 runs;
    tests/e2e/test_artefacts.py checks the plots of :data:`PLOTTED_TASKS`). No run.mcap unless asked
    (``mcap=True``) either: the recording's writer thread (forward kinematics for ``/tf``, JSON, zstd at
    50 Hz) cost ~0.34 s of host CPU per run, about half the host's CPU of a lockstep task (tasks 26, 9
    and 18, 2 interleaved rounds each way in one process: 4.27 vs 2.21 host CPU-s, the board's 4.3 either
    way); tests/e2e/test_mcap_e2e.py and :data:`PLOTTED_TASKS`' runs record it."""
    options.setdefault("lockstep", True)
    options.setdefault("plots", False)
    options.setdefault("mcap", False)
    opts = RunOptions(program=program, out=out, **options)
    return E2ERun(anyio.run(run_program, opts, backend="asyncio"))


_TASK_RUNS: dict[tuple[int, str], E2ERun] = {}

#: the ground-truth runs that also draw timeline.png and joints.png and record run.mcap, on the Python board
#: (tests/e2e/test_artefacts.py reads them; a worker's first plot imports matplotlib, ~0.7 CPU-s)
PLOTTED_TASKS = frozenset({26})

#: the boards a task runs on: the Python emulator and the C firmware (native, over the same pty);
#: ``qemu`` (the C firmware on an emulated Cortex-M3) runs a few tasks in tests/cfirmware
FIRMWARES = ("python", "c")


@pytest.fixture(scope="session")
def task_run(tmp_path_factory: pytest.TempPathFactory):
    """``task_run(tid, firmware="python") -> E2ERun``: the ground truth of task ``tid`` on that board's
    firmware (``python -m firmware_sim --firmware``), run once per session."""
    def get(tid: int, firmware: str = "python") -> E2ERun:
        key = (tid, firmware)
        if key not in _TASK_RUNS:
            out = tmp_path_factory.mktemp(f"task{tid}-{firmware}")
            plotted = tid in PLOTTED_TASKS and firmware == "python"  # test_artefacts reads the Python board's
            _TASK_RUNS[key] = run_e2e(TASKS[tid].ground_truth, out, task_label=f"task {tid}", firmware=firmware,
                                      plots=plotted, mcap=plotted)
        return _TASK_RUNS[key]
    return get
