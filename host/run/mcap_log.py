"""A run as Foxglove channels, recorded live to ``run.mcap`` (foxglove-sdk) and shown live (its WebSocket server).

:class:`RunLog` owns one :class:`foxglove.Context`: every channel below is created on it, and each
sink attached to it receives every message: the MCAP writer (:meth:`RunLog.open`) and, with
``--foxglove``, the live WebSocket server (:mod:`host.run.foxglove_live`). All times are **board
time** (the board's clock since it started, ns in MCAP ``log_time`` and in message stamps), so a run
reads the same in Foxglove as in timeline.json.

Channels (written live, :data:`HOLD_S` behind the board's reports, so a killed run leaves an MCAP that is
readable up to its last complete chunk; the writer ends a chunk every :data:`FLUSH_S` board seconds of
log time, and when it reaches :data:`CHUNK_BYTES`). The SDK writes a channel's record with its first
message, so a channel that got none (a run that never speaks has no ``/speech``) is not in the file.

Order: the file's log times never go back (a player that checks message order, or reads the file as a
stream, sees one timeline). Things are known out of time order: a SERVO_FRAME is sent ahead of its apply
time, a call's start line and a photo are noticed a report or a 50 ms poll after they happened. So every
message goes through a reorder buffer on the feeding thread (a heap keyed by log time, then arrival): a
report at board time t writes everything held up to ``t - HOLD_S``, earliest first. Chosen over stamping
targets at their send time because a target plotted at its apply time lines up with the joint state
measured then, which is what the plot is for. Bounded: at most :data:`MAX_HELD` messages (past it the
earliest is written at once) and the buffer is drained by :meth:`RunLog.close`. A message that comes
later than the buffer waited (a turn's Events for calls cut by a stop) is written at the file's latest
log time, its own stamp keeping when it happened (:attr:`RunLog.late` counts them). The live view gets
each message when the file does, :data:`HOLD_S` behind the board:

==========================  ===========================  ===================================================
topic                        schema (encoding)            what, when
==========================  ===========================  ===================================================
``/joint_states``            foxglove.JointStates (pb)    measured position, velocity, effort per servo; each TELEMETRY
``/joint_targets``           foxglove.JointStates (pb)    each SERVO_FRAME sent, at its apply time: the masked servos' targets
``/tf``                      foxglove.FrameTransforms     every body (robot, scene objects) in its parent's frame (:mod:`host.run.scene3d`); each TELEMETRY
``/scene``                   foxglove.SceneUpdate         the robot's and the scene's geoms as primitives, meshes as STL models; at board time 0 (live: then every :data:`SCENE_EVERY_S`)
``/telemetry``               ghostshell.Telemetry (json)  every TELEMETRY field decoded (faults by name)
``/sim_state``               ghostshell.SimState (json)   the emulator's ground truth (base pose, scene objects); each new SIM_STATE
``/link/tx``                 ghostshell.LinkFrame (json)  every host-to-board message: seq, type, decoded fields, serial wire bytes (hex)
``/calls``                   foxglove.Log                 one line when a call starts (board-measured) and one when it ends (outcome, error)
``/calls/events``            foxglove.Event               each finished call at its end: board-measured start/end, function, channel, path, outcome, args
``/speech``                  ghostshell.Speech (json)     each sentence spoken, at its end: text, start/end, outcome (cut sentences end at the cut)
``/camera``                  foxglove.CompressedImage     each photo the robot took (PNG)
``/link/faults``             foxglove.Log                 board fault bits raised/cleared, NACKs, decode errors, re-sent requests, reconnects
``/link/gaps``               ghostshell.SeqGap (json)     each time board messages went missing (gaps in the board's sequence numbers)
==========================  ===========================  ===================================================

(pb = protobuf, the SDK's encoding for its typed channels; json = a JSON channel with a JSON schema.)
``/scene``'s entities are ``frame_locked`` with no lifetime: Foxglove draws them in their body's frame as
``/tf`` moves it, until replaced. Playing a file, Foxglove shows on a seek the last message of each topic
before that time, so the file gets ``/scene`` once, at board time 0 (:meth:`RunLog.prepare`, before the
session streams its first frame); with a live view (:attr:`RunLog.scene_every_s`, set by
:mod:`host.run.foxglove_live`) it is re-sent every :data:`SCENE_EVERY_S` for a viewer that connects late.
The primitives are built once (:mod:`host.run.scene3d`), but each send is the SDK's encoding and chunk
compression of the whole message inside one ``log()`` that holds the GIL (the event loop's thread waits
meanwhile, even though a writer thread calls it): ~20-30 ms for the ~5 MB of an arm with ~100 000 mesh
triangles on a quiet machine, 0.2 s on a loaded one (``bench/bench_recording.py``). That is why the one
send of a file is made before any frame goes out; only a live view's re-sends fall inside a run.
The MCAP also holds a ``run`` metadata record (robot, scene, link, clock) and the robot's MJCF as an
attachment. Everything goes through the SDK; the ``mcap`` package is used only to read files back
(:mod:`host.run.mcap_read`).

Errors: :meth:`RunLog.open` raises :class:`McapError` (one line naming the path and the reason) when
the file cannot be created; the caller decides (a run goes on without its MCAP). A write that fails
later (disk full) stops the recording with one warning; the caller (:mod:`host.run.recording`) also
turns any other exception of a logging method into one warning.
"""

from __future__ import annotations

import dataclasses
import heapq
import json
import logging
from enum import Enum, IntFlag
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import foxglove
from foxglove.channels import (
    CompressedImageChannel,
    EventChannel,
    FrameTransformsChannel,
    JointStatesChannel,
    LogChannel,
    SceneUpdateChannel,
)
from foxglove.mcap import MCAPWriteOptions
from foxglove.messages import CompressedImage, Event, JointState, JointStates, KeyValuePair, Log, LogLevel

from host.run.scene3d import RobotScene, stamp
from protocol.framing import encode_frame
from protocol.messages import FaultFlags, Message, Nack, ServoFrame, SimState, Telemetry, nack_detail
from robots.description import Robot

__all__ = ["FLUSH_S", "HOLD_S", "MAX_HELD", "McapError", "RunLog", "SCENE_EVERY_S", "TOPICS", "board_us"]

log = logging.getLogger("host.run")

#: board seconds of log time between forced chunk ends: a killed run loses at most the last FLUSH_S + HOLD_S
#: of board time
#: (board time, not wall time, so where a lockstep run's file can be cut is reproducible)
FLUSH_S = 1.0
#: board seconds between re-sent scene primitives while a live view is on (a viewer that connects late gets
#: them; a file needs them once, see the module docstring). 5 s: a mesh robot's scene is megabytes
SCENE_EVERY_S = 5.0
#: target uncompressed chunk size; small, so chunks end often and a cut file loses little. A chunk is
#: compressed inside the ``log()`` call that fills it, on the host's event loop: with 256 KiB at zstd's
#: default level that call took 4-5 ms (a token chunk waiting behind it was that much later), with
#: 64 KiB at level 1 (``ZSTD_LEVEL``) at most 0.56 ms (20 000 12-joint JointStates through foxglove-sdk
#: 0.30.3 alone, quiet). A run's mix makes a ~7 % larger file: ``bench/bench_foxglove.py --log-cost``
CHUNK_BYTES = 64 * 1024
#: zstd level of the chunks (1: the fastest; zstd's default is 3)
ZSTD_LEVEL = 1
#: board seconds a message waits in the reorder buffer behind the latest report's time before it is
#: written: what comes later than that (a call's end line polled every 50 ms, a photo stamped with its last
#: chunk) still lands in log-time order. 0.25 s: 5 polls; the live view lags the board by as much
HOLD_S = 0.25
#: messages the reorder buffer holds at most (~0.25 s + the frames' lookahead is a few hundred); past it
#: the earliest is written at once, so the buffer never grows without bound (a board that stopped reporting)
MAX_HELD = 20_000

TOPICS = ("/joint_states", "/joint_targets", "/tf", "/scene", "/telemetry", "/sim_state", "/link/tx", "/calls",
          "/calls/events", "/speech", "/camera", "/link/faults", "/link/gaps")


class McapError(OSError):
    """The MCAP file cannot be written (the message names the path and the reason)."""


def _schema(name: str, properties: Mapping[str, Any]) -> dict[str, Any]:
    return {"title": name, "type": "object", "properties": dict(properties)}


_NUM = {"type": "number"}
_INT = {"type": "integer"}
_STR = {"type": "string"}
_NUMS = {"type": "array", "items": _NUM}

TELEMETRY_SCHEMA = _schema("ghostshell.Telemetry", {
    "board_time_us": _INT, "positions": _NUMS, "velocities": _NUMS, "efforts": _NUMS, "imu_rpy": _NUMS,
    "faults": _STR, "buffer_fill": _INT, "last_applied_seq": _INT, "late_count": _INT, "dropped_count": _INT,
    "link_errors": _INT})
SIM_STATE_SCHEMA = _schema("ghostshell.SimState", {
    "board_time_us": _INT, "base_pos": _NUMS, "base_quat": _NUMS, "objects": _INT, "toppled": _INT})
LINK_FRAME_SCHEMA = _schema("ghostshell.LinkFrame", {
    "seq": _INT, "type": _STR, "fields": {"type": "object"}, "raw": _STR})
SPEECH_SCHEMA = _schema("ghostshell.Speech", {
    "text": _STR, "start_s": _NUM, "end_s": _NUM, "outcome": _STR, "path": _STR})
GAP_SCHEMA = _schema("ghostshell.SeqGap", {
    "board_time_us": _INT, "lost": _INT, "lost_total": _INT})


def _ns(board_time_us: int) -> int:
    return max(0, int(board_time_us)) * 1000


def board_us(board_time_s: float) -> int:
    """Board seconds as whole µs, rounded to the nearest (``int(6.9 * 1e6)`` is 6 899 999: truncation
    put a photo taken at 6.9 s at 6.899999 s)."""
    return round(board_time_s * 1e6)


def _flag_names(f: int) -> str:
    return "|".join(e.name or "" for e in FaultFlags if e.value and f & e) or "NONE"


def _fields(msg: Any) -> dict[str, Any]:
    """A message's fields for a JSON channel: :func:`protocol.framelog.message_fields`' rendering (enums by
    name, flags as ``A|B``, bytes as hex), done per field instead of per element: this runs for every
    report and every frame sent, on the link's own event loop."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(msg):
        v = getattr(msg, f.name)
        if isinstance(v, (IntFlag, Enum, bytes, bytearray)):
            v = message_fields_one(v)
        elif isinstance(v, tuple) and v and not isinstance(v[0], (int, float)):
            v = message_fields_one(v)
        out[f.name] = v
    return out


def message_fields_one(v: Any) -> Any:
    from protocol.framelog import _jsonable  # noqa: PLC2701 (the log's own rendering of one value)

    return _jsonable(v)


class RunLog:
    """The run's Foxglove channels on one context (see the module docstring for topics and timing).

    ``RunLog(robot, scene=None)`` creates the channels (``scene``: the run's scene, whose objects are drawn
    too; None: the robot alone); :meth:`open` adds the MCAP sink (or create it with
    :meth:`create`). Feed it with the ``on_*`` methods from one thread at a time (a session's
    :class:`host.run.recording.Recording` feeds it from its writer thread, :mod:`host.run.log_writer`);
    :meth:`close` finishes the file. ``time_listeners`` get the board time (ns) of every report as it is
    written (:data:`HOLD_S` behind the board), on the feeding thread (the live server broadcasts it as the viewer's clock; the SDK's server is
    thread-safe). The robot's :class:`RobotScene` (its MJCF compiled: 0.15-0.9 s with meshes) is built
    on first use (:attr:`scene`, or :meth:`prepare`), on the feeding thread.
    """

    def __init__(self, robot: Robot, scene: str | None = None) -> None:
        self.robot = robot
        #: the run's scene (robot.toml ``[scenes.NAME]``): its objects are drawn too; None: the robot alone
        self.scene_name = scene
        self.context = foxglove.Context()
        self._scene: RobotScene | None = None
        self.names = list(robot.servos.names)
        ctx = self.context
        self.joint_states = JointStatesChannel("/joint_states", context=ctx)
        self.joint_targets = JointStatesChannel("/joint_targets", context=ctx)
        self.tf = FrameTransformsChannel("/tf", context=ctx)
        self.scene_ch = SceneUpdateChannel("/scene", context=ctx)
        self.telemetry = foxglove.Channel("/telemetry", schema=TELEMETRY_SCHEMA, context=ctx)
        self.sim_state = foxglove.Channel("/sim_state", schema=SIM_STATE_SCHEMA, context=ctx)
        self.link_tx = foxglove.Channel("/link/tx", schema=LINK_FRAME_SCHEMA, context=ctx)
        self.calls = LogChannel("/calls", context=ctx)
        self.call_events = EventChannel("/calls/events", context=ctx)
        self.speech = foxglove.Channel("/speech", schema=SPEECH_SCHEMA, context=ctx)
        self.camera = CompressedImageChannel("/camera", context=ctx)
        self.faults = LogChannel("/link/faults", context=ctx)
        self.gaps = foxglove.Channel("/link/gaps", schema=GAP_SCHEMA, context=ctx)
        self.writer: Any = None
        self.path: Path | None = None
        self.time_listeners: list[Callable[[int], None]] = []
        self.last_us = 0  # latest board time seen (µs)
        self._scene_at: int | None = None
        #: board seconds between re-sent ``/scene`` messages; None: sent once (the live view sets it)
        self.scene_every_s: float | None = None
        self._last_sim: SimState | None = None
        self._pending: Telemetry | None = None  # a report waiting for its SIM_STATE (on_message)
        self._flushed_us = 0
        self.closed = False
        #: the reorder buffer: (log time ns, arrival order, channel, message), earliest first
        self._held: list[tuple[int, int, Any, Any]] = []
        self._arrivals = 0
        self._written_ns = 0  # log time of the latest message written (the file's log times never go back)
        self._tx_ns = 0  # log time of the latest /link/tx message (send order is log-time order)
        #: messages written later than their own time (clamped to the file's latest log time; their
        #: stamps keep the time they happened)
        self.late = 0

    @property
    def scene(self) -> RobotScene:
        """The robot's 3D scene (built on first use)."""
        if self._scene is None:
            self._scene = RobotScene(self.robot, self.scene_name or "empty")
        return self._scene

    def prepare(self) -> None:
        """Build the scene and write ``/scene`` at board time 0, now (a recording does this first thing on
        its writer thread, and the session waits for it before it streams a frame: the SDK holds the GIL
        while it encodes a mesh robot's megabytes, 20-30 ms, which must not land on the control path)."""
        self._scene_at = 0
        self.scene_ch.log(self.scene.scene_update(0), log_time=self._written_ns)  # 0: nothing was written yet

    @classmethod
    def create(cls, path: Path, robot: Robot, meta: Mapping[str, str] | None = None) -> RunLog:
        """A RunLog recording to ``path`` (:class:`McapError` if it cannot be written)."""
        run_log = cls(robot)
        run_log.open(path, meta)
        return run_log

    def open(self, path: Path, meta: Mapping[str, str] | None = None) -> None:
        """Start recording every channel to the MCAP file ``path`` (replaced if it exists)."""
        path = Path(path)
        options = MCAPWriteOptions(chunk_size=CHUNK_BYTES, compression_level=ZSTD_LEVEL, compression_threads=0)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self.writer = foxglove.open_mcap(path, allow_overwrite=True, context=self.context, writer_options=options)
        except (OSError, RuntimeError) as e:
            reason = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
            raise McapError(f"cannot write {path}: {reason}") from e
        self.path = path
        info = {"robot": self.robot.name, "servos": ",".join(self.names), "clock": "board", **(meta or {})}
        self.writer.write_metadata("run", {k: str(v) for k, v in info.items()})
        try:
            mjcf = Path(self.robot.mjcf)
            self.writer.attach(log_time=0, create_time=0, name=mjcf.name, media_type="application/xml",
                               data=mjcf.read_bytes())
        except OSError:
            pass

    # -- telemetry ----------------------------------------------------------------------------
    def on_telemetry(self, tel: Telemetry, sim: SimState | None = None) -> None:
        """One report: joint states and the decoded telemetry; with ``sim`` (the SIM_STATE of its time) also
        that SIM_STATE and the transforms. Without it, give those with :meth:`on_sim_state` and
        :meth:`on_transforms` when they come."""
        t = tel.board_time_us
        self.last_us = max(self.last_us, t)
        ns = _ns(t)
        n = min(len(self.names), len(tel.positions))
        vel, eff = tel.velocities, tel.efforts
        self._put(self.joint_states, JointStates(timestamp=stamp(t), joints=[
            JointState(name=self.names[i], position=float(tel.positions[i]),
                       velocity=float(vel[i]) if i < len(vel) else None,
                       effort=float(eff[i]) if i < len(eff) else None) for i in range(n)]), ns)
        self._put(self.telemetry, _fields(tel), ns)
        if sim is not None:
            self.on_sim_state(sim)
            self.on_transforms(tel, sim)
        self._release(ns - int(HOLD_S * 1e9))

    def on_message(self, msg: Message) -> None:
        """A board-to-host message as it arrives: TELEMETRY and SIM_STATE paired by board time.

        A report's transforms wait for the SIM_STATE of the same board time (the board sends it right
        after the TELEMETRY); when the next report comes first (it was lost, or replaced on CAN) they
        use the latest one. Until a board has sent any SIM_STATE (real hardware never does) they come
        at once, with the root where the MJCF places it. Other messages are ignored.
        """
        if isinstance(msg, Telemetry):
            if self._pending is not None:
                self.on_transforms(self._pending, self._last_sim)
                self._pending = None
            self.on_telemetry(msg)
            if self._last_sim is None:
                self.on_transforms(msg, None)
            else:
                self._pending = msg
        elif isinstance(msg, SimState):
            self.on_sim_state(msg)
            tel, self._pending = self._pending, None
            if tel is not None:
                self.on_transforms(tel, msg)

    def on_sim_state(self, sim: SimState) -> None:
        """The emulator's ground truth (each new SIM_STATE once)."""
        if sim is not self._last_sim:
            self._last_sim = sim
            self._put(self.sim_state, _fields(sim), _ns(sim.board_time_us))

    def on_transforms(self, tel: Telemetry, sim: SimState | None) -> None:
        """The robot's frames at ``tel``'s joint angles, its base where ``sim`` puts it (None: where the
        MJCF places it), and the scene's primitives when they are due."""
        t = tel.board_time_us
        ns = _ns(t)
        every = self.scene_every_s
        if self._scene_at is None or (every is not None and t - self._scene_at >= every * 1e6):
            self._scene_at = t
            self._put(self.scene_ch, self.scene.scene_update(t), ns)
        base = (sim.base_pos, sim.base_quat) if sim is not None else None
        self._put(self.tf, self.scene.transforms(t, tel.positions[:len(self.names)], base), ns)

    def on_frame_sent(self, seq: int, msg: Message, board_time_us: int) -> None:
        """A host-to-board message went out (``board_time_us``: the board clock estimate at sending).

        ``/link/tx`` gets it at ``board_time_us`` (never before the previous one: send order); a
        SERVO_FRAME's targets go to ``/joint_targets`` at its apply time, which is ahead (the reorder
        buffer holds them until the reports catch up). The frame's ``targets`` are packed: one per set
        bit of ``mask``, lowest servo first (a frame for servos 10 and 11 carries two values)."""
        try:
            raw = encode_frame(msg, seq).hex()
        except (ValueError, OverflowError):
            raw = ""
        self._tx_ns = max(self._tx_ns, _ns(board_time_us))
        self._put(self.link_tx, {"seq": seq, "type": type(msg).__name__, "fields": _fields(msg), "raw": raw},
                  self._tx_ns)
        if isinstance(msg, ServoFrame):
            servos = [i for i in range(msg.mask.bit_length()) if msg.mask >> i & 1]
            joints = [JointState(name=self.names[i], position=float(q))
                      for i, q in zip(servos, msg.targets) if i < len(self.names)]
            self._put(self.joint_targets, JointStates(timestamp=stamp(msg.apply_at_us), joints=joints),
                      _ns(msg.apply_at_us))

    # -- calls, speech, images ----------------------------------------------------------------
    def on_call_start(self, path: str, function: str, channel: str | None, args: Mapping[str, Any],
                      board_time_s: float) -> None:
        t = board_us(board_time_s)
        self._put(self.calls, Log(timestamp=stamp(t), level=LogLevel.Info, name=channel or "main",
                                  message=f"start {path} {function}({_args(args)})"), _ns(t))

    def on_call_end(self, path: str, function: str, channel: str | None, outcome: str, error: str | None,
                    board_time_s: float) -> None:
        level = LogLevel.Info if outcome in ("done", "interrupted", "cancelled") else LogLevel.Warning
        text = f"end {path} {function}: {outcome}" + (f": {error}" if error else "")
        t = board_us(board_time_s)
        self._put(self.calls, Log(timestamp=stamp(t), level=level, name=channel or "main", message=text), _ns(t))

    def on_call(self, record: Any) -> None:
        """A finished call (``host.run.artefacts.BoardCall``: board-measured times) as an Event, logged at
        its end (when it is known; the Event's start and end times say when it ran)."""
        if record.start is None:
            return
        start_us = board_us(record.start)
        end_us = max(start_us, board_us(record.end if record.end is not None else record.start))
        meta = {"function": record.function, "channel": record.channel or "", "path": record.path,
                "outcome": record.outcome, "args": json.dumps(record.args, ensure_ascii=False, default=str),
                **({"error": record.error} if record.error else {})}
        self._put(self.call_events, Event(start_time=stamp(start_us), end_time=stamp(end_us),
                                          metadata=[KeyValuePair(key=k, value=str(v)) for k, v in meta.items()]),
                  _ns(end_us))

    def on_speech(self, text: str, start_s: float, end_s: float | None, outcome: str, path: str = "") -> None:
        """A sentence that was spoken from ``start_s`` to ``end_s`` (board seconds; cut sentences end at the
        cut), logged at its end (when it is known)."""
        end = end_s if end_s is not None else start_s
        self._put(self.speech, {"text": text, "start_s": start_s, "end_s": end, "outcome": outcome, "path": path},
                  _ns(max(board_us(start_s), board_us(end))))

    def on_image(self, board_time_s: float, png: bytes, frame_id: str = "camera") -> None:
        """A photo (PNG bytes) taken at ``board_time_s``."""
        t = board_us(board_time_s)
        self._put(self.camera, CompressedImage(timestamp=stamp(t), frame_id=frame_id, data=png, format="png"), _ns(t))

    # -- link ---------------------------------------------------------------------------------
    def on_fault(self, board_time_us: int, raised: int, cleared: int) -> None:
        """Board fault bits changed (``host.link.client.FaultEvent``)."""
        parts = ([f"raised {_flag_names(raised)}"] if raised else []) + ([f"cleared {_flag_names(cleared)}"] if cleared else [])
        level = LogLevel.Error if raised & (FaultFlags.ESTOP | FaultFlags.WATCHDOG_FAULT) else LogLevel.Warning
        self.link_note("board fault " + ", ".join(parts), board_time_us, level)

    def on_nack(self, nack: Nack, board_time_us: int) -> None:
        reason = getattr(nack.reason, "name", str(nack.reason))
        kind = getattr(nack.msg_type, "name", str(nack.msg_type))
        self.link_note(f"NACK {kind} seq {nack.ack_seq}: {reason}: {nack_detail(nack)}",
                       board_time_us, LogLevel.Warning)

    def on_gap(self, board_time_us: int, lost: int, lost_total: int) -> None:
        """``lost`` board messages went missing since the last report (``lost_total`` since the handshake)."""
        self._put(self.gaps, {"board_time_us": board_time_us, "lost": lost, "lost_total": lost_total},
                  _ns(board_time_us))

    def link_note(self, text: str, board_time_us: int, level: LogLevel = LogLevel.Warning) -> None:
        """One line on ``/link/faults``."""
        self._put(self.faults, Log(timestamp=stamp(board_time_us), level=level, name="link", message=text),
                  _ns(board_time_us))

    # -- the reorder buffer ---------------------------------------------------------------------
    def _put(self, channel: Any, msg: Any, ns: int) -> None:
        """Hold ``msg`` for ``channel`` at log time ``ns`` until :meth:`_release` passes it (the earliest
        goes at once past :data:`MAX_HELD`)."""
        heapq.heappush(self._held, (ns, self._arrivals, channel, msg))
        self._arrivals += 1
        if len(self._held) > MAX_HELD:
            self._write(*heapq.heappop(self._held))

    def _release(self, upto_ns: int) -> None:
        """Write every held message with a log time up to ``upto_ns``, earliest first (same time: in the
        order they came), and end the chunk each :data:`FLUSH_S` of log time."""
        held = self._held
        while held and held[0][0] <= upto_ns:
            self._write(*heapq.heappop(held))
        if self._written_ns - self._flushed_us * 1000 >= FLUSH_S * 1e9:
            self._flushed_us = self._written_ns // 1000
            self.flush()

    def _write(self, ns: int, _order: int, channel: Any, msg: Any) -> None:
        if ns < self._written_ns:  # later than the buffer could wait: at the file's time, its stamp says when
            ns = self._written_ns
            self.late += 1
        self._written_ns = ns
        channel.log(msg, log_time=ns)
        if channel is self.joint_states:  # the live view's clock: the board time written so far
            for cb in list(self.time_listeners):
                cb(ns)

    def drain(self) -> None:
        """Write everything held now, in log-time order (:meth:`close` does this first)."""
        self._release(1 << 62)

    # -- file ---------------------------------------------------------------------------------
    def flush(self) -> None:
        """End the current chunk and flush the file (what is written so far survives a kill)."""
        if self.writer is not None and not self.closed:
            try:
                self.writer.flush()
            except (OSError, RuntimeError) as e:  # disk full, file removed: stop recording, keep running
                log.warning("ghostshell: run.mcap: %s; recording stopped", e)
                self._drop_writer()

    def _drop_writer(self) -> None:
        writer, self.writer = self.writer, None
        if writer is not None:
            try:
                writer.close()
            except (OSError, RuntimeError):
                pass

    def close(self) -> None:
        """Finish the MCAP (summary, statistics, index) and close every channel. Idempotent."""
        if self.closed:
            return
        if self._pending is not None:
            self.on_transforms(self._pending, self._last_sim)
            self._pending = None
        self.drain()
        self.closed = True
        try:
            if self.writer is not None:
                self.writer.close()
        except (OSError, RuntimeError) as e:
            log.warning("ghostshell: run.mcap: cannot finish %s: %s", self.path, e)
        self.writer = None
        for ch in (self.joint_states, self.joint_targets, self.tf, self.scene_ch, self.telemetry, self.sim_state,
                   self.link_tx, self.calls, self.call_events, self.speech, self.camera, self.faults, self.gaps):
            ch.close()


def _args(args: Mapping[str, Any]) -> str:
    text = ", ".join(f"{k}={v!r}" for k, v in args.items())
    return text if len(text) <= 200 else text[:199] + "\u2026"

