"""A robot whose MJCF passed the loader's check loads again without MuJoCo (robots.mjcf_check_cache),
and any change to what the check read checks again: an edit of the same size right after the last
load, a failing robot (never recorded). A robot the folder's digest cannot cover (an include or a
mesh folder outside it, a symbolic link, a FIFO, an edit while the check ran) is checked every time."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from robots import loader, mjcf_check_cache
from robots.description import RobotDataError
from robots.loader import load_robot_dir

COCO = Path(__file__).resolve().parents[2] / "robots" / "coco"


@pytest.fixture
def robot(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv(mjcf_check_cache.CACHE_ENV, str(tmp_path / "cache"))
    folder = tmp_path / "coco"
    shutil.copytree(COCO, folder, ignore=shutil.ignore_patterns("__pycache__"))
    return folder


@pytest.fixture
def checks(monkeypatch: pytest.MonkeyPatch) -> list[Path]:
    """The MJCFs the loader compiled, in order."""
    seen: list[Path] = []
    real = loader.check_against_mjcf

    def counting(mjcf: Path, *args: object, **kw: object) -> list[Path]:
        seen.append(mjcf)
        return real(mjcf, *args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(loader, "check_against_mjcf", counting)
    return seen


def _entries(robot: Path) -> list[Path]:
    return sorted((robot.parent / "cache").glob("*.json"))


def test_a_pass_is_recorded_and_the_next_load_skips_the_check(robot: Path, checks: list[Path]) -> None:
    load_robot_dir(robot)
    assert len(checks) == 1 and len(_entries(robot)) == 1
    load_robot_dir(robot)
    assert len(checks) == 1, "the second load compiled the MJCF again"


def test_an_edit_of_the_same_size_at_once_is_checked(robot: Path, checks: list[Path]) -> None:
    load_robot_dir(robot)
    xml = robot / "coco.xml"
    text = xml.read_text()
    assert text.count('range="-1.0472 1.0472"') == 1
    xml.write_text(text.replace('range="-1.0472 1.0472"', 'range="-1.4472 1.0472"'))  # same size, same second
    with pytest.raises(RobotDataError, match="fr_hip.*-82.92"):
        load_robot_dir(robot)
    assert len(checks) == 2
    with pytest.raises(RobotDataError):  # a failure is not recorded: refused every time
        load_robot_dir(robot)
    assert len(checks) == 3 and len(_entries(robot)) == 1


def test_a_servo_table_edit_is_checked(robot: Path, checks: list[Path]) -> None:
    load_robot_dir(robot)
    servos = robot / "servos.toml"
    text = servos.read_text()
    servos.write_text(text.replace("min_deg = -60.0", "min_deg = -61.0", 1))
    assert servos.read_text() != text
    with pytest.raises(RobotDataError, match="the table says"):
        load_robot_dir(robot)
    assert len(checks) == 2


def _share_actuators(robot: Path, name: str = "../shared/coco_actuators.xml") -> Path:
    """Move CoCo's <actuator> block to ../shared/coco_actuators.xml, included from there as ``name``."""
    xml = robot / "coco.xml"
    text = xml.read_text()
    start, end = text.index("  <actuator>"), text.index("</actuator>") + len("</actuator>")
    shared = robot.parent / "shared"
    shared.mkdir()
    (shared / "coco_actuators.xml").write_text(f"<mujoco>\n{text[start:end]}\n</mujoco>\n")
    xml.write_text(text[:start] + f'  <include file="{name}"/>' + text[end:])
    return shared / "coco_actuators.xml"


@pytest.mark.parametrize("name", ["../shared/coco_actuators.xml", "&#46;&#46;/shared/coco_actuators.xml"],
                         ids=["plain", "character-references"])
def test_an_include_outside_the_folder_is_checked_every_time(robot: Path, checks: list[Path], name: str) -> None:
    acts = _share_actuators(robot, name)
    load_robot_dir(robot)
    load_robot_dir(robot)
    assert len(checks) == 2 and not _entries(robot)
    acts.write_text(acts.read_text().replace('joint="fr_hip"', 'joint="fr_knee"', 1))
    with pytest.raises(RobotDataError, match="does not drive joint 'fr_hip'"):
        load_robot_dir(robot)


@pytest.mark.parametrize("attr", ['meshdir="../meshes"', 'texturedir="/usr/share"', 'assetdir="~/assets"'])
def test_a_folder_named_outside_is_checked_every_time(robot: Path, checks: list[Path], attr: str) -> None:
    xml = robot / "coco.xml"
    xml.write_text(xml.read_text().replace('<compiler angle="radian"', f'<compiler {attr} angle="radian"', 1))
    load_robot_dir(robot)
    load_robot_dir(robot)
    assert len(checks) == 2 and not _entries(robot)


@pytest.mark.parametrize("kind", ["linked-folder", "linked-mjcf", "fifo"])
def test_links_and_special_files_are_checked_every_time(robot: Path, checks: list[Path], kind: str) -> None:
    if kind == "linked-folder":
        (robot.parent / "elsewhere").mkdir()
        (robot / "meshes").symlink_to(robot.parent / "elsewhere")
    elif kind == "linked-mjcf":
        (robot / "coco_real.xml").write_bytes((robot / "coco.xml").read_bytes())
        (robot / "coco.xml").unlink()
        (robot / "coco.xml").symlink_to(robot / "coco_real.xml")
    else:
        os.mkfifo(robot / "a-fifo")  # never opened for reading: a hash must not block on it
    load_robot_dir(robot)
    load_robot_dir(robot)
    assert len(checks) == 2 and not _entries(robot)


def test_an_edit_while_the_check_runs_is_not_recorded(robot: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    real = loader.check_against_mjcf
    calls: list[int] = []

    def check_then_edit(*args: object, **kw: object) -> None:
        real(*args, **kw)  # type: ignore[arg-type]
        calls.append(1)
        if len(calls) == 1:  # saved after MuJoCo read the file, before the pass is recorded
            poses = robot / "poses.toml"
            poses.write_text(poses.read_text() + "\n")

    monkeypatch.setattr(loader, "check_against_mjcf", check_then_edit)
    load_robot_dir(robot)
    assert not _entries(robot)
    load_robot_dir(robot)
    assert len(calls) == 2 and len(_entries(robot)) == 1


def test_old_entries_and_stale_temporary_files_are_removed(robot: Path, checks: list[Path],
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(mjcf_check_cache, "MAX_ENTRIES", 2)
    cache = robot.parent / "cache"
    cache.mkdir()
    stale = cache / ".mjcf-check-dead.tmp"
    theirs = [cache / "r1.json", cache / ".entry-old.tmp", cache / "mjcf-check-notours.json"]  # a user's own files
    for p in theirs:
        p.write_text("{}")
        os.utime(p, (1, 1))
    stale.write_text("{")
    os.utime(stale, (1, 1))
    for k in range(3):  # three servo tables: three entries, the oldest goes
        servos = robot / "servos.toml"
        text = servos.read_text()
        servos.write_text(text.replace(f"max_speed_dps = {400 + k}.0", f"max_speed_dps = {401 + k}.0", 1))
        assert servos.read_text() != text
        load_robot_dir(robot)
    ours = sorted(cache.glob("mjcf-check-" + "[0-9a-f]" * 64 + ".json"))
    assert len(checks) == 3 and len(ours) == 2 and not stale.exists()
    assert all(p.exists() for p in theirs), "removed a file this cache did not write"


def test_off_checks_every_time(robot: Path, checks: list[Path], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(mjcf_check_cache.CACHE_ENV, "off")
    load_robot_dir(robot)
    load_robot_dir(robot)
    assert len(checks) == 2 and not _entries(robot)


def test_a_recorded_robot_loads_without_importing_mujoco(robot: Path) -> None:
    load_robot_dir(robot)
    probe = ("import sys; from robots.loader import load_robot_dir; r = load_robot_dir(sys.argv[1]); "
             "print(r.name, 'mujoco imported:', 'mujoco' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", probe, str(robot)], capture_output=True, text=True, timeout=60,
                       env=dict(os.environ))
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["coco", "mujoco", "imported:", "False"], r.stdout


@pytest.mark.parametrize("entry", ["{not json", '{"digest": 3}', '{"digest": "0"}', '[]',
                                   '{"digest": "' + "0" * 10_000 + '"}'],
                         ids=["not-json", "wrong-type", "stale-digest", "wrong-shape", "oversized"])
def test_a_damaged_entry_means_check_again(robot: Path, checks: list[Path], entry: str) -> None:
    load_robot_dir(robot)
    (path,) = _entries(robot)
    path.write_text(entry)
    load_robot_dir(robot)  # no hang on a device, no exception: the check runs and records a good entry
    assert len(checks) == 2
    load_robot_dir(robot)
    assert len(checks) == 2


def test_an_unusable_cache_folder_only_costs_the_check(robot: Path, checks: list[Path],
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    blocker = robot.parent / "a-file"
    blocker.write_text("not a folder")
    monkeypatch.setenv(mjcf_check_cache.CACHE_ENV, str(blocker))
    load_robot_dir(robot)
    load_robot_dir(robot)
    assert len(checks) == 2 and blocker.read_text() == "not a folder"


@pytest.mark.timeout(60, method="thread")
@pytest.mark.parametrize("kind", ["fifo", "link-to-stdin"])
def test_an_entry_that_is_not_a_regular_file_is_never_opened(robot: Path, checks: list[Path], kind: str) -> None:
    load_robot_dir(robot)
    (path,) = _entries(robot)
    path.unlink()
    if kind == "fifo":
        os.mkfifo(path)
    else:
        path.symlink_to("/dev/stdin")
    load_robot_dir(robot)  # would block in open() or read() of the entry
    assert len(checks) == 2


@pytest.mark.parametrize("value", ["off", "OFF", " none ", "disabled", "relative/folder", "~/x"])
def test_off_and_relative_values_check_every_time(robot: Path, checks: list[Path], monkeypatch: pytest.MonkeyPatch,
                                                  value: str) -> None:
    home = robot.parent / "home"
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(robot.parent)
    monkeypatch.setenv(mjcf_check_cache.CACHE_ENV, value)
    load_robot_dir(robot)
    load_robot_dir(robot)
    if value == "~/x":  # an absolute path after ~ is expanded
        assert len(checks) == 1 and len(list((home / "x").glob("*.json"))) == 1
    else:
        assert len(checks) == 2
        assert sorted(p.name for p in robot.parent.iterdir()) == ["coco"], "a folder was made where the command ran"
