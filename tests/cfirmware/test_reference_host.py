"""A new implementer's host, written from docs/wire-protocol.md alone (pyserial + cobs + crcmod).

Everything protocol-specific here is read from the reference's tables at run time: the frame header,
the CRC parameters (checked against the stated check value), the schema hash, the message type
numbers and each payload layout (an interpreter of the reference's type vocabulary). Nothing of
``protocol``, ``host`` or ``firmware_sim`` is imported. The host then talks to a real board
subprocess, the Python board and the C firmware alike, as the reference says a client should: a
TIME_SYNC before any HELLO (HELLO is optional), HELLO -> CAPS, frames and ADVANCE in lockstep,
TELEMETRY confirming the frames, CONFIG (its keys table, the refusals table's NACK codes), the servo table
hash computed by the reference's recipe, ESTOP and ESTOP_CLEAR. The hash recipes are also checked against the
code (``test_hashes_from_the_recipe``: the only test here that imports the project, to compare).
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import select
import struct
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import crcmod
import pytest
import serial
from cobs import cobs

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "wire-protocol.md"


def _rows(lines: list[str]) -> list[list[str]]:
    out = []
    for ln in lines:
        if ln.startswith("|") and not ln.startswith("| ---"):
            out.append([c.strip() for c in ln.strip().strip("|").split("|")])
    return out[1:]  # without the header row


class Reference:
    """The tables of the reference, parsed."""

    def __init__(self, text: str) -> None:
        m = re.search(r"poly `(0x[0-9a-fA-F]+)` reflected, init `(0x[0-9a-fA-F]+)`, xorout `(0x[0-9a-fA-F]+)`", text)
        assert m, "CRC parameters not found"
        poly, init, xorout = (int(x, 16) for x in m.groups())
        self.crc = crcmod.mkCrcFun(0x10000 | poly, initCrc=init ^ xorout, rev=True, xorOut=xorout)
        check = int(re.search(r"check value of `b\"123456789\"` is `(0x[0-9a-fA-F]+)`", text).group(1), 16)
        assert self.crc(b"123456789") == check
        self.schema = int(re.search(r"Current value: `(0x[0-9a-fA-F]+)`", text).group(1), 16)
        lines = text.splitlines()
        framing = lines[lines.index("## Serial framing") + 2:]
        header = _rows(framing[:framing.index("")])
        self.version = int(next(r for r in header if r[1] == "version")[4])
        types = lines[lines.index("## Message types"):]
        self.types = {r[1]: int(r[0], 16) for r in _rows(types[2:types.index("", 3)])}
        self.layouts: dict[str, list[tuple[str, str]]] = {}
        payload = lines[lines.index("## Payload layouts"):lines.index("## Enumerations")]
        for k, ln in enumerate(payload):
            hm = re.match(r"### (\w+) \(0x", ln)
            if hm:
                end = next(j for j in range(k + 2, len(payload)) if not payload[j].startswith("|"))
                self.layouts[hm.group(1)] = [(r[1], r[2]) for r in _rows(payload[k + 2:end]) if r[1] != "(empty payload)"]
        flags = lines[lines.index("### FaultFlags"):]
        self.faults = {r[1]: int(r[0], 16) for r in _rows(flags[2:flags.index("", 3)])}
        self.nack_reasons = {r[1]: int(r[0]) for r in self._table(lines, "### NackReason")}
        #: CONFIG key name -> (value, min, max)
        self.config_keys = {r[1]: (int(r[0]), int(r[3]), int(r[4])) for r in self._table(lines, "## CONFIG keys")}
        #: the refusals table: what arrives -> what the board does
        self.refusals = {r[0]: r[1] for r in self._table(lines, "## Refusals")}
        block = text[text.index("```text\n") + len("```text\n"):]
        self.schema_text = block[:block.index("\n```")]

    @staticmethod
    def _table(lines: list[str], heading: str) -> list[list[str]]:
        """The rows of the first table after ``heading``."""
        k = next(i for i in range(lines.index(heading), len(lines)) if lines[i].startswith("|"))
        return _rows(lines[k:lines.index("", k)])

    def refusal(self, arrives: str) -> str:
        """The NackReason name the refusals table gives for the row starting with ``arrives``."""
        does = next(v for k, v in self.refusals.items() if k.startswith(arrives))
        return re.match(r"NACK (\w+)", does).group(1)

    # -- payloads ---------------------------------------------------------------------------------
    _INT = {"u8": "<B", "u16": "<H", "u32": "<I", "u64": "<Q", "i8": "<b", "i16": "<h", "i32": "<i", "i64": "<q",
            "bool": "<B", "mask16": "<H"}

    def encode(self, name: str, **values) -> bytes:
        out = bytearray()
        for field, typ in self.layouts[name]:
            v = values[field]
            if typ in self._INT:
                out += struct.pack(self._INT[typ], v)
            elif typ.startswith("enum8"):
                out += struct.pack("<B", v)
            elif typ.startswith("i16[popcount("):
                out += struct.pack(f"<{len(v)}h", *v)
            elif typ.startswith("u8 len + utf8"):
                b = v.encode()
                out += bytes([len(b)]) + b
            else:
                raise AssertionError(f"this host does not send {typ}")
        return bytes(out)

    def decode(self, name: str, payload: bytes) -> dict:
        pos, out = 0, {}
        for field, typ in self.layouts[name]:
            if typ in self._INT or typ.startswith(("enum8", "flags16")):
                fmt = self._INT.get(typ, "<B" if typ.startswith("enum8") else "<H")
                (out[field],) = struct.unpack_from(fmt, payload, pos)
                pos += struct.calcsize(fmt)
            elif typ == "u8 n + i16[n]":
                n = payload[pos]
                out[field] = struct.unpack_from(f"<{n}h", payload, pos + 1)
                pos += 1 + 2 * n
            elif m := re.fullmatch(r"i16\[(\d+)\]", typ):
                n = int(m.group(1))
                out[field] = struct.unpack_from(f"<{n}h", payload, pos)
                pos += 2 * n
            elif m := re.fullmatch(r"f32\[(\d+)\]", typ):
                n = int(m.group(1))
                out[field] = struct.unpack_from(f"<{n}f", payload, pos)
                pos += 4 * n
            elif typ.startswith("u8 len + utf8"):
                n = payload[pos]
                out[field] = payload[pos + 1:pos + 1 + n].decode()
                pos += 1 + n
            elif typ.startswith("bytes[rest"):
                out[field] = payload[pos:]
                pos = len(payload)
            else:
                raise AssertionError(f"unknown type {typ}")
        assert pos == len(payload), (name, pos, len(payload))
        return out

    # -- frames -----------------------------------------------------------------------------------
    def frame(self, name: str, seq: int, payload: bytes) -> bytes:
        body = struct.pack("<BBHB", self.version, self.types[name], seq, len(payload)) + payload
        return cobs.encode(body + struct.pack("<H", self.crc(body))) + b"\x00"

    def unframe(self, block: bytes) -> tuple[str, int, dict] | None:
        try:
            body = cobs.decode(block)
        except cobs.DecodeError:
            return None
        if len(body) < 7 or struct.unpack_from("<H", body, len(body) - 2)[0] != self.crc(body[:-2]):
            return None
        _, t, seq, n = struct.unpack_from("<BBHB", body)
        name = next(k for k, v in self.types.items() if v == t)
        return name, seq, self.decode(name, body[5:5 + n])


class Host:
    def __init__(self, ref: Reference, port: str) -> None:
        self.ref, self.ser, self.seq, self.buf, self.got = ref, serial.Serial(port, 115200, timeout=0), 0, b"", []

    def send(self, name: str, **values) -> int:
        s = self.seq
        self.ser.write(self.ref.frame(name, s, self.ref.encode(name, **values)))
        self.seq += 1
        return s

    def wait(self, pred, timeout: float = 30.0):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for item in self.got:
                if pred(item):
                    return item
            select.select([self.ser.fileno()], [], [], 0.2)
            self.buf += self.ser.read(65536)
            *blocks, self.buf = self.buf.split(b"\x00")
            self.got += [f for f in map(self.ref.unframe, (b for b in blocks if b)) if f is not None]
        raise AssertionError(f"timed out; last: {[g[0] for g in self.got[-5:]]}")


@pytest.mark.parametrize("firmware", ["python", "c"])
def test_host_from_the_reference_tables(firmware: str, tmp_path: Path) -> None:
    ref = Reference(DOC.read_text(encoding="utf-8"))
    assert {"HELLO", "CAPS", "SERVO_FRAME", "TELEMETRY", "ADVANCE", "ACK", "TIME_SYNC_REQUEST"} <= set(ref.types)
    err = open(tmp_path / "board.stderr", "w")
    proc = subprocess.Popen([sys.executable, "-m", "firmware_sim", "--link", "pty", "--lockstep", "--firmware", firmware],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=err, text=True, env=dict(os.environ))
    try:
        line = proc.stdout.readline().strip()
        assert line.startswith("board: listening on "), line
        host = Host(ref, line.removeprefix("board: listening on "))
        # HELLO is optional: a TIME_SYNC first is answered
        host.send("TIME_SYNC_REQUEST", t1_host_us=123)
        _, _, reply = host.wait(lambda g: g[0] == "TIME_SYNC_REPLY")
        assert reply["t1_host_us"] == 123 and reply["t3_board_us"] >= reply["t2_board_us"]
        host.send("HELLO", protocol_version=ref.version, schema_hash=ref.schema, host_time_us=0)
        _, _, caps = host.wait(lambda g: g[0] == "CAPS")
        assert caps["schema_hash"] == ref.schema and caps["lockstep"] == 1
        n = caps["servo_count"]
        # frames for every servo at its present position + a small offset on servo id 1, 10 ms apart
        host.send("ADVANCE", until_us=20_000)
        _, _, tel = host.wait(lambda g: g[0] == "TELEMETRY")
        q0 = tel["positions"]
        assert len(q0) == n
        last = 0
        for k in range(1, 51):
            targets = [q0[0] + min(k, 20) * 100] + list(q0[1:])  # servo id 1: +0.2 rad in 0.2 s (1/10000 rad)
            last = host.send("SERVO_FRAME", apply_at_us=20_000 + 10_000 * k, mask=(1 << n) - 1, targets=targets)
        host.send("ADVANCE", until_us=600_000)  # past the last frame (due at 520 ms)
        _, _, tel = host.wait(lambda g: g[0] == "TELEMETRY" and g[2]["board_time_us"] >= 600_000)
        assert tel["last_applied_seq"] == last
        assert abs(tel["positions"][0] - (q0[0] + 2000)) < 300, (tel["positions"][0], q0[0])
        assert tel["faults"] & ref.faults["WATCHDOG_HOLD"] == 0
        # CONFIG keys and refusals, from their tables: a value in range is acknowledged, one below the range and
        # an unknown key are refused with the code the refusals table names
        value, lo, hi = ref.config_keys["TELEMETRY_RATE_HZ"]
        s = host.send("CONFIG", key=value, value=caps["telemetry_rate_hz"])
        host.wait(lambda g: g[0] == "ACK" and g[2]["ack_seq"] == s)
        value, lo, hi = ref.config_keys["WATCHDOG_MS"]
        s = host.send("CONFIG", key=value, value=lo - 1)
        _, _, nack = host.wait(lambda g: g[0] == "NACK" and g[2]["ack_seq"] == s)
        assert nack["reason"] == ref.nack_reasons[ref.refusal("CONFIG with a value out of")]
        s = host.send("CONFIG", key=max(v for v, _, _ in ref.config_keys.values()) + 1, value=1)
        _, _, nack = host.wait(lambda g: g[0] == "NACK" and g[2]["ack_seq"] == s)
        assert nack["reason"] == ref.nack_reasons[ref.refusal("CONFIG with an unknown key")]
        assert nack["msg_type"] == ref.types["CONFIG"]
        assert caps["servo_table_hash"] == servo_table_hash(ROOT / "robots" / caps["robot"] / "servos.toml")
        assert "HEARTBEAT" not in {g[0] for g in host.got}  # the board never sends one
        s = host.send("ESTOP")
        host.wait(lambda g: g[0] == "ACK" and g[2]["ack_seq"] == s)
        s = host.send("ESTOP_CLEAR")
        host.wait(lambda g: g[0] == "ACK" and g[2]["ack_seq"] == s)
        host.ser.close()
    finally:
        proc.terminate()
        proc.wait(10)
        err.close()


def servo_table_hash(servos_toml: Path) -> int:
    """The reference's recipe ("Hashes"), written from its text: tomllib, math.radians, %.9g, SHA-256."""
    table = tomllib.loads(servos_toml.read_text(encoding="utf-8"))
    rad = math.radians
    lines = [f"servos {len(table['servo'])}"]
    for sv in sorted(table["servo"], key=lambda r: r["id"]):
        joint = sv["joint"]
        lines.append(" ".join([str(sv["id"]), sv["name"], joint, sv.get("actuator", joint)]
                              + [f"{rad(sv.get(k, 0.0)):.9g}" for k in ("neutral_deg", "min_deg", "max_deg")]
                              + [str(sv.get("direction", 1)), f"{rad(sv.get('max_speed_dps', 300.0)):.9g}"]))
    model = table.get("model", {})
    lines.append(f"model {rad(model.get('resolution_deg', 0.088)):.9g} {rad(model.get('deadband_deg', 0.2)):.9g}")
    text = "\n".join(lines) + "\n"
    return int.from_bytes(hashlib.sha256(text.encode("utf-8")).digest()[:4], "big")


def test_hashes_from_the_recipe() -> None:
    """The reference's "Hashes" recipes, followed by hand, give the stated schema hash and each built-in robot's
    servo_table_hash (what CAPS reports)."""
    ref = Reference(DOC.read_text(encoding="utf-8"))
    digest = hashlib.sha256((ref.schema_text + "\n").encode("utf-8")).digest()
    assert int.from_bytes(digest[:4], "big") == ref.schema
    from protocol.codec import SCHEMA_HASH
    from robots.registry import load_robot

    assert ref.schema == SCHEMA_HASH
    tables = sorted((ROOT / "robots").glob("*/servos.toml"))
    assert len(tables) >= 2
    for path in tables:
        assert servo_table_hash(path) == load_robot(path.parent.name).servos.hash, path


def test_reference_is_current() -> None:
    """docs/wire-protocol.md is what the declaration generates (python -m firmware_sim.wire_reference), and its constants
    copied from modules that need MuJoCo still hold."""
    from firmware_sim.peripherals import MAX_IMAGE_SIDE
    from firmware_sim.wire_reference import DOC as GENERATED
    from firmware_sim.wire_reference import MAX_IMAGE_SIDE as DOC_MAX_IMAGE_SIDE
    from firmware_sim.wire_reference import render

    assert GENERATED == DOC
    assert DOC_MAX_IMAGE_SIDE == MAX_IMAGE_SIDE
    assert DOC.read_text(encoding="utf-8") == render(), "stale: python -m firmware_sim.wire_reference"
