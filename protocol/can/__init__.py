"""The CoCo protocol on CAN (classic and FD): identifiers, fixed frame layouts, ISO-TP envelope.

Pure code (no I/O, no python-can): :mod:`protocol.can.ids` (11-bit COB-IDs), :mod:`.frame`
(:class:`CanFrame`), :mod:`.layouts` (signals and parts), :mod:`.codec` (encode), :mod:`.decoder`
(reassemble, never raises). ``python -m protocol.can.make_dbc`` writes ``protocol/coco.dbc`` and
``protocol/coco_fd.dbc`` from the layouts with cantools.
"""

from protocol.can.codec import Sender, decode_bulk, encode_bulk, encode_fixed, is_fixed
from protocol.can.decoder import CanDecodeError, CanDecoder, CanErrorKind, CanItem
from protocol.can.frame import CanFrame
from protocol.can.ids import ESTOP_BROADCAST_ID, FunctionCode, bulk_ids, cob_id, split_id
from protocol.can.layouts import CAN_SERVOS, FIXED_LAYOUTS, unwrap_seq

__all__ = [
    "CAN_SERVOS",
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
    "cob_id",
    "decode_bulk",
    "encode_bulk",
    "encode_fixed",
    "is_fixed",
    "split_id",
    "unwrap_seq",
]
