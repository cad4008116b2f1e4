"""Link specs: every documented form parses, prints back canonically, and bad specs fail clearly."""

from __future__ import annotations

import pytest

from protocol.linkspec import LinkSpec, LinkSpecError, parse_link_spec


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("pty", LinkSpec("serial", port="pty")),
        ("/dev/ttyUSB0", LinkSpec("serial", port="/dev/ttyUSB0")),
        ("COM3", LinkSpec("serial", port="COM3")),
        ("socket://localhost:7777", LinkSpec("serial", port="socket://localhost:7777")),
        ("rfc2217://host:2217?logging=debug", LinkSpec("serial", port="rfc2217://host:2217?logging=debug")),
        ("can:socketcan:vcan0", LinkSpec("can", interface="socketcan", channel="vcan0")),
        ("can:socketcan:can0?fd=1", LinkSpec("can", interface="socketcan", channel="can0", fd=True)),
        ("can:slcan:pty", LinkSpec("can", interface="slcan", channel="pty")),
        ("can:slcan:/dev/ttyACM0?bitrate=1000000",
         LinkSpec("can", interface="slcan", channel="/dev/ttyACM0", bitrate=1_000_000)),
        ("can:virtual:bus0?node=2", LinkSpec("can", interface="virtual", channel="bus0", node=2)),
        ("can:socketcan:can0?fd=true&data_bitrate=5000000&bitrate=500000",
         LinkSpec("can", interface="socketcan", channel="can0", fd=True, bitrate=500_000, data_bitrate=5_000_000)),
        ("can:virtual:bus0?receive_own_messages=1",
         LinkSpec("can", interface="virtual", channel="bus0", options={"receive_own_messages": "1"})),
        ("can:", LinkSpec("can")),
        ("can::", LinkSpec("can")),
        ("can:socketcan", LinkSpec("can", interface="socketcan")),
        ("can::vcan0", LinkSpec("can", channel="vcan0")),
        ("can:?node=3", LinkSpec("can", node=3)),
    ],
)
def test_valid_specs_parse_and_round_trip(text: str, expected: LinkSpec) -> None:
    spec = parse_link_spec(text)
    assert spec == expected
    assert parse_link_spec(str(spec)) == spec
    assert parse_link_spec(spec) is spec


def test_canonical_text() -> None:
    assert str(parse_link_spec("can:socketcan:can0?fd=yes&node=07")) == "can:socketcan:can0?node=7&fd=1"
    assert str(parse_link_spec("can::")) == "can:"
    assert str(parse_link_spec("can:socketcan")) == "can:socketcan:"
    assert str(parse_link_spec("/dev/ttyACM0")) == "/dev/ttyACM0"


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("", "empty"),
        (" pty", "spaces"),
        ("pty?node=2", "no options"),
        ("can:virtual:bus0?node=0", "node must be in 1..127"),
        ("can:virtual:bus0?node=128", "node must be in 1..127"),
        ("can:virtual:bus0?node=two", "whole number"),
        ("can:virtual:bus0?node=1&node=2", "given twice"),
        ("can:virtual:bus0?colour=red", "unknown option 'colour'"),
        ("can:virtual:bus0?fd=maybe", "fd must be 0 or 1"),
        ("can:virtual:bus0?bitrate=0", "bitrate must be in"),
        ("can:virtual:bus0?data_bitrate=2000000", "add fd=1"),
        ("can:virtual:bus0?", "followed by options"),
        ("can:virtual:bus0?node", "name=value"),
        ("can:virtual:bus0?=3", "name=value"),
        ("can:bad iface:x", "not a python-can interface name"),
        ("CAN:virtual:bus0", "lower case"),
        ("socketcan:vcan0", "did you mean 'can:socketcan:vcan0'"),
        ("vcan0", "can:socketcan:vcan0"),
        ("can", "did you mean 'can:'"),
    ],
)
def test_bad_specs_fail_with_a_clear_message(text: str, needle: str) -> None:
    with pytest.raises(LinkSpecError) as info:
        parse_link_spec(text)
    msg = str(info.value)
    assert needle in msg
    assert "valid link specs" in msg and "can:socketcan:vcan0" in msg
    assert isinstance(info.value, ValueError)


def test_not_text_is_refused() -> None:
    with pytest.raises(LinkSpecError, match="a link spec is text"):
        parse_link_spec(3)  # type: ignore[arg-type]


def test_bus_kwargs_leave_unset_fields_to_python_can_configuration() -> None:
    assert parse_link_spec("can:").bus_kwargs() == {}
    assert parse_link_spec("can::vcan0").bus_kwargs() == {"channel": "vcan0"}
    kw = parse_link_spec("can:slcan:/dev/ttyACM0?bitrate=1000000&tty_baudrate=115200&receive_own_messages=true"
                         "&serial_number=AB12").bus_kwargs()
    assert kw == {"interface": "slcan", "channel": "/dev/ttyACM0", "bitrate": 1_000_000, "tty_baudrate": 115200,
                  "receive_own_messages": True, "serial_number": "AB12"}
    assert parse_link_spec("can:socketcan:can0?fd=1").bus_kwargs() == {"interface": "socketcan", "channel": "can0", "fd": True}
    with pytest.raises(LinkSpecError, match="serial"):
        parse_link_spec("pty").bus_kwargs()


def test_emulated_board_links_and_with_port() -> None:
    assert parse_link_spec("pty").implies_emulated_board
    assert parse_link_spec("can:slcan:pty").implies_emulated_board
    assert not parse_link_spec("can:socketcan:vcan0").implies_emulated_board
    assert not parse_link_spec("/dev/ttyUSB0").implies_emulated_board
    assert parse_link_spec("pty").with_port("/dev/pts/4") == LinkSpec("serial", port="/dev/pts/4")
    moved = parse_link_spec("can:slcan:pty?node=3&bitrate=1000000").with_port("/dev/pts/5")
    assert moved == LinkSpec("can", interface="slcan", channel="/dev/pts/5", node=3, bitrate=1_000_000)


def test_specs_are_hashable_and_equal_by_value() -> None:
    a = parse_link_spec("can:virtual:bus0?node=2")
    b = parse_link_spec("can:virtual:bus0?node=2")
    assert a == b and hash(a) == hash(b) and len({a, b}) == 1
