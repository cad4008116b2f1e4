"""The parts the C firmware is built for: ``--target`` -> part, flash and RAM budget, build kind, QEMU machine.

=========  ==========================================  ===========  =========  ==========  ==============
target     part                                        flash        RAM        build kind  QEMU machine
=========  ==========================================  ===========  =========  ==========  ==============
native     this computer (POSIX executable)            no budget    no budget  native      (none)
mps2       small Cortex-M3 part (our stand-in)          32 KiB       8 KiB      mps2        mps2-an385
stm32f4    STM32F405RG / STM32F407VG (Cortex-M4F)       1024 KiB     128 KiB    stm32f4     netduinoplus2
=========  ==========================================  ===========  =========  ==========  ==============

``mps2``'s budget is the project's goal for a small part (the image runs on QEMU's mps2-an385,
whose own memories are larger); ``stm32f4``'s is the part's: 1 MiB flash, 128 KiB SRAM (its
64 KiB CCM RAM is not used). Each port's linker script declares its target's budget as its FLASH and
RAM regions (``firmware_sim/c/ports/mps2/mps2_an385.ld``, ``ports/stm32f4/stm32f405.ld``), so an image
that does not fit does not link; :func:`link_overflow` reads the flash and RAM such an image needs from
the linker's output (``--print-memory-usage``), for the build command's one-line refusal. How an image is counted (:func:`image_use`, bytes, as
``bench/bench_cfirmware.py`` counts): flash = ``.text + .ARM.exidx + .data`` (``.data``'s initial
values live in flash), RAM = ``.data + .bss + .stack + .bootcfg`` (the main stack and the boot
configuration block are sections of their own in our linker scripts). ``tests/cfirmware/test_image_size.py``
checks the default robot against :data:`TARGETS` ``["mps2"]``.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from protocol.messages import MAX_WIRE_SERVOS

__all__ = ["FLASH_SECTIONS", "HSE_HZ", "RAM_SECTIONS", "REGIONS", "TARGETS", "Define", "ImageUse", "Target", "image_use",
           "link_overflow"]

#: sections counted as flash (bytes in the image); absent ones count 0
FLASH_SECTIONS = (".text", ".ARM.exidx", ".data")
#: sections counted as RAM (what the image occupies at run time); absent ones count 0
RAM_SECTIONS = (".data", ".bss", ".stack", ".bootcfg")
#: our linker scripts' memory regions -> what they hold: FLASH the flash sections, RAM the RAM sections (with no
#: gaps between them, so a region's use is the sum :func:`image_use` counts)
REGIONS = {"FLASH": "flash", "RAM": "ram"}


@dataclass(frozen=True)
class Define:
    """A build setting a target's port reads (``--define NAME=N``): allowed values ``low``..``high`` in steps of
    ``step`` (all integers), and what it is, for the refusal line."""

    what: str
    low: int
    high: int
    step: int = 1

    def problem(self, name: str, value: int) -> str | None:
        """Why ``value`` cannot be ``name`` (one line), or None."""
        if not self.low <= value <= self.high or (value - self.low) % self.step:
            unit = f" in steps of {self.step}" if self.step > 1 else ""
            return f"{name}={value}: {self.what} must be {self.low}..{self.high}{unit}"
        return None


#: the STM32F4 port's crystal (ports/stm32f4: PLL M = the HSE in MHz, RM0090 6.3.2 RCC_PLLCFGR; 4..26 MHz crystals)
HSE_HZ = Define("the HSE crystal frequency in Hz (a whole number of MHz)", 4_000_000, 26_000_000, 1_000_000)


@dataclass(frozen=True)
class Target:
    """One ``--target``: ``part`` (what it stands for), ``kind`` (the build kind,
    :data:`firmware_sim.cfirmware.build.KINDS`), ``flash_bytes`` / ``ram_bytes`` (the budget, None:
    none), ``qemu_machine`` (``qemu-system-arm -M`` that runs the image, None: none), ``max_servos``
    (the most servos its firmware drives), ``elf`` (True: an ARM image written as .elf, .bin and .hex;
    False: a native executable), ``defines`` (the build settings its port reads, ``--define``)."""

    name: str
    part: str
    kind: str
    flash_bytes: int | None
    ram_bytes: int | None
    qemu_machine: str | None
    max_servos: int = MAX_WIRE_SERVOS
    elf: bool = True
    defines: Mapping[str, Define] = field(default_factory=dict)


TARGETS: Mapping[str, Target] = {
    t.name: t for t in (
        Target("native", "this computer (POSIX executable)", "native", None, None, None, elf=False),
        Target("mps2", "small Cortex-M3 part (our stand-in)", "mps2", 32 * 1024, 8 * 1024, "mps2-an385"),
        Target("stm32f4", "STM32F405RG / STM32F407VG (Cortex-M4F)", "stm32f4", 1024 * 1024, 128 * 1024,
               "netduinoplus2", defines={"GS_HSE_HZ": HSE_HZ}),
    )
}


@dataclass(frozen=True)
class ImageUse:
    """Flash and RAM an image uses (bytes) and the section sizes they were summed from."""

    flash: int
    ram: int
    sections: Mapping[str, int]


def image_use(elf: Path) -> ImageUse:
    """Flash and RAM of an ARM ELF image (module docstring: which sections count), from
    ``arm-none-eabi-size -A`` (:func:`firmware_sim.cfirmware.build.size_of`). Raises
    :class:`firmware_sim.cfirmware.build.ToolchainMissing` without arm-none-eabi-size."""
    from firmware_sim.cfirmware.build import size_of

    s = size_of(elf)
    return ImageUse(sum(s.get(k, 0) for k in FLASH_SECTIONS), sum(s.get(k, 0) for k in RAM_SECTIONS), s)


_OVERFLOW = re.compile(r"region [`'](\w+)' overflowed by \d+ bytes")
#: a row of ``ld --print-memory-usage``: ``FLASH:  33184 B  32 KB  101.27%`` (whole KB, MB, GB in those units)
_USAGE = re.compile(r"^\s*(\w+):\s+(\d+) (B|KB|MB|GB)\s+\d+ (?:B|KB|MB|GB)\s+[\d.]+%", re.M)
_UNIT = {"B": 1, "KB": 1 << 10, "MB": 1 << 20, "GB": 1 << 30}


def link_overflow(output: str) -> tuple[int, int] | None:
    """``(flash, ram)`` bytes an image needs when the linker refused it for overflowing a memory region, from the
    linker's ``output`` (an ARM build links with ``--print-memory-usage``: the table of each region's use is printed
    even when a region overflows; :class:`firmware_sim.cfirmware.build.BuildError` carries it). None when the
    output tells of no region overflow or has no usage table for both FLASH and RAM (another link error)."""
    if _OVERFLOW.search(output) is None:
        return None
    used = {m[1]: int(m[2]) * _UNIT[m[3]] for m in _USAGE.finditer(output) if m[1] in REGIONS}
    if set(used) != set(REGIONS):
        return None
    return used["FLASH"], used["RAM"]
