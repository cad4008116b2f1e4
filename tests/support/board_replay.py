"""A finished serial run's host traffic fed again into an in-process lockstep board: its final world.

SIM_STATE carries only the base pose and object counts, so where the scene's objects ended up
is read here from a :class:`firmware_sim.board.Board` built in this process (same robot and scene,
lockstep) that receives the messages the host sent (``host_frames.jsonl``), in order, through
:meth:`Board.handle`, ticking whenever it may between them, exactly as a lockstep board serving a
link does (:meth:`firmware_sim.server.BoardServer._serve_lockstep`: a message takes effect at the
board time the messages before it covered). The host log is a serial run's ``host_frames.jsonl`` or a
CAN run's candump capture (:func:`host.run.replay.read_host_to_board` picks the reader). Camera
requests are skipped (they render, they do not move anything).

The replay is only evidence if it is the same physics as the run, so :class:`Replayed` keeps the
replay's TELEMETRY and :meth:`Replayed.max_telemetry_error` compares it with the TELEMETRY the
run's board sent (its frame log, through :func:`host.run.video.load_states`); on a run without
faults they agree to the wire's quantum (1e-4 rad).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from firmware_sim.board import Board
from firmware_sim.config import BoardConfig
from host.run.replay import find_host_log, read_host_to_board
from host.run.video import load_states
from protocol.messages import CameraCapture, CameraResend, Telemetry
from robots.scenes import object_positions

__all__ = ["Replayed", "replay_in_process"]


@dataclass
class Replayed:
    """The replayed board and the TELEMETRY positions it reported, by board time (us)."""

    board: Board
    telemetry: dict[int, tuple[float, ...]] = field(default_factory=dict)

    def objects(self) -> dict[str, tuple[float, float, float]]:
        """World position (m) of every movable scene object at the end of the replay."""
        return object_positions(self.board.data, self.board.scene_objects)

    def max_telemetry_error(self, run_dir: Path) -> tuple[float, int]:
        """(largest joint-position difference in rad, reports compared) between this replay and the
        TELEMETRY the run's board sent at the same board times."""
        states = load_states(run_dir)
        recorded = {int(round(t * 1e6)): q for t, q in zip(states.t, states.joints)}
        common = sorted(set(recorded) & set(self.telemetry))
        err = max((abs(a - b) for k in common for a, b in zip(recorded[k], self.telemetry[k])), default=float("inf"))
        return err, len(common)


def replay_in_process(run_dir: Path, robot: str, scene: str | None = None) -> Replayed:
    """Feed the host log of ``run_dir`` into a fresh lockstep board for ``robot`` (and ``scene``)."""
    rep = Replayed(Board(BoardConfig(lockstep=True, robot=robot, scene=scene)))
    board = rep.board

    def tick() -> None:
        for msg in board.tick():
            if isinstance(msg, Telemetry):
                rep.telemetry[msg.board_time_us] = msg.positions

    for _, seq, msg in read_host_to_board(find_host_log(run_dir)):
        while board.can_tick():
            tick()
        if isinstance(msg, (CameraCapture, CameraResend)):
            continue
        board.handle(msg, seq)
    while board.can_tick():
        tick()
    return rep
