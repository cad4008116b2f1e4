"""The User-Mode Linux harness for tests: :mod:`host.tools.vcan.uml` (``ghostshell vcan`` is its command line).

Kept so tests and benchmarks import ``support.uml`` as before: importing it gives the package's
module itself (so a test's ``monkeypatch.setattr(support.uml, ...)`` reaches the harness).
``python tests/support/uml.py ARGS`` is ``ghostshell vcan ARGS``.
"""

from __future__ import annotations

import sys

import host.tools.vcan.uml as _uml

if __name__ == "__main__":
    from host.cli import main

    sys.exit(main(["vcan", *sys.argv[1:]]))
else:
    sys.modules[__name__] = _uml
