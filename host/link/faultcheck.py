"""What the host does at connect about a fault the board already reports.

A board that lost its previous host latches WATCHDOG_FAULT: the previous host's
heartbeat stopped when it disconnected, the board held (200 ms) and then crouched
(1 s) and latched the fault until ESTOP_CLEAR. That fault says nothing about the
robot or the new host; it is the normal trace of a host going away. A new host
that did not clear it would have every SERVO_FRAME refused (NACK FAULT_LATCHED).
So :func:`clear_leftover_fault` clears it explicitly with ESTOP_CLEAR and returns a
one-line note for the user.

A servo fault (SERVO_FAULT: a servo on the board's bus stopped answering, answered garbled, or reported
overload, overheating or a bad voltage; every servo holds and frames are refused until ESTOP_CLEAR) is a
hardware problem: never cleared automatically either. Its one line, the same whichever way the host
learns of it (the telemetry flag at connect or mid-run, a refused frame), is :func:`servo_fault_line`:
servo id, name and cause as the board's NACK SERVO_FAULT details named them (the host waits for or asks
for one: the flag alone says no servo and no cause, and nothing is invented then), advice by cause, and
the clear command only for a board that outlives the command (one the run started is stopped with it:
rerun once fixed). The board reports each failed servo with its own NACK (the Python board; the C
firmware names the first only), so several servos silent at once point at what they share: the adapter,
the bus power, the cable.

ESTOP is different: someone (or something) asked the robot to stop, and only a
person may decide it is safe to move again. It is never cleared automatically;
:func:`clear_leftover_fault` raises :class:`BoardFaulted` telling the user how to
clear it (``ghostshell estop --link SPEC --clear``).
"""

from __future__ import annotations

import re
import shlex
from collections.abc import Sequence
from dataclasses import dataclass

from host.link.errors import BoardFaulted, LinkError, LinkTimeout
from host.link.client import BoardClient
from protocol.messages import FaultFlags, MsgType, Nack, NackReason, Telemetry, nack_detail

__all__ = ["DETAIL_WAIT_S", "LATCHED", "ServoFault", "ServoFaulted", "ask_servo_fault", "clear_command",
           "clear_leftover_fault", "estop_message", "parse_servo_fault", "refusal_message", "servo_fault_line",
           "servo_fault_message", "servo_fault_named"]

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


#: a NACK SERVO_FAULT's detail as both boards word it: ``servo id 3 (elbow_flex) overload; torque off``
_DETAIL = re.compile(r"servo id (\d+) \(([^)]*)\)?\s*(.*)", re.DOTALL)
#: the ways the boards say a servo went silent (Python board; C firmware's first NACK; its frame refusals)
_SILENT = ("not answering", "stopped answering", "is not answering")
#: the cause as the line names a silent servo
SILENT = "not answering on the servo bus"
#: how long (wall s) a run that saw the SERVO_FAULT flag waits for the NACK that names the servo
DETAIL_WAIT_S = 1.0


@dataclass(frozen=True)
class ServoFault:
    """One servo's fault as the board's NACK SERVO_FAULT named it."""

    servo_id: int
    name: str
    cause: str  # "overload", "overheating", "input voltage", "not answering on the servo bus", ...
    torque_off: bool  # the board said its torque is off

    @property
    def kind(self) -> str:
        """silent | garbled | overload | heat | voltage | other (what the advice depends on)."""
        c = self.cause.lower()
        if c == SILENT:
            return "silent"
        for kind, words in (("garbled", ("garbled", "checksum")), ("overload", ("overload", "overcurrent")),
                            ("heat", ("overheat",)), ("voltage", ("voltage",))):
            if any(w in c for w in words):
                return kind
        return "other"

    @property
    def limp(self) -> bool:
        """Its torque is off: the board said so, or the cause is one both boards switch torque off for."""
        return self.torque_off or self.kind in ("overload", "heat")

    def __str__(self) -> str:
        return f"servo id {self.servo_id} ({self.name}) {self.cause}"


def parse_servo_fault(detail: str) -> ServoFault | None:
    """The servo, cause and torque state a NACK SERVO_FAULT's ``detail`` names; None when it names no servo
    (an empty detail, e.g. over CAN, or another board's wording). The board's own tails (``; torque off``,
    ``; send ESTOP_CLEAR``) are not part of the cause; the silent servo's wordings become :data:`SILENT`."""
    m = _DETAIL.match(detail.strip())
    if m is None:
        return None
    parts = [p.strip() for p in m.group(3).split(";")]
    cause = parts[0] or "failed"
    if cause.startswith(_SILENT):
        cause = SILENT
    return ServoFault(int(m.group(1)), m.group(2), cause, any(p.startswith("torque off") for p in parts[1:]))


def _faults(nacks: Sequence[Nack]) -> list[ServoFault]:
    """One :class:`ServoFault` per servo named (first cause seen; torque off if any NACK said so)."""
    out: dict[int, ServoFault] = {}
    for n in nacks:
        if n.reason != NackReason.SERVO_FAULT:
            continue
        f = parse_servo_fault(n.detail or "")
        if f is None:
            continue
        seen = out.get(f.servo_id)
        if seen is None:
            out[f.servo_id] = f
        elif f.torque_off and not seen.torque_off:
            out[f.servo_id] = ServoFault(seen.servo_id, seen.name, seen.cause, True)
    return list(out.values())


_ADVICE = {
    "overload": "free the joint (nothing blocking it, not pressed against its end stop) or reduce its load",
    "heat": "let it cool down and give it less load",
    "voltage": "check the servo supply's voltage, also under load",
    "silent": "check that servo's power, its cable and its id (if others went silent too: the USB adapter, the bus power, the bus cable)",
    "garbled": "check the bus cable and connectors and that no two servos share an id",
    "other": "check that servo (the board's log names its error)",
}
#: several servos silent at once: what they share
SEVERAL_SILENT = "several servos went silent at once: check what they share, the USB adapter, the bus power and the bus cable"


def servo_fault_line(nacks: Sequence[Nack], board_time_us: int | None = None, link: object | None = None) -> str:
    """THE one line for a board that latched SERVO_FAULT, whichever way the host learnt of it.

    ``nacks``: the board's NACK SERVO_FAULTs (unsolicited or refusing a frame), oldest first; ``board_time_us``:
    when the telemetry first showed the fault (None: not known); ``link``: the link spec of a board that
    outlives the command (the line ends with the command that clears it), None for a board the command
    started and stopped (the line says to run again once fixed)."""
    faults = _faults(nacks)
    at = f" at board time {board_time_us / 1e6:.3f} s" if board_time_us is not None else ""
    silent = [f for f in faults if f.kind == "silent"]
    if not faults:
        what = "the board latched SERVO_FAULT without naming the servo or the cause (the board's log names them)"
        advice = ["fix what the board's log names"]
    elif len(silent) > 1 and len(silent) == len(faults):
        what = ("servo ids " + ", ".join(f"{f.servo_id} ({f.name})" for f in silent) + f" {SILENT}")
        advice = [SEVERAL_SILENT]
    else:
        what = ", ".join(str(f) + (" (its torque is off)" if f.limp else "") for f in faults)
        advice = [SEVERAL_SILENT] if len(silent) > 1 else []
        for f in faults:
            a = _ADVICE[f.kind]
            if len(faults) > 1:
                a = a.replace("that servo", f"servo {f.servo_id}").replace("the joint", f"joint {f.name}")
                a = a.split(" (if others")[0]
            if not (f.kind == "silent" and len(silent) > 1) and a not in advice:
                advice.append(a)
    then = (f"clear it with `{clear_command(link)}`" if link is not None else
            "run again: this run stopped the board it started, and the fault with it")
    todo = "; ".join(advice)
    return f"board fault{at}: {what}; the board holds the servos and refuses motion. {todo[0].upper()}{todo[1:]}, then {then}"


def _board_stays(client: BoardClient) -> object | None:
    """The link spec to clear the board on, or None when the board stops with this command (it started it)."""
    return None if getattr(client, "board_started_here", False) else client.link_spec


def _client_nacks(client: BoardClient) -> list[Nack]:
    nacks = list(getattr(client, "servo_faults", None) or ())
    latest = getattr(client, "servo_fault", None)
    if latest is not None and latest not in nacks:
        nacks.append(latest)
    return nacks


def _first_fault_time(client: BoardClient) -> int | None:
    events = getattr(client, "fault_events", None) or ()
    return next((e.board_time_us for e in reversed(events) if e.raised & FaultFlags.SERVO_FAULT), None)


def servo_fault_named(client: BoardClient) -> bool:
    """Whether the board's NACKs so far name a faulty servo (else the line would have no servo to name)."""
    return bool(_faults(_client_nacks(client)))


def servo_fault_message(client: BoardClient, board_time_us: int | None = None) -> str:
    """:func:`servo_fault_line` for ``client``: every NACK SERVO_FAULT it received, the clear command unless
    the board stops with this command (``client.board_started_here``)."""
    if board_time_us is None:
        board_time_us = _first_fault_time(client)
    return servo_fault_line(_client_nacks(client), board_time_us, _board_stays(client))


class ServoFaulted(BoardFaulted):
    """A board that latched SERVO_FAULT; its text (:func:`servo_fault_message`) is rendered when shown, from
    every NACK the client has received by then: a run that fails on the first NACK still names every servo
    the board reported in the same breath (several silent at once)."""

    def __init__(self, client: BoardClient, board_time_us: int | None = None) -> None:
        super().__init__()
        self.client, self.board_time_us = client, board_time_us

    def __str__(self) -> str:
        return servo_fault_message(self.client, self.board_time_us)


async def ask_servo_fault(client: BoardClient, tel: Telemetry, timeout: float = 1.0) -> None:
    """Make a board that reports SERVO_FAULT in ``tel`` name it, when no NACK has yet (the fault latched
    before this host connected: its unsolicited NACK went nowhere): send one frame holding the reported
    positions, which a faulted board refuses with a NACK SERVO_FAULT naming the servo and its cause.
    Harmless otherwise (it holds where the servos are). Best effort: nothing is raised."""
    if servo_fault_named(client):
        return
    try:
        seq = client.send_targets(tel.board_time_us + 100_000, tel.positions)
        nack = await client.wait_frame_nack(seq, timeout)
    except LinkError:
        return
    if nack is not None and nack.reason == NackReason.SERVO_FAULT and nack not in _client_nacks(client):
        faults = getattr(client, "servo_faults", None)
        if isinstance(faults, list):
            faults.append(nack)


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
        await ask_servo_fault(client, tel)
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
        return servo_fault_line([nack], None, link)
    return None
