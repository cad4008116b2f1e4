"""The Protocol 2.0 codec (firmware_sim.plant.dynamixel) against the e-Manual's example packets and the
SDK's own packet builder: CRC-16 as ROBOTIS computes it, byte stuffing both ways, and a parser that
skips garbage, counts bad CRCs and holds a bounded buffer."""

from __future__ import annotations

import random

from dynamixel_sdk.protocol2_packet_handler import Protocol2PacketHandler

from firmware_sim.plant.dynamixel import (
    MAX_BUFFER, DxlInst, DxlParser, crc16, instruction_packet, status_packet, stuff, unstuff,
)


def test_e_manual_example_packets() -> None:
    # e-Manual Protocol 2.0 (emanual.robotis.com/docs/en/dxl/protocol2/), the "Ping" example: the
    # instruction to ID 1 and its status packet (model number 0x0406 = 1030, firmware version 0x26)
    assert instruction_packet(1, DxlInst.PING) == bytes.fromhex("FFFFFD0001030001194E")
    assert status_packet(1, 0, bytes.fromhex("060426")) == bytes.fromhex("FFFFFD000107005500060426655D")


def test_crc_is_the_sdks() -> None:
    sdk = Protocol2PacketHandler()
    rng = random.Random(3)
    for _ in range(200):
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 60)))
        assert crc16(data) == sdk.updateCRC(0, list(data), len(data))


def test_stuffing_matches_the_sdk_and_round_trips() -> None:
    sdk = Protocol2PacketHandler()
    rng = random.Random(5)
    for _ in range(200):
        params = bytes(rng.choice([0xFF, 0xFD, 0x00, rng.randrange(256)]) for _ in range(rng.randrange(0, 30)))
        params += b"\xff\xff\xfd" * rng.randrange(0, 3)
        pkt = [0xFF, 0xFF, 0xFD, 0x00, 7, (len(params) + 3) & 0xFF, (len(params) + 3) >> 8, 0x03, *params, 0, 0]
        stuffed = sdk.addStuffing(pkt)
        n = stuffed[5] | stuffed[6] << 8
        assert bytes(stuffed[7:7 + n - 2]) == stuff(bytes([0x03]) + params)
        assert unstuff(stuff(params)) == params
        wire = instruction_packet(7, 0x03, params)
        assert wire[:-2] == bytes(stuffed[:7 + n - 2])  # same bytes the SDK would send
        got = DxlParser().feed(wire)
        assert len(got) == 1 and got[0].params == params and got[0].id == 7


def test_parser_skips_garbage_counts_bad_crcs_and_stays_bounded() -> None:
    p = DxlParser()
    good = instruction_packet(3, DxlInst.READ, bytes.fromhex("84000400"))
    bad = bytearray(good)
    bad[-1] ^= 0x55
    stream = b"\x00\x12\xff" + bytes(bad) + b"\xfe" + good + status_packet(3, 0, b"\x01") + good[:5]
    got = p.feed(stream)
    assert [(i.id, i.instruction, i.params) for i in got] == [(3, DxlInst.READ, bytes.fromhex("84000400"))]
    assert p.bad_crc == 1 and p.garbage_bytes > 0
    assert [i.id for i in p.feed(good[5:])] == [3]  # the held partial packet completes
    for _ in range(50):  # a flood of noise never grows the buffer past one packet
        p.feed(bytes(random.Random(1).randrange(256) for _ in range(500)) + b"\xff\xff\xfd\x00\x01\xe8\x03")
        assert len(p._buf) <= MAX_BUFFER
