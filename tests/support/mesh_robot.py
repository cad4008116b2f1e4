"""A third-party-style robot with meshes, written from scratch in a test: a 6-servo desk arm whose links
are binary STL meshes pulled in through an ``<include>``, made into a package as ``ghostshell robots new``
makes one (:func:`robots.generate.generate_package` + :func:`robots.generate.install_package`).

``write_mesh_arm(folder, name="mesh_arm", segments=64) -> Path`` writes the MJCF (``arm.xml`` including
``parts.xml``), 13 STL files under ``meshes/`` and the robot package under ``folder / "robots"``, and
returns that robots folder (pass it as ``--robots-dir``). Every mesh is a closed, faceted capsule-like
tube of ``segments`` sides and ``segments // 2`` rings per cap, so the default has 13 meshes of about
8 000 triangles each (~100 000 in all, ~5 MB of STL): the size of a real arm's meshes (the public arm model
that tripped the board's watchdog had 13 STL meshes). Joint names follow the SO-100's (``shoulder_pan`` ...
``gripper``). Binary STL is written by the recording's own writer (:func:`host.run.scene3d.stl_bytes`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from host.run.scene3d import stl_bytes as scene_stl_bytes

__all__ = ["JOINTS", "stl_bytes", "tube_mesh", "write_mesh_arm", "write_stl"]

JOINTS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")



def tube_mesh(radius: float, length: float, segments: int) -> np.ndarray:
    """Triangles ``(n, 3, 3)`` (m) of a closed tube along z from 0 to ``length`` with hemispherical caps
    approximated by ``segments // 2`` rings each; ``segments`` sides around."""
    rings = max(2, segments // 2)
    # profile: (r, z) from the bottom pole to the top pole
    lower = [(radius * np.sin(a), -radius * np.cos(a)) for a in np.linspace(0, np.pi / 2, rings)]
    upper = [(radius * np.cos(a), length + radius * np.sin(a)) for a in np.linspace(0, np.pi / 2, rings)]
    profile = np.asarray(lower + upper)
    theta = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    pts = np.empty((len(profile), segments, 3))
    pts[:, :, 0] = profile[:, None, 0] * ring[None, :, 0]
    pts[:, :, 1] = profile[:, None, 0] * ring[None, :, 1]
    pts[:, :, 2] = profile[:, None, 1]
    a = pts[:-1]
    b = np.roll(pts[:-1], -1, axis=1)
    c = pts[1:]
    d = np.roll(pts[1:], -1, axis=1)
    tri = np.concatenate([np.stack([a, b, d], axis=2), np.stack([a, d, c], axis=2)], axis=0).reshape(-1, 3, 3)
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    return tri[area > 1e-12]


def stl_bytes(triangles: np.ndarray, header: bytes = b"ghostshell test mesh") -> bytes:
    """Binary STL of ``triangles`` ``(n, 3, 3)`` (the product's writer, :func:`host.run.scene3d.stl_bytes`)."""
    tri = np.asarray(triangles, dtype=np.float32).reshape(-1, 3)
    return scene_stl_bytes(tri, np.arange(len(tri)).reshape(-1, 3), header)


def write_stl(path: Path, triangles: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(stl_bytes(triangles))
    return path


_LINKS = (  # (body, joint axis, mesh length m, radius m, joint range deg)
    ("base_link", None, 0.05, 0.04, None),
    ("shoulder", "0 0 1", 0.06, 0.03, (-110, 110)),
    ("upper_arm", "0 1 0", 0.11, 0.022, (-100, 100)),
    ("lower_arm", "0 1 0", 0.10, 0.02, (-97, 97)),
    ("wrist", "0 1 0", 0.05, 0.018, (-95, 95)),
    ("hand", "0 0 1", 0.04, 0.018, (-160, 160)),
    ("jaw", "1 0 0", 0.04, 0.008, (-10, 100)),
)


def write_mesh_arm(folder: str | Path, name: str = "mesh_arm", segments: int = 64) -> Path:
    """Write the mesh arm's MJCF, meshes and robot package under ``folder``; returns the robots folder."""
    from robots.generate import generate_package, install_package

    root = Path(folder)
    src = root / "mjcf"
    meshes = src / "meshes"
    mesh_names: list[str] = []
    for body, _axis, length, radius, _rng in _LINKS:
        for part in ("visual", "shell"):  # two meshes a link, as real arm models ship (visual + a cover)
            r = radius if part == "visual" else radius * 1.05
            mesh = f"{body}_{part}"
            write_stl(meshes / f"{mesh}.stl", tube_mesh(r, length, segments))
            mesh_names.append(mesh)
            if body == "jaw":
                break  # 13 meshes in all
    assets = "\n".join(f'    <mesh name="{m}" file="{m}.stl"/>' for m in mesh_names)
    (src / "parts.xml").write_text(f"<mujocoinclude>\n  <asset>\n{assets}\n  </asset>\n</mujocoinclude>\n")
    lines = [f'<mujoco model="{name}">',
             '  <compiler angle="degree" meshdir="meshes"/>',
             '  <option timestep="0.002"/>',
             '  <include file="parts.xml"/>',
             '  <default>',
             '    <joint damping="0.4" armature="0.01"/>',
             '    <geom contype="0" conaffinity="0" density="800"/>',
             '    <position kp="12" forcerange="-3.35 3.35"/>',
             '  </default>',
             '  <worldbody>',
             '    <light pos="0 0 2"/>']
    indent = "    "
    actuators = []
    for i, (body, axis, length, _radius, rng) in enumerate(_LINKS):
        z = 0.0 if i == 0 else _LINKS[i - 1][2]
        lines.append(f'{indent}<body name="{body}" pos="0 0 {z}">')
        if axis is not None:
            joint = JOINTS[i - 1]
            lines.append(f'{indent}  <joint name="{joint}" axis="{axis}" range="{rng[0]} {rng[1]}"/>')
            actuators.append(f'    <position name="{joint}" joint="{joint}" ctrlrange="{rng[0]} {rng[1]}"/>')
        lines.append(f'{indent}  <geom type="mesh" mesh="{body}_visual" rgba="0.9 0.6 0.2 1"/>')
        if body != "jaw":
            lines.append(f'{indent}  <geom type="mesh" mesh="{body}_shell" rgba="0.2 0.2 0.2 0.4" mass="0.01"/>')
        indent += "  "
    for _ in _LINKS:
        indent = indent[:-2]
        lines.append(f"{indent}</body>")
    lines += ['  </worldbody>', '  <actuator>', *actuators, '  </actuator>', '</mujoco>', '']
    mjcf = src / "arm.xml"
    mjcf.write_text("\n".join(lines))
    robots_dir = root / "robots"
    robots_dir.mkdir(parents=True, exist_ok=True)
    install_package(generate_package(name, mjcf), robots_dir, force=True)
    return robots_dir
