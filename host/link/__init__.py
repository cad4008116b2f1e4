"""host/link: the host end of the serial link to CoCo's board (asyncio client over pyserial)."""

from host.link.client import ALL_SERVOS, FAULT_BITS, BoardClient, FaultEvent, LinkStats, host_now_us
from host.link.errors import HandshakeError, LinkDown, LinkError, LinkTimeout, NackError
from host.link.timesync import ClockEstimate, ClockSync

__all__ = [
    "ALL_SERVOS",
    "FAULT_BITS",
    "BoardClient",
    "ClockEstimate",
    "ClockSync",
    "FaultEvent",
    "HandshakeError",
    "LinkDown",
    "LinkError",
    "LinkStats",
    "LinkTimeout",
    "NackError",
    "host_now_us",
]
