"""``python -m host`` is the ``ghostshell`` command."""

import sys

from host.cli import main

sys.exit(main())
