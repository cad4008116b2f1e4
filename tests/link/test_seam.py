"""The link seam: transports built from link specs, the session's public request(), clear errors."""

from __future__ import annotations

import asyncio
import subprocess
import sys

import pytest

from host.cli import main as cli_main
from host.link import BoardClient, LinkError, NackError
from host.link.transports import open_transport
from host.link.transports.serial import SerialLinkTransport
from protocol.linkspec import LinkSpecError, parse_link_spec
from protocol.messages import Ack, Config, ConfigKey, MsgType, NackReason, ScreenCommand, ScreenTarget

pytestmark = pytest.mark.timeout(60)


def test_request_returns_the_ack_or_raises_the_nack(board_factory) -> None:
    board = board_factory("--lockstep")
    assert board.spec == parse_link_spec(board.port)

    async def main() -> None:
        async with await BoardClient.connect(board.spec, reconnect=False) as c:
            assert isinstance(c.transport, SerialLinkTransport) and c.transport.name == board.port
            ack = await c.request(ScreenCommand(ScreenTarget.FACE, "happy", 0, 0))
            assert isinstance(ack, Ack) and ack.msg_type == MsgType.SCREEN
            with pytest.raises(NackError) as info:
                await c.request(Config(ConfigKey.WATCHDOG_MS, 0))
            assert info.value.reason == NackReason.BAD_VALUE

    asyncio.run(main())


def test_specs_that_cannot_be_opened_fail_clearly() -> None:
    async def main() -> None:
        with pytest.raises(LinkSpecError, match=r"node must be in 1\.\.127"):
            await BoardClient.connect("can:virtual:bus0?node=0")
        with pytest.raises(LinkError, match="emulated board creates"):
            open_transport("pty")

    asyncio.run(main())


def test_wrong_specs_exit_2_on_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    for argv in (["run", "--task", "1", "--link", "vcan0"], ["pose", "--pose", "sit", "--link", "can:x:y?bogus=1"],
                 ["tour", "--link", "socketcan:vcan0"], ["log", "decode", "f.jsonl", "--link", ""]):
        with pytest.raises(SystemExit) as info:
            cli_main(argv)
        assert info.value.code == 2, argv
        assert "valid link specs" in capsys.readouterr().err
    proc = subprocess.run([sys.executable, "-m", "firmware_sim", "--link", "can:virtual:bus0?fd=2"],
                          capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2 and "fd must be 0 or 1" in proc.stderr


def test_a_can_spec_without_channel_fails_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    # found by a fresh-user review: python-can's slcan class raised a TypeError through the CLI
    assert cli_main(["pose", "--pose", "sit", "--link", "can:slcan"]) == 2
    err = capsys.readouterr().err
    assert "no channel given or configured" in err and "Traceback" not in err
