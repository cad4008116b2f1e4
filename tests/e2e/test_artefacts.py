"""The run folder: timeline.json on the board clock, summary.json, the plots and both frame logs."""

from __future__ import annotations

import json

from protocol.framelog import iter_records

from .conftest import E2ERun

CALL_KEYS = {"function", "channel", "args", "path", "start", "end", "outcome", "error"}
SUMMARY_KEYS = {"task", "outcome", "fell", "base_start", "base_end", "max_tilt_deg", "first_action_latency_ms",
                "outcomes"}


def test_artefacts_well_formed(task_run) -> None:
    run: E2ERun = task_run(26)  # music, ears, head and body: most channels in one run (one of PLOTTED_TASKS)
    out = run.out
    doc = json.loads((out / "timeline.json").read_text(encoding="utf-8"))
    assert doc["clock"] == "board"
    assert len(doc["calls"]) == len(run.calls) == 11
    for c, call in zip(doc["calls"], run.calls):
        assert CALL_KEYS <= c.keys(), c
        assert (c["function"], c["path"], c["start"], c["end"], c["outcome"]) == \
            (call.function, call.path, round(call.start, 6), round(call.end, 6), call.outcome)  # to the µs
        assert isinstance(c["args"], dict) and c["start"] <= c["end"]

    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert SUMMARY_KEYS <= summary.keys()
    assert summary["task"] == "task 26" and summary["outcome"] == "done" and summary["fell"] is False
    assert len(summary["base_start"]) == len(summary["base_end"]) == 3
    assert summary["outcomes"]["done"] == 11 and sum(summary["outcomes"].values()) == 11
    assert 0 < summary["first_action_latency_ms"] < 2000
    assert 4 < summary["duration_s"] < 8  # 3 ear flaps, 3 nods (one gesture per call) and two strides

    for png in ("timeline.png", "joints.png"):
        data = (out / png).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000, png

    for log, sender in (("host_frames.jsonl", "tx"), ("board_frames.jsonl", "rx")):
        with open(out / log, encoding="utf-8") as f:
            recs = list(iter_records(f))  # every line parses as a frame-log record
        assert not [r for r in recs if "error" in r], log
        types = {r["type"] for r in recs if r["dir"] == sender}  # what the host sent, as each end saw it
        assert {"HELLO", "SERVO_FRAME"} <= types, (log, types)
