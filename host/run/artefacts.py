"""Files a run leaves behind: timeline.json/png, joints.png and summary.json.

Plots use matplotlib's Agg backend (no display needed). They are laid out with fixed margins in
inches (:func:`_place_axes`), not ``tight_layout``, and written at zlib level 1 (:data:`PNG_OPTIONS`):
on CoCo's joints.png those two halve the time per plot (0.48 -> 0.25 s, 3 runs each, quiet) for a
file ~10 % larger. Every run writes both plots, so the test suite's ~150 runs paid it too.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from robots.description import Robot

#: the emulated board's object poses (``python -m firmware_sim --objects-log``, firmware_sim.objects_log)
OBJECTS_LOG = "objects.jsonl"
#: the suffixes of the frame logs (``host_frames.jsonl`` on a serial link; CAN: host.link.canlog.CAN_LOG_SUFFIXES)
FRAME_LOG_SUFFIXES = (".jsonl", ".log", ".asc", ".blf", ".csv", ".trc", ".mf4")
#: every file a run (``run``, ``demo``) may write into its folder, by name: the files an earlier run left
#: there are removed before the next run writes (:func:`host.commands.outarg.clear_run_artefacts`)
RUN_ARTEFACTS = ("timeline.json", "timeline.png", "joints.png", "summary.json",
                 *(f"{end}_frames{s}" for end in ("host", "board") for s in FRAME_LOG_SUFFIXES),
                 "run.mcap", "board.stderr", OBJECTS_LOG, "run.mp4")
#: the run's photos (``capture_session_N.png``), as :meth:`pathlib.Path.glob` patterns
RUN_ARTEFACT_PATTERNS = ("capture_session_*.png",)
OUTCOMES = ("done", "failed", "cancelled", "interrupted", "pending", "timeout")


@dataclass
class BoardCall:
    """One call on the board clock (seconds), as ``timeline.json`` lists it."""

    function: str
    channel: str | None
    args: dict[str, Any]
    path: str
    start: float | None
    end: float | None
    outcome: str
    error: str | None = None
    persistent: bool = False
    ended_by: str | None = None  # a scope that ended early: the child's path or "timeout" (else not written)


@dataclass
class Summary:
    """``summary.json``: how the run went, in numbers. ``base_start`` / ``base_end`` are ``[x m, y m, yaw deg]``
    from the board's SIM_STATE reports; they, ``fell`` and ``max_tilt_deg`` are None (``null``) when no such
    report reached the host (``extra.base_reports`` 0: a line too slow for them, a link lost before the
    first), never zeros that would read as "upright, did not move". ``final_joints_deg``: servo name (the
    name ``joint_move`` takes) -> its measured joint angle in degrees (2 decimals) in the last TELEMETRY
    of the turn; None when no report reached the host."""

    task: str
    outcome: str
    fell: bool | None
    base_start: list[float] | None
    base_end: list[float] | None
    max_tilt_deg: float | None
    first_action_latency_ms: float | None
    outcomes: dict[str, int] = field(default_factory=dict)
    duration_s: float = 0.0
    final_joints_deg: dict[str, float] | None = None
    extra: dict[str, Any] = field(default_factory=dict)


def _jsonable(v: Any) -> Any:
    if isinstance(v, (str, int, float, bool)) or v is None:
        return v
    if hasattr(v, "value") and hasattr(v, "name"):  # Enum
        return v.value
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    return str(v)


def calls_table(calls: Sequence[BoardCall], t0: float = 0.0) -> str:
    """A plain-text table of ``calls`` with their board-measured times in board seconds, the time base
    of ``timeline.json`` and ``timeline.png`` (the header line says so and gives ``t0``, the turn's
    start on that clock), in the layout of :meth:`host.shell.timeline.Timeline.table`."""
    rows = [f"  start     end  channel  outcome      path  args      (board time, s; the turn began at {t0:.2f})"]
    for c in calls:
        s = "   -  " if c.start is None else f"{c.start:6.2f}"
        e = "   -  " if c.end is None else f"{c.end:6.2f}"
        rows.append(f"{s}  {e}  {c.channel or '-':7}  {c.outcome:11}  {c.path}  {c.args}{'  ' + c.error if c.error else ''}"
                    f"{'  ended by ' + c.ended_by if c.ended_by else ''}")
    return "\n".join(rows)


#: decimals of the floats in timeline.json: 6, a microsecond of board time
DECIMALS = 6


def _rounded(v: Any) -> Any:
    """``v`` with every float rounded to :data:`DECIMALS` (0.9239999999999999 -> 0.924)."""
    if isinstance(v, float):
        return round(v, DECIMALS) if math.isfinite(v) else v
    if isinstance(v, dict):
        return {k: _rounded(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_rounded(x) for x in v]
    return v


def write_timeline_json(path: Path, calls: Sequence[BoardCall], t0: float = 0.0) -> None:
    """Write ``{"clock": "board", "t0": run start, "calls": [...]}`` (times in board seconds, every
    float rounded to 6 decimals: a microsecond, the board clock's resolution)."""
    doc = _rounded({"clock": "board", "t0": t0, "calls": [{k: _jsonable(v) for k, v in asdict(c).items()
                                                             if k != "ended_by" or v is not None} for c in calls]})
    _write_atomic(path, json.dumps(doc, indent=1, ensure_ascii=False) + "\n")


def write_summary_json(path: Path, summary: Summary) -> None:
    _write_atomic(path, json.dumps(_jsonable(asdict(summary)), indent=1) + "\n")


def _write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to a temporary file beside ``path`` and rename it: a reader (or a process
    stopped mid-write) never sees half a file."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


_COLOURS = {"done": "#4c9be8", "failed": "#e05050", "cancelled": "#aaaaaa", "interrupted": "#f0a030",
            "pending": "#dddddd", "timeout": "#b07cd8"}


_plotting_warm = False

#: PNG encoder options for the plots: zlib level 1 (Pillow's default, 6, took ~40 % of a joints plot)
PNG_OPTIONS: dict[str, Any] = {"compress_level": 1}


def _place_axes(fig: Any, *, left_in: float, bottom_in: float, top_in: float, right_in: float = 0.15,
                hspace: float = 0.08) -> None:
    """Margins of ``fig``'s subplots in inches, whatever its size (``tight_layout`` measured every
    label on a dry draw first: ~40 % of a plot's time)."""
    w, h = fig.get_size_inches()
    fig.subplots_adjust(left=left_in / w, right=1 - right_in / w, bottom=bottom_in / h, top=1 - top_in / h,
                        hspace=hspace)


def new_figure(size_in: tuple[float, float]) -> Any:
    """A matplotlib ``Figure`` of ``size_in`` (width, height) inches on its own Agg canvas.

    Not pyplot: its import (~0.1 s of CPU, backend selection, the global figure manager) buys nothing
    for a file that is saved once, and its global state is shared between the threads that write
    artefacts. No registry keeps the ``Figure``: the garbage collector frees it (figure, canvas and
    axes refer to each other) once the caller drops it."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size_in)
    FigureCanvasAgg(fig)
    return fig


def warm_up_plotting() -> None:
    """Import matplotlib (Agg) and draw one tiny figure, once per process, before a session's link is up.

    The artefact writer plots in a worker thread while the link is live. Its first plot of a process
    imported matplotlib and set up the Agg renderer and fonts there: hundreds of ms in which the event
    loop thread got the GIL only in stretches (loading C extensions holds it), so heartbeats and
    frames stalled. Measured on a realtime run's live view (bench/bench_foxglove.py --n 1 --task 1):
    /joint_states gaps of 104-208 ms on a quiet machine; in one CI run the stall reached 1.2 s and the
    board's watchdog latched. Draws on its own ``Figure`` (not pyplot's global state, which another
    session's writer thread may be using); only the first call does anything."""
    global _plotting_warm
    if _plotting_warm:
        return
    import io

    fig = new_figure((1, 1))
    ax = fig.add_subplot()
    ax.barh(0, 1.0)
    ax.text(0, 0, "warm", fontsize=7)
    fig.savefig(io.BytesIO(), format="png", dpi=20)
    _plotting_warm = True


#: legend text (pt): the plots' legends sit right of their axes, never over a curve or a bar
LEGEND_PT = 6.0
#: most entries in one legend column of joints.png (a 2.3 in panel holds ~14 lines of 6 pt)
LEGEND_ROWS = 12


def _legend_width_in(labels: Sequence[str], ncol: int = 1) -> float:
    """Inches a legend of ``labels`` in ``ncol`` columns takes right of the axes (its handles, gaps and
    the widest label at :data:`LEGEND_PT`, ~0.6 em a character: a generous guess, measuring it costs a dry draw), with the gap to the axes."""
    col = 0.4 + 0.6 * LEGEND_PT / 72 * max((len(x) for x in labels), default=1)
    return 0.12 + ncol * col


def _outside_legend(ax: Any, ncol: int = 1) -> Any:
    """``ax``'s legend right of its axes (upper left corner at the axes' upper right): the data area
    stays clear whatever the curves do."""
    return ax.legend(fontsize=LEGEND_PT, ncol=ncol, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)


def plot_timeline(path: Path, calls: Sequence[BoardCall], title: str = "") -> Any:
    """A Gantt chart of the calls, one row per channel; the outcome colours' legend right of the chart.
    Returns the matplotlib ``Figure`` (already saved; for tests)."""
    shown = [c for c in calls if c.start is not None]
    row = lambda c: c.channel or ("skills" if c.function == "RUN" else "?")  # noqa: E731 (a RUN spans its calls)
    channels = list(dict.fromkeys(row(c) for c in shown)) or ["-"]
    fig = new_figure((10, 0.6 * len(channels) + 1.4))
    ax = fig.subplots()
    t_max = max((c.end or c.start or 0.0) for c in shown) if shown else 1.0
    for c in shown:
        start = c.start if c.start is not None else 0.0  # (shown calls all started)
        y = channels.index(row(c))
        end = c.end if c.end is not None else t_max
        h = 0.35 if c.persistent else 0.7
        ax.barh(y, max(end - start, 0.02), left=start, height=h, color=_COLOURS.get(c.outcome, "#888"),
                edgecolor="black", linewidth=0.5, alpha=0.6 if c.persistent else 0.9)
        label = f"RUN {c.args.get('id', '')}" if c.function == "RUN" else c.function
        ax.text(start + 0.02, y, label, va="center", fontsize=7, clip_on=True)
    ax.set_yticks(range(len(channels)), channels)
    ax.invert_yaxis()
    ax.set_xlabel("board time (s)")
    ax.set_title(title or "timeline")
    ax.grid(axis="x", alpha=0.3)
    from matplotlib.patches import Patch

    outcomes = [o for o in _COLOURS if any(c.outcome == o for c in shown)]
    right_in = 0.15
    if outcomes:
        ax.legend(handles=[Patch(facecolor=_COLOURS[o], edgecolor="black", linewidth=0.5, label=o) for o in outcomes],
                  fontsize=LEGEND_PT, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
        right_in = _legend_width_in(outcomes)
    # the channel names are the y tick labels (10 pt, ~0.09 in a character)
    _place_axes(fig, left_in=0.25 + 0.09 * max(len(c) for c in channels), bottom_in=0.55, top_in=0.35,
                right_in=right_in)
    fig.savefig(path, dpi=110, pil_kwargs=PNG_OPTIONS)
    return fig


def joint_groups(robot: Robot) -> list[tuple[str, list[int]]]:
    """Panels of ``joints.png``: one per motion channel of ``robot`` (its servos), then the servos no
    channel drives ("joints"); a robot without channels gets one panel."""
    groups = [(c.name, list(c.servos)) for c in robot.channels.values() if c.servos]
    taken = {i for _, idx in groups for i in idx}
    rest = [i for i in range(robot.servo_count) if i not in taken]
    return groups + ([("joints", rest)] if rest else [])


def plot_joints(path: Path, times: np.ndarray, positions: np.ndarray, names: Sequence[str],
                targets: tuple[np.ndarray, np.ndarray] | None = None,
                groups: Sequence[tuple[str, Sequence[int]]] | None = None) -> Any:
    """Joint angles (degrees) against board time, one panel per servo group (``groups``: (label,
    servo indices), e.g. :func:`joint_groups`; default one panel of every servo), each panel's legend
    right of it (a column per :data:`LEGEND_ROWS` servos). Returns the matplotlib ``Figure`` (already
    saved; for tests)."""
    panels = [(label, list(idx)) for label, idx in (groups or [("joints", range(len(names)))]) if len(idx)]
    fig = new_figure((10, max(3.0, 2.3 * len(panels))))
    axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False)
    right_in = 0.15
    for ax, (label, idx) in zip(axes[:, 0], panels):
        for i in idx:
            line, = ax.plot(times, np.degrees(positions[:, i]), lw=1, label=names[i])
            if targets is not None and len(targets[0]):
                ax.plot(targets[0], np.degrees(targets[1][:, i]), lw=0.6, ls="--", color=line.get_color())
        ax.set_ylabel(f"{label}\n(deg)")
        ncol = -(-len(idx) // LEGEND_ROWS)
        _outside_legend(ax, ncol)
        right_in = max(right_in, _legend_width_in([names[i] for i in idx], ncol))
        ax.grid(alpha=0.3)
    axes = axes[:, 0]
    axes[-1].set_xlabel("board time (s)  (solid: measured, dashed: commanded)")
    _place_axes(fig, left_in=1.0, bottom_in=0.5, top_in=0.15, right_in=right_in)  # two-line panel labels, ticks to "-1000"
    fig.savefig(path, dpi=110, pil_kwargs=PNG_OPTIONS)
    return fig


def joint_angles_deg(names: Sequence[str], positions: Sequence[float] | None) -> dict[str, float] | None:
    """``{servo name: angle in degrees, 2 decimals}`` of ``positions`` (radians, servo order; a NaN
    becomes None in JSON terms: left out); None when ``positions`` is None."""
    if positions is None:
        return None
    return {n: round(math.degrees(float(q)), 2) for n, q in zip(names, positions) if math.isfinite(float(q))}


def tilt_deg(quat_wxyz: Sequence[float]) -> float:
    """Angle between the body's up axis and the world's up axis."""
    w, x, y, z = quat_wxyz
    up_z = 1.0 - 2.0 * (x * x + y * y)
    return math.degrees(math.acos(max(-1.0, min(1.0, up_z))))


def yaw_deg(quat_wxyz: Sequence[float]) -> float:
    w, x, y, z = quat_wxyz
    return math.degrees(math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def count_outcomes(calls: Sequence[BoardCall]) -> dict[str, int]:
    out = {k: 0 for k in OUTCOMES}
    for c in calls:
        out[c.outcome] = out.get(c.outcome, 0) + 1
    return out


def recorded_robot(run_dir: Path) -> str | None:
    """The robot a recorded run drove, from its ``summary.json``: its folder (``extra.robot_folder``) while
    that still holds a robot, else its name (``extra.robot``); None when not recorded."""
    from robots.loader import ROBOT_FILE

    try:
        doc = json.loads((Path(run_dir) / "summary.json").read_text(encoding="utf-8"))
        extra = doc.get("extra") or {}
        name, folder = extra.get("robot"), extra.get("robot_folder")
    except (OSError, ValueError, AttributeError):
        return None
    if isinstance(folder, str) and folder and (Path(folder) / ROBOT_FILE).is_file():
        return folder
    return name if isinstance(name, str) and name else None


def run_robot(run_dir: Path) -> str:
    """The robot the run drove (:func:`recorded_robot`; the default robot if not recorded)."""
    from robots.registry import DEFAULT_ROBOT

    return recorded_robot(Path(run_dir)) or DEFAULT_ROBOT
