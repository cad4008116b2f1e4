"""Exceptions raised by the link client (all are :class:`LinkError`)."""

from __future__ import annotations

from protocol.messages import MsgType, Nack, NackReason, nack_detail

__all__ = ["BoardFaulted", "HandshakeError", "LinkConfigError", "LinkDown", "LinkError", "LinkTimeout", "NackError",
           "RobotMismatch", "SchemaMismatch"]


class LinkError(Exception):
    """Anything that went wrong on the link; the message says what and what to do."""


class LinkDown(LinkError):
    """The port is closed or vanished (the client may be reconnecting)."""


class LinkConfigError(LinkDown):
    """The link cannot be opened as specified: no such device or interface, a driver missing, an
    option value the driver refuses, a bus no board process can reach. A usage/configuration error:
    the commands exit with status 2 (:func:`host.commands.linkarg.link_exit_status`). The message is
    one line naming the link spec and what to do; the library's own error is the ``__cause__``."""


class LinkTimeout(LinkError):
    """No reply within the time allowed."""


class BoardFaulted(LinkError):
    """The board is in ESTOP or has latched WATCHDOG_FAULT, or refused frames for that reason
    (NACK ESTOPPED / FAULT_LATCHED): motion cannot run until the fault is cleared."""


class HandshakeError(LinkError):
    """HELLO/CAPS failed: wrong protocol version or schema, or no board answering."""


class SchemaMismatch(HandshakeError):
    """The board refused the HELLO: its message schema (:class:`protocol.codec.WireSchema`) is not the
    one HELLO named (another protocol build, or a robot whose servo mask is another width)."""


class RobotMismatch(HandshakeError):
    """The board drives another robot (name, servo count or servo table hash in CAPS differ from the
    robot the host was started for): a usage error, exit status 2, never retried."""


class NackError(LinkError):
    """The board refused a message; ``nack`` holds its reason and detail."""

    def __init__(self, nack: Nack) -> None:
        self.nack = nack
        mt = nack.msg_type.name if isinstance(nack.msg_type, MsgType) else str(nack.msg_type)
        reason = nack.reason.name if isinstance(nack.reason, NackReason) else str(nack.reason)
        super().__init__(f"board refused {mt} (seq {nack.ack_seq}): {reason}: {nack_detail(nack)}")

    @property
    def reason(self) -> NackReason:
        return self.nack.reason
