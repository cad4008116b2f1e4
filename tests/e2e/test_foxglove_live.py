"""Live view: a WebSocket client speaking the Foxglove protocol (``websockets``) subscribes to a running
robot's channels through the foxglove-sdk server and receives its joint states as they happen."""

from __future__ import annotations

import json
import socket
import struct
from pathlib import Path
from typing import Any

import anyio
import pytest
import websockets
from mcap.records import Schema
from mcap_protobuf.decoder import DecoderFactory

from host.run.robot_session import RobotSession, SessionOptions
from robots.coco.tasks import load_tasks
from robots.registry import load_robot

SUBPROTOCOL = "foxglove.sdk.v1"
OP_MESSAGE_DATA, OP_TIME = 1, 2
TASK26 = load_tasks()[26].ground_truth


class FoxgloveClient:
    """The client side of the Foxglove WebSocket protocol, as far as a viewer needs it."""

    def __init__(self, ws: Any) -> None:
        self.ws = ws
        self.server_info: dict[str, Any] = {}
        self.channels: dict[str, dict[str, Any]] = {}
        self.times: list[int] = []  # server time broadcasts (ns)

    @classmethod
    async def connect(cls, port: int) -> tuple[Any, FoxgloveClient]:
        ws = await websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], max_size=None)
        return ws, cls(ws)

    async def subscribe(self, topic: str, sub_id: int = 1) -> None:
        while topic not in self.channels:
            await self._control(await self.ws.recv())
        await self.ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": sub_id, "channelId": self.channels[topic]["id"]}]}))

    async def _control(self, msg: str | bytes) -> tuple[int, int, bytes] | None:
        if isinstance(msg, str):
            doc = json.loads(msg)
            if doc["op"] == "serverInfo":
                self.server_info = doc
            elif doc["op"] == "advertise":
                for c in doc["channels"]:
                    self.channels[c["topic"]] = c
            return None
        if msg[0] == OP_TIME:
            self.times.append(struct.unpack_from("<Q", msg, 1)[0])
            return None
        op, sub, t = struct.unpack_from("<BIQ", msg)
        assert op == OP_MESSAGE_DATA
        return sub, t, bytes(msg[13:])

    async def messages(self):
        async for msg in self.ws:
            got = await self._control(msg)
            if got is not None:
                yield got

    def decoder(self, topic: str) -> Any:
        c = self.channels[topic]
        assert c["encoding"] == "protobuf" and c["schemaEncoding"] == "protobuf"
        import base64

        schema = Schema(id=c["id"], name=c["schemaName"], encoding="protobuf", data=base64.b64decode(c["schema"]))
        return DecoderFactory().decoder_for("protobuf", schema)


async def joint_state_times(port: int, until_s: float) -> list[float]:
    """Board times (s) of the joint states received until one at or past ``until_s``."""
    ws, client = await FoxgloveClient.connect(port)
    seen: list[float] = []
    async with ws:
        await client.subscribe("/joint_states")
        async for _, t, _ in client.messages():
            seen.append(t / 1e9)
            if seen[-1] >= until_s:
                break
    return seen


@pytest.mark.realtime
def test_live_view_streams_joint_states_of_a_realtime_run(tmp_path: Path) -> None:
    servos = list(load_robot("coco").servos.names)

    async def main() -> dict[str, Any]:
        got: list[tuple[float, int, Any]] = []
        early: list[int] = []
        async with RobotSession(SessionOptions(out=tmp_path, foxglove=0)) as s:  # realtime board
            live = s.recording.live
            ws, client = await FoxgloveClient.connect(live.port)

            async def watch() -> None:
                async with ws:
                    await client.subscribe("/joint_states")
                    decode = client.decoder("/joint_states")
                    async for _, t, payload in client.messages():
                        got.append((anyio.current_time(), t, decode(payload)))

            async def leaves_early() -> None:  # a viewer that disconnects mid-run costs the run nothing
                ws2, c2 = await FoxgloveClient.connect(live.port)
                async with ws2:
                    await c2.subscribe("/tf")
                    async for _, t, _ in c2.messages():
                        early.append(t)
                        if len(early) >= 10:
                            break

            async with anyio.create_task_group() as tg:
                tg.start_soon(watch)
                tg.start_soon(leaves_early)
                turn = await s.run_turn(TASK26, label="task 26")
                tg.cancel_scope.cancel()
            info = client.server_info
        return {"got": got, "early": early, "outcome": turn.summary.outcome, "info": info,
                "reports": turn.summary.extra["link"], "times": client.times}

    r = anyio.run(main, backend="asyncio")
    assert r["outcome"] == "done" and len(r["early"]) == 10
    assert r["info"]["capabilities"] == ["time"]  # the viewer's clock is the board's
    got = r["got"]
    assert got and [j.name for j in got[0][2].joints] == servos
    stamps = [t for _, t, _ in got]
    assert stamps == sorted(stamps)
    assert all(abs(m.timestamp.ToNanoseconds() - t) == 0 for _, t, m in got)
    # nothing lost on the way: the viewer got every joint state the run recorded while it was subscribed
    from host.run.mcap_read import McapRun

    recorded = [m.log_time_ns for m in McapRun(tmp_path / "run.mcap").messages(["/joint_states"], decode=False)
                if stamps[0] <= m.log_time_ns <= stamps[-1]]
    assert stamps == recorded
    # at the telemetry rate: one joint state per 20 ms report (50 Hz; a realtime board on a loaded machine
    # may skip a report now and then, which the recording shows too)
    steps = [round((b - a) / 1e6) for a, b in zip(stamps, stamps[1:])]
    assert sorted(steps)[len(steps) // 2] == 20 and min(steps) == 20, steps
    board_rate = (len(stamps) - 1) / ((stamps[-1] - stamps[0]) / 1e9)
    wall_rate = (len(got) - 1) / (got[-1][0] - got[0][0])
    assert r["times"] and max(r["times"]) >= stamps[-1]
    print(f"live /joint_states: {len(got)} messages, {board_rate:.2f} Hz by board time, {wall_rate:.2f} Hz by wall time")


def test_foxglove_port_argument_is_checked(capsys: pytest.CaptureFixture[str]) -> None:
    from host.cli import main as cli_main

    with pytest.raises(SystemExit) as e:
        cli_main(["run", "--xml", "<head_act/>", "--foxglove", "70000"])
    assert e.value.code == 2 and "must be a port number 0..65535" in capsys.readouterr().err


def test_a_taken_port_is_one_line_and_the_run_goes_on(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    import logging

    holder = socket.socket()
    holder.bind(("127.0.0.1", 0))
    holder.listen()
    port = holder.getsockname()[1]

    async def main() -> Any:
        async with RobotSession(SessionOptions(out=tmp_path, foxglove=port, lockstep=True)) as s:
            assert s.recording is not None and s.recording.live is None and s.recording.run_log.writer is not None
            return await s.run_turn('<head_act action="nod"/>')

    try:
        with caplog.at_level(logging.WARNING, logger="host.run"):
            turn = anyio.run(main, backend="asyncio")
    finally:
        holder.close()
    assert turn.summary.outcome == "done"
    notes = [r.getMessage() for r in caplog.records]
    assert len(notes) == 1 and f"port {port} is taken" in notes[0], notes
    assert (tmp_path / "run.mcap").stat().st_size > 0


# --- the handshake: which subprotocols the live view accepts, and that the docs and the start line say so

RUNNING_MD = Path(__file__).resolve().parents[2] / "docs" / "guides" / "running.md"


def _live_section() -> str:
    """The live-view bullet of docs/guides/running.md (from ``--foxglove [PORT]`` to the next top-level bullet)."""
    text = RUNNING_MD.read_text()
    start = text.index("- with `--foxglove [PORT]`")
    end = text.index("\n- ", start + 1)
    return " ".join(text[start:end].split())


@pytest.mark.parametrize("offer", [
    ["foxglove.sdk.v1"],                              # Python websockets, ws-protocol with a socket offering it
    ["foxglove.websocket.v1", "foxglove.sdk.v1"],     # Lichtblick >= 1.22.1, the Foxglove app: both names
    ["foxglove.websocket.v1"],                        # Foxglove Studio 1.x, FoxgloveClient.SUPPORTED_SUBPROTOCOL
    None,                                             # no subprotocol at all
])
def test_handshake_answers_each_subprotocol_offer_as_the_docs_say(tmp_path: Path, offer: list[str] | None) -> None:
    """A real WebSocket handshake against the live server: 101 with ``foxglove.sdk.v1`` echoed and a
    ``serverInfo`` when it is offered; HTTP 400 otherwise, and then the docs name that offer as refused."""
    from websockets.exceptions import InvalidStatus

    from host.run.foxglove_live import OLD_SUBPROTOCOL, SUBPROTOCOL, start_live
    from host.run.mcap_log import RunLog

    run_log = RunLog(load_robot("coco"))
    live = start_live(run_log, 0)

    async def handshake() -> tuple[int, str | None, dict[str, Any]]:
        try:
            async with websockets.connect(live.url, subprotocols=offer, open_timeout=10) as ws:  # type: ignore[arg-type]
                info = json.loads(await ws.recv())
                return ws.response.status_code, ws.subprotocol, info
        except InvalidStatus as e:
            return e.response.status_code, None, {}

    try:
        status, chosen, info = anyio.run(handshake, backend="asyncio")
    finally:
        live.stop()
        run_log.close()
    docs = _live_section()
    assert SUBPROTOCOL in docs and f"{OLD_SUBPROTOCOL}` and is refused (HTTP 400)" in docs
    if offer is not None and SUBPROTOCOL in offer:
        assert (status, chosen) == (101, SUBPROTOCOL)
        assert info["op"] == "serverInfo" and info["capabilities"] == ["time"]
    else:
        assert status == 400
        assert offer is None or offer == [OLD_SUBPROTOCOL]  # the one refusal the docs name, word for word
        assert "a client that does not offer it gets HTTP 400" in docs
        assert f"offer only `{OLD_SUBPROTOCOL}`: refused" in docs


def test_the_start_line_names_the_url_and_the_subprotocol(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    async def main() -> str:
        async with RobotSession(SessionOptions(out=tmp_path, foxglove=0, lockstep=True)) as s:
            assert s.recording is not None and s.recording.live is not None
            return str(s.recording.live.url)

    url = anyio.run(main, backend="asyncio")
    lines = [ln for ln in capsys.readouterr().err.splitlines() if "live view" in ln]
    assert lines == [f"foxglove: live view on {url}, WebSocket subprotocol foxglove.sdk.v1 "
                     "(Foxglove: Open connection > Foxglove WebSocket; a client offering only "
                     "foxglove.websocket.v1 gets HTTP 400)"], lines
