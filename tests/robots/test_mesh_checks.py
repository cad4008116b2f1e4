"""A robot package whose mesh files are missing, too big, or not a binary STL, OBJ or MSH MuJoCo reads is refused when it loads: one
line naming the ``<mesh>`` (file:line) and the file, before MuJoCo reads them; ``ghostshell run`` exits 2
with that line before any board starts, and ``robots new`` refuses the MJCF the same way.

The robot is tests/support's mesh arm (13 binary STL meshes behind an ``<include>``), made as ``robots
new`` makes one; each case breaks one mesh file of a fresh copy. A file over the byte cap is sparse
(``truncate``): its size is what the check reads first.
"""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

import numpy as np
import pytest

import robots.loader as loader
from robots.description import RobotDataError
from robots.loader import MAX_MESH_FILE_BYTES, check_meshes, load_robot_dir
from support.robot_samples import cli, line_of, one_line_error
from tests.support.mesh_robot import write_mesh_arm

XML = '<pose name="home"/><joint_move joint="shoulder_pan" deg="30" duration="1"/>'


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The mesh arm's robots folder (built once; cases copy it)."""
    return write_mesh_arm(tmp_path_factory.mktemp("arm"), segments=8)


@pytest.fixture
def arm(made: Path, tmp_path: Path) -> Path:
    """A fresh copy of the mesh arm's package folder."""
    robots = tmp_path / "robots"
    shutil.copytree(made, robots)
    return robots / "mesh_arm"


def _refusal(pkg: Path) -> str:
    with pytest.raises(RobotDataError) as e:
        load_robot_dir(pkg)
    text = str(e.value)
    assert "\n" not in text
    return text


def _parts_line(pkg: Path, mesh: str) -> str:
    line = line_of(pkg / "parts.xml", 'name="' + mesh + '"')
    return f"{pkg / 'parts.xml'}:{line}"


def test_the_mesh_arm_loads(arm: Path) -> None:
    assert load_robot_dir(arm).name == "mesh_arm"


def test_a_missing_mesh_is_named(arm: Path) -> None:
    (arm / "meshes" / "wrist_visual.stl").unlink()
    text = _refusal(arm)
    assert text == (f"{_parts_line(arm, 'wrist_visual')}: mesh 'wrist_visual' file {arm / 'meshes' / 'wrist_visual.stl'}"
                    ": no such file")


def test_a_mesh_over_the_file_cap_is_named(arm: Path) -> None:
    with open(arm / "meshes" / "hand_visual.stl", "r+b") as f:
        f.truncate(MAX_MESH_FILE_BYTES + 1)  # sparse: no 32 MiB written
    text = _refusal(arm)
    assert text.startswith(f"{_parts_line(arm, 'hand_visual')}: mesh 'hand_visual' file ")
    assert "hand_visual.stl: 32.0 MiB, over the 32 MiB a mesh file may have" in text


def test_meshes_over_the_total_cap_are_refused_with_the_largest_named(arm: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    sizes = [p.stat().st_size for p in (arm / "meshes").iterdir()]
    monkeypatch.setattr(loader, "MAX_MESH_TOTAL_BYTES", sum(sizes) - 1)
    text = _refusal(arm)
    assert text.startswith(f"{arm / 'arm.xml'}: its 13 mesh files hold ") and "(largest: " in text


@pytest.mark.parametrize("content, why", [
    (b"<html>404 Not Found</html>", "not an STL file"),
    (b"version https://git-lfs.github.com/spec/v1\noid sha256:abc\nsize 123\n", "a Git LFS pointer, not the mesh"),
])
def test_a_file_that_is_not_an_stl_is_named(arm: Path, content: bytes, why: str) -> None:
    (arm / "meshes" / "jaw_visual.stl").write_bytes(content)
    text = _refusal(arm)
    assert text.startswith(f"{_parts_line(arm, 'jaw_visual')}: mesh 'jaw_visual' file ") and why in text


def test_another_format_is_refused_with_the_ones_that_work(arm: Path) -> None:
    (arm / "meshes" / "jaw_visual.stl").rename(arm / "meshes" / "jaw_visual.ply")
    parts = arm / "parts.xml"
    parts.write_text(parts.read_text().replace("jaw_visual.stl", "jaw_visual.ply"))
    text = _refusal(arm)
    assert ".ply is not a mesh format MuJoCo reads; give .stl, .obj, .msh" in text and "jaw_visual.ply" in text


def test_an_ascii_stl_is_refused_as_mujoco_reads_binary_stl_only(arm: Path) -> None:
    (arm / "meshes" / "jaw_visual.stl").write_text("solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\n"
                                                    "vertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid t\n")
    assert "an ASCII STL; MuJoCo reads binary STL only" in _refusal(arm)


def test_an_stl_over_mujocos_triangle_limit_is_named(arm: Path) -> None:
    n = loader.MAX_STL_TRIANGLES + 1
    with open(arm / "meshes" / "jaw_visual.stl", "wb") as f:
        f.write(bytes(80) + struct.pack("<I", n))
        f.truncate(84 + 50 * n)
    assert f"a binary STL of {n} triangles; MuJoCo reads 1 to 200000" in _refusal(arm)


def test_obj_and_msh_pass(tmp_path: Path) -> None:
    """The other formats MuJoCo reads pass the check (and MuJoCo compiles the model)."""
    import mujoco

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype="<f4")
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], dtype="<i4")
    (tmp_path / "t.obj").write_text("".join(f"v {a} {b} {c}\n" for a, b, c in v) +
                                    "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f))
    (tmp_path / "t.msh").write_bytes(struct.pack("<4i", 4, 0, 0, 4) + v.tobytes() + f.tobytes())
    assets = "".join(f'<mesh name="{s}" file="t.{s}"/>' for s in ("obj", "msh"))
    geoms = "".join(f'<geom type="mesh" mesh="{s}"/>' for s in ("obj", "msh"))
    mjcf = tmp_path / "m.xml"
    mjcf.write_text(f"<mujoco><asset>{assets}</asset><worldbody><body>{geoms}</body></worldbody></mujoco>")
    check_meshes(mjcf)
    assert mujoco.MjModel.from_xml_path(str(mjcf)).nmesh == 2


def test_run_with_a_missing_mesh_is_one_line_exit_2_and_no_board(arm: Path, tmp_path: Path) -> None:
    (arm / "meshes" / "wrist_visual.stl").unlink()
    out = tmp_path / "run"
    res = cli("run", "--robots-dir", str(arm.parent), "--robot", "mesh_arm", "--xml", XML, "--no-live",
              "--out", str(out), data_home=tmp_path)
    line = one_line_error(res)
    assert "mesh 'wrist_visual' file " in line and "wrist_visual.stl: no such file" in line
    assert not out.exists()  # nothing ran: no run folder, no board


def test_robots_new_refuses_a_huge_mesh_before_mujoco_reads_it(tmp_path: Path) -> None:
    write_mesh_arm(tmp_path / "src", segments=8)
    with open(tmp_path / "src" / "mjcf" / "meshes" / "shoulder_shell.stl", "r+b") as f:
        f.truncate(MAX_MESH_FILE_BYTES + 1)
    res = cli("robots", "new", "big_arm", "--mjcf", str(tmp_path / "src" / "mjcf" / "arm.xml"), data_home=tmp_path)
    line = one_line_error(res)
    assert "mesh 'shoulder_shell' file " in line and "over the 32 MiB a mesh file may have" in line


def test_a_missing_include_names_each_place_it_was_looked_for_once(tmp_path: Path) -> None:
    from robots.mjcf_index import index_mjcf

    main = tmp_path / "arm.xml"
    main.write_text('<mujoco>\n  <include file="parts.xml"/>\n</mujoco>\n')
    with pytest.raises(RobotDataError) as e:
        index_mjcf(main)
    assert str(e.value).endswith("included file 'parts.xml' not found (next to arm.xml)"), e.value
    (tmp_path / "sub").mkdir()
    (tmp_path / "parts.xml").write_text('<mujocoinclude>\n  <include file="sub/more.xml"/>\n</mujocoinclude>\n')
    with pytest.raises(RobotDataError) as e:
        index_mjcf(main)
    assert str(e.value).endswith("included file 'sub/more.xml' not found (next to arm.xml or parts.xml)"), e.value
