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
64 KiB CCM RAM is not used). How an image is counted (:func:`image_use`, bytes, as
``bench/bench_cfirmware.py`` counts): flash = ``.text + .ARM.exidx + .data`` (``.data``'s initial
values live in flash), RAM = ``.data + .bss + .stack + .bootcfg`` (the main stack and the boot
configuration block are sections of their own in our linker scripts). ``tests/cfirmware/test_image_size.py``
checks the default robot against :data:`TARGETS` ``["mps2"]``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from protocol.messages import MAX_WIRE_SERVOS

__all__ = ["FLASH_SECTIONS", "HSE_HZ", "RAM_SECTIONS", "TARGETS", "Define", "ImageUse", "Target", "image_use"]

#: sections counted as flash (bytes in the image); absent ones count 0
FLASH_SECTIONS = (".text", ".ARM.exidx", ".data")
#: sections counted as RAM (what the image occupies at run time); absent ones count 0
RAM_SECTIONS = (".data", ".bss", ".stack", ".bootcfg")


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
