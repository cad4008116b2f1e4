"""The Cortex-M3 image (mps2-an385) of the default robot fits a small MCU: the ``mps2`` target's budget,
flash <= 32 KiB, RAM <= 8 KiB (firmware_sim/cfirmware/targets.py ``TARGETS``; flash = .text + .ARM.exidx +
.data; RAM = .data + .bss + the main stack + the boot block, as bench/bench_cfirmware.py counts them,
``image_use``). A 32-servo robot's image (the u32-mask codec) builds too, for the part it fits (stm32f4: the
small part's linker script refuses it, tests/cfirmware/test_link_budget.py)."""

from __future__ import annotations

from pathlib import Path

from firmware_sim.cfirmware.build import build
from firmware_sim.cfirmware.targets import TARGETS, image_use
from robots.loader import load_robot_dir
from robots.registry import DEFAULT_ROBOT, load_robot
from support.gen_robot import write_chain_robot

MPS2 = TARGETS["mps2"]
FLASH_BUDGET, RAM_BUDGET = MPS2.flash_bytes, MPS2.ram_bytes


def _flash_ram(elf: Path) -> tuple[int, int]:
    use = image_use(elf)
    return use.flash, use.ram


def test_the_budget_is_the_projects_goal() -> None:
    assert (FLASH_BUDGET, RAM_BUDGET) == (32 * 1024, 8 * 1024)


def test_default_robots_image_fits(tmp_path: Path) -> None:
    flash, ram = _flash_ram(build(MPS2.kind, load_robot(DEFAULT_ROBOT)))
    assert FLASH_BUDGET is not None and RAM_BUDGET is not None
    assert flash <= FLASH_BUDGET and ram <= RAM_BUDGET, f"flash {flash} B, RAM {ram} B"


def test_a_32_servo_image_builds_with_the_u32_codec(tmp_path: Path) -> None:
    small = _flash_ram(build("stm32f4", load_robot(DEFAULT_ROBOT)))
    wide = _flash_ram(build("stm32f4", load_robot_dir(write_chain_robot(tmp_path, 32))))
    assert wide[0] > small[0] and wide[1] > small[1]  # more servos: more state, the wider codec
