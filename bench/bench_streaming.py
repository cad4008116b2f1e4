"""Streaming advantage: time to the first action when executing while streaming vs after the whole reply.

Each task's ground-truth program is replayed by the scripted LLM at 30 tokens/s
(seeded jitter, the first token after one gap) and run end to end twice on a real
board subprocess over a pty:

* streaming: the shell executes each function token as soon as it completes;
* buffered (``RunOptions.buffer_response=True``): the shell gets the complete
  response only after its last token arrived (a non-streaming executor).

Time to first action = board start of the first call (any channel, ``wait``/``async``
excluded) - board time when the request was sent (``RunReport.board_t0``); this is
``summary.first_action_latency_ms``. The advantage is buffered - streaming. In both
modes the first call still waits for the frame lookahead (~60 ms), so the advantage
is essentially the time the rest of the reply takes to stream after the first
function token completes.

Lockstep is the default: the scripted LLM is paced on the board clock, so
lockstep numbers are exact and reproducible (chunk times are quantised to the
20 ms telemetry period). ``--realtime`` runs the same on a realtime board.

Run:

    python bench/bench_streaming.py                     # all 30 tasks, lockstep (~2 min)
    python bench/bench_streaming.py --tasks 1,5,23 --realtime
    python bench/bench_streaming.py --json streaming.json

Numbers are printed, never asserted.
"""

from __future__ import annotations

import argparse
import json
import signal
import statistics
import sys
from pathlib import Path
from typing import Any

from _tasks_common import fmt, output_folder, run_task, selected_tasks, task_arguments
from host.run.runner import RunReport
from robots.description import Robot

NOT_ACTIONS = ("wait", "async", "RUN")


def first_action_ms(rep: RunReport) -> float | None:
    """Board ms from the request to the first call's board start (recomputed from the calls)."""
    starts = [c.start for c in rep.calls if c.start is not None and c.function not in NOT_ACTIONS]
    return None if not starts else (min(starts) - rep.board_t0) * 1e3


def reply_ms(rep: RunReport) -> float | None:
    """Board ms from the request to the arrival of the reply's last chunk."""
    return (rep.token_times[-1][0] - rep.board_t0) * 1e3 if rep.token_times else None


def main(argv: list[str] | None = None) -> int:
    ap = task_arguments(__doc__.splitlines()[0], "also write the per-task rows as JSON")
    ap.add_argument("--realtime", action="store_true", help="realtime board instead of lockstep")
    args = ap.parse_args(argv)

    robot, programs = selected_tasks(ap, args)
    root = output_folder(ap, args, "bench_streaming_")
    try:
        return _run(args, robot, programs, root)
    except KeyboardInterrupt:  # a run's board stopped with its session
        signal.signal(signal.SIGINT, signal.SIG_DFL)  # a further Ctrl-C ends the process: no traceback, no hang
        print("bench_streaming: interrupted; no summary (the runs so far are in their folders)", file=sys.stderr)
        return 130


def _run(args: argparse.Namespace, robot: Robot, programs: list[tuple[int, str]], root: Path) -> int:
    lockstep = not args.realtime
    print(f"time to first action, streaming vs buffered, {'lockstep' if lockstep else 'realtime'} board over a pty, "
          f"{args.tokens_per_s:g} tokens/s, {len(programs)} task(s); artefacts in {root}", flush=True)
    print(f"{'task':>4} {'tokens':>6} {'reply ms':>8} {'tok/s':>5} {'streaming ms':>12} {'reply(b) ms':>11} "
          f"{'buffered ms':>11} {'advantage ms':>12}  first call", flush=True)
    rows: list[dict[str, Any]] = []
    for tid, program in programs:
        s = run_task(tid, program, lockstep=lockstep, out_root=root, tokens_per_s=args.tokens_per_s, seed=args.seed,
                     robot=str(robot.root))
        b = run_task(tid, program, lockstep=lockstep, out_root=root, tokens_per_s=args.tokens_per_s, seed=args.seed,
                     buffer_response=True, robot=str(robot.root))
        ts, tb = first_action_ms(s), first_action_ms(b)
        reply, reply_b = reply_ms(s), reply_ms(b)
        rate = None if not reply else len(s.token_times) / (reply * 1e-3)
        first = min((c for c in s.calls if c.start is not None and c.function not in NOT_ACTIONS),
                    key=lambda c: c.start, default=None)
        row = {"task": tid, "tokens": len(s.token_times), "reply_ms": reply, "reply_buffered_ms": reply_b,
               "effective_tokens_per_s": rate, "streaming_ms": ts, "buffered_ms": tb,
               "advantage_ms": None if ts is None or tb is None else tb - ts,
               "summary_streaming_ms": s.summary.first_action_latency_ms,
               "summary_buffered_ms": b.summary.first_action_latency_ms,
               "first_call": first.function if first else None,
               "outcomes": [s.summary.outcome, b.summary.outcome]}
        rows.append(row)
        print(f"{tid:>4} {row['tokens']:>6} {fmt(reply, 8)} {fmt(rate, 5)} {fmt(ts, 12)} {fmt(reply_b, 11)} "
              f"{fmt(tb, 11)} {fmt(row['advantage_ms'], 12)}"
              f"  {row['first_call'] or '-'}"
              f"{'' if row['outcomes'] == ['done', 'done'] else '  outcomes ' + '/'.join(row['outcomes'])}", flush=True)

    adv = [r["advantage_ms"] for r in rows if r["advantage_ms"] is not None]
    st = [r["streaming_ms"] for r in rows if r["streaming_ms"] is not None]
    bu = [r["buffered_ms"] for r in rows if r["buffered_ms"] is not None]
    print()
    if adv:
        print(f"streaming: mean {statistics.fmean(st):.1f} ms, median {statistics.median(st):.1f} ms")
        print(f"buffered:  mean {statistics.fmean(bu):.1f} ms, median {statistics.median(bu):.1f} ms")
        rates = [r["effective_tokens_per_s"] for r in rows if r["effective_tokens_per_s"]]
        print(f"effective pacing: mean {statistics.fmean(rates):.1f} tokens/s (requested {args.tokens_per_s:g})")
        print(f"advantage: mean {statistics.fmean(adv):.1f} ms, median {statistics.median(adv):.1f} ms, "
              f"min {min(adv):.1f} ms, max {max(adv):.1f} ms over {len(adv)} task(s)")
    if args.json:
        Path(args.json).write_text(json.dumps({"lockstep": lockstep, "tokens_per_s": args.tokens_per_s, "rows": rows},
                                              indent=1), encoding="utf-8")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
