"""Tests that boot User-Mode Linux (see ``support/uml.py``).

Where this kernel has ``vcan0`` natively, ``tests/socketcan`` runs in the normal session and the
UML run of it is left out of collection (not reported as a skip).
"""

from __future__ import annotations

from support.uml import native_vcan

if native_vcan("vcan0"):
    collect_ignore = ["test_socketcan_in_uml.py"]
