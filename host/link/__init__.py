"""host/link: the host end of the link to a robot's board.

The client (:mod:`host.link.client`, :class:`BoardClient`: a facade over its parts, the session
:mod:`host.link.core` first) runs over a transport (:mod:`host.link.transports`: serial, CAN) built
from a link spec (:mod:`protocol.linkspec`).
"""

from host.link.client import FAULT_BITS, BoardClient, FaultEvent, LinkStats, RobotIdentity, host_now_us
from host.link.errors import (BoardFaulted, HandshakeError, LinkConfigError, LinkDown, LinkError, LinkTimeout, NackError,
                             RobotMismatch)
from host.link.timesync import ClockEstimate, ClockSync

__all__ = [
    "FAULT_BITS",
    "BoardClient",
    "BoardFaulted",
    "ClockEstimate",
    "ClockSync",
    "FaultEvent",
    "HandshakeError",
    "LinkConfigError",
    "LinkDown",
    "LinkError",
    "LinkStats",
    "LinkTimeout",
    "NackError",
    "RobotIdentity",
    "RobotMismatch",
    "host_now_us",
]
