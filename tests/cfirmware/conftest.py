"""Fixtures for the C firmware tests: builds (cached, firmware_sim.cfirmware.build) and harnesses.

A missing toolchain is a failure with the install command (ToolchainMissing's message), not a skip.
"""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from firmware_sim.cfirmware.build import build
from protocol.codec import WIRE_SCHEMAS, WireSchema, schema_for
from robots.loader import load_robot_dir
from robots.registry import load_robot
from support.gen_robot import write_chain_robot


class CodecHarness:
    """The C codec harness as a line-oriented subprocess (firmware_sim/c/tests/codec_harness.c)."""

    def __init__(self, exe: Path) -> None:
        self.proc = subprocess.Popen([str(exe)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1)

    def ask(self, line: str) -> str:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        answer = self.proc.stdout.readline()
        if not answer:
            raise AssertionError(f"the C codec harness died (status {self.proc.poll()}) on {line[:120]!r}")
        return answer.rstrip("\n")

    def close(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.close()
        rc = self.proc.wait(30)
        assert rc == 0, f"codec harness exit status {rc} (a sanitizer report is on stderr)"


@pytest.fixture(scope="session")
def coco():
    return load_robot("coco")


@pytest.fixture(scope="session")
def codec_harness(coco) -> Iterator[CodecHarness]:
    h = CodecHarness(build("codec", coco))
    yield h
    h.close()


@pytest.fixture(scope="session", params=WIRE_SCHEMAS, ids=lambda s: f"schema{s.max_servos}")
def schema_codec(request, coco, tmp_path_factory) -> Iterator[tuple[WireSchema, CodecHarness]]:
    """Every wire schema with the C codec harness built for it: CoCo's (12 servos) for the 16 schema, a
    generated robot of the schema's full servo count above (the build picks the codec by servo count)."""
    schema: WireSchema = request.param
    robot = coco if schema.max_servos <= 16 else load_robot_dir(
        write_chain_robot(tmp_path_factory.mktemp("robots"), schema.max_servos))
    assert schema_for(robot.servo_count) is schema
    h = CodecHarness(build("codec", robot))
    yield schema, h
    h.close()
