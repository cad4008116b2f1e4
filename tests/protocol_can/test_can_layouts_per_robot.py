"""CAN layouts per robot servo count: frame sizes, the classic TELEMETRY that goes bulk above 27 servos,
round trips through our decoder, and a generated DBC that cantools loads and decodes our frames with."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import cantools
import pytest

from protocol.can import CanDecoder, CanItem, encode_bulk, encode_fixed, is_fixed
from protocol.can.codec import Sender, fixed_crc, message_to_raw
from protocol.can.ids import FunctionCode, cob_id
from protocol.can.layouts import CRC_SIGNAL, DEFAULT_SERVO_COUNT, FIXED_LAYOUTS, MAX_PARTS, can_layouts
from protocol.can.make_dbc import DbcRobot, dbc_text
from protocol.codec import WireBoundError, schema_for
from protocol.messages import MsgType
from protocol.testing.samples import servo_frame_n, telemetry_n
from support.gen_robot import write_chain_robot

ROOT = Path(__file__).resolve().parents[2]
COCO_DIR = ROOT / "robots" / "coco"

#: servos -> (SERVO_FRAME classic parts, FD bytes, TELEMETRY classic parts (None: ISO-TP), FD frames x bytes)
SIZES = {1: (2, 12, 6, (1, 48)), 12: (6, 48, 17, (2, 64)), 16: (7, 48, 21, (3, 64)), 17: (8, 48, 22, (3, 64)),
         27: (11, 64, 32, (4, 64)), 28: (12, 64, None, (4, 64)), 32: (13, 64, None, (4, 64))}


def _same(a: object, b: object) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or a == b
    if isinstance(a, tuple) and isinstance(b, tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a == b


def test_default_table_is_cocos() -> None:
    assert DEFAULT_SERVO_COUNT == 12 and FIXED_LAYOUTS is can_layouts(12).fixed and can_layouts(12) is can_layouts()
    assert FIXED_LAYOUTS[(FunctionCode.SERVO_FRAME, False)].parts == 6
    assert FIXED_LAYOUTS[(FunctionCode.SERVO_FRAME, True)].length == 48


@pytest.mark.parametrize("n", sorted(SIZES))
def test_sizes_per_servo_count(n: int) -> None:
    sf_parts, sf_fd, tel_parts, (tel_fd_parts, tel_fd_len) = SIZES[n]
    t = can_layouts(n)
    assert t is can_layouts(n)  # cached per N
    assert t.layout(FunctionCode.SERVO_FRAME, False).parts == sf_parts  # type: ignore[union-attr]
    fd_sf = t.layout(FunctionCode.SERVO_FRAME, True)
    assert fd_sf is not None and fd_sf.length == sf_fd
    tel = t.layout(FunctionCode.TELEMETRY, False)
    assert (tel.parts if tel is not None else None) == tel_parts
    if tel is not None:
        assert tel.parts == n + 5 <= MAX_PARTS
    fd_tel = t.layout(FunctionCode.TELEMETRY, True)
    assert fd_tel is not None and (fd_tel.parts, fd_tel.length) == (tel_fd_parts, tel_fd_len)
    mask = next(p for p in t.layout(FunctionCode.FLUSH, False).signals if p.spec.name == "mask")  # type: ignore[union-attr]
    assert mask.spec.bits == (16 if n <= 16 else 32)
    assert t.schema is schema_for(n)


def test_no_table_beyond_the_wire_bound() -> None:
    with pytest.raises(WireBoundError):
        can_layouts(33)


@pytest.mark.parametrize("fd", [False, True])
@pytest.mark.parametrize("n", [1, 17, 27, 28, 32])
def test_round_trip_per_servo_count(n: int, fd: bool) -> None:
    t = can_layouts(n)
    for msg, sender, receiver in ((servo_frame_n(n), Sender.HOST, "board"), (telemetry_n(n), Sender.BOARD, "host")):
        dec = CanDecoder(3, receiver, t)
        dec.last_seq = 500
        if is_fixed(msg, fd, t):
            items = [i for f in encode_fixed(msg, 501, 3, fd, sender, t) for i in dec.feed(f)]
        else:  # classic TELEMETRY above 27 servos: the ISO-TP unit, in the robot's serial schema
            assert isinstance(msg, type(telemetry_n(1))) and not fd and n > 27
            with pytest.raises(Exception, match="no fixed CAN layout for"):
                encode_fixed(msg, 501, 3, fd, sender, t)
            items = [dec.feed_bulk(encode_bulk(msg, 501, t.schema))]
        assert len(items) == 1 and isinstance(items[0], CanItem), items
        assert items[0].seq == 501 and _same(items[0].msg, t.schema.quantize_message(msg))


def test_a_fixed_telemetry_frame_where_the_table_has_none_is_dropped() -> None:
    frames = encode_fixed(telemetry_n(12), 7, 1, False, Sender.BOARD)
    dec = CanDecoder(1, "host", can_layouts(32))
    out = [i for f in frames for i in dec.feed(f)]
    assert out and not any(isinstance(i, CanItem) for i in out) and dec.error_count == len(frames)


def test_checked_in_coco_dbcs_are_generated() -> None:
    coco = DbcRobot("coco", "CoCo", 12)
    for fd, name in ((False, "coco.dbc"), (True, "coco_fd.dbc")):
        assert (COCO_DIR / name).read_text() == dbc_text(fd, robot=coco)
        # the protocol-only command line (a servo count, no robot) prints the same bytes
        r = subprocess.run([sys.executable, "-m", "protocol.can.make_dbc", "--servos", "12", "--name", "coco",
                            "--title", "CoCo", *(["--fd"] if fd else [])], capture_output=True, cwd=ROOT, timeout=120)
        assert r.returncode == 0 and r.stdout == (COCO_DIR / name).read_bytes(), r.stderr


def test_every_built_in_robots_checked_in_dbcs_are_current() -> None:
    from robots.registry import BUILTIN_DIR

    robots = sorted(p.parent.name for p in BUILTIN_DIR.glob("*/*.dbc") if p.stem == p.parent.name)
    # every built-in robot ships its DBCs (a user's `ghostshell dbc --robot arm --check` on a clean clone
    # said "robots/arm/arm.dbc is missing")
    assert robots == sorted(p.parent.name for p in BUILTIN_DIR.glob("*/robot.toml")), robots
    for name in robots:
        r = subprocess.run([sys.executable, "-m", "host", "dbc", "--robot", name, "--check"], capture_output=True,
                           text=True, cwd=ROOT, timeout=120)
        assert r.returncode == 0 and r.stdout == "" and r.stderr == "", (name, r.stdout, r.stderr)


def test_ghostshell_dbc_check_and_write_a_robots_files(tmp_path: Path) -> None:
    pkg = write_chain_robot(tmp_path, 20)
    classic, fd = pkg / "chain20.dbc", pkg / "chain20_fd.dbc"

    def dbc(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "host", "dbc", "--robot", str(pkg), *args], capture_output=True,
                              text=True, timeout=120)

    r = dbc("--check")
    assert r.returncode == 1 and r.stdout == "", r
    assert [ln.split(": ")[1].split(" ")[0] for ln in r.stderr.splitlines()] == [str(classic), str(fd)]
    assert all("is missing (ghostshell dbc --robot chain20 --write)" in ln for ln in r.stderr.splitlines())
    r = dbc("--write")
    assert r.returncode == 0 and r.stdout.splitlines() == [f"wrote {classic}", f"wrote {fd}"], r
    assert classic.read_text() == dbc().stdout and fd.read_text() == dbc("--fd").stdout
    assert dbc("--check").returncode == 0
    fd.write_text(fd.read_text().replace("Chain 20 board", "Chain 21 board"))
    r = dbc("--check")
    assert r.returncode == 1 and r.stderr.strip() == (f"ghostshell dbc: {fd} differs from the generated DBC "
                                                      "(ghostshell dbc --robot chain20 --write)"), r
    r = dbc("--check", "--fd")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "drop --fd" in r.stderr, r


def test_protocol_imports_no_robot() -> None:
    """protocol/ is pure codecs (DEVELOPERS.md): it imports neither robots nor host nor firmware_sim."""
    import ast

    for path in sorted((ROOT / "protocol").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            for n in names:
                assert n.split(".")[0] not in ("robots", "host", "firmware_sim"), f"{path}: imports {n}"


@pytest.mark.parametrize("fd", [False, True])
def test_ghostshell_dbc_prints_cocos_checked_in_file(fd: bool) -> None:
    r = subprocess.run([sys.executable, "-m", "host", "dbc", "--robot", "coco", *(["--fd"] if fd else [])],
                       capture_output=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout == (COCO_DIR / ("coco_fd.dbc" if fd else "coco.dbc")).read_bytes()


@pytest.mark.parametrize("fd", [False, True])
def test_a_32_servo_robots_dbc_decodes_our_frames(tmp_path: Path, fd: bool) -> None:
    pkg = write_chain_robot(tmp_path, 32)
    r = subprocess.run([sys.executable, "-m", "host", "dbc", "--robot", str(pkg), "--nodes", "1,5",
                        *(["--fd"] if fd else [])], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith('VERSION "chain32-1"') and "Chain 32 board, node id 5" in r.stdout
    db = cantools.database.load_string(r.stdout, database_format="dbc")
    t = can_layouts(32)
    sent = [(servo_frame_n(32), Sender.HOST)] + ([(telemetry_n(32), Sender.BOARD)] if fd else [])
    for msg, sender in sent:
        frames = encode_fixed(msg, 1234, 5, fd, sender, t)
        layout = t.layout(FunctionCode.SERVO_FRAME if sender == Sender.HOST else FunctionCode.TELEMETRY, fd)
        assert layout is not None and len(frames) == layout.parts
        raw = message_to_raw(msg, t)
        raw[CRC_SIGNAL] = fixed_crc(layout, 1234, raw)
        for k, f in enumerate(frames):
            dm = db.get_message_by_frame_id(f.arbitration_id)
            assert dm.is_fd == fd and dm.length == len(f.data)
            sig = dm.decode(f.data, decode_choices=False, scaling=False)
            assert sig["part"] == k and sig["seq"] == 1234 % 2048
            assert {n: v for n, v in sig.items() if n not in ("part", "seq")} == \
                {p.spec.name: raw[p.spec.name] for p in layout.signals if p.part == k}
        if sender == Sender.HOST:
            assert raw["mask"] == 0xFFFF_FFFF and raw["target_32"] == round(servo_frame_n(32).targets[31] * 1e4)
    # classic CAN: 32-servo TELEMETRY goes as ISO-TP, so the DBC has no TELEMETRY message for it
    names = {m.name for m in db.messages}
    assert ("TELEMETRY_N5" in names) == fd and "BULK_TO_HOST_N5" in names
    assert db.get_message_by_frame_id(cob_id(FunctionCode.SERVO_FRAME, 5)).name == "SERVO_FRAME_N5"


def test_ghostshell_dbc_refuses_bad_input(tmp_path: Path) -> None:
    for args, what in ((["--robot", "no_such_robot"], "no robot 'no_such_robot'"),
                       (["--robot", str(write_chain_robot(tmp_path, 33))], "33 servos; the wire carries at most 32"),
                       (["--robot", "coco", "--nodes", "1,x"], "node ids")):
        r = subprocess.run([sys.executable, "-m", "host", "dbc", *args], capture_output=True, text=True, timeout=120)
        assert r.returncode == 2 and r.stdout == "", (args, r.stdout, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert what in r.stderr, r.stderr


def test_bulk_payload_uses_the_robots_schema() -> None:
    t = can_layouts(20)
    sdu = encode_bulk(servo_frame_n(20), 9, t.schema)
    assert CanDecoder(1, "board", t).feed_bulk(sdu).msg_type is MsgType.SERVO_FRAME  # type: ignore[union-attr]
    assert not isinstance(CanDecoder(1, "board").feed_bulk(sdu), CanItem)  # the default table's u16 schema refuses it
