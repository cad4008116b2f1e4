"""The GhostShell protocol on CAN (classic and FD): identifiers, fixed frame layouts, ISO-TP envelope.

Pure code (no I/O, no python-can): :mod:`protocol.can.ids` (11-bit COB-IDs), :mod:`.frame`
(:class:`CanFrame`), :mod:`.layouts` (signals and parts, one table per robot servo count:
:func:`can_layouts`, derived from the message declarations of :mod:`protocol.messages`),
:mod:`.codec` (encode), :mod:`.decoder` (reassemble, never raises). :mod:`protocol.can.make_dbc`
builds a robot's DBC from its layouts with cantools (``ghostshell dbc --robot NAME [--fd]
[--check | --write]``; ``python -m protocol.can.make_dbc --servos N`` without a robot).
"""

from protocol.can.codec import Sender, decode_bulk, encode_bulk, encode_fixed, is_fixed
from protocol.can.decoder import CanDecodeError, CanDecoder, CanErrorKind, CanItem
from protocol.can.frame import CanFrame
from protocol.can.ids import ESTOP_BROADCAST_ID, FunctionCode, bulk_ids, cob_id, split_id
from protocol.can.layouts import DEFAULT_SERVO_COUNT, FIXED_LAYOUTS, CanLayouts, can_layouts, unwrap_seq

__all__ = [
    "CanLayouts",
    "DEFAULT_SERVO_COUNT",
    "CanDecodeError",
    "CanDecoder",
    "CanErrorKind",
    "CanFrame",
    "CanItem",
    "ESTOP_BROADCAST_ID",
    "FIXED_LAYOUTS",
    "FunctionCode",
    "Sender",
    "bulk_ids",
    "can_layouts",
    "cob_id",
    "decode_bulk",
    "encode_bulk",
    "encode_fixed",
    "is_fixed",
    "split_id",
    "unwrap_seq",
]
