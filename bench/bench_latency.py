"""Token -> servo latency over the 30 paper tasks, on a real board subprocess over a pty.

For every function token of every task's ground-truth program, replayed by the
scripted LLM at 30 tokens/s:

    latency = (board time of the first board tick that applies the call's first frame)
              - (board time at which the chunk that completes the function token reached the shell)

The completing chunk is found by re-feeding the recorded chunks to a fresh
``FunctionTokenParser`` (a tag completes in the chunk holding its closing ``>``)
and numbering the elements exactly as the scheduler does (``wait[0]/head_act[0]``).
Speech has no tag: a ``speak`` call completes in the chunk that ends its sentence
(or the next tag / the end of the stream); it is reported with the peripherals.
The board start comes from telemetry (``RunReport.calls``): for motion, the grid
time of the segment's first frame once telemetry shows that frame applied (the
board applies a frame at the first 2 ms control tick at or after its time; frames
are on a 10 ms grid, so that tick is the frame time); for face / music / speech
the board time the peripheral command was scheduled at (and the board reached);
for the camera the board time the capture was requested. A message that reached the board after
its due time (the board's frame log, ``board_frames.jsonl``, stamps every received message with the
board time it arrived) took effect at the first tick after it arrived, not at its due time: the
start is then ``tick_of(arrival)`` and the call counts as *arrived late* (printed with its n). A link
whose board log is not JSON Lines (CAN) is not checked, and the output says so.

Calls that the scheduler holds back (same channel busy, ``<wait>`` barriers) do
not start when their token completes; their token -> servo time is mostly the
program's own ordering. They are counted as *queued* and reported apart, with
``ready -> servo`` = board start - max(chunk arrival, the moment the scheduler
released the call). The headline p50/p99 is over *immediate* motion calls.

What it is made of (host/motion/streamer.py, host/runtime/robot_runtime.py, firmware_sim):

* a new call's first frame is due at the board's now + the link's measured latency (TIME_SYNC
  round trips; with ``--baud`` the frame's wire time too) + the host's own send path (planning the
  start to writing it, ``FrameStreamer.send_path_us``), both for a quick arrival (their 0.1 quantile,
  ``FrameStreamer.start_due_us``), rounded up to the 2 ms control tick: the frames
  already sent for its servos (the 60 ms lookahead) are FLUSHed and re-sent, not waited out; the
  board applies it at the first tick at or after that time, or, when it arrives later, at the first
  tick after it arrived;
* host work between the chunk and the first frame (parse, map, plan the trajectory in numpy; about
  a millisecond on a quiet machine, several when the cores are shared);
* face / music / speech commands start at the same time a motion would; speech is synthesised (espeak-ng,
  in a worker thread) before it is scheduled, so its latency adds the synthesis time;
* telemetry (50 Hz) does *not* add to this latency - it only delays when the host *learns* the
  frame was applied;
* in lockstep the board clock only advances as frames are sent and chunk times are quantised to
  telemetry reports, so a new call starts at the first unsent frame (60-70 ms after the chunk in
  board time); lockstep latencies measure scheduling, not the link.

Calls on one channel are planned back to back (the next starts at the previous one's planned end;
the shell releases it ~0.26 s before that end), so their ``ready -> servo`` is that planning lead.

Run (realtime is the real measurement; ~4-5 min for all 30 tasks):

    python bench/bench_latency.py                       # all 30 tasks, realtime over a pty
    python bench/bench_latency.py --tasks 1,5,23        # a few tasks
    python bench/bench_latency.py --lockstep            # the same on a lockstep board
    python bench/bench_latency.py --baud 115200         # the board models 115200-baud wire time
    python bench/bench_latency.py --link can:slcan:pty  # over CAN: the board is a SLCAN adapter on a pty
    python bench/bench_latency.py --json lat.json --out runs/bench_latency

More calls, load and priority (issue 17):

    python bench/bench_latency.py --repeat 2            # every task twice (>= 200 calls for the p99)
    python bench/bench_latency.py --load                # a busy-loop subprocess per core meanwhile (said in the output)
    python bench/bench_latency.py --nice 0              # leave host and board at their priority

Every percentile is printed with its n; the header gives the 1-minute load average at the start.
A realtime run also prints the machine floor before and after its runs (``--floor N``, :mod:`_machine`):
how late N 2-ms sleeps of this process wake at its priority, the kind of wait the board's loop does
between ticks; and the CPU steal of its runs (``/proc/stat``): on a virtual machine the hypervisor's
other guests take the CPUs now and then, which no priority inside the guest wins back. Both could
account for some of the spread of the token -> servo p99 from run to run; that was not measured.
``--load`` starts ``os.cpu_count()`` ``while True: pass`` subprocesses before anything else (so they
keep nice 0) and kills them at the end, also on Ctrl-C or an error.

Where the tail comes from: on a loaded machine the host's event loop and the board's control loop
are simply not running when a chunk arrives or a tick is due (a run queue of 5-10 on 2 cores: tens
of ms per wait), which dwarfs the host's own work per call (parse, map, plan: ~1 ms) and adds to the
link's measured uplink that a start is planned with. The lever is priority: by default
(``--nice -10``) this process (the host) lowers its nice value by 10 where permitted (root or
``CAP_SYS_NICE``; otherwise it says so and runs as it is) and its board inherits that
(``$GHOSTSHELL_BOARD_NICE=0``); a realtime board started any other way raises its own priority
(:mod:`firmware_sim.priority`). Under CFS a nice -10 task gets ~10x the share of a nice 0 hog, so the
hogs of ``--load`` mostly stop delaying ticks and the host's sends.

Numbers depend on the machine and its load; they are printed, never asserted.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from _machine import MAX_FLOOR_N, MIN_FLOOR_N, cpu_steal_s, floor_line, floor_stats, steal_line, wakeup_lateness_ms
from _tasks_common import fmt, home_channels, output_folder, run_task, selected_tasks, stats_ms, task_arguments
from host.commands.inputs import baud_rate
from host.link import HandshakeError, LinkConfigError, LinkError
from host.run.runner import RunReport
from host.speech.sentences import SentenceSplitter
from host.shell.parser import EmptyTag, EndTag, FunctionTokenParser, StartTag, Text
from host.shell.registry import Registry
from robots.description import Robot

NOT_CALLS = ("wait", "async", "RUN", "SAVE")


@dataclass
class CallLatency:
    """One function token's timing (board seconds, latencies in ms)."""

    task: int
    path: str
    function: str
    channel: str  # home channel
    kind: str  # "motion" | "peripheral"
    chunk: int  # index of the chunk that completed the token
    t_chunk: float
    t_board: float
    queued: bool  # the scheduler held it back behind earlier calls (or a queued ancestor)
    host_ms: float  # scheduler release - t_chunk (event-loop and queueing delay on the host)
    token_ms: float  # t_board - t_chunk
    ready_ms: float  # t_board - max(t_chunk, scheduler release)
    dispatch_skew_ms: float  # scheduler dispatch time - t_chunk (consistency check, ~0)
    arrived_late: bool = False  # the board received its first message after its due time (started at the next tick)


#: the fields of a received message that say when it is due on the board (µs), by message type
#: (protocol.messages); a motion's start is its FLUSH and first frame, a peripheral's its command
DUE_FIELDS = {"SERVO_FRAME": "apply_at_us", "FLUSH": "from_us", "SPEAKER": "start_at_us", "SCREEN": "start_at_us"}
MOTION_TYPES = frozenset({"SERVO_FRAME", "FLUSH"})


def board_arrivals(run_dir: Path) -> dict[tuple[int, str], float] | None:
    """``(due time in board µs, "motion" | "peripheral")`` -> the board time (s) by which the messages
    due then had reached the board, from the board's JSON Lines frame log in ``run_dir``; None when the
    run has none (a CAN link logs in a CAN format). Motion: the latest FLUSH or SERVO_FRAME due then (a
    start's FLUSH and first frame; the lookahead frames due then came long before). Peripheral: per
    command type the first copy (the board acts on the first; a re-sent request is a later copy), then
    the latest over the types. Two starts due at the same tick share one value."""
    log = run_dir / "board_frames.jsonl"
    if not log.exists():
        return None
    motion: dict[int, float] = {}
    first_copy: dict[tuple[int, str], float] = {}
    with log.open(encoding="utf-8") as f:
        for line in f:
            rec = json.loads(line)
            name = DUE_FIELDS.get(rec.get("type", ""))
            due = rec["fields"].get(name) if name is not None and rec.get("dir") == "rx" else None
            if not isinstance(due, int):
                continue
            t = float(rec["t"])
            if rec["type"] in MOTION_TYPES:
                motion[due] = max(motion.get(due, 0.0), t)
            else:
                first_copy.setdefault((due, rec["type"]), t)
    out = {(due, "motion"): t for due, t in motion.items()}
    for (due, _), t in first_copy.items():
        out[due, "peripheral"] = max(out.get((due, "peripheral"), 0.0), t)
    return out


def completing_chunks(chunks: list[str], speech_name: str = "speak") -> dict[str, int]:
    """Element path -> index of the chunk that completed it, numbering as the scheduler does.

    ``<RUN>``/``<SAVE>`` (skills) are not expanded; the ground-truth programs do not use them.
    """
    parser = FunctionTokenParser(strict=True)
    stack: list[tuple[str, dict[str, int]]] = [("", {})]
    text = SentenceSplitter()
    done: dict[str, int] = {}

    def path(name: str) -> str:
        base, counts = stack[-1]
        i = counts.get(name, 0)
        counts[name] = i + 1
        return f"{base}/{name}[{i}]" if base else f"{name}[{i}]"

    def speak(segments: list[str], k: int) -> None:
        for _ in segments:
            done[path(speech_name)] = k

    def events(evs: list[Any], k: int) -> None:
        for ev in evs:
            if isinstance(ev, Text):
                speak(text.feed(ev.text), k)
            elif isinstance(ev, (StartTag, EmptyTag)):
                speak(text.flush(), k)
                if ev.name in ("RUN", "SAVE"):
                    raise ValueError(f"<{ev.name}> (skills) is not supported by this benchmark")
                p = path(ev.name)
                done[p] = k
                if isinstance(ev, StartTag):
                    stack.append((p, {}))
            elif isinstance(ev, EndTag):
                speak(text.flush(), k)
                if len(stack) > 1:
                    stack.pop()

    for k, chunk in enumerate(chunks):
        events(parser.feed(chunk), k)
    last = max(len(chunks) - 1, 0)
    events(parser.close(), last)
    speak(text.flush(), last)
    return done


def queued_paths(records: list[Any]) -> set[str]:
    """Paths of calls the scheduler held back, rebuilt from the timeline with its rules.

    Call ``j`` depends on every call still pending when ``j`` was dispatched that is on its
    channel, or when either is on the main channel, except ``j``'s ancestors; a call under a
    queued ancestor waits for that ancestor's activation, so it is queued too.
    """
    from host.shell.types import MAIN_CHANNEL

    queued: set[str] = set()
    for j, r in enumerate(records):
        ancestors = {r.path.rsplit("/", i)[0] for i in range(1, r.path.count("/") + 1)}
        if ancestors & queued:
            queued.add(r.path)
            continue
        for p in records[:j]:
            pending = p.end is None or p.end > r.dispatch
            if (pending and p.function != "RUN" and p.path not in ancestors
                    and (MAIN_CHANNEL in (p.channel, r.channel) or (r.channel is not None and p.channel == r.channel))):
                queued.add(r.path)
                break
    return queued


#: the board's control tick (s): a frame or peripheral command due at t takes effect at the first tick >= t
TICK_S = 0.002


def tick_of(t: float) -> float:
    """The first control tick at or after board time ``t`` (s)."""
    return math.ceil(round(t / TICK_S, 6)) * TICK_S


def task_latencies(task: int, rep: RunReport, registry: Registry,
                   motion: frozenset[str] = frozenset()) -> tuple[list[CallLatency], list[str]]:
    """The latency of every function token of one run, and notes about calls left out. A call whose
    message reached the board after its due time starts at the first tick after it arrived
    (:func:`board_arrivals`, from the run's folder ``rep.out``)."""
    arrivals = board_arrivals(rep.out)
    notes: list[str] = []
    speech = registry.speech
    done = completing_chunks([c for _, c in rep.token_times], speech.name if speech else "speak")
    board = {c.path: c for c in rep.calls}
    out: list[CallLatency] = []
    queued = queued_paths(list(rep.result.timeline))
    for r in rep.result.timeline:
        if r.function in NOT_CALLS:
            continue
        k = done.get(r.path)
        call = board.get(r.path)
        if k is None:
            notes.append(f"task {task} {r.path}: no completing chunk found")
            continue
        if r.start is None or call is None or call.start is None:
            notes.append(f"task {task} {r.path}: never started ({r.outcome}{': ' + r.error if r.error else ''})")
            continue
        try:
            channel = registry.resolve(r.function).channel
        except LookupError:
            channel = r.channel or "?"
        t_chunk = rep.token_times[k][0]
        t_ready = rep.result.t0 + r.start
        kind = "motion" if channel in motion else "peripheral"
        arrived = arrivals.get((round(call.start * 1e6), kind), 0.0) if arrivals is not None else 0.0
        start = tick_of(max(call.start, arrived))
        out.append(CallLatency(
            task=task, path=r.path, function=r.function, channel=channel,
            kind=kind, chunk=k, t_chunk=t_chunk, t_board=start,
            queued=r.path in queued, host_ms=(t_ready - t_chunk) * 1e3, token_ms=(start - t_chunk) * 1e3,
            ready_ms=(start - max(t_chunk, t_ready)) * 1e3,
            dispatch_skew_ms=(rep.result.t0 + r.dispatch - t_chunk) * 1e3, arrived_late=arrived > call.start))
    return out, notes


def _summary(rows: list[CallLatency]) -> dict[str, Any]:
    def pick(kind: str, queued: bool | None) -> list[CallLatency]:
        return [c for c in rows if c.kind == kind and (queued is None or c.queued == queued)]

    return {
        "motion_immediate_token_ms": stats_ms([c.token_ms for c in pick("motion", False)]),
        "motion_queued_token_ms": stats_ms([c.token_ms for c in pick("motion", True)]),
        "motion_all_ready_ms": stats_ms([c.ready_ms for c in pick("motion", None)]),
        "peripheral_immediate_token_ms": stats_ms([c.token_ms for c in pick("peripheral", False)]),
        "peripheral_all_ready_ms": stats_ms([c.ready_ms for c in pick("peripheral", None)]),
        "by_channel_ready_ms": {ch: stats_ms([c.ready_ms for c in rows if c.channel == ch])
                                for ch in sorted({c.channel for c in rows})},
        "immediate_arrived_late": sum(c.arrived_late for c in rows if not c.queued),
        "max_abs_dispatch_skew_ms": round(max((abs(c.dispatch_skew_ms) for c in rows), default=0.0), 3),
    }


def _line(name: str, s: dict[str, Any]) -> str:
    return (f"{name:<36} n={s['n']:4d}  p50={fmt(s['p50'])}  p99={fmt(s['p99'])}  max={fmt(s['max'])}"
            f"  min={fmt(s['min'])}  mean={fmt(s['mean'])}  ms")


@contextlib.contextmanager
def cpu_load(n: int) -> Iterator[list[subprocess.Popen[bytes]]]:
    """``n`` busy-loop subprocesses (a CPU hog per core) for the span of the block, killed at its end
    (also on an exception or Ctrl-C); yields them so the caller can say how many ran."""
    procs: list[subprocess.Popen[bytes]] = []
    try:
        for _ in range(n):
            # stderr too: a Ctrl-C reaches the hogs (the terminal's process group) before they are
            # killed, and each printed its KeyboardInterrupt traceback under the bench's own line
            procs.append(subprocess.Popen([sys.executable, "-c", "while True: pass"], stdin=subprocess.DEVNULL,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        yield procs
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait()


#: 2-ms sleeps per floor measurement (``--floor``)
DEFAULT_FLOOR_N = 2000


def load_1min() -> float:
    """The 1-minute load average (``os.getloadavg``)."""
    return os.getloadavg()[0]


def main(argv: list[str] | None = None) -> int:
    ap = task_arguments(__doc__.splitlines()[0], "also write every call and the summary as JSON")
    ap.add_argument("--lockstep", action="store_true", help="lockstep board instead of realtime")
    ap.add_argument("--baud", type=baud_rate, default=None, help="the board models wire time at this baud rate")
    ap.add_argument("--link", default="pty", metavar="SPEC",
                    help="link spec the board is started on (default pty; e.g. can:slcan:pty, 'can:slcan:pty?fd=1', "
                         "can:socketcan:vcan0 inside UML)")
    ap.add_argument("--servo-bus-plant", choices=("sts", "dxl2"), default=None, metavar="PROTOCOL",
                    help="the real-bus path: the board drives a servo bus (--servo-bus) on a pty served by the plant "
                         "(python -m firmware_sim.plant, realtime, 1 Mbaud) in this protocol, as a USB adapter appears")
    ap.add_argument("--repeat", type=int, default=1, metavar="K",
                    help="run the selected task set K times (more calls for the percentiles; default 1)")
    ap.add_argument("--load", action="store_true",
                    help="run a CPU hog (a busy-loop subprocess) on every core (os.cpu_count()) meanwhile")
    ap.add_argument("--nice", type=int, default=-10, metavar="N",
                    help="nice increment for this host process and its board (default -10; 0: leave as is)")
    ap.add_argument("--floor", type=int, default=None, metavar="N",
                    help="before and after a realtime run, time N 2-ms sleeps at this priority: the machine's "
                         f"wake-up lateness (default {DEFAULT_FLOOR_N}, ~4 s each; 0: skip; {MIN_FLOOR_N}-{MAX_FLOOR_N})")
    args = ap.parse_args(argv)
    if args.repeat < 1:
        ap.error("--repeat: expected K >= 1")
    if args.servo_bus_plant and (args.lockstep or args.link != "pty"):
        ap.error("--servo-bus-plant: a realtime board over --link pty (the plant runs on the wall clock)")
    if args.floor is not None and args.lockstep:
        ap.error("--floor: a lockstep board does not wait on the wall clock; give --floor only for a realtime run")
    if args.floor is not None and args.floor != 0 and not MIN_FLOOR_N <= args.floor <= MAX_FLOOR_N:
        ap.error(f"--floor: expected 0 (skip) or {MIN_FLOOR_N} <= N <= {MAX_FLOOR_N}, got {args.floor}")
    from protocol.linkspec import LinkSpecError, parse_link_spec

    try:
        parse_link_spec(args.link)
    except LinkSpecError as e:
        ap.error(f"--link: {e}")
    robot, programs = selected_tasks(ap, args)  # a bad --robot or --tasks: a usage error before any run
    root = output_folder(ap, args, "bench_latency_")
    try:
        with cpu_load((os.cpu_count() or 1) if args.load else 0) as hogs:  # the hogs keep nice 0
            print(raise_host_priority(args.nice), flush=True)
            with servo_bus_plant(args.servo_bus_plant, robot) as servo_bus:
                return _run(args, len(hogs), robot, programs, root, servo_bus)
    except KeyboardInterrupt:  # the hogs are gone (cpu_load), a run's board stopped with its session
        signal.signal(signal.SIGINT, signal.SIG_DFL)  # a further Ctrl-C ends the process: no traceback, no hang
        print("bench_latency: interrupted; no summary (the runs so far are in their folders)", file=sys.stderr)
        return 130


def raise_host_priority(inc: int) -> str:
    """Lower this process's nice value by ``-inc`` (the host; the board it starts inherits it and keeps
    it: ``$GHOSTSHELL_BOARD_NICE=0``); returns what happened, also when it was not permitted."""
    os.environ["GHOSTSHELL_BOARD_NICE"] = "0"
    if inc == 0:
        return f"priority: host and board at nice {os.nice(0)} (--nice 0)"
    from firmware_sim.priority import lower_nice

    try:
        before, after = lower_nice(inc)
    except PermissionError:
        os.environ.pop("GHOSTSHELL_BOARD_NICE")  # the board tries on its own (and says what happened)
        return f"priority: host at nice {os.nice(0)}: --nice {inc} not permitted (needs root or CAP_SYS_NICE)"
    return f"priority: host and board at nice {after} (--nice {inc}; the --load hogs at {before})"


@contextlib.contextmanager
def servo_bus_plant(protocol: str | None, robot: Robot) -> Iterator[tuple[str, ...]]:
    """With ``protocol``: the plant (``python -m firmware_sim.plant``, realtime, 1 Mbaud) serving ``robot``'s
    servos on a pty for the whole benchmark, and the board arguments that put it under the board
    (``--servo-bus PTY:1000000 --bus-protocol PROTOCOL``); without: no plant, ``()``. The plant's bus-time
    line is printed when it stops."""
    if protocol is None:
        yield ()
        return
    proc = subprocess.Popen([sys.executable, "-m", "firmware_sim.plant", "--robot", str(robot.root), "--protocol",
                             protocol, "--baud", "1000000"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    line = proc.stdout.readline().strip()
    try:
        if not line.startswith("plant: servo bus on "):
            raise SystemExit(f"bench_latency: the plant did not start: {line!r}")
        port = line.removeprefix("plant: servo bus on ")
        print(f"real-bus path: the board drives {protocol} servos at 1 Mbaud on {port} (the plant)", flush=True)
        yield ("--servo-bus", f"{port}:1000000", "--bus-protocol", protocol)
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=30)
        print("".join(x for x in err.splitlines(keepends=True) if "bus time" in x or "lateness" in x).rstrip(), flush=True)


def _run(args: Any, hogs: int, robot: Robot, programs: list[tuple[int, str]], root: Path,
         servo_bus: tuple[str, ...] = ()) -> int:
    registry = home_channels(robot=robot)
    motion_channels = frozenset(robot.channels) | {"joints"}  # the generic pose/joint_move channel
    mode = ("lockstep" if args.lockstep else "realtime") + (f", {args.baud} baud wire" if args.baud else "")
    load = (f"under --load: {hogs} busy-loop processes (one per core)" if hogs else "no added load")
    print(f"token -> servo latency, {mode} board over {args.link}, {args.tokens_per_s:g} tokens/s, "
          f"{len(programs)} task(s) x {args.repeat}; {load}; 1-min load average at start "
          f"{load_1min():.2f} on {os.cpu_count()} cores; artefacts in {root}", flush=True)
    floor_n = 0 if args.lockstep else (DEFAULT_FLOOR_N if args.floor is None else args.floor)
    floors: dict[str, Any] = {}
    if floor_n:
        floors["start"] = floor_stats(wakeup_lateness_ms(floor_n))
        print(floor_line("start", floors["start"]), flush=True)
    steal0, wall0 = cpu_steal_s(), time.monotonic()
    print(f"{'task':>4} {'calls':>5} {'queued':>6}  {'motion imm. n':>13} {'p50':>7} {'max':>7}  "
          f"{'periph imm. n':>13} {'p50':>7} {'max':>7}  {'ready max':>9}  {'wall s':>6}  outcome", flush=True)
    rows: list[CallLatency] = []
    notes: list[str] = []
    failed: list[str] = []
    unchecked = 0  # runs whose board log cannot show late arrivals
    for rep_i, (tid, program) in ((r, tp) for r in range(args.repeat) for tp in programs):
        w0 = time.monotonic()
        try:
            rep = run_task(tid, program, lockstep=args.lockstep,
                           out_root=root / f"r{rep_i}" if args.repeat > 1 else root, tokens_per_s=args.tokens_per_s,
                           seed=args.seed, wire_baud=args.baud, link=args.link, robot=str(robot.root),
                           servo_bus=servo_bus)
        except (HandshakeError, LinkConfigError) as e:  # no run can work (wrong link, wrong robot): stop here
            print(f"bench_latency: {e}", file=sys.stderr)
            return 1 if isinstance(e, HandshakeError) else 2
        except LinkError as e:  # the run ended (its board latched a fault, the link went): say so, measure the rest
            failed.append(f"task {tid} (repetition {rep_i + 1}): {e}")
            print(f"{tid:>4} failed: {e}", flush=True)
            continue
        got, why = task_latencies(tid, rep, registry, motion_channels)
        unchecked += not (rep.out / "board_frames.jsonl").exists()
        rows += got
        notes += why
        mi = stats_ms([c.token_ms for c in got if c.kind == "motion" and not c.queued])
        pi = stats_ms([c.token_ms for c in got if c.kind == "peripheral" and not c.queued])
        ready = max((c.ready_ms for c in got), default=None)
        print(f"{tid:>4} {len(got):>5} {sum(c.queued for c in got):>6}  {mi['n']:>13} {fmt(mi['p50'])} {fmt(mi['max'])}  "
              f"{pi['n']:>13} {fmt(pi['p50'])} {fmt(pi['max'])}  {fmt(ready, 9)}  {time.monotonic() - w0:6.1f}  "
              f"{rep.summary.outcome}{' FELL' if rep.summary.fell else ''}", flush=True)

    summary = _summary(rows)
    steal1, wall = cpu_steal_s(), time.monotonic() - wall0
    steal = None if steal0 is None or steal1 is None else round(steal1 - steal0, 2)
    if floor_n:
        floors["end"] = floor_stats(wakeup_lateness_ms(floor_n))
    print()
    print(_line("motion, immediate: token -> servo", summary["motion_immediate_token_ms"]))
    print(_line("motion, queued: token -> servo", summary["motion_queued_token_ms"]))
    print(_line("motion, all: ready -> servo", summary["motion_all_ready_ms"]))
    print(_line("peripheral, immediate: token -> start", summary["peripheral_immediate_token_ms"]))
    print(_line("peripheral, all: ready -> start", summary["peripheral_all_ready_ms"]))
    for ch, s in summary["by_channel_ready_ms"].items():
        print(_line(f"  {ch}: ready -> start", s))
    immediate = sum(not c.queued for c in rows)
    print(f"immediate calls whose message reached the board after its due time: {summary['immediate_arrived_late']} "
          f"of n={immediate} (counted from the first tick after arrival)"
          + ("" if unchecked == 0 else f"; not checked in {unchecked} run(s) without a board_frames.jsonl (a CAN link)"))
    print(f"max |scheduler dispatch - chunk arrival| = {summary['max_abs_dispatch_skew_ms']} ms (consistency check)")
    if "end" in floors:
        print(floor_line("end", floors["end"]))
    if steal is not None:
        print(steal_line(steal, wall, os.cpu_count() or 1))
    for n in notes:
        print("note:", n)
    for f in failed:
        print("FAILED:", f)
    if args.json:
        Path(args.json).write_text(json.dumps({"mode": mode, "link": args.link, "tokens_per_s": args.tokens_per_s,
                                               "repeat": args.repeat, "load_processes": hogs,
                                               "machine_floor_wakeup_late_ms": floors or None,
                                               "cpu_steal_cpu_s": steal, "wall_s": round(wall, 1),
                                               "cpu_count": os.cpu_count(),
                                               "summary": summary, "notes": notes, "failed": failed,
                                               "calls": [asdict(c) for c in rows]}, indent=1), encoding="utf-8")
        print(f"wrote {args.json}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
