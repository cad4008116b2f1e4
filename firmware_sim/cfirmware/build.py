"""Build the C firmware and its test and fuzz harnesses into a cache folder (never the source tree).

``build(kind, robot)`` compiles ``firmware_sim/c`` for one robot and returns the output path; the
output is reused while every input is unchanged: the key is a SHA-256 over the C sources, the
generated servo table, the compiler's version line and the flags, so editing a source, the robot's
servo table or the toolchain rebuilds. Builds are written to a temporary folder and renamed into
place, so parallel test processes never see a half-written binary.

Kinds (``KINDS``):

=============  ==================================================================================
native         the POSIX firmware (``cc -std=c99 -O2 -Wall -Wextra -Werror``)
native-asan    the same with ``-fsanitize=address,undefined`` (tests run the core under it)
mps2           the Cortex-M3 image for QEMU's ``mps2-an385`` (``arm-none-eabi-gcc``, newlib-nano)
codec          the codec harness (stdin hex lines -> decode/dump/re-encode), ASan/UBSan
fuzz-c-wire    libFuzzer: bytes into the C link decoder + board session (clang, fuzzer+ASan+UBSan)
libdecode      the C frame decoder as a shared library (the differential target c-diff loads it)
=============  ==================================================================================

A missing compiler raises :class:`ToolchainMissing` whose message is the Debian install command
(``.ci/setup`` installs them; tests fail with that line, they do not skip).

Cache folder: ``$GHOSTSHELL_CFIRMWARE_CACHE`` or the user cache dir (platformdirs) ``/cfirmware``.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import platformdirs

from firmware_sim.cfirmware.servo_table import servo_table_c, servo_table_h
from robots.description import Robot

__all__ = ["BuildError", "KINDS", "ToolchainMissing", "build", "cache_root", "c_root", "size_of"]

C_ROOT = Path(__file__).resolve().parents[1] / "c"
WARN = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-Wshadow", "-Wpointer-arith", "-Wstrict-prototypes"]
SAN = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-fno-omit-frame-pointer", "-g"]
APT = {
    "cc": "apt-get install -y gcc libc6-dev",
    "arm-none-eabi-gcc": "apt-get install -y gcc-arm-none-eabi libnewlib-arm-none-eabi",
    "clang": "apt-get install -y clang",
    "qemu-system-arm": "apt-get install -y qemu-system-arm",
    "arm-none-eabi-size": "apt-get install -y binutils-arm-none-eabi",
}


class BuildError(RuntimeError):
    """The compiler refused the sources (message: the command and its output's tail)."""


class ToolchainMissing(BuildError):
    """A compiler or emulator is not installed; the message is the command that installs it."""


def c_root() -> Path:
    return C_ROOT


def cache_root() -> Path:
    env = os.environ.get("GHOSTSHELL_CFIRMWARE_CACHE")
    return Path(env) if env else Path(platformdirs.user_cache_dir("ghostshell")) / "cfirmware"


def require(tool: str) -> str:
    """The path of ``tool`` or :class:`ToolchainMissing` with its Debian install command."""
    path = shutil.which(tool)
    if path is None:
        raise ToolchainMissing(f"{tool} is not installed; install it with: {APT.get(tool, 'apt-get install -y ' + tool)}"
                               " (.ci/setup does this as root)")
    return path


@dataclass(frozen=True)
class _Kind:
    compiler: str
    sources: tuple[str, ...]  # globs under firmware_sim/c
    flags: tuple[str, ...]
    output: str
    link: tuple[str, ...] = ()


_CORE = ("core/*.c",)
KINDS: dict[str, _Kind] = {
    "native": _Kind("cc", _CORE + ("ports/native/*.c",), (*WARN, "-O2", "-D_GNU_SOURCE"), "gs_firmware"),
    "native-asan": _Kind("cc", _CORE + ("ports/native/*.c",), (*WARN, "-O1", "-D_GNU_SOURCE", *SAN), "gs_firmware"),
    "mps2": _Kind(
        "arm-none-eabi-gcc", _CORE + ("ports/mps2/*.c",),
        (*WARN, "-mcpu=cortex-m3", "-mthumb", "-Os", "-ffunction-sections", "-fdata-sections", "-g"),
        "gs_firmware.elf",
        ("-nostartfiles", "--specs=nano.specs", "-Wl,--gc-sections", "-Wl,-T,{c}/ports/mps2/mps2_an385.ld",
         "-Wl,-Map={out}/gs_firmware.map", "-lgcc"),
    ),
    "codec": _Kind("cc", ("core/gs_proto.c", "core/gs_cobs.c", "core/gs_crc.c", "tests/codec_harness.c"),
                   (*WARN, "-O1", "-DGS_PROTO_DUMP", *SAN), "codec_harness"),
    "fuzz-c-wire": _Kind("clang", _CORE + ("tests/fuzz_hal.c", "tests/fuzz_c_wire.c"),
                         (*WARN, "-O1", "-g", "-fsanitize=fuzzer,address,undefined", "-fno-sanitize-recover=all"),
                         "fuzz_c_wire"),
    "libdecode": _Kind("cc", ("core/gs_link.c", "core/gs_proto.c", "core/gs_cobs.c", "core/gs_crc.c",
                              "tests/diff_lib.c"),
                       (*WARN, "-O1", "-fPIC", "-shared", "-DGS_PROTO_DUMP"), "libgs_decode.so"),
}


def _sources(kind: _Kind) -> list[Path]:
    out: list[Path] = []
    for pattern in kind.sources:
        found = sorted(C_ROOT.glob(pattern))
        if not found:
            raise BuildError(f"no C sources match {pattern} under {C_ROOT}")
        out.extend(found)
    return out


def _version(compiler: str) -> str:
    try:
        return subprocess.run([compiler, "--version"], capture_output=True, text=True, timeout=30).stdout.splitlines()[0]
    except (OSError, IndexError, subprocess.TimeoutExpired):
        return compiler


def build(kind_name: str, robot: Robot, *, quiet: bool = True) -> Path:
    """Compile ``kind_name`` for ``robot`` (cached); returns the binary's path.

    Raises :class:`ToolchainMissing` (install command) or :class:`BuildError` (compiler output).
    """
    kind = KINDS[kind_name]
    cc = require(kind.compiler)
    gen = {"gs_servo_table.h": servo_table_h(robot), "gs_servo_table.c": servo_table_c(robot)}
    sources = _sources(kind)
    headers = sorted(C_ROOT.glob("**/*.h")) + sorted(C_ROOT.glob("ports/mps2/*.ld"))
    h = hashlib.sha256()
    for p in sorted(set(sources) | set(headers)):
        h.update(str(p.relative_to(C_ROOT)).encode() + b"\0" + p.read_bytes() + b"\0")
    for name, text in sorted(gen.items()):
        h.update(name.encode() + b"\0" + text.encode() + b"\0")
    h.update(repr((kind, _version(cc))).encode())
    out = cache_root() / f"{kind_name}-{robot.name}-{h.hexdigest()[:16]}"
    binary = out / kind.output
    if binary.is_file():
        return binary
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{kind_name}-", dir=out.parent))
    try:
        for name, text in gen.items():
            (tmp / name).write_text(text, encoding="utf-8")
        includes = ["-I", str(tmp), "-I", str(C_ROOT / "core")]
        port_dirs = sorted({str(p.parent) for p in sources if p.parent != C_ROOT / "core"})
        for d in port_dirs:
            includes += ["-I", d]
        link = [a.format(c=C_ROOT, out=tmp) for a in kind.link]
        cmd = [cc, *kind.flags, *includes, *map(str, sources), str(tmp / "gs_servo_table.c"), "-o",
               str(tmp / kind.output), *link]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
        if r.returncode != 0:
            tail = "\n".join((r.stdout + r.stderr).splitlines()[-40:])
            raise BuildError(f"building {kind_name} for {robot.name} failed:\n{' '.join(cmd)}\n{tail}")
        if kind_name == "mps2":
            objcopy = shutil.which("arm-none-eabi-objcopy") or "arm-none-eabi-objcopy"
            subprocess.run([objcopy, "-O", "binary", str(tmp / kind.output), str(tmp / "gs_firmware.bin")],
                           check=True, capture_output=True, timeout=60)
        try:
            tmp.rename(out)
        except OSError:  # another process built the same key first: keep its output
            shutil.rmtree(tmp, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if not quiet:
        print(f"built {binary}")
    return binary


def size_of(elf: Path) -> dict[str, int]:
    """``.text``/``.data``/``.bss`` bytes of an ARM ELF (``arm-none-eabi-size -A``)."""
    tool = require("arm-none-eabi-size")
    r = subprocess.run([tool, "-A", str(elf)], capture_output=True, text=True, check=True, timeout=60)
    sizes: dict[str, int] = {}
    for line in r.stdout.splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[0].startswith(".") and parts[1].isdigit():
            sizes[parts[0]] = int(parts[1])
    return sizes
