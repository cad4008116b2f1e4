"""The board's link transport interface: what :class:`firmware_sim.server.BoardServer` needs from a wire.

The same seam as the host's (:mod:`host.link.transports.base`), for a single-threaded
``select`` loop instead of asyncio: a transport moves whole protocol-v1 messages with
their 16-bit sequence numbers and owns its wire framing, any wire-time model and its
frame log. Everything is non-blocking; times are ``time.monotonic()`` seconds, except
``log_time`` (board seconds, used only to stamp frame-log records).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable

from protocol.framing import DecodeError, Frame
from protocol.messages import Message, MsgType, SimState, Telemetry

__all__ = ["PERIODIC_REPORTS", "BoardTransport"]

#: the board's periodic reports (message class -> its type): newer ones supersede older, so the server
#: drops them first under backlog and the CAN transport keeps only the newest one waiting per type
PERIODIC_REPORTS: dict[type[Message], MsgType] = {Telemetry: MsgType.TELEMETRY, SimState: MsgType.SIM_STATE}


class BoardTransport(ABC):
    """One wire served by the board. Subclasses: :class:`firmware_sim.transports.serial.SerialBoardTransport`, CAN."""

    def __init__(self) -> None:
        #: what the board announces on its first stdout line: ``board: listening on {name}``
        self.name: str = ""
        #: board time in seconds for frame-log records; the server sets it to the board clock
        self.log_time: Callable[[], float] = lambda: 0.0

    def use_board_clock(self, board_clock: Callable[[], int] | None) -> None:
        """A lockstep board's time (ns) for the wire's own timers (CAN's ISO-TP: :mod:`protocol.can.isotp_link`);
        None: wall time. A wire without timers ignores it."""

    @abstractmethod
    def fileno(self) -> int | None:
        """A descriptor to ``select()`` on for incoming data, or None (the server then polls)."""

    @abstractmethod
    def receive(self, now: float, *, read: bool = True) -> list[Frame | DecodeError]:
        """Items whose bytes have arrived by ``now`` (wire model), in wire order; never blocks.

        With ``read=False`` nothing new is read from the OS (only bytes already read and
        held back by the wire model are released): the realtime loop calls it that way
        between ticks (it reads when another tick is due at once: a board catching up still
        serves its link). Received items are logged here.
        """

    @abstractmethod
    def queue(self, msg: Message, seq: int, now: float) -> bool:
        """Encode ``msg`` with ``seq`` (0..65535), log it and queue it for the wire (never blocks).

        Returns whether ``seq`` was used. False: the message could not be encoded (nothing sent), or
        it took the place of an older periodic report still waiting and kept that one's sequence
        number (the CAN transport's newest-report-wins). A number the board consumed and never sent
        would be a gap the host counts as a lost message: a false "the link is degrading"."""

    @abstractmethod
    def flush(self, now: float) -> None:
        """Write what the wire model has released by ``now`` and the OS accepts without blocking."""

    @property
    @abstractmethod
    def backlog(self) -> int:
        """Bytes queued and not yet accepted by the OS (the server's drop/throttle decisions use it)."""

    @property
    def wants_write(self) -> bool:
        """True while released bytes wait for the OS to take them (select for writability)."""
        return False

    def tx_busy_s(self, now: float) -> float:
        """Seconds of wire time already committed beyond ``now`` (0 without a wire model)."""
        return 0.0

    def next_io_time(self) -> float | None:
        """The next ``time.monotonic()`` at which the wire model releases bytes either way, or None."""
        return None

    def exit_note(self) -> str | None:
        """A statistic worth one line at exit (printed once by the board's command line), or None."""
        return None

    @abstractmethod
    def close(self) -> None:
        """Close the wire and the frame log (idempotent)."""
