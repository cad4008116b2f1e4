"""The ARM ports' linker scripts hold an image to its target's budget (firmware_sim/cfirmware/targets.py
``TARGETS``): their FLASH and RAM regions are the budget, so an image that does not fit the part does not
link, and ``ghostshell firmware build`` turns the linker's region overflow into its one-line refusal with the
numbers (exit 1, nothing written), not the linker's output. On mps2 the sections ``size -A`` lists add up to
the regions' use (no gaps between them), so the refusal's numbers and a built image's are counted alike."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from firmware_sim.cfirmware.build import KINDS, BuildError, build, c_root
from firmware_sim.cfirmware.targets import TARGETS, image_use, link_overflow
from robots.loader import load_robot_dir
from robots.registry import DEFAULT_ROBOT, load_robot
from support.gen_robot import write_chain_robot

pytestmark = pytest.mark.timeout(300)

ARM_TARGETS = [t for t in TARGETS.values() if t.elf]
_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20}


def _script(kind: str) -> Path:
    arg = next(a for a in KINDS[kind].link if a.startswith("-Wl,-T,"))
    return Path(arg.removeprefix("-Wl,-T,").format(c=c_root()))


def _regions(script: Path) -> dict[str, tuple[int, int]]:
    """name -> (origin, length) of the script's MEMORY regions."""
    memory = re.search(r"MEMORY\s*\{(.*?)\}", script.read_text(), re.S)
    assert memory is not None, script
    return {m[1]: (int(m[2], 0), int(m[3]) * _UNITS[m[4]]) for m in re.finditer(
        r"(\w+)\s*\([rwx]+\)\s*:\s*ORIGIN\s*=\s*(0x[0-9A-Fa-f]+|\d+)\s*,\s*LENGTH\s*=\s*(\d+)([KM]?)", memory[1])}


@pytest.mark.parametrize("target", ARM_TARGETS, ids=lambda t: t.name)
def test_the_linker_regions_are_the_targets_budget(target) -> None:
    regions = _regions(_script(target.kind))
    assert (regions["FLASH"][1], regions["RAM"][1]) == (target.flash_bytes, target.ram_bytes), regions


def test_mps2_sections_add_up_to_the_regions_use() -> None:
    elf = build("mps2", load_robot(DEFAULT_ROBOT))
    nm = subprocess.run(["arm-none-eabi-nm", str(elf)], capture_output=True, text=True, check=True).stdout
    sym = {p[2]: int(p[0], 16) for p in (ln.split() for ln in nm.splitlines()) if len(p) == 3}
    regions = _regions(_script("mps2"))
    flash_used = sym["_sidata"] + sym["_edata"] - sym["_sdata"] - regions["FLASH"][0]  # .data's copy ends flash
    ram_used = sym["_estack"] - regions["RAM"][0]  # the stack is RAM's last section
    use = image_use(elf)
    assert (use.flash, use.ram) == (flash_used, ram_used), use.sections


def test_an_image_over_the_ram_budget_fails_at_link_time(tmp_path: Path) -> None:
    """16 servos: the code fits the small part's flash, the state does not fit its RAM."""
    robot = load_robot_dir(write_chain_robot(tmp_path, 16))
    with pytest.raises(BuildError) as e:
        build("mps2", robot)
    text = str(e.value)
    over = re.search(r"region `RAM' overflowed by (\d+) bytes", text)
    assert over is not None and "region `FLASH' overflowed" not in text, text
    need = link_overflow(text)
    budget = TARGETS["mps2"]
    assert need is not None and budget.flash_bytes is not None and budget.ram_bytes is not None
    flash, ram = need
    assert ram == budget.ram_bytes + int(over[1]) and flash <= budget.flash_bytes


def test_the_build_command_refuses_it_in_one_line(tmp_path: Path) -> None:
    pkg = write_chain_robot(tmp_path / "robots", 16)
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "host", "firmware", "build", "--robot", str(pkg), "--target", "mps2",
                        "--out", str(out)], cwd=tmp_path, capture_output=True, text=True, timeout=240,
                       stdin=subprocess.DEVNULL)
    assert r.returncode == 1, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    with pytest.raises(BuildError) as e:
        build("mps2", load_robot_dir(pkg))
    need = link_overflow(str(e.value))
    assert need is not None
    flash, ram = (f"{n:,}".replace(",", " ") for n in need)
    assert lines[0] == (f"ghostshell firmware: robot chain16 needs {ram} B RAM, mps2 has 8 192 B "
                        f"(flash {flash} of 32 768 B)"), lines[0]
    assert not out.exists()


def test_link_overflow_reads_the_linkers_table() -> None:
    ld = "/usr/bin/arm-none-eabi-ld"
    table = ("Memory region         Used Size  Region Size  %age Used\n"
             "           FLASH:       32768 B        32 KB    100.00%\n"
             "             RAM:          9 KB         8 KB    112.50%\n")
    assert link_overflow(table + f"{ld}: region `RAM' overflowed by 1024 bytes\n") == (32 * 1024, 9 * 1024)
    assert link_overflow(table.replace("32768 B", "32 KB") + f"{ld}: region `RAM' overflowed by 1024 bytes") \
        == (32 * 1024, 9 * 1024)
    assert link_overflow(table + f"{ld}: undefined reference to `gs_tick'\n") is None  # another link error
    assert link_overflow(f"{ld}: region `RAM' overflowed by 1024 bytes\n") is None  # no table: no numbers


def test_a_qemu_board_of_a_robot_that_does_not_fit_says_so_in_one_line(tmp_path: Path) -> None:
    """``--firmware qemu`` runs the mps2 image: a robot whose image the small part's script refuses is one line,
    exit 2 (the linker's output stays out of it)."""
    pkg = write_chain_robot(tmp_path / "robots", 16)
    r = subprocess.run([sys.executable, "-m", "firmware_sim", "--link", "pty", "--firmware", "qemu", "--lockstep",
                        "--robot", str(pkg)], cwd=tmp_path, capture_output=True, text=True, timeout=240,
                       stdin=subprocess.DEVNULL)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("board: robot chain16 does not fit the mps2 image's part: it needs "), \
        r.stderr
