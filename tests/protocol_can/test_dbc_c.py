"""The microcontroller's side: C generated from the DBC by cantools packs frames our decoder reads."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from protocol.can import CanDecoder, CanFrame, CanItem
from protocol.codec import quantize_message
from protocol.messages import MsgType, ServoFrame

DBC = Path(__file__).resolve().parents[2] / "robots" / "coco" / "coco.dbc"
CC = shutil.which("cc") or shutil.which("gcc")

TARGETS = [0.05 * i - 0.3 for i in range(12)]
APPLY_AT = 1_234_567

MAIN_C = r"""
#include <stdio.h>
#include <string.h>
#include <math.h>
#include "coco.h"

/* cantools' generated *_encode() truncates toward zero; the protocol rounds to nearest. */
static int16_t q(double rad) { return (int16_t)lround(rad / 0.0001); }

/* CRC-16/X-25 (poly 0x1021 reflected, init and xorout 0xFFFF), as protocol.can.codec.fixed_crc */
static uint16_t x25(uint16_t crc, const uint8_t *p, int n) {
    while (n--) {
        crc ^= *p++;
        for (int b = 0; b < 8; b++) crc = (crc & 1) ? (uint16_t)((crc >> 1) ^ 0x8408) : (uint16_t)(crc >> 1);
    }
    return crc;
}

int main(void) {
    static const double targets[12] = {%(targets)s};
    uint16_t crc = 0xFFFF;
    for (int pass = 0; pass < 2; pass++)  /* pass 0: CRC over the parts with crc16 = 0; pass 1: print */
    for (int part = 0; part < 6; part++) {
        struct coco_servo_frame_n1_t msg;
        uint8_t buf[8];
        coco_servo_frame_n1_init(&msg);
        msg.part = (uint8_t)part;
        msg.seq = 1234 %% 2048;
        msg.apply_at_us = %(apply_at)dU;
        msg.mask = 0x0FFF;
        msg.target_01 = q(targets[0]);
        msg.target_02 = q(targets[1]);
        msg.target_03 = q(targets[2]);
        msg.target_04 = q(targets[3]);
        msg.target_05 = q(targets[4]);
        msg.target_06 = q(targets[5]);
        msg.target_07 = q(targets[6]);
        msg.target_08 = q(targets[7]);
        msg.target_09 = q(targets[8]);
        msg.target_10 = q(targets[9]);
        msg.target_11 = q(targets[10]);
        msg.target_12 = q(targets[11]);
        msg.crc16 = pass ? (uint16_t)(crc ^ 0xFFFF) : 0;
        int n = coco_servo_frame_n1_pack(buf, &msg, sizeof buf);
        if (n != 8) return 1;
        if (!pass) { crc = x25(crc, buf, n); continue; }
        for (int i = 0; i < n; i++) printf("%%02x", buf[i]);
        printf("\n");
    }
    return 0;
}
"""


@pytest.mark.skipif(CC is None, reason="no C compiler (cc/gcc) on PATH; .ci/setup installs gcc")
def test_generated_c_packs_a_servo_frame_we_decode(tmp_path: Path) -> None:
    subprocess.run(
        [sys.executable, "-m", "cantools", "generate_c_source", str(DBC), "-o", str(tmp_path)],
        check=True, capture_output=True, text=True,
    )
    (tmp_path / "main.c").write_text(
        MAIN_C % {"targets": ", ".join(repr(t) for t in TARGETS), "apply_at": APPLY_AT}
    )
    build = subprocess.run(
        [str(CC), "-std=c99", "-Wall", "-Werror", "-O2", "main.c", "coco.c", "-o", "pack", "-lm"],
        cwd=tmp_path, capture_output=True, text=True,
    )
    assert build.returncode == 0, build.stderr
    out = subprocess.run([str(tmp_path / "pack")], capture_output=True, text=True, check=True).stdout.split()
    assert len(out) == 6
    dec = CanDecoder(1, "board")
    dec.last_seq = 1230
    items = [i for line in out for i in dec.feed(CanFrame(0x081, bytes.fromhex(line)))]
    assert len(items) == 1 and isinstance(items[0], CanItem)
    assert items[0].seq == 1234 and items[0].msg_type is MsgType.SERVO_FRAME
    assert items[0].msg == quantize_message(ServoFrame(APPLY_AT, 0x0FFF, tuple(TARGETS)))
