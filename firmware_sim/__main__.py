"""Entry point: ``python -m firmware_sim --link pty``."""

import sys

from firmware_sim.cli import main

sys.exit(main())
