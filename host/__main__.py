"""``python -m host`` is the ``ghostshell`` command."""

import sys

from host.cli import entry

sys.exit(entry())
