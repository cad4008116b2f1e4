"""firmware_sim's servo ends import one way: the C firmware's tooling runs the plant, the plant never reads the firmware's code.

Both take what they share from :mod:`firmware_sim.servo_load` (the torque of a load reading) and
:mod:`robots.hardware` (the step maths); checked on the source with :mod:`ast`, nothing imported.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _imports(path: Path) -> set[str]:
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
    return out


def test_the_plant_imports_nothing_from_the_c_firmware_package() -> None:
    bad = {f"{p.relative_to(ROOT)}: {m}" for p in sorted((ROOT / "firmware_sim" / "plant").rglob("*.py"))
           for m in _imports(p) if m == "firmware_sim.cfirmware" or m.startswith("firmware_sim.cfirmware.")}
    assert not bad, sorted(bad)


def test_the_c_firmware_package_uses_the_plant() -> None:
    """The direction that stays: cfirmware's launcher runs the plant (so the check above is not vacuous)."""
    assert any(m.startswith("firmware_sim.plant") for m in _imports(ROOT / "firmware_sim" / "cfirmware" / "launcher.py"))
