"""Fuzz target ``can-decoder``: arbitrary CAN frames into the CAN reassembly/decoder, ISO-TP included.

Each input is a stream of frames for node 5, decoded by :class:`protocol.can.decoder.CanDecoder`
(receiver ``board`` or ``host``, chosen by the first byte) while frames on the receiver's bulk
identifier also go through :class:`protocol.can.isotp_link.IsoTpLink` (can-isotp, listen
mode) and every completed ISO-TP unit through :meth:`CanDecoder.feed_bulk`. Frame record::

    flags u8   bit0 FD, bit1 29-bit id, bit2 remote, bit3/bit4 pick the id (see below)
    id         bit3: u8 -> function code (low 4 bits) of node 5 (bit4: node 0/broadcast or 6)
               bit4 without bit3: the receiver's ISO-TP id; neither: u16 raw id (u32 when 29-bit)
    len u8     data length (clipped to 8 classic / 64 FD, FD rounded up to a valid FD length)
    data

The two ISO-TP links (one per receiver) are built once per process and reset before each input
(can-isotp's parameter check sleeps 1 ms twice per link built: more than the rest of an input); coverage
instruments the decoder, its layouts, ids and codec and the ISO-TP link only. The decoder's state
bounds (assemblies per function code) are checked after every frame the decoder took (not counted
``foreign``: a frame it ignores leaves its state alone) and at the end of the input; the ISO-TP
queue after every frame fed to it. "Only frames it was given" is looked up by identity first.
Measured exec/s (command, n, load): docs/guides/fuzzing.md#throughput.

Invariants: no internal error is ever reported; every surfaced fixed message was carried by
exactly its layout's parts, all fed, all of one sequence and one frame kind (no partial frame
surfaces) and survives re-encoding (encode -> decode gives the same message); at most one assembly per function code; the ISO-TP
receive queue stays bounded and every unit is at most 4095 bytes.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

__all__ = ["load"]

NODE = 5


def load(instrument: bool = False) -> Callable[[bytes], None]:
    """Import the CAN decoder (instrumented when ``instrument``) and return the one-input function."""
    if instrument:
        from host.tools.fuzz.harness import instrument_only

        # the reassembly/decoder, its layouts and ids, the fixed-layout codec and the ISO-TP link
        with instrument_only(["protocol.can.decoder", "protocol.can.codec", "protocol.can.layouts",
                              "protocol.can.ids", "protocol.can.isotp_link"]):
            import protocol.can.isotp_link  # noqa: F401
            import protocol.can.decoder  # noqa: F401
    from protocol.can.isotp_link import IsoTpLink
    from protocol.can.codec import Sender, encode_fixed
    from protocol.can.decoder import MAX_ASSEMBLIES, CanDecodeError, CanDecoder, CanItem
    from protocol.can.frame import FD_LENGTHS, CanFrame
    from protocol.can.ids import FunctionCode, bulk_ids, cob_id
    from protocol.can.layouts import SEQ_MASK
    from protocol.messages import MsgType

    fns = list(FunctionCode)
    fd_up = tuple(next(s for s in FD_LENGTHS if s >= n) for n in range(65))  # data length -> FD length
    n_fns = len(fns)
    logging.getLogger("isotp").setLevel(logging.CRITICAL)  # malformed frames are the point here; keep quiet
    to_board, to_host = bulk_ids(NODE)
    # one ISO-TP link per receiver for the whole process, reset before each input: building one costs
    # 2 ms (can-isotp's parameter check calls its wait_func, time.sleep, for 1 ms, twice), 10x the rest
    links = {
        "board": IsoTpLink(to_board, to_host, False, lambda f: None, listen=True),
        "host": IsoTpLink(to_host, to_board, False, lambda f: None, listen=True),
    }

    def check_bounds(dec: CanDecoder) -> None:
        assert len(dec._assemblies) <= n_fns
        assert max(map(len, dec._assemblies.values()), default=0) <= MAX_ASSEMBLIES

    def one_input(data: bytes) -> None:
        if not data:
            return
        receiver = "board" if data[0] % 2 == 0 else "host"
        dec = CanDecoder(NODE, receiver)
        rxid = to_board if receiver == "board" else to_host
        iso = links[receiver]
        iso.layer.reset()  # can-isotp: empty queues and buffers, both state machines idle, timers stopped
        iso._rx.clear()
        # the frames fed, for "surfaced only frames it was given": by identity first (a set of ids, the
        # frames kept alive in the list), by equality as before if that misses (a CanFrame hash is a
        # Python call per frame)
        fed: list[CanFrame] = []
        fed_ids: set[int] = set()
        i = 1
        n = len(data)
        while i < n:
            flags = data[i]
            i += 1
            fd, ext, rtr = bool(flags & 1), bool(flags & 2), bool(flags & 4)
            if flags & 8:
                if i >= n:
                    break
                fn = fns[data[i] % n_fns]
                i += 1
                node = 0 if flags & 16 and fn is FunctionCode.ESTOP else (6 if flags & 16 else NODE)
                aid = cob_id(fn, node) if node else 0
            elif flags & 16:
                aid = rxid
            else:
                size = 4 if ext else 2
                if i + size > n:
                    break
                aid = int.from_bytes(data[i : i + size], "little") & (0x1FFFFFFF if ext else 0x7FF)
                i += size
            if i >= n:
                break
            length = min(data[i], 64 if fd else 8)
            i += 1
            if fd:
                length = fd_up[length]
            payload = data[i : i + length].ljust(length, b"\0")
            i += length
            frame = CanFrame(aid, payload, is_fd=fd, is_extended_id=ext, is_remote=rtr)
            fed.append(frame)
            fed_ids.add(id(frame))
            foreign = dec.foreign
            items = dec.feed(frame)
            if aid == rxid and not ext and not rtr:
                iso.feed(frame)
                for sdu in iso.poll():
                    assert len(sdu) <= 4095, f"ISO-TP unit of {len(sdu)} bytes"
                    items.append(dec.feed_bulk(sdu))
                assert len(iso._rx) <= 4096
            if dec.foreign == foreign:  # the decoder took the frame (most fuzzed frames are not its own)
                check_bounds(dec)
            for it in items:
                if isinstance(it, CanDecodeError):
                    assert "internal" not in it.detail, f"decoder bug: {it.detail}"
                    continue
                assert isinstance(it, CanItem)
                if it.bulk or not it.frames:
                    continue
                if it.msg_type is MsgType.ESTOP and len(it.frames[0].data) < 2:
                    continue  # a bare ESTOP frame is honoured whatever its length
                assert all(id(f) in fed_ids or f in fed for f in it.frames), "surfaced a frame that was never received"
                kinds = {(f.is_fd, f.arbitration_id) for f in it.frames}
                assert len(kinds) == 1, f"parts of different kinds surfaced together: {kinds}"
                headers = [int.from_bytes(f.data[:2], "little") for f in it.frames]
                assert [h & 0x1F for h in headers] == list(range(len(it.frames))), f"parts {headers}"
                assert len({(h >> 5) & SEQ_MASK for h in headers}) == 1, "parts of different sequences"
                sender = Sender.HOST if receiver == "board" else Sender.BOARD
                again = encode_fixed(it.msg, it.seq, it.frames[0].arbitration_id & 0x7F or NODE,
                                     it.frames[0].is_fd, sender)
                assert len(again) == len(it.frames), f"{it.msg_type.name}: {len(again)} parts vs {len(it.frames)}"
                # bytes may differ where the layout has don't-care slots (e.g. targets of unmasked
                # servos); the message itself must survive encode -> decode unchanged
                fresh = CanDecoder(NODE, receiver)
                back = [x for f in again for x in fresh.feed(f) if isinstance(x, CanItem)]
                assert len(back) == 1 and back[0].msg == it.msg, (
                    f"{it.msg_type.name} seq {it.seq} does not round-trip: {it.msg} -> {back}"
                )
        check_bounds(dec)
        assert len(iso._rx) <= 4096

    return one_input


if __name__ == "__main__":
    from host.tools.fuzz.harness import run_atheris

    run_atheris(load, "host.tools.fuzz.can_decoder")
