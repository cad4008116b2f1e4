"""``python -m firmware_sim.refdoc [--check]``: write ``docs/wire-protocol.md`` (:func:`protocol.refdoc.render`)
with the board behaviour numbers of the emulated board's defaults; ``--check`` exits 1 when the
checked-in file differs."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from firmware_sim.config import BoardConfig
from protocol.generated import check_or_write
from protocol.refdoc import BoardFacts, render

__all__ = ["DOC", "facts", "main"]

DOC = Path(__file__).resolve().parents[1] / "docs" / "wire-protocol.md"
C_BUFFER_DEPTH = 32  # firmware_sim/c/core/gs_config.h GS_BUFFER_DEPTH


def facts() -> BoardFacts:
    import firmware_sim.board as board

    cfg = BoardConfig()
    doc = board.__doc__ or ""
    policy = doc[doc.index("Reply policy:"):].strip() if "Reply policy:" in doc else ""
    return BoardFacts(rate_hz=cfg.rate_hz, telemetry_rate_hz=cfg.telemetry_rate_hz, watchdog_ms=cfg.watchdog_ms,
                      crouch_after_ms=cfg.crouch_after_ms, max_late_us=cfg.max_late_us,
                      max_future_us=cfg.max_future_us, buffer_depth=cfg.buffer_depth, c_buffer_depth=C_BUFFER_DEPTH,
                      reply_policy=policy)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m firmware_sim.refdoc", description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=DOC)
    p.add_argument("--check", action="store_true", help="exit 1 when the page differs from the generated text")
    args = p.parse_args(argv)
    return check_or_write({args.out: render(facts())}, check=args.check, command="python -m firmware_sim.refdoc")

if __name__ == "__main__":
    sys.exit(main())
