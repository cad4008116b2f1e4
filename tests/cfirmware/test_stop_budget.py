"""The C firmware's launcher stops the firmware (or QEMU) within its own budget, well inside the host's budget
for stopping the launcher, so a realtime run's stderr always ends with the launcher's lateness record.

The kind of failure this keeps away: a CI run (test_task_on_stm32f4[23-realtime], load ~4) where QEMU was
slow to exit on SIGTERM; the launcher waited 5 s for it, the host's ``BoardProcess.stop`` also waited 5 s for
the launcher and then killed it mid-wait, and the run's board.stderr had no lateness record."""

from __future__ import annotations

import inspect

from firmware_sim.cfirmware.launcher import FIRMWARE_STOP_S
from host.link.board_process import BoardProcess

#: seconds the launcher needs after the firmware exits: drain its log channel, print the plant's and the
#: lateness lines (milliseconds on a quiet machine; a loaded one is descheduled for a second now and then)
DRAIN_MARGIN_S = 6.0  # 3 s left once, in a quiet CI, were not enough (STM32F4 task 23, realtime: no record)


def test_the_launcher_gives_up_on_the_firmware_before_the_host_gives_up_on_the_launcher() -> None:
    host_budget = inspect.signature(BoardProcess.stop).parameters["timeout"].default
    assert isinstance(host_budget, float)
    assert FIRMWARE_STOP_S + DRAIN_MARGIN_S <= host_budget, (FIRMWARE_STOP_S, host_budget)
