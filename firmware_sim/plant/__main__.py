import sys

from firmware_sim.plant.server import main

sys.exit(main())
