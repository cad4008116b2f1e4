"""A slow line paced by the host (``BoardFrameLink.pace``): lookahead frames are held and written
earliest apply time first as the line drains, so a new motion's FLUSH and first frame do not wait
behind them. A real board subprocess over a real pty, modelling 115 200-baud wire time (``--baud``).

What could go wrong and is checked: frames held and never written (the motion would never be
confirmed), a held frame overriding the new motion (the FLUSH must act on held frames), frames
written too late (the board NACKs them LATE), sequence numbers not reaching the confirmations.
Synchronised on telemetry with timeouts, no sleeps.
"""

from __future__ import annotations

import anyio
import numpy as np
import pytest

from host.link import BoardClient
from host.motion.board_link import PACE_MARGIN_US, BoardFrameLink
from host.motion.mixer import Mixer
from host.motion.moves import max_error_deg
from host.motion.streamer import FrameStreamer
from protocol.messages import Nack, ServoFrame
from robots.motion import JointLimits, transition
from robots.registry import load_robot

pytestmark = [pytest.mark.timeout(60), pytest.mark.realtime]
BAUD = 115_200


def test_a_new_motion_overtakes_held_lookahead_frames_and_lands(board_factory) -> None:
    board = board_factory("--realtime", "--baud", str(BAUD))

    async def main() -> None:
        async with await BoardClient.connect(board.port, wire_baud=BAUD) as client:
            assert not client.lockstep
            link = BoardFrameLink(client, wire_baud=BAUD)
            # past the board's first second: its subject is the pacing, not the boot (in one CI run of 8e55da7
            # the first frames, written ~0.1 s into the board's life, were handled at 0.59 s, 0.46 s late)
            tel = await client.wait_for(lambda t: t.board_time_us >= 1_000_000, timeout=10)
            q0 = np.asarray(tel.positions, dtype=float)
            servos = (0, 1, 2)
            goal = q0.copy()
            goal[list(servos)] += 0.3
            motion = transition(q0, goal, servos, JointLimits.of_robot(load_robot("coco")), min_duration=0.3)
            streamer = FrameStreamer(link, Mixer(q0))
            nacks: list[Nack] = []
            client.on_nack.append(nacks.append)
            # A busy wait here made this process a CPU hog; on a loaded machine the kernel then held it off
            # the CPU for ~30 ms at a time, with the first frames planned and not yet written (they
            # reached the board 22-30 ms late, 1 run in 4 under two busy loops). Waits are on events.
            written = [anyio.Event()]

            def on_sent(seq: int, msg: object) -> None:
                if isinstance(msg, ServoFrame):
                    written[0].set()

            client.on_sent.append(on_sent)

            async def confirm() -> None:  # as host.run.pump does
                async for t in client.telemetry(maxsize=256):
                    streamer.on_telemetry(t)
                    await streamer.top_up()

            async def topper() -> None:  # as host.run.pump.realtime_topper does
                while True:
                    await streamer.top_up()
                    await anyio.sleep(streamer.period_us * 1e-6)

            async with anyio.create_task_group() as tg:
                tg.start_soon(link.pace)
                tg.start_soon(confirm)
                tg.start_soon(topper)
                with anyio.fail_after(5):
                    while not link.paced:
                        await anyio.lowlevel.checkpoint()
                line = client.tx_wire
                assert line is not None
                await anyio.lowlevel.checkpoint()
                await streamer.top_up()
                held = len(link.queue)
                assert held >= 1  # the lookahead waits in the queue, not in the line

                def due_soon() -> bool:  # the held frame due first must go now (PACE_MARGIN_US)
                    due = link.queue.next_apply_at()
                    return due is not None and due <= client.board_now_estimate() + link.latency_us(0) + PACE_MARGIN_US

                with anyio.fail_after(2):  # the pacing writes what is due soon; the rest stays held
                    while due_soon():  # (only a write makes it false: wait for the next, not a spin)
                        written[0] = anyio.Event()
                        await written[0].wait()
                assert len(link.queue) >= 1  # the far end of the 60 ms lookahead is still held

                seg = await streamer.start_now(motion, "nudge")
                t0 = seg.first_frame_us
                assert t0 is not None and t0 < streamer.first_free_us  # it did not wait for the unsent grid
                # every held frame from t0 on that still moves these servos moves them as the new motion
                # does (the FLUSH removed the hold the lookahead had planned for them)
                later = [f for f in link.queue.held() if f.apply_at_us >= t0 and f.mask & 0b111]
                assert later, "the re-sent grid is held too"
                for f in later:
                    bits = [i for i in range(12) if f.mask >> i & 1]
                    planned = streamer.mixer.sample_servo_targets(f.apply_at_us)
                    for i, v in zip(bits, f.targets, strict=True):
                        assert v == pytest.approx(planned[i]), (f.apply_at_us, i)
                with anyio.fail_after(10):
                    start = await streamer.wait_started(seg)
                    end = await streamer.wait_ended(seg)
                    assert start == pytest.approx(t0 * 1e-6)  # confirmed by the board, at the planned time
                    assert end > start
                    settled = await client.wait_for(
                        lambda t: t.board_time_us >= end * 1e6 + 300_000, timeout=10)
                assert max_error_deg(settled, goal)[0] < 3.0  # the held frames did not override the motion
                assert not nacks, nacks[:3]  # nothing arrived late or was refused
                assert streamer.frames_sent > held
                tg.cancel_scope.cancel()
            assert not link.paced and len(link.queue) == 0  # what was still held went out on the way out

    anyio.run(main)
