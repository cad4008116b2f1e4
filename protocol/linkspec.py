"""Link specs: one text syntax naming the link between host and board (pure, shared by both ends).

Accepted forms (``parse_link_spec``)::

    pty                                   the emulated board creates a pty pair (serial)
    /dev/ttyUSB0, COM3, socket://h:p ...  a serial device path or any pyserial URL (serial)
    can:INTERFACE:CHANNEL[?opt=v&...]     a CAN bus through python-can, e.g.
        can:socketcan:vcan0               SocketCAN, classic CAN
        can:socketcan:can0?fd=1           SocketCAN, CAN FD
        can:slcan:pty                     the emulated board acts as an SLCAN adapter on a new pty
        can:slcan:/dev/ttyACM0?bitrate=1000000
        can:virtual:bus0                  python-can's in-process virtual bus
    can:  can::  can:INTERFACE  can::CHANNEL
                                          leave the interface and/or channel to python-can's own
                                          configuration (env vars CAN_INTERFACE / CAN_CHANNEL /
                                          CAN_BITRATE, ``~/.canrc`` / ``can.ini``); an empty field
                                          means "python-can's configured default".

CAN options: ``node=N`` (the board's node id, 1..127, default 1), ``fd=0|1``,
``bitrate=BIT/S``, ``data_bitrate=BIT/S`` (CAN FD data phase) and the python-can bus
arguments in :data:`CAN_PASSTHROUGH_OPTIONS` (kept as text in ``LinkSpec.options``;
:meth:`LinkSpec.bus_kwargs` converts them). Anything else, a repeated option or a
bad value raises :class:`LinkSpecError`. A serial spec is taken verbatim (pyserial
URLs carry their own ``?options``), except that it must not be empty, a URL's scheme must be one
pyserial knows (:data:`PYSERIAL_SCHEMES`), and ``socket://`` / ``rfc2217://`` need ``HOST:PORT``
(pyserial itself fails on ``rfc2217://x`` with a ``TypeError``).

``str(spec)`` gives the canonical text; ``parse_link_spec(str(spec)) == spec``.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal
from urllib.parse import quote, unquote

from protocol.linkkinds import link_kind

__all__ = [
    "CAN_PASSTHROUGH_OPTIONS",
    "DEFAULT_NODE",
    "LINK_SPEC_FORMS",
    "MAX_NODE",
    "LinkSpec",
    "LinkSpecError",
    "parse_link_spec",
]

DEFAULT_NODE = 1
MAX_NODE = 127  # 7 node bits in the 11-bit identifier (CANopen COB-ID layout, protocol.can.ids)

#: python-can bus arguments that may be given as spec options (value text -> int/bool/str in bus_kwargs)
CAN_PASSTHROUGH_OPTIONS: frozenset[str] = frozenset({
    "receive_own_messages", "local_loopback", "ignore_rx_error_frames", "tty_baudrate",
    "sleep_after_open", "rtscts", "sjw_abr", "tseg1_abr", "tseg2_abr",
    "sjw_dbr", "tseg1_dbr", "tseg2_dbr", "preserve_timestamps", "rx_queue_size",
    "serial_number", "app_name", "poll_interval",
})
_OWN_OPTIONS = ("node", "fd", "bitrate", "data_bitrate")

LINK_SPEC_FORMS = (
    "valid link specs: 'pty' | a serial device path or pyserial URL (/dev/ttyUSB0, socket://host:port) | "
    "'can:INTERFACE:CHANNEL[?node=N&fd=0|1&bitrate=B&data_bitrate=B]' "
    "(e.g. can:socketcan:vcan0, can:socketcan:can0?fd=1, can:slcan:pty, can:virtual:bus0; "
    "'can:' or 'can::' uses python-can's configured interface/channel)"
)

# python-can interface names, only to catch "socketcan:vcan0" typed without the "can:" prefix
_CAN_INTERFACES = frozenset({
    "socketcan", "slcan", "virtual", "pcan", "kvaser", "vector", "ixxat", "nican", "gs_usb",
    "serial", "udp_multicast", "cantact", "neovi", "robotell", "seeedstudio", "socketcand",
})
#: URL schemes pyserial's ``serial_for_url`` handles (pyserial 3.5 ``serial.protocol_handler_packages``)
PYSERIAL_SCHEMES = ("rfc2217", "socket", "loop", "hwgrep", "spy", "alt", "cp2110")
_TRUE = ("1", "true", "yes", "on")
_FALSE = ("0", "false", "no", "off")


class LinkSpecError(ValueError):
    """A link spec that cannot be parsed; the message names the problem and the valid forms."""


@dataclass(frozen=True)
class LinkSpec:
    """A parsed link spec (see the module docstring for the syntax).

    ``kind`` is ``"serial"`` (``port`` set: ``"pty"``, a device path or a pyserial URL) or
    ``"can"`` (``interface``/``channel``: python-can names, ``""`` = python-can's configured
    default; ``node``: the board's node id 1..127; ``fd``: CAN FD; ``bitrate`` /
    ``data_bitrate`` in bit/s or None; ``options``: further python-can bus arguments as text).
    """

    kind: Literal["serial", "can"]
    port: str = ""
    interface: str = ""
    channel: str = ""
    node: int = DEFAULT_NODE
    fd: bool = False
    bitrate: int | None = None
    data_bitrate: int | None = None
    options: Mapping[str, str] = field(default_factory=dict)

    @classmethod
    def serial(cls, port: str) -> LinkSpec:
        """A serial spec for ``port`` (``"pty"``, a device path or a pyserial URL)."""
        return parse_link_spec(port)

    @property
    def is_pty(self) -> bool:
        """True for ``pty``: the emulated board creates the pty and announces it."""
        return self.kind == "serial" and self.port == "pty"

    @property
    def implies_emulated_board(self) -> bool:
        """True where only an emulated board can serve the link, which it creates: ``pty`` and
        ``can:slcan:pty`` (:attr:`protocol.linkkinds.LinkKind.board_creates` of the spec's kind)."""
        return link_kind(self).board_creates

    def with_port(self, port: str) -> LinkSpec:
        """The same spec on another port/channel (e.g. the pty a board announced)."""
        if self.kind == "serial":
            return LinkSpec("serial", port=port)
        return LinkSpec("can", interface=self.interface, channel=port, node=self.node, fd=self.fd,
                        bitrate=self.bitrate, data_bitrate=self.data_bitrate, options=dict(self.options))

    def bus_kwargs(self) -> dict[str, object]:
        """Keyword arguments for ``can.Bus(**kw)``: interface/channel only where given (else python-can's
        configuration decides), ``fd``, bitrates, and the pass-through options (``"1"``/``"true"`` -> True,
        digits -> int, else text). CAN specs only."""
        if self.kind != "can":
            raise LinkSpecError(f"{self} is a serial link, not CAN")
        kw: dict[str, object] = {}
        if self.interface:
            kw["interface"] = self.interface
        if self.channel:
            kw["channel"] = self.channel
        if self.fd:
            kw["fd"] = True
        if self.bitrate is not None:
            kw["bitrate"] = self.bitrate
        if self.data_bitrate is not None:
            kw["data_bitrate"] = self.data_bitrate
        for k, v in self.options.items():
            low = v.lower()
            kw[k] = True if low in ("true", "yes", "on") else False if low in ("false", "no", "off") else (
                int(v) if re.fullmatch(r"-?\d+", v) else v)
        return kw

    def __str__(self) -> str:
        if self.kind == "serial":
            return self.port
        text = f"can:{self.interface}:{self.channel}" if (self.interface or self.channel) else "can:"
        opts: list[tuple[str, str]] = []
        if self.node != DEFAULT_NODE:
            opts.append(("node", str(self.node)))
        if self.fd:
            opts.append(("fd", "1"))
        if self.bitrate is not None:
            opts.append(("bitrate", str(self.bitrate)))
        if self.data_bitrate is not None:
            opts.append(("data_bitrate", str(self.data_bitrate)))
        opts += sorted(self.options.items())
        if opts:
            text += "?" + "&".join(f"{k}={quote(v, safe='')}" for k, v in opts)
        return text

    def __hash__(self) -> int:
        return hash(str(self))


def _error(text: str, problem: str) -> LinkSpecError:
    return LinkSpecError(f"bad link spec {text!r}: {problem}; {LINK_SPEC_FORMS}")


def _int_option(text: str, key: str, value: str, lo: int, hi: int | None) -> int:
    try:
        v = int(value)
    except ValueError:
        raise _error(text, f"{key} must be a whole number, got {value!r}") from None
    if v < lo or (hi is not None and v > hi):
        raise _error(text, f"{key} must be in {lo}..{hi if hi is not None else 'inf'}, got {v}")
    return v


def _parse_can(text: str) -> LinkSpec:
    body, sep, query = text[len("can:"):].partition("?")
    interface, _, channel = body.partition(":")
    if interface and not re.fullmatch(r"[A-Za-z0-9_.-]+", interface):
        raise _error(text, f"interface {interface!r} is not a python-can interface name")
    if sep and not query:
        raise _error(text, "'?' must be followed by options (opt=value&...)")
    seen: dict[str, str] = {}
    if query:
        for part in query.split("&"):
            key, eq, value = part.partition("=")
            if not eq or not key or not value:
                raise _error(text, f"option {part!r} must look like name=value")
            if key in seen:
                raise _error(text, f"option {key!r} given twice")
            if key not in _OWN_OPTIONS and key not in CAN_PASSTHROUGH_OPTIONS:
                raise _error(text, f"unknown option {key!r} (known: {', '.join(_OWN_OPTIONS)}, "
                                   f"and python-can's {', '.join(sorted(CAN_PASSTHROUGH_OPTIONS))})")
            seen[key] = unquote(value)
    node = _int_option(text, "node", seen.pop("node"), 1, MAX_NODE) if "node" in seen else DEFAULT_NODE
    fd = False
    if "fd" in seen:
        v = seen.pop("fd").lower()
        if v not in _TRUE + _FALSE:
            raise _error(text, f"fd must be 0 or 1, got {v!r}")
        fd = v in _TRUE
    bitrate = _int_option(text, "bitrate", seen.pop("bitrate"), 1, None) if "bitrate" in seen else None
    data_bitrate = (_int_option(text, "data_bitrate", seen.pop("data_bitrate"), 1, None)
                    if "data_bitrate" in seen else None)
    if data_bitrate is not None and not fd:
        raise _error(text, "data_bitrate is a CAN FD setting: add fd=1")
    return LinkSpec("can", interface=interface, channel=channel, node=node, fd=fd,
                    bitrate=bitrate, data_bitrate=data_bitrate, options=seen)


def parse_link_spec(text: str | LinkSpec) -> LinkSpec:
    """Parse a link spec (a :class:`LinkSpec` is returned unchanged); :class:`LinkSpecError` if invalid."""
    if isinstance(text, LinkSpec):
        return text
    if not isinstance(text, str):
        raise LinkSpecError(f"a link spec is text, got {type(text).__name__}; {LINK_SPEC_FORMS}")
    if not text.strip():
        raise _error(text, "empty")
    if text != text.strip():
        raise _error(text, "leading or trailing spaces")
    if text.lower().startswith("can:"):
        if not text.startswith("can:"):
            raise _error(text, "write the prefix in lower case: 'can:'")
        return _parse_can(text)
    if text == "pty":
        return LinkSpec("serial", port="pty")
    if text.startswith("pty?") or text.startswith("pty:"):
        raise _error(text, "'pty' takes no options (node ids are for CAN links)")
    head, colon, _ = text.partition(":")
    if colon and head.lower() in _CAN_INTERFACES and "://" not in text:
        raise _error(text, f"did you mean 'can:{text}'?")
    if text == "can":
        raise _error(text, "did you mean 'can:' (python-can's configured default bus)?")
    if re.fullmatch(r"v?can\d+", text):
        raise _error(text, f"{text!r} looks like a CAN network interface: did you mean 'can:socketcan:{text}'?")
    if "://" in text:
        _check_serial_url(text)
    return LinkSpec("serial", port=text)


def _check_serial_url(text: str) -> None:
    scheme, _, rest = text.partition("://")
    if scheme.lower() not in PYSERIAL_SCHEMES:
        raise _error(text, f"pyserial has no URL scheme {scheme!r} (it has {', '.join(PYSERIAL_SCHEMES)})")
    if scheme.lower() in ("socket", "rfc2217"):
        address = rest.partition("?")[0]
        host, colon, port = address.rpartition(":")
        if not colon or not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise _error(text, f"the {scheme}:// URL needs HOST:PORT with a port 1-65535, "
                               f"e.g. {scheme}://192.168.1.20:{2217 if scheme.lower() == 'rfc2217' else 7777}")
