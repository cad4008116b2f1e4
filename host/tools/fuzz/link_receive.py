"""Fuzz target ``session``: fuzzed board replies into the host link client's receive path.

The entry point is :meth:`host.link.receive.ReceivePath.on_items` (a client's ``receiver``), the receive handler:
a serial transport feeds every chunk it reads through a :class:`protocol.framing.FrameDecoder` and
hands the items to it; this target does the same with fuzzed bytes (no port is opened). Before the input, the client is given what a live
session has in flight: a pending ACK wait (seq 7), a time-sync probe (t1 = 1000) and a camera
capture (request 1, seq 9), so replies to them are matched too.

Input layout (atheris ``FuzzedDataProvider``): the last 4 bytes seed the chunking, the rest are the
bytes "from the board"; a seed file is ``wire bytes + 4 bytes`` (see ``host.tools.fuzz.seeds``).

Invariants: nothing is logged as an error (the client swallows handler exceptions with a log, so a
log record at ERROR is a crash here); the NACK map holds at most 1024 entries and the fault-event
history 256; the session's frame/error counters equal the decoder's; the board time seen never goes
back; the fault state equals the latest telemetry's fault bits; a completed capture is exactly the
chunks 0 .. total-1 of the first chunk's ``total`` (chunks
that disagree with it are dropped; no partial image surfaces).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

from host.tools.fuzz.serial_decoder import chunks

__all__ = ["load"]


class _Errors(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


def _describe(record: logging.LogRecord) -> str:
    exc = record.exc_info[1] if record.exc_info else None
    return record.getMessage() + (f": {type(exc).__name__}: {exc}" if exc is not None else "")


def load(instrument: bool = False) -> Callable[[bytes], None]:
    """Import the link client (instrumented when ``instrument``) and return the one-input function."""
    if instrument:
        import atheris  # type: ignore[import-not-found,unused-ignore]

        with atheris.instrument_imports(include=["host.link", "protocol"]):
            import host.link.client  # noqa: F401
    import atheris  # type: ignore[import-not-found,unused-ignore]

    from host.link.client import FAULT_BITS, BoardClient
    from protocol.framing import FrameDecoder
    from protocol.messages import CameraChunk, FaultFlags

    errors = _Errors()
    logging.getLogger("host.link").addHandler(errors)
    loop = asyncio.new_event_loop()

    def one_input(data: bytes) -> None:
        fdp = atheris.FuzzedDataProvider(data)
        seed = fdp.ConsumeIntInRange(0, 2**32 - 1)
        stream = fdp.ConsumeBytes(fdp.remaining_bytes())
        errors.records.clear()
        client = BoardClient("/dev/fuzz-board", reconnect=False)
        dec = FrameDecoder()
        ack: asyncio.Future[object] = loop.create_future()
        cap: asyncio.Future[object] = loop.create_future()
        sync: asyncio.Future[object] = loop.create_future()
        client.requests.pending[7] = ack
        client.requests.pending[9] = cap
        client.camera.start(1, 9)
        client.supervisor.sync_pending[1000] = sync
        camera = client.camera
        on_chunk = camera.on_chunk

        def observed_chunk(msg: CameraChunk) -> tuple[int, bytes] | None:
            done = on_chunk(msg)
            if done is not None and done[0] == 9 and not cap.done():
                parts, total = camera.parts[1], camera.totals.get(1, msg.total)
                missing = [i for i in range(total) if i not in parts]
                assert not missing, f"a partial image surfaced: chunks {missing} of {total} missing"
            return done

        camera.on_chunk = observed_chunk  # type: ignore[method-assign]
        on_items, clock = client.receiver.on_items, client.board_clock
        seen = 0
        for piece in chunks(stream, seed):
            on_items(dec.feed(piece))
            assert not errors.records, f"receive path failed: {_describe(errors.records[0])}"
            assert clock.seen_us >= seen, "board time went back"
            seen = clock.seen_us
            assert len(client.requests.frame_nacks) <= 1024 and len(client.fault_events) <= 256
            assert client.stats.rx_frames == dec.frames_ok
            assert client.stats.decode_errors == dec.error_count
            if client.latest_telemetry is not None:
                assert client.faults == FaultFlags(client.latest_telemetry.faults & FAULT_BITS)
        for f in (ack, cap, sync):
            if f.done() and not f.cancelled():
                f.exception()  # a NACK sets an exception: mark it retrieved

    return one_input


if __name__ == "__main__":
    from host.tools.fuzz.harness import run_atheris

    run_atheris(load, "host.tools.fuzz.link_receive")
