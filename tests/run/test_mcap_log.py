"""run.mcap as a viewer reads it (issue 45): partial-mask targets under their servos' names, log times that
never go back (the reorder buffer), photo stamps rounded, not truncated, the run's first report, and the
scene's objects in ``/scene`` and ``/tf``. A real :class:`RunLog` writes a real MCAP; the ``mcap`` package
reads it back in file order."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from mcap.reader import make_reader

from host.link.receive import LinkStats
from host.run import mcap_log
from host.run.mcap_log import HOLD_S, RunLog, board_us
from host.run.mcap_read import McapRun
from host.run.recording import Recording
from protocol.framelog import decode_raw
from protocol.framing import Frame, encode_frame
from protocol.messages import FaultFlags, ServoFrame, SimState, Telemetry
from robots.registry import load_robot

COCO = load_robot("coco")
NAMES = list(COCO.servos.names)


def _tel(t_us: int, n: int = 12) -> Telemetry:
    return Telemetry(t_us, (0.0,) * n, (0.0,) * n, (0.0,) * n, (0.0, 0.0, 0.0), FaultFlags.NONE, 0, 0, 0, 0, 0)


def _file_order(path: Path) -> list[tuple[str, int]]:
    """(topic, log time ns) of every message in the order the file holds them."""
    with open(path, "rb") as f:
        return [(ch.topic, m.log_time) for _, ch, m in make_reader(f).iter_messages(log_time_order=False)]


def test_a_partial_mask_frame_gives_its_targets_to_its_own_servos(tmp_path: Path) -> None:
    # the ear servos (10, 11) alone: the wire carries two targets, one per set bit of the mask
    frame = ServoFrame(500_000, 0xC00, (0.25, -0.5))
    sent = decode_raw(encode_frame(frame, 9).hex())  # the message as it goes on the wire and comes back
    assert isinstance(sent, Frame) and isinstance(sent.msg, ServoFrame) and len(sent.msg.targets) == 2
    log = RunLog.create(tmp_path / "run.mcap", COCO)
    log.on_frame_sent(9, sent.msg, 480_000)
    log.on_frame_sent(10, ServoFrame(510_000, 0b101, (1.0, 2.0)), 490_000)  # servos 0 and 2
    log.close()
    targets = [m.value["joints"] for m in McapRun(tmp_path / "run.mcap").messages(["/joint_targets"])]
    assert [(j["name"], j["position"]) for j in targets[0]] == [(NAMES[10], 0.25), (NAMES[11], -0.5)]
    assert [(j["name"], j["position"]) for j in targets[1]] == [(NAMES[0], 1.0), (NAMES[2], 2.0)]


def test_messages_fed_out_of_order_are_written_in_log_time_order(tmp_path: Path) -> None:
    log = RunLog.create(tmp_path / "run.mcap", COCO)
    log.prepare()
    for k in range(1, 101):  # 2 s of reports; targets 60 ms ahead; a call's start line 40 ms late
        t = 20_000 * k
        log.on_frame_sent(k, ServoFrame(t + 60_000, 0xFFF, (0.0,) * 12), t)
        if k % 10 == 0:
            log.on_call_start(f"c[{k}]", "nod", "head", {}, (t - 40_000) * 1e-6)
        log.on_message(_tel(t))
        log.on_message(SimState(t, (0.0, 0.0, 0.3), (1.0, 0.0, 0.0, 0.0)))
        assert len(log._held) < 6 * (HOLD_S + 0.06) / 0.02 + 6  # HOLD_S of reports and the frames ahead, no more
    log.on_call_end("c[0]", "nod", "head", "done", None, 0.5)  # far later than the buffer waits
    log.close()
    order = _file_order(tmp_path / "run.mcap")
    times = [t for _, t in order]
    assert times == sorted(times)
    assert log.late == 1  # the one end line written at the file's time; its stamp keeps 0.5 s
    end = [m for m in McapRun(tmp_path / "run.mcap").messages(["/calls"]) if "end" in m.value["message"]]
    assert end[0].value["timestamp"] == "1970-01-01T00:00:00.500Z" and end[0].log_time_ns > 5e8 + HOLD_S * 1e9
    calls = list(McapRun(tmp_path / "run.mcap").messages(["/calls"]))
    starts = [m.log_time_ns for m in calls if m.value["message"].startswith("start")]
    assert starts == [(20_000 * k - 40_000) * 1000 for k in range(10, 101, 10)]  # on time, not clamped
    assert sum(topic == "/joint_targets" for topic, _ in order) == 100


def test_the_reorder_buffer_is_bounded(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(mcap_log, "MAX_HELD", 50)
    log = RunLog.create(tmp_path / "run.mcap", COCO)
    for k in range(500):  # a board that stopped reporting: nothing moves the watermark
        log.on_frame_sent(k, ServoFrame(10_000 * k, 1, (0.0,)), 10_000 * k)
        assert len(log._held) <= 50
    log.close()
    times = [t for _, t in _file_order(tmp_path / "run.mcap")]
    assert len(times) == 1000 and times == sorted(times)


def test_a_photo_at_6_9_s_is_stamped_6_9_s(tmp_path: Path) -> None:
    t = 6_900_000 * 1e-6  # a photo's time: the board µs its last chunk came at, in seconds
    assert int(t * 1e6) == 6_899_999 and board_us(t) == 6_900_000  # what truncation did
    log = RunLog.create(tmp_path / "run.mcap", COCO)
    log.on_image(t, b"\x89PNG")
    log.on_speech("hi", 1.3, 2.3, "done")
    log.close()
    run = McapRun(tmp_path / "run.mcap")
    photo = next(iter(run.messages(["/camera"])))
    assert photo.log_time_ns == 6_900_000_000 and photo.value["timestamp"] == "1970-01-01T00:00:06.900Z"
    assert next(iter(run.messages(["/speech"]))).log_time_ns == 2_300_000_000  # at its end, when it is known


def test_the_report_that_came_before_the_recording_is_recorded(tmp_path: Path) -> None:
    first, sim = _tel(20_000), SimState(20_000, (0.0, 0.0, 0.3), (1.0, 0.0, 0.0, 0.0))
    client = SimpleNamespace(on_fault=[], on_nack=[], on_sent=[], on_received=[], stats=LinkStats(),
                             board_now_estimate=lambda: 20_000, latest_telemetry=first, latest_sim_state=sim)
    runtime = SimpleNamespace(captures=[], board_times={}, robot=COCO)
    log = RunLog.create(tmp_path / "run.mcap", COCO)
    rec = Recording(log, client, runtime, SimpleNamespace(last_result=None))  # type: ignore[arg-type]
    client.on_received[0](_tel(40_000))
    rec.close()
    run = McapRun(tmp_path / "run.mcap")
    for topic in ("/joint_states", "/telemetry", "/tf"):
        assert [m.log_time_ns for m in run.messages([topic])] == [20_000_000, 40_000_000], topic
    assert [m.log_time_ns for m in run.messages(["/sim_state"])] == [20_000_000]


def _entity_frames(run: McapRun) -> set[str]:
    scene = next(iter(run.messages(["/scene"])))
    return {e["frame_id"] for e in scene.value["entities"]}


def test_the_scene_objects_are_in_scene_and_tf(tmp_path: Path) -> None:
    arm = load_robot("arm")
    objects = {o.name for o in arm.scene("table").objects}
    assert {"table", "red_cube", "blue_cube"} <= objects
    log = RunLog.create(tmp_path / "run.mcap", arm)
    log.scene_name = "table"  # (what Recording.start passes from the run's meta)
    log.prepare()
    log.on_message(_tel(20_000, arm.servo_count))
    log.close()
    run = McapRun(tmp_path / "run.mcap")
    assert objects <= _entity_frames(run)
    tf: Any = next(iter(run.messages(["/tf"]))).value["transforms"]
    placed = {t["child_frame_id"]: t for t in tf if t["child_frame_id"] in objects}
    assert set(placed) == objects and all(t["parent_frame_id"] == "world" for t in placed.values())
    red = next(o for o in arm.scene("table").objects if o.name == "red_cube")
    assert [placed["red_cube"]["translation"][k] for k in "xyz"] == pytest.approx(list(red.pos), abs=1e-9)
    alone = RunLog.create(tmp_path / "alone.mcap", arm)  # no scene: the robot alone, as before
    alone.prepare()
    alone.close()
    assert not objects & _entity_frames(McapRun(tmp_path / "alone.mcap"))
