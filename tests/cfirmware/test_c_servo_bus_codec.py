"""The C firmware's servo-bus framing (firmware_sim/c/core/gs_bus_sts.c, gs_bus_dxl2.c) against the vendor SDKs'
packet code: Dynamixel Protocol 2.0 (``dynamixel_sdk``: header, LEN, byte stuffing, CRC-16) and Feetech STS
(``scservo_sdk``: checksum), instructions encoded byte for byte as the SDK sends them and status packets the
SDK's framing builds parsed back (unstuffed), among garbage and broken CRCs. Through the C harness
firmware_sim/c/tests/bus_codec_harness.c (ASan/UBSan)."""

from __future__ import annotations

import random
import subprocess
from collections.abc import Iterator

import pytest
from dynamixel_sdk.protocol2_packet_handler import Protocol2PacketHandler
from scservo_sdk.protocol_packet_handler import protocol_packet_handler

from firmware_sim.cfirmware.build import build
from robots.registry import load_robot


class _Capture:
    """A port object for the SDKs' txPacket: keeps what they would write."""

    def __init__(self) -> None:
        self.is_using = False
        self.sent = b""

    def clearPort(self) -> None:  # noqa: N802 (the SDKs' name)
        pass

    def writePort(self, packet: list[int]) -> int:  # noqa: N802
        self.sent = bytes(packet)
        return len(packet)


def dxl_packet(dev_id: int, inst: int, params: bytes) -> bytes:
    """This instruction as dynamixel_sdk frames it: its addStuffing, then its updateCRC. (Its txPacket itself
    sends the packet unstuffed: addStuffing returns the stuffed packet as a new list, which txPacket drops.)"""
    h = Protocol2PacketHandler()
    pkt = [0xFF, 0xFF, 0xFD, 0x00, dev_id, (len(params) + 3) & 0xFF, (len(params) + 3) >> 8, inst, *params, 0, 0]
    pkt = h.addStuffing(pkt)
    crc = h.updateCRC(0, pkt, len(pkt) - 2)
    pkt[-2:] = [crc & 0xFF, crc >> 8]
    return bytes(pkt)


def sts_packet(dev_id: int, inst: int, params: bytes) -> bytes:
    pkt = [0] * (6 + len(params))
    pkt[2], pkt[3], pkt[4] = dev_id, len(params) + 2, inst
    pkt[5:5 + len(params)] = list(params)
    port = _Capture()
    assert protocol_packet_handler().txPacket(port, pkt) == 0
    return port.sent


class Harness:
    def __init__(self) -> None:
        exe = build("bus-codec", load_robot("coco"))
        self.proc = subprocess.Popen([str(exe)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1)

    def ask(self, line: str) -> str:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        out = self.proc.stdout.readline()
        assert out, f"the harness died ({self.proc.poll()})"
        return out.strip()

    def encode(self, proto: int, dev_id: int, inst: int, params: bytes) -> bytes:
        return bytes.fromhex(self.ask(f"E {proto} {dev_id} {inst} {params.hex()}"))

    def parse(self, proto: int, data: bytes) -> tuple[list[tuple[int, int, bytes]], int]:
        text, _, bad = self.ask(f"P {proto} {data.hex()}").rpartition(" bad=")
        got = [] if text == "-" else [(int(a), int(b), bytes.fromhex(c)) for a, b, c in
                                       (p.split(" ") + [""] if p.count(" ") == 1 else p.split(" ")
                                        for p in text.split(";"))]
        return got, int(bad)

    def close(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.close()
        assert self.proc.wait(30) == 0


@pytest.fixture(scope="module")
def harness() -> Iterator[Harness]:
    h = Harness()
    yield h
    h.close()


def _params(rng: random.Random, n: int) -> bytes:
    """Random bytes with FF FF FD runs (the stuffing's case) planted in."""
    b = bytearray(rng.randrange(256) for _ in range(n))
    for _ in range(rng.randrange(4)):
        if n >= 3:
            k = rng.randrange(n - 2)
            b[k:k + 3] = b"\xff\xff\xfd"
    return bytes(b)


def test_dynamixel_instructions_are_the_sdks_bytes(harness: Harness) -> None:
    rng = random.Random(1)
    assert harness.encode(1, 1, 0x01, b"").hex() == "fffffd0001030001194e"  # the e-Manual's PING example
    for _ in range(300):
        params = _params(rng, rng.randrange(0, 60))
        dev_id, inst = rng.choice([1, 7, 0xF0, 0xFE]), rng.choice([0x01, 0x02, 0x03, 0x82, 0x83])
        assert harness.encode(1, dev_id, inst, params) == dxl_packet(dev_id, inst, params), params.hex()


def test_sts_instructions_are_the_sdks_bytes(harness: Harness) -> None:
    rng = random.Random(2)
    for _ in range(200):
        params = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 60)))
        dev_id, inst = rng.choice([1, 7, 0xF0, 0xFE]), rng.choice([0x01, 0x02, 0x03, 0x82, 0x83])
        assert harness.encode(0, dev_id, inst, params) == sts_packet(dev_id, inst, params)


def test_dynamixel_status_packets_parse_unstuffed_among_garbage(harness: Harness) -> None:
    rng = random.Random(3)
    for _ in range(200):
        want, stream = [], b""
        for _ in range(rng.randrange(1, 5)):
            if rng.random() < 0.3:  # garbage, half headers
                stream += rng.choice([b"\xff", b"\xff\xff", b"\xff\xff\xfd", b"\x00\x55"]) + _params(rng, rng.randrange(5))
            dev_id, err, data = rng.randrange(0, 0xFD), rng.choice([0, 0, 0x80, 0x01]), _params(rng, rng.randrange(0, 40))
            pkt = dxl_packet(dev_id, 0x55, bytes([err]) + data)
            if rng.random() < 0.2:  # a broken CRC: refused, the search goes on
                stream += pkt[:-1] + bytes([pkt[-1] ^ 0x5A])
                continue
            stream += pkt
            want.append((dev_id, err, data))
        got, _ = harness.parse(1, stream)
        # a broken packet's bytes may hide a header a later one starts with: only what was kept must match
        assert got[-len(want):] == want if want else True, (stream.hex(), got, want)
        assert [w for w in want if w not in got] == [], (stream.hex(), got, want)


def test_dynamixel_instruction_echo_and_bad_crc_are_not_answers(harness: Harness) -> None:
    status = dxl_packet(3, 0x55, b"\x00\x10\x20")
    echo = dxl_packet(3, 0x02, b"\x84\x00\x04\x00")
    broken = status[:-1] + bytes([status[-1] ^ 1])
    got, bad = harness.parse(1, echo + broken + status)
    assert got == [(3, 0, b"\x10\x20")] and bad >= 1


def test_sts_status_packets_parse(harness: Harness) -> None:
    pkt = sts_packet(5, 0x20, b"\x00\x08\x10\x00\x05\x04")  # error byte 0x20 (overload) in the instruction's place
    got, bad = harness.parse(0, b"\x00\xff" + pkt + pkt[:-1] + b"\x00" + pkt)
    assert got == [(5, 0x20, b"\x00\x08\x10\x00\x05\x04")] * 2 and bad >= 1
