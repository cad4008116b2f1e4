"""What the host does at connect about a fault the board already reports.

A board that lost its previous host latches WATCHDOG_FAULT: the previous host's
heartbeat stopped when it disconnected, the board held (200 ms) and then crouched
(1 s) and latched the fault until ESTOP_CLEAR. That fault says nothing about the
robot or the new host; it is the normal trace of a host going away. A new host
that did not clear it would have every SERVO_FRAME refused (NACK FAULT_LATCHED).
So :func:`clear_leftover_fault` clears it explicitly with ESTOP_CLEAR and returns a
one-line note for the user.

A servo that stopped answering on the board's servo bus (the C firmware's SERVO_FAULT: it holds every
servo and refuses frames until ESTOP_CLEAR) is a hardware problem: never cleared automatically either;
:func:`servo_fault_message` is the one line a run or a connect ends with.

ESTOP is different: someone (or something) asked the robot to stop, and only a
person may decide it is safe to move again. It is never cleared automatically;
:func:`clear_leftover_fault` raises :class:`BoardFaulted` telling the user how to
clear it (``ghostshell estop --link SPEC --clear``).
"""

from __future__ import annotations

import shlex

from host.link.errors import BoardFaulted, LinkTimeout
from host.link.session import BoardClient
from protocol.messages import FaultFlags, MsgType, Nack, NackReason, nack_detail

__all__ = ["LATCHED", "clear_command", "clear_leftover_fault", "estop_message", "refusal_message", "servo_fault_message"]

#: telemetry bits under which the board refuses every servo frame
LATCHED = FaultFlags.ESTOP | FaultFlags.WATCHDOG_FAULT | FaultFlags.SERVO_FAULT


def clear_command(link: object) -> str:
    """The shell command that clears an estop or latched fault on ``link`` (a link spec, quoted for a POSIX shell:
    a CAN spec's ``?node=2&fd=1`` must survive copy and paste)."""
    return f"ghostshell estop --link {shlex.quote(str(link))} --clear"


def estop_message(link: object) -> str:
    """The error for a board found in ESTOP (with the command that clears it); ``link``: its link spec."""
    return (f"the board on {link} is in ESTOP and refuses motion; once it is safe to move, clear it with "
            f"`{clear_command(link)}`")


def servo_fault_message(client: BoardClient, board_time_us: int) -> str:
    """The one line for a board that latched SERVO_FAULT (a servo stopped answering on its bus)."""
    nack = client.servo_fault
    which = nack_detail(nack) if nack is not None else nack_detail(Nack(0, MsgType.SERVO_FRAME, NackReason.SERVO_FAULT))
    return (f"board fault: {which} (reported at board time {board_time_us / 1e6:.3f} s); the board holds every "
            f"servo and refuses motion. Check that servo's power and cable, then clear it with "
            f"`{clear_command(client.link_spec)}`")


async def clear_leftover_fault(client: BoardClient, timeout: float = 10.0) -> str | None:
    """Clear a latched WATCHDOG_FAULT left by a previous host; refuse a board in ESTOP.

    Waits for the first telemetry report (up to ``timeout`` s). Returns a one-line
    note when a fault was cleared, None when there was none. Raises
    :class:`BoardFaulted` when the board is in ESTOP, or still reports the fault after
    ESTOP_CLEAR was acknowledged; :class:`~host.link.errors.LinkError` on link failures.
    """
    tel = await client.wait_for(lambda t: True, timeout, nudge=True)
    faults = FaultFlags(tel.faults)
    if faults & FaultFlags.ESTOP:
        raise BoardFaulted(estop_message(client.link_spec))
    if faults & FaultFlags.SERVO_FAULT:
        raise BoardFaulted(servo_fault_message(client, tel.board_time_us))
    if not faults & FaultFlags.WATCHDOG_FAULT:
        return None
    at = tel.board_time_us
    await client.estop_clear()
    try:
        await client.wait_for(lambda t: t.board_time_us > at and not t.faults & LATCHED, timeout, nudge=True)
    except LinkTimeout as e:
        raise BoardFaulted(f"the board on {client.port_name} still reports a fault after ESTOP_CLEAR: {e}") from None
    return (f"cleared the board's latched WATCHDOG_FAULT (left by the previous host's missing heartbeat, "
            f"board time {at / 1e6:.3f} s) with ESTOP_CLEAR")


def refusal_message(nack: Nack, link: object) -> str | None:
    """The one line a run fails with when the board refuses motion (a SERVO_FRAME NACKed ESTOPPED, or any
    NACK SERVO_FAULT), else None; ``link``: its link spec. The reason's text comes from
    :func:`protocol.messages.nack_detail`: the same over CAN, whose NACK to a servo frame has no detail."""
    if nack.msg_type == MsgType.SERVO_FRAME and nack.reason == NackReason.ESTOPPED:
        return f"the board refused servo frames (ESTOPPED: {nack_detail(nack)}); clear it with `{clear_command(link)}`"
    if nack.reason == NackReason.SERVO_FAULT:
        return (f"the board lost a servo ({nack_detail(nack)}) and refuses motion; "
                f"clear it with `{clear_command(link)}`")
    return None
