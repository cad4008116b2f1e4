"""Write a robot package for N servos into a folder: a chain of N hinge joints, each driven by a
``<position>`` actuator (what :mod:`robots.loader` reads: robot.toml, servos.toml, poses.toml, MJCF).

``write_chain_robot(root, n) -> Path`` (the package folder). Joints ``j01..jNN`` alternate their axis
(z, y) so a long chain stays a light, well-conditioned model; each link is a 4 cm capsule of 20 g,
the base is fixed (an arm on a table). Poses: ``home`` (all 0 deg) and ``rest`` (all 10 deg). The
loader itself refuses N > 32 (:data:`robots.description.MAX_WIRE_SERVOS`), so this writes any N.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["joint_name", "write_chain_robot"]

RANGE_DEG = 90.0


def joint_name(i: int) -> str:
    """The joint (and servo, and actuator) name of servo index ``i`` (0-based)."""
    return f"j{i + 1:02d}"


def _mjcf(n: int, name: str) -> str:
    lines = [f'<mujoco model="{name}">',
             '  <compiler angle="degree"/>',
             '  <option timestep="0.002"/>',
             '  <default>',
             f'    <joint type="hinge" range="-{RANGE_DEG} {RANGE_DEG}" damping="0.05" armature="0.002" limited="true"/>',
             '    <geom type="capsule" size="0.008" mass="0.02" contype="0" conaffinity="0"/>',
             '    <position kp="4" ctrlrange="-1.6 1.6" forcerange="-3 3"/>',
             '  </default>',
             '  <worldbody>',
             '    <light pos="0 0 2"/>',
             '    <geom name="floor" type="plane" size="1 1 0.1" contype="1" conaffinity="1"/>',
             '    <body name="base" pos="0 0 0.05">',
             '      <geom type="box" size="0.03 0.03 0.02" mass="0.2"/>']
    indent = "      "
    for i in range(n):
        axis = "0 0 1" if i % 2 == 0 else "0 1 0"
        z = 0.02 if i == 0 else 0.04
        lines.append(f'{indent}<body name="l{i + 1:02d}" pos="0 0 {z}">')
        lines.append(f'{indent}  <joint name="{joint_name(i)}" axis="{axis}"/>')
        lines.append(f'{indent}  <geom fromto="0 0 0 0 0 0.04"/>')
        indent += "  "
    for i in reversed(range(n)):
        indent = indent[:-2]
        lines.append(f"{indent}</body>")
    lines += ['    </body>', '  </worldbody>', '  <actuator>']
    lines += [f'    <position name="{joint_name(i)}" joint="{joint_name(i)}"/>' for i in range(n)]
    lines += ['  </actuator>', '</mujoco>', '']
    return "\n".join(lines)


def _servos(n: int) -> str:
    out = ["[model]", "resolution_deg = 0.088", "deadband_deg = 0.2", ""]
    for i in range(n):
        out += ["[[servo]]", f"id = {i + 1}", f'name = "{joint_name(i)}"', f'joint = "{joint_name(i)}"',
                f'actuator = "{joint_name(i)}"', "neutral_deg = 0.0", f"min_deg = -{RANGE_DEG}",
                f"max_deg = {RANGE_DEG}", "direction = 1", "max_speed_dps = 400.0", ""]
    return "\n".join(out)


def _poses(n: int) -> str:
    home = ", ".join(["0.0"] * n)
    rest = ", ".join(["10.0"] * n)
    return f"[poses]\nhome = [{home}]\nrest = [{rest}]\n"


def write_chain_robot(root: Path, n: int, name: str | None = None) -> Path:
    """Write the package for an ``n``-servo chain robot into ``root / name`` and return that folder."""
    name = name or f"chain{n}"
    pkg = Path(root) / name
    pkg.mkdir(parents=True, exist_ok=True)
    (pkg / f"{name}.xml").write_text(_mjcf(n, name), encoding="utf-8")
    (pkg / "servos.toml").write_text(_servos(n), encoding="utf-8")
    (pkg / "poses.toml").write_text(_poses(n), encoding="utf-8")
    (pkg / "robot.toml").write_text(
        f'name = "{name}"\ntitle = "Chain {n}"\ndescription = "a chain of {n} hinge joints (test robot)"\n'
        f'mjcf = "{name}.xml"\nservo_table = "servos.toml"\nposes = "poses.toml"\n'
        'start_pose = "home"\nrest_pose = "home"\nsafe_pose = "rest"\n\n'
        '[base]\nfloating = false\n\n'
        f'[channels.arm]\nservos = [{", ".join(repr(joint_name(i)).replace(chr(39), chr(34)) for i in range(n))}]\n'
        'doc = "every joint of the chain"\n',
        encoding="utf-8")
    return pkg
