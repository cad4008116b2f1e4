"""``ghostshell firmware build|targets|check`` as a user runs it (real processes, real toolchains, real boards).

* build: CoCo for native, mps2 and stm32f4 writes its files into ``--out``, and the flash and RAM it prints are
  what ``arm-none-eabi-size -A`` says of the written .elf (flash = .text + .ARM.exidx + .data, RAM =
  .data + .bss + .stack + .bootcfg); the .bin is the flash image, the .hex Intel HEX of it;
* a generated 32-servo robot is refused for mps2 with one line naming its numbers, nothing written;
* bad arguments: one line, exit 2, nothing on stdout; Ctrl-C during a build: exit 130, nothing written;
* check: the handshake with the Python board and the native C firmware on a pty, one line per fact,
  exit 0; a board of another robot: one line, exit 1 (the same line from every board:
  tests/cfirmware/test_handshake_refusal.py).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from firmware_sim.cfirmware.build import BuildError, build
from firmware_sim.cfirmware.targets import TARGETS
from host.link.board_process import start_board
from protocol.codec import WIRE_SCHEMA_16
from protocol.messages import MAX_WIRE_SERVOS
from robots.loader import load_robot_dir
from robots.registry import load_robot
from support.cliproc import start, wait_until
from support.gen_robot import write_chain_robot

pytestmark = pytest.mark.timeout(300)


def _ghostshell(*argv: str, cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "host", *argv], cwd=cwd, capture_output=True, text=True,
                          timeout=240, env=env, stdin=subprocess.DEVNULL)


def _arm_size(elf: Path) -> dict[str, int]:
    """``arm-none-eabi-size -A`` of ``elf``: section -> bytes (run here, not through firmware_sim)."""
    out = subprocess.run(["arm-none-eabi-size", "-A", str(elf)], capture_output=True, text=True, check=True).stdout
    return {p[0]: int(p[1]) for p in (ln.split() for ln in out.splitlines()) if len(p) >= 2 and p[0].startswith(".")
            and p[1].isdigit()}


def _bytes(text: str) -> int:
    return int(text.replace(" ", ""))


def _b(n: int) -> str:
    """``32 768``: bytes as the command prints them."""
    return f"{n:,}".replace(",", " ")


@pytest.mark.parametrize("target", ["mps2", "stm32f4"])
def test_coco_for_an_arm_target_writes_elf_bin_hex_and_prints_what_arm_none_eabi_size_says(target: str,
                                                                                          tmp_path: Path) -> None:
    out = tmp_path / "out"
    r = _ghostshell("firmware", "build", "--robot", "coco", "--target", target, "--out", str(out), cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stderr == ""
    elf, bin_, hex_ = (out / f"gs_firmware.{ext}" for ext in ("elf", "bin", "hex"))
    assert elf.is_file() and bin_.is_file() and hex_.is_file()
    s = _arm_size(elf)
    flash = s[".text"] + s.get(".ARM.exidx", 0) + s[".data"]
    ram = s[".data"] + s[".bss"] + s.get(".stack", 0) + s.get(".bootcfg", 0)
    t = TARGETS[target]
    assert t.flash_bytes is not None and t.ram_bytes is not None
    printed_flash = re.search(rf"flash +(\d[\d ]*) B of {_b(t.flash_bytes)} B", r.stdout)
    printed_ram = re.search(rf"RAM +(\d[\d ]*) B of {_b(t.ram_bytes)} B", r.stdout)
    assert printed_flash and printed_ram, r.stdout
    assert (_bytes(printed_flash[1]), _bytes(printed_ram[1])) == (flash, ram), r.stdout
    assert bin_.stat().st_size == flash  # the raw image: vectors and code from the start of flash, then .data
    lines = hex_.read_text().split()
    assert all(ln.startswith(":") for ln in lines) and lines[-1] == ":00000001FF"  # Intel HEX, its EOF record


def test_a_define_is_a_build_setting_of_the_image(tmp_path: Path) -> None:
    """--define GS_HSE_HZ=12000000 (a pyboard's crystal, docs/guides/stm32f4.md) builds another image."""
    images = {}
    for hse in ("8000000", "12000000"):
        out = tmp_path / hse
        r = _ghostshell("firmware", "build", "--target", "stm32f4", "--define", f"GS_HSE_HZ={hse}", "--out", str(out),
                        cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        assert f"GS_HSE_HZ={hse}" in r.stdout.splitlines()[0]
        images[hse] = (out / "gs_firmware.bin").read_bytes()
    assert images["8000000"] != images["12000000"]


def test_coco_for_native_writes_the_executable(tmp_path: Path) -> None:
    r = _ghostshell("firmware", "build", "--robot", "coco", "--target", "native", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    exe = tmp_path / "firmware" / "coco-native" / "gs_firmware"  # the default --out: ./firmware/ROBOT-TARGET/
    assert exe.is_file() and os.access(exe, os.X_OK)
    assert "no flash or RAM budget" in r.stdout
    assert exe.read_bytes() == build("native", load_robot("coco")).read_bytes()


def test_a_32_servo_robot_is_refused_for_mps2_with_its_numbers(tmp_path: Path) -> None:
    pkg = write_chain_robot(tmp_path / "robots", 32)
    out = tmp_path / "out"
    r = _ghostshell("firmware", "build", "--robot", str(pkg), "--target", "mps2", "--out", str(out), cwd=tmp_path)
    assert r.returncode == 1, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    with pytest.raises(BuildError) as e:  # the small part's linker script refuses it: its numbers are the linker's
        build("mps2", load_robot_dir(pkg))
    used = {m[1]: int(m[2]) for m in re.finditer(r"^\s*(FLASH|RAM):\s+(\d+) B\b", str(e.value), re.M)}
    flash, ram = used["FLASH"], used["RAM"]
    budget = TARGETS["mps2"]
    assert budget.flash_bytes is not None and budget.ram_bytes is not None
    assert flash > budget.flash_bytes and ram > budget.ram_bytes  # this robot is over both
    assert lines[0] == (f"ghostshell firmware: robot chain32 needs {_b(flash)} B flash and {_b(ram)} B RAM, mps2 has "
                        f"{_b(budget.flash_bytes)} B flash and {_b(budget.ram_bytes)} B RAM"), lines[0]
    assert not out.exists()


def test_a_robot_wider_than_the_wire_is_bad_input(tmp_path: Path) -> None:
    """33 servos: no firmware, no board, no host carries it (the loader refuses the robot, as every command does)."""
    pkg = write_chain_robot(tmp_path / "robots", 33)
    r = _ghostshell("firmware", "build", "--robot", str(pkg), "--target", "native", cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ghostshell firmware: "), r.stderr
    assert "33 servos" in lines[0] and f"at most {MAX_WIRE_SERVOS}" in lines[0], r.stderr
    assert r.stdout == "" and not (tmp_path / "firmware").exists()


def test_targets_prints_the_table(tmp_path: Path) -> None:
    r = _ghostshell("firmware", "targets", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    rows = {ln.split()[0]: ln for ln in r.stdout.splitlines()[1:]}
    assert set(rows) == set(TARGETS)
    assert "32 KB" in rows["mps2"] and "8 KB" in rows["mps2"] and "mps2-an385" in rows["mps2"]
    assert "1024 KB" in rows["stm32f4"] and "128 KB" in rows["stm32f4"] and "netduinoplus2" in rows["stm32f4"]


BAD = [
    (("firmware",), "ghostshell firmware: error: the following arguments are required: ACTION"),
    (("firmware", "build"), "ghostshell firmware build: error: the following arguments are required: --target"),
    (("firmware", "build", "--target", "avr"), "argument --target: invalid choice: 'avr'"),
    (("firmware", "build", "--target", "mps2", "--robot", "no-such-robot"), "ghostshell firmware: no robot 'no-such-robot'"),
    (("firmware", "build", "--target", "mps2", "--out", "{FILE}"), "is a regular file, not a folder"),
    (("firmware", "build", "--target", "mps2", "--bogus"), "unrecognized arguments: --bogus"),
    (("firmware", "build", "--target", "stm32f4", "--define", "hse=12"), "argument --define: expected NAME=N"),
    (("firmware", "build", "--target", "stm32f4", "--define", "GS_HSE_HZ=fast"), "expected a non-negative integer"),
    # a new user's findings (2026-12-07): each of these reached the compiler (exit 1, a 2-4 KB gcc dump), built
    # with no effect, or wrote into the current folder
    (("firmware", "build", "--target", "stm32f4", "--define", "GS_HSE_HZ=0"), "must be 4000000..26000000"),
    (("firmware", "build", "--target", "stm32f4", "--define", "GS_HSE_HZ=12500000"), "in steps of 1000000"),
    (("firmware", "build", "--target", "stm32f4", "--define", "GS_HSE_HZ=99999999999999999999"), "must be 4000000"),
    (("firmware", "build", "--target", "stm32f4", "--define", "GS_FOO=1"), "reads no such setting (it reads: GS_HSE_HZ)"),
    (("firmware", "build", "--target", "mps2", "--define", "GS_HSE_HZ=12000000"), "target mps2 reads no such setting"),
    (("firmware", "build", "--target", "stm32f4", "--define", "GS_HSE_HZ=12000000", "--define", "GS_HSE_HZ=8000000"),
     "GS_HSE_HZ: given twice"),
    (("firmware", "build", "--target", "stm32f4", "--calibrated"), "robot coco has no calibration.toml"),
    (("firmware", "build", "--target", "mps2", "--out", ""), "argument --out: give a folder"),
    (("firmware", "check"), "ghostshell firmware check: error: the following arguments are required: --link"),
    (("firmware", "check", "--link", "pty"), "a link the emulated board creates"),
    (("firmware", "check", "--link", "/dev/null", "--robot", "no-such-robot"), "no robot 'no-such-robot'"),
]


@pytest.mark.parametrize(("argv", "says"), BAD, ids=[" ".join(a) for a, _ in BAD])
def test_bad_arguments_exit_2_with_one_line(argv: tuple[str, ...], says: str, tmp_path: Path) -> None:
    regular = tmp_path / "regular.txt"
    regular.write_text("kept\n", encoding="utf-8")
    r = _ghostshell(*(a.replace("{FILE}", str(regular)) for a in argv), cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and says in lines[0] and lines[0].startswith("ghostshell firmware"), r.stderr
    assert r.stdout == "" and "Traceback" not in r.stderr
    assert regular.read_text(encoding="utf-8") == "kept\n" and not (tmp_path / "firmware").exists()


def _held_compiler(tmp_path: Path) -> tuple[Path, Path]:
    """A stand-in ``arm-none-eabi-gcc`` first on PATH: it answers ``--version``, and a compile marks a file
    and then holds (until a signal stops it), so a Ctrl-C is sure to find the build compiling however busy
    the machine is (a real compile takes about a second: on a loaded machine it can finish first)."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    mark = tmp_path / "compiling"
    gcc = bin_dir / "arm-none-eabi-gcc"
    gcc.write_text("#!/bin/sh\n"
                   'if [ "$1" = --version ]; then echo "arm-none-eabi-gcc (held stand-in) 0"; exit 0; fi\n'
                   f'echo "$$" > "{mark}"\n'
                   "exec sleep 600\n", encoding="utf-8")
    gcc.chmod(0o755)
    return bin_dir, mark


def test_ctrl_c_during_a_build_exits_130_and_writes_nothing(tmp_path: Path) -> None:
    cache = tmp_path / "cache"  # empty: the build compiles
    out = tmp_path / "out"
    bin_dir, compiling = _held_compiler(tmp_path)
    env = dict(os.environ, GHOSTSHELL_CFIRMWARE_CACHE=str(cache), PATH=f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    cli = start(["firmware", "build", "--robot", "coco", "--target", "mps2", "--out", str(out)], tmp_path / "logs",
                env=env)
    try:
        wait_until(compiling.exists, "the build is compiling", proc=cli)
        cli.ctrl_c()
        status = cli.wait(60)
    finally:
        cli.kill()
    assert status == 130, cli.stderr
    assert cli.stderr.strip().splitlines() == ["ghostshell firmware: interrupted by SIGINT (Ctrl-C)"], cli.stderr
    assert not out.exists()
    assert not list(cache.glob(".*")), list(cache.iterdir())  # no half-built folder left in the cache
    compiler_pid = int(compiling.read_text())
    wait_until(lambda: not Path(f"/proc/{compiler_pid}").exists() or "zombie" in _state(compiler_pid),
               "the compiler is stopped too", timeout=10)


def _state(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/status").read_text().split("State:", 1)[1].split("\n", 1)[0].lower()
    except (OSError, IndexError):
        return "zombie"


@pytest.fixture(params=["python", "c"])
def board(request: pytest.FixtureRequest, tmp_path: Path):
    b = start_board(["--firmware", request.param], tmp_path / "board.stderr", timeout=120)
    yield b
    b.stop()


def test_check_prints_one_line_per_fact(board, tmp_path: Path) -> None:
    r = _ghostshell("firmware", "check", "--link", board.port, "--robot", "coco", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    facts = dict(ln.split(": ", 1) for ln in r.stdout.splitlines())
    assert list(facts) == ["link", "firmware", "robot", "servos", "schema", "control rate", "telemetry rate",
                           "board time", "faults"], r.stdout
    coco = load_robot("coco")
    assert facts["link"].startswith(board.port)
    assert facts["firmware"].startswith("GhostShell protocol v1, realtime")
    assert facts["robot"] == f"coco, servo table {coco.servo_table_hash:#010x} (as --robot coco)"
    assert facts["servos"] == "12"
    assert facts["schema"].startswith(f"{WIRE_SCHEMA_16.hash:#010x} (u16 servo mask")
    assert facts["control rate"].endswith(" Hz") and facts["telemetry rate"].endswith(" Hz")
    # a realtime board on a loaded machine may report a late tick (TICK_OVERRUN); nothing else is expected
    assert facts["faults"] == "none" or set(facts["faults"].split(", ")) == {"TICK_OVERRUN"}, facts["faults"]


def test_check_refuses_a_board_of_another_robot(board, tmp_path: Path) -> None:
    r = _ghostshell("firmware", "check", "--link", board.port, "--robot", "arm", cwd=tmp_path)
    assert r.returncode == 1, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"ghostshell firmware check: the board on {board.port} drives "
                                                   "robot 'coco'") and "started for 'arm'" in lines[0], r.stderr
    assert r.stdout == ""
    assert board.proc.poll() is None  # the board still serves
