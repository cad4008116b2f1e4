"""The kinds of link (pure data, shared by both ends): what each needs, logs and allows.

A link spec (:mod:`protocol.linkspec`) names a link; :func:`link_kind` says which kind it is. A kind
holds the facts both ends and every command decide by, so no code outside the registries branches on
a spec's fields: its wire unit and frame-log format, whether only the emulated board can create the
link, whether a board in another process can be on it at all, whether the host may start the
emulated board for it, which board firmwares can serve it, and one line saying what it needs. Each end
maps kind names to its transport in its own registry (``host.link.kinds``, ``firmware_sim.transports.kinds``);
a new kind is one :class:`LinkKind` here plus one entry in each registry that serves it.

=============  ==========================  ==========  ===============  ========================
kind           specs                       frame log   emulated board   firmwares
=============  ==========================  ==========  ===============  ========================
``pty``        ``pty``                     ``.jsonl``  creates it       python, c, qemu, stm32f4
``serial``     a device path, pyserial URL ``.jsonl``  may be started   python, c, qemu, stm32f4
``slcan-pty``  ``can:slcan:pty``           ``.log``    creates it       python
``slcan``      ``can:slcan:DEVICE``        ``.log``    may be started   python
``socketcan``  ``can:socketcan:IF``        ``.log``    may be started   python, c
``virtual``    ``can:virtual:BUS``         ``.log``    never (in one    python (in-process)
                                                       process only)
``can``        any other CAN spec          ``.log``    may be started   python
=============  ==========================  ==========  ===============  ========================
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

__all__ = ["LINK_KINDS", "LinkKind", "SpecFields", "link_kind"]


class SpecFields(Protocol):
    """The fields of a link spec a kind decides by (:class:`protocol.linkspec.LinkSpec` has them).

    A protocol, not the class: :mod:`protocol.linkspec` asks this module for a spec's kind
    (``LinkSpec.implies_emulated_board``), so this one must not import it.
    """

    @property
    def kind(self) -> str: ...
    @property
    def port(self) -> str: ...
    @property
    def interface(self) -> str: ...
    @property
    def channel(self) -> str: ...


@dataclass(frozen=True)
class LinkKind:
    """One kind of link (see the module docstring).

    ``wire``: ``"serial"`` or ``"can"`` (the unit a frame log holds, :mod:`protocol.logfile`);
    ``log_suffix``: the frame-log suffix a run uses; ``board_creates``: only the emulated board can
    create the link (it announces where: ``board: listening on X``), so a host connects to it only
    after starting that board; ``cross_process``: a board process can be on the link at all (False:
    python-can's in-process virtual bus); ``firmwares``: the board firmwares that serve it;
    ``needs``: one line for messages; ``matches(spec)``: whether ``spec`` is of this kind;
    ``preflight``: how a command checks the link before starting anything (``"device"``: the port
    path must be a character device, not opened; ``"open"``: open and close it again, harmless for a
    raw SocketCAN socket; ``""``: no check, opening it says); ``models_baud``: the emulated board models
    wire time at its ``--baud`` on this link (a serial line; the SLCAN board on a pty does not, so a
    ``--baud`` for it is refused rather than ignored).
    """

    name: str
    wire: str
    log_suffix: str
    matches: Callable[[SpecFields], bool]
    needs: str
    board_creates: bool = False
    cross_process: bool = True
    firmwares: tuple[str, ...] = ("python",)
    preflight: str = ""
    models_baud: bool = False

    @property
    def host_may_start_board(self) -> bool:
        """The host may start the emulated board for this link (``--emulate-board``; implied when it creates it)."""
        return self.cross_process


def _can(interface: str, channel: str | None = None) -> Callable[[SpecFields], bool]:
    return lambda s: s.kind == "can" and s.interface == interface and (channel is None or s.channel == channel)


#: every kind, most specific first (:func:`link_kind` takes the first that matches)
LINK_KINDS: tuple[LinkKind, ...] = (
    LinkKind("pty", "serial", ".jsonl", lambda s: s.kind == "serial" and s.port == "pty",
             "the emulated board, which creates the pty and announces it", board_creates=True,
             firmwares=("python", "c", "qemu", "stm32f4"), models_baud=True),
    LinkKind("serial", "serial", ".jsonl", lambda s: s.kind == "serial",
             "a serial device (a character device) or a pyserial URL a board serves",
             firmwares=("python", "c", "qemu", "stm32f4"), preflight="device", models_baud=True),
    LinkKind("slcan-pty", "can", ".log", _can("slcan", "pty"),
             "the emulated board as an SLCAN adapter on a pty it creates and announces", board_creates=True),
    LinkKind("slcan", "can", ".log", _can("slcan"), "an SLCAN (Lawicel) USB-CAN adapter on a serial port"),
    LinkKind("socketcan", "can", ".log", _can("socketcan"),
             "a SocketCAN interface (Linux; vcan inside User-Mode Linux here: ghostshell vcan)", preflight="open",
             firmwares=("python", "c")),
    LinkKind("virtual", "can", ".log", _can("virtual"),
             "python-can's virtual bus, which exists inside one process (tests serve a board on it in-process)",
             cross_process=False),
    LinkKind("can", "can", ".log", lambda s: s.kind == "can", "a CAN bus python-can opens (its configuration decides)"),
)


def link_kind(spec: SpecFields) -> LinkKind:
    """The kind of ``spec`` (every parsed spec has one)."""
    for kind in LINK_KINDS:
        if kind.matches(spec):
            return kind
    raise ValueError(f"no link kind for {spec}")  # unreachable: the last serial and CAN kinds take any
