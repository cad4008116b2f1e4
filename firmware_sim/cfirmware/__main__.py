"""Entry point: ``python -m firmware_sim.cfirmware build --robot NAME --target mps2`` (:mod:`firmware_sim.cfirmware.cli`)."""

import sys

from firmware_sim.cfirmware.cli import main

sys.exit(main())
