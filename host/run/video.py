"""A run's video: ``run.mp4`` rendered after the run from the board's recorded state.

Nothing is rendered inside the control loop. The board's frame log
(``board_frames.jsonl``, written with ``--log``; on CAN the candump capture ``board_frames.log``,
read through :mod:`host.link.canlog`) already records, at the
telemetry rate (50 Hz), every joint angle (TELEMETRY ``positions``) and the
base's pose (SIM_STATE ``base_pos``/``base_quat``) at the same board
time: together that is the robot's whole ``qpos``. Each video frame takes the
latest recorded state at its time (25 fps reads every other 50 Hz sample).

A frame (640x480) is a third-person view: for a floating robot a free MuJoCo camera that follows its
base (distance and angles from the robot's ``[view]``), as for a fixed-base robot with a ``[view]``; a
fixed-base robot without one gets a camera framed on the model's bounding box at the neutral pose. A
fixed-base robot whose model has no floor gets one drawn under it (:mod:`host.run.framing`). Then the
robot's camera
(its ``[peripherals] camera``, when it has one) as an inset, and a caption
strip: the board time, the calls active on each channel (``timeline.json``) and
the sentence being spoken. The scene's movable objects are drawn where the
emulated board's objects log (``objects.jsonl``, :mod:`firmware_sim.objects_log`) puts them at each
time, at their start poses when the run has none. Frames are rendered offscreen (``MUJOCO_GL=egl`` unless
set) by a pool of worker processes (both cores by default; ``spawn``, so each
worker opens its own GL context) and encoded to H.264 by the ffmpeg binary that
the ``imageio-ffmpeg`` wheel ships. The sound (speech and music at the timeline's times) is then
muxed in as AAC (:mod:`host.run.soundtrack`).
"""

from __future__ import annotations

import json
import logging
import multiprocessing
import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from protocol.framelog import FrameLogError, iter_records

__all__ = ["VideoError", "VideoSettings", "load_states", "render_video"]

log = logging.getLogger("host.run")

WIDTH, HEIGHT = 640, 480  # multiples of 16: H.264 macroblocks, no rescaling by ffmpeg
CAPTION_H = 72
INSET_W, INSET_H = 192, 144


class VideoError(RuntimeError):
    """The video cannot be made (no frame log, no GL renderer, ffmpeg failed); the message says why."""


class VideoInputError(VideoError):
    """The run folder given holds nothing to render (no frame log, an unreadable one, no reports):
    bad input (``ghostshell render`` exits 2)."""


@dataclass(frozen=True)
class VideoSettings:
    fps: int = 25
    workers: int = 2
    distance_m: float = 0.75  # follow camera: distance from the base (m)
    azimuth_deg: float = 140.0
    elevation_deg: float = -22.0


@dataclass(frozen=True)
class States:
    """Recorded simulation state: ``t`` (n,) board seconds, ``base`` (n, 7) pos + quat (w, x, y, z),
    ``joints`` (n, N) servo angles (rad, servo order); ``objects``: per sample the movable objects'
    poses (name -> x y z qw qx qy qz), empty dicts when the run has no objects log."""

    t: np.ndarray
    base: np.ndarray
    joints: np.ndarray
    objects: tuple[dict[str, list[float]], ...] = ()


def load_states(run_dir: Path) -> States:
    """TELEMETRY + SIM_STATE pairs from the run's frame log.

    Serial runs: ``run_dir/board_frames.jsonl`` (the board's own log, its ``tx`` records). CAN runs:
    ``board_frames.log`` (candump; any suffix :data:`host.link.canlog.CAN_LOG_SUFFIXES` names), else the
    host's own capture ``host_frames.<suffix>`` (a CAN capture holds both directions, so a run against a
    board it did not start still has the board's reports), read through :func:`host.link.canlog.iter_can_log`
    (fixed layouts reassembled, SIM_STATE by ISO-TP). Raises :class:`VideoError` when none holds a pair.
    """
    path = run_dir / "board_frames.jsonl"
    if path.exists():
        joints, base = _states_from_jsonl(path)
    else:
        from host.link.canlog import CAN_LOG_SUFFIXES

        found = [run_dir / f"{stem}{suffix}" for stem in ("board_frames", "host_frames") for suffix in CAN_LOG_SUFFIXES]
        found = [p for p in found if p.exists()]
        if not found:
            raise VideoInputError(f"{path} not found (nor a CAN log board_frames.log): the video is made from the "
                                  "board's frame log (board --log); give a run folder (ghostshell run/demo --out)")
        path = found[0]
        joints, base = _states_from_can(path)
    # every TELEMETRY sample from the first SIM_STATE on, each with the latest SIM_STATE at or before
    # it (the same pairs where both come at every report; over CAN a newer SIM_STATE may replace one
    # still queued for ISO-TP, so some TELEMETRY samples have none of their own)
    base_t = sorted(base)
    times = [t for t in sorted(joints) if base_t and t >= base_t[0]]
    if not times:
        raise VideoInputError(f"{path} holds no TELEMETRY/SIM_STATE pairs to render")
    bt = np.asarray(base_t)
    which = np.searchsorted(bt, np.asarray(times), side="right") - 1
    return States(np.asarray(times, dtype=float) * 1e-6, np.asarray([base[base_t[i]] for i in which]),
                  np.asarray([joints[t] for t in times]), _objects_at(run_dir, times))


def _objects_at(run_dir: Path, times: Sequence[int]) -> tuple[dict[str, list[float]], ...]:
    """The objects log's poses at each board time (us): the latest record at or before it."""
    from host.run.artefacts import OBJECTS_LOG

    path = run_dir / OBJECTS_LOG
    if not path.exists():
        return tuple({} for _ in times)
    rec_t: list[int] = []
    rec: list[dict[str, list[float]]] = []
    with open(path, encoding="utf-8") as f:
        for line in f:
            try:
                doc = json.loads(line)
                t, poses = int(doc["t_us"]), {str(k): [float(x) for x in v] for k, v in doc["objects"].items()}
            except (ValueError, KeyError, TypeError, AttributeError):
                continue  # a torn last line (the board was stopped mid-write)
            rec_t.append(t)
            rec.append(poses)
    if not rec:
        return tuple({} for _ in times)
    idx = np.searchsorted(np.asarray(rec_t), np.asarray(times), side="right") - 1
    return tuple(rec[i] if i >= 0 else {} for i in idx)


def _states_from_jsonl(path: Path) -> tuple[dict[int, list[float]], dict[int, list[float]]]:
    """The board's TELEMETRY positions and SIM_STATE poses by board time (us); :class:`VideoInputError`
    naming the file for a damaged or garbage log (a record that is not JSON, a field missing or of the
    wrong kind, not UTF-8, unreadable)."""
    joints: dict[int, list[float]] = {}
    base: dict[int, list[float]] = {}
    try:
        with open(path, encoding="utf-8") as f:
            for rec in iter_records(f):
                if rec.get("dir") != "tx":
                    continue
                kind, fields = rec.get("type"), rec.get("fields") or {}
                if kind == "TELEMETRY":
                    joints[int(fields["board_time_us"])] = [float(x) for x in fields["positions"]]
                elif kind == "SIM_STATE":
                    base[int(fields["board_time_us"])] = [float(x) for x in (*fields["base_pos"], *fields["base_quat"])]
    except FrameLogError as e:  # a torn or garbage line (a board killed mid-write, a file that is no frame log)
        raise VideoInputError(f"{path} is not a readable frame log ({e}); give a run folder whose "
                              "board_frames.jsonl the board wrote whole") from None
    except UnicodeDecodeError as e:
        raise VideoInputError(f"{path} is not a frame log: not UTF-8 text ({e.reason} at byte {e.start})") from None
    except (KeyError, TypeError, ValueError, AttributeError) as e:
        raise VideoInputError(f"{path} holds a TELEMETRY/SIM_STATE record without its fields "
                              f"({type(e).__name__}: {e})") from None
    except OSError as e:
        raise VideoInputError(f"cannot read {path}: {e.strerror or e}") from None
    return joints, base


def _states_from_can(path: Path) -> tuple[dict[int, list[float]], dict[int, list[float]]]:
    """Board-to-host TELEMETRY and SIM_STATE of the first node that reports in a CAN capture."""
    from host.link.canlog import CanLogError, iter_can_log
    from protocol.can import CanItem
    from protocol.can.ids import split_id
    from protocol.messages import SimState, Telemetry

    joints: dict[int, list[float]] = {}
    base: dict[int, list[float]] = {}
    node: int | None = None
    try:
        for e in iter_can_log(path, dbc=False):
            if e.direction != "b>h":
                continue
            for it in e.items:
                if not isinstance(it, CanItem) or not isinstance(it.msg, (Telemetry, SimState)):
                    continue
                n = split_id(e.frame.arbitration_id)[1]
                node = n if node is None else node
                if n != node:
                    continue
                if isinstance(it.msg, Telemetry):
                    joints[it.msg.board_time_us] = list(it.msg.positions)
                else:
                    base[it.msg.board_time_us] = [*it.msg.base_pos, *it.msg.base_quat]
    except ValueError as e:  # python-can cannot read the file (CanLogError names it)
        raise VideoInputError(str(e) if isinstance(e, CanLogError) else f"{path} is not a CAN log python-can reads: {e}") from None
    return joints, base


@dataclass(frozen=True)
class _Call:
    channel: str
    label: str
    start: float
    end: float
    text: str | None


def _calls(run_dir: Path) -> list[_Call]:
    path = run_dir / "timeline.json"
    if not path.exists():
        return []
    out = []
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        for c in doc.get("calls", []):
            if c.get("start") is None or c.get("end") is None or c.get("channel") in (None, "main"):
                continue
            args = c.get("args") or {}
            shown = ", ".join(f"{k}={v}" for k, v in args.items() if k != "text")
            label = f"{c['function']}({shown})" if shown else str(c["function"])
            out.append(_Call(str(c["channel"]), label, float(c["start"]), float(c["end"]),
                             str(args["text"]) if c["function"] == "speak" and "text" in args else None))
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as e:  # a damaged timeline: bad input
        raise VideoInputError(f"{path} is not a readable timeline ({type(e).__name__}: {e}); "
                              "give a run folder whose timeline.json the run wrote whole") from None
    return out


def caption_at(calls: Sequence[_Call], t: float) -> tuple[str, str]:
    """(active calls per channel, the sentence being spoken) at board time ``t``."""
    active: dict[str, list[str]] = {}
    spoken = ""
    for c in calls:
        if c.start <= t <= c.end:
            if c.text is not None:
                spoken = c.text
            else:
                active.setdefault(c.channel, []).append(c.label)
    line = "   ".join(f"{ch}: {' + '.join(labels)}" for ch, labels in active.items())
    return line or "(idle)", spoken


# --- worker side (one GL context per process) -------------------------------------------------

_W: dict[str, Any] = {}


def run_scene(run_dir: Path) -> str:
    """The scene the run's board simulated (``summary.json`` extra.scene.name; "empty" if not recorded)."""
    try:
        doc = json.loads((Path(run_dir) / "summary.json").read_text(encoding="utf-8"))
        scene = (doc.get("extra") or {}).get("scene") or {}
        name = scene.get("name") if isinstance(scene, dict) else scene
    except (OSError, ValueError, AttributeError):
        return "empty"
    return name if isinstance(name, str) and name else "empty"


def _init_worker(settings: VideoSettings, scene: str = "empty", robot: str | None = None,
                 robots_dir: str | None = None) -> None:
    """Set up one render process. Never raises: a Pool whose initializer raises respawns workers
    forever, so a failure is kept and raised by the first :func:`_render` instead."""
    import signal

    # the terminal's Ctrl-C reaches the whole process group: the parent stops the pool (terminate), so a
    # worker ignores SIGINT rather than print a KeyboardInterrupt traceback of its own
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        _setup_worker(settings, scene, robot, robots_dir)
    except Exception as e:
        _W["error"] = e if isinstance(e, VideoError) else VideoError(f"render worker: {type(e).__name__}: {e}")


def _setup_worker(settings: VideoSettings, scene: str, robot: str | None, robots_dir: str | None) -> None:
    os.environ.setdefault("MUJOCO_GL", "egl")
    import mujoco

    from robots.description import RobotDataError
    from robots.registry import DEFAULT_ROBOT, load_robot

    try:
        bot = load_robot(robot or DEFAULT_ROBOT, robots_dir)
        cm = bot.model(scene)  # the run's objects (e.g. bottles) at their start poses
    except (RobotDataError, KeyError, ValueError) as e:
        raise VideoError(f"cannot build the run's robot and scene: {e}") from e
    model = cm.model
    # software GL (EGL on llvmpipe here) spends most of a frame on the 4096² shadow map and 4x MSAA:
    # a 1024² map and no MSAA render a 640x408 view ~4x faster (visual settings only, no physics)
    model.vis.quality.shadowsize = 1024
    model.vis.quality.offsamples = 0
    data = mujoco.MjData(model)
    camera = bot.peripherals.camera
    try:
        main = mujoco.Renderer(model, height=HEIGHT - CAPTION_H, width=WIDTH)
        head = mujoco.Renderer(model, height=INSET_H, width=INSET_W) if camera is not None else None
    except Exception as e:  # no GL backend
        raise VideoError(f"no OpenGL renderer ({type(e).__name__}: {e}); try MUJOCO_GL=egl") from e
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    view = bot.view
    framing = None
    if not cm.floating:  # the floor it lacks, and (no [view]) a camera framed on it: host.run.framing
        from host.run.framing import frame_fixed_base

        static = sum(1 for o in bot.scene(scene).objects if not o.free)
        framing = frame_fixed_base(model, data, cm.qpos_adr, bot.servos.neutral, static_objects=static)
    cam.distance = float(view.get("distance_m", settings.distance_m))
    cam.azimuth = float(view.get("azimuth_deg", settings.azimuth_deg))
    cam.elevation = float(view.get("elevation_deg", settings.elevation_deg))
    framed = framing is not None and not view  # a robot package's own [view] wins
    if framed:
        assert framing is not None
        cam.lookat[:], cam.distance = framing.lookat, framing.distance
    head_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera) if camera is not None else -1
    _W.update(mujoco=mujoco, model=model, data=data, main=main, head=head, cam=cam, head_id=head_id,
              qpos_adr=np.asarray(cm.qpos_adr), rm=cm, label=bot.peripherals.camera_label,
              lookat_z=float(view.get("lookat_z", 0.05)), framing=framing, framed=framed)


def _render(job: tuple[float, np.ndarray, np.ndarray, str, str, dict[str, list[float]]]) -> bytes:
    from PIL import Image, ImageDraw, ImageFont

    if "error" in _W:
        raise _W["error"]
    t, base, joints, line, spoken, objects = job
    data = _W["data"]
    _W["rm"].set_state(data, base, joints, objects)
    cam = _W["cam"]
    framing = _W.get("framing")
    if not _W.get("framed"):  # follow the base (a floating robot, or a [view] of the robot's own)
        cam.lookat[:] = [base[0], base[1], max(_W["lookat_z"], base[2])]
    _W["main"].update_scene(data, cam)
    if framing is not None:
        from host.run.framing import add_floor

        add_floor(_W["main"].scene, framing)
    view = _W["main"].render()
    img = Image.new("RGB", (WIDTH, HEIGHT), (18, 18, 24))
    img.paste(Image.fromarray(view), (0, 0))
    draw = ImageDraw.Draw(img)
    font = ImageFont.load_default(size=15)
    small = ImageFont.load_default(size=13)
    if _W["head"] is not None:
        _W["head"].update_scene(data, _W["head_id"])
        inset = _W["head"].render()
        x0, y0 = WIDTH - INSET_W - 8, 8
        img.paste((235, 235, 235), (x0 - 2, y0 - 2, x0 + INSET_W + 2, y0 + INSET_H + 2))
        img.paste(Image.fromarray(inset), (x0, y0))
        draw.text((x0 + 4, y0 + INSET_H - 18), _W["label"], fill=(255, 255, 255), font=small)
    top = HEIGHT - CAPTION_H
    draw.text((10, top + 8), f"t = {t:6.2f} s", fill=(160, 200, 255), font=font)
    draw.text((110, top + 8), _fit(draw, line, font, WIDTH - 120), fill=(240, 240, 240), font=font)
    if spoken:
        draw.text((10, top + 38), _fit(draw, f"\u201c{spoken}\u201d", font, WIDTH - 20), fill=(255, 220, 120),
                  font=font)
    return img.tobytes()


def _fit(draw: Any, text: str, font: Any, width: int) -> str:
    """``text`` cut (with an ellipsis) to ``width`` pixels."""
    if draw.textlength(text, font=font) <= width:
        return text
    while text and draw.textlength(text + "\u2026", font=font) > width:
        text = text[:-1]
    return text + "\u2026"


# --- driver -------------------------------------------------------------------------------------


def _jobs(states: States, calls: Sequence[_Call], fps: int, t0: float | None
          ) -> Iterator[tuple[float, np.ndarray, np.ndarray, str, str, dict[str, list[float]]]]:
    start = states.t[0] if t0 is None else max(states.t[0], t0)
    times = np.arange(start, states.t[-1] + 1e-9, 1.0 / fps)
    idx = np.clip(np.searchsorted(states.t, times, side="right") - 1, 0, len(states.t) - 1)
    for t, i in zip(times, idx):
        line, spoken = caption_at(calls, float(t))
        objects = states.objects[i] if states.objects else {}
        yield float(t - (t0 or 0.0)), states.base[i], states.joints[i], line, spoken, objects


def render_video(run_dir: Path, out: Path | None = None, settings: VideoSettings | None = None,
                 robots_dir: str | None = None, progress: Callable[[int, int], None] | None = None) -> Path:
    """Render ``run_dir``'s recorded run to ``out`` (default ``run_dir/run.mp4``); returns the path.

    The robot is the one the run's summary.json names (``robots_dir`` is searched first for it).
    ``progress(frames done, frames)`` is called after each frame (e.g. :mod:`host.progress`).
    Raises :class:`VideoError` with the reason when it cannot. The video (and its sound) is written
    to ``<stem>.partial<suffix>`` beside ``out`` and renamed to ``out`` only when it is complete: a
    render that fails or is interrupted (Ctrl-C) leaves no truncated ``run.mp4`` (nor the partial
    file), and an older complete ``out`` stays as it was.
    """
    import imageio_ffmpeg

    settings = settings or VideoSettings()
    run_dir = Path(run_dir)
    out = run_dir / "run.mp4" if out is None else Path(out)
    states = load_states(run_dir)
    calls = _calls(run_dir)
    t0 = None
    tl = run_dir / "timeline.json"
    if tl.exists():
        t0 = json.loads(tl.read_text(encoding="utf-8")).get("t0")
    jobs = list(_jobs(states, calls, settings.fps, t0))
    from host.run.artefacts import run_robot
    from robots.description import RobotDataError
    from robots.registry import load_robot

    try:  # here, not only in the workers: a robot that cannot be found is one clear line
        robot = str(load_robot(run_robot(run_dir), robots_dir).root)
    except RobotDataError as e:
        raise VideoError(f"cannot load the robot the run drove: {e}") from None
    partial = out.with_name(f"{out.stem}.partial{out.suffix}")
    writer = imageio_ffmpeg.write_frames(str(partial), (WIDTH, HEIGHT), fps=settings.fps, codec="libx264",
                                         pix_fmt_out="yuv420p", quality=7, macro_block_size=16,
                                         output_params=["-preset", "veryfast"])
    complete = False
    try:
        writer.send(None)
        ctx = multiprocessing.get_context("spawn")
        with ctx.Pool(max(1, settings.workers), initializer=_init_worker,
                      initargs=(settings, run_scene(run_dir), robot, robots_dir)) as pool:
            for done, frame in enumerate(pool.imap(_render, jobs, chunksize=4), 1):
                writer.send(frame)
                if progress is not None:
                    progress(done, len(jobs))
        writer.close()  # ffmpeg finishes the file here
        if jobs:  # the sound: speech and music where the timeline has them (host.run.soundtrack)
            from host.run.soundtrack import add_soundtrack

            start = float(states.t[0]) if t0 is None else max(float(states.t[0]), float(t0))
            for note in add_soundtrack(run_dir, partial, start, len(jobs) / settings.fps, robots_dir):
                log.warning("%s", note)
        complete = True
    except VideoError:
        raise
    except Exception as e:
        raise VideoError(f"rendering failed: {type(e).__name__}: {e}") from e
    finally:
        if not complete:
            try:
                writer.close()
            except Exception:
                pass
            finally:  # also when a second Ctrl-C cuts the close short (it left a 48-byte file)
                partial.unlink(missing_ok=True)
    os.replace(partial, out)
    return out
