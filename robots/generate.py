"""A robot package from one MJCF file, no code: what ``ghostshell robots new NAME --mjcf FILE`` writes.

:func:`generate_package` reads an MJCF (compiled with MuJoCo; places found with
:mod:`robots.mjcf_index`) and returns the package as data (:class:`RobotPackage`: the texts of
``robot.toml``, ``servos.toml``, ``poses.toml`` and the files to copy); :func:`install_package`
writes it into a robot folder, loads it with :func:`robots.loader.load_robot_dir` (the same checks
as every robot) and only then puts it in place. No host imports; MuJoCo and the stdlib only.

Generation rules
----------------
* **Servos** are the MJCF's *position actuators* in actuator order, ids 1..N: an actuator with a
  joint transmission on a hinge or slide joint and an affine bias with ``biasprm[1] = -kp``
  (``<position kp=...>``, or ``<general biastype="affine" gainprm="kp" biasprm="0 -kp ...">``;
  :func:`robots.loader.position_kp`). Other actuators (motors, velocity servos, tendons, a
  ``<general>`` with scaled control) are skipped and listed in :attr:`RobotPackage.notes`. The
  servo, its ``name`` and ``joint`` are the joint's name; ``actuator`` is the actuator's name.
* Refused (one line, ``file:line`` of the element): an MJCF MuJoCo cannot compile; no position
  actuator at all; an unnamed position actuator (the servo table names it); two position
  actuators on one joint; a driven joint without a range (``range="lo hi"``; there is no default
  range: a made-up limit would let the LLM drive the joint where the model says it cannot go; the
  message offers the actuator's ``ctrlrange`` when it has one); a joint ``range`` that is infinite,
  inverted or empty, or an actuator ``ctrlrange`` that is inverted or empty (MuJoCo compiles those as
  no limit); a ``ctrlrange`` wholly outside its joint's range (no target could be reached); a NaN in
  any number (refused before MuJoCo reads it, which would take a NaN range as none); more than
  :data:`robots.description.MAX_WIRE_SERVOS` servos (the wire's servo mask); a file the MJCF
  references by an absolute path, or one that does not exist.
* **Limits**: ``min_deg``/``max_deg`` = the range the servo reaches, in degrees
  (:func:`robots.loader.servo_range`): the joint's ``range`` (its mechanical stop) intersected with
  its actuator's ``ctrlrange`` (the software limit MuJoCo clamps targets to). A ctrlrange narrower
  than the joint range narrows the servo range; a wider one is clamped to the joint range; either is
  one note for all the servos it concerns, and a comment in ``servos.toml``. An actuator without a
  ctrlrange leaves the joint range. A slide joint's "degrees"
  are its position in metres x 180/pi (the loader's one unit for every servo; 0.1 m = 5.73).
  ``neutral_deg`` = 0 clamped into the range; ``direction`` = 1; ``max_speed_dps`` =
  :data:`DEFAULT_MAX_SPEED_DPS` (a position actuator states no speed; ``--max-speed-dps``
  overrides it). ``[model]``: a generic 12-bit smart servo (resolution 0.088 deg, deadband 0.2 deg).
* **Poses**: ``zero`` (every joint 0, clamped into its range) and ``home`` (the MJCF's keyframe
  ``home`` if it has one, else the neutral); every other named keyframe becomes a pose of its name
  too. Keyframe values outside a joint's range are clamped (noted). start, rest and safe pose: ``home``.
* **Base**: floating when a free joint on a body under ``<worldbody>`` carries the servos' joints
  (a mobile robot), else fixed. A floating robot gets no foot sites (nothing in a third-party MJCF
  says which sites are feet); instead ``spawn_height`` puts its lowest collision geom 5 mm above
  the floor at the neutral pose, and when the MJCF has no ground plane the package's default scene
  ``floor`` adds one (a welded box).
* **Peripherals**: ``camera`` = the MJCF's first named camera (none: no camera); no screen, no
  speaker. No channels (``pose`` and ``joint_move`` run on the generic channel ``joints``), no
  tasks, no interface or behaviours module: the loader gives every robot ``pose`` and ``joint_move``.
* **Files**: the MJCF is copied with every file it references: ``<include file>``, and the
  ``file`` attributes of ``mesh``, ``skin``, ``hfield``, ``texture`` (cube faces too), ``flexcomp``
  and ``model`` assets, resolved as MuJoCo does (``compiler`` ``meshdir``/``texturedir``/``assetdir``,
  ``strippath``). Relative layout is kept: the MJCF sits at the package's top, or under ``model/``
  when some file lies above the MJCF's folder (``../meshes``), so every relative path still holds.
* **Notes** (printed, not refused): skipped actuators, servo ranges a ctrlrange changed, clamped keyframes, and joints whose
  actuator is too weak for the load at the neutral pose (the static error ``|qfrc_bias| / kp``
  above :data:`SAG_NOTE_DEG`: it would miss its targets by about that much).

The TOML is written by hand: the stdlib's ``tomllib`` only reads, and ``tomli-w`` writes no comments,
which these files need for the person who edits them next; every text is read back with ``tomllib``
and the whole package with the loader before it is installed.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import shutil
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from robots.description import MAX_WIRE_SERVOS, RobotDataError
from robots.loader import (NAME_RE, ROBOT_FILE, check_meshes, check_no_nan, compile_error, load_robot_dir,
                           position_kp, range_notes, servo_range)
from robots.mjcf_index import Element, MjcfIndex, index_mjcf

__all__ = ["DEFAULT_MAX_SPEED_DPS", "GeneratedServo", "RobotPackage", "generate_package", "install_package"]

#: servo speed limit written to every servo (deg/s) unless ``--max-speed-dps`` says otherwise
DEFAULT_MAX_SPEED_DPS = 300.0
#: the static error under load (deg) above which a joint is noted as too weak
SAG_NOTE_DEG = 1.0
#: a floating robot's lowest collision geom starts this far above the floor (m)
SPAWN_CLEARANCE_M = 0.005
#: generated file names (the MJCF and its files must not collide with them)
SERVOS_FILE, POSES_FILE = "servos.toml", "poses.toml"
#: the folder the MJCF goes into when its files reach above its own folder
MODEL_SUBDIR = "model"

#: asset element -> (its file attributes, the compiler directory they are relative to)
_ASSET_FILES: dict[str, tuple[tuple[str, ...], str]] = {
    "mesh": (("file",), "meshdir"),
    "skin": (("file",), "meshdir"),
    "hfield": (("file",), "meshdir"),
    "flexcomp": (("file",), "meshdir"),
    "texture": (("file", "fileright", "fileleft", "fileup", "filedown", "filefront", "fileback"), "texturedir"),
    "model": (("file",), "assetdir"),
}


@dataclass(frozen=True)
class GeneratedServo:
    """One servo of a generated package (degrees; a slide joint's "degrees" = metres x 180/pi)."""

    id: int
    joint: str
    actuator: str
    kind: str  # "hinge" | "slide"
    min_deg: float
    max_deg: float
    neutral_deg: float
    range_from: str = ""  # where min/max come from when the actuator's ctrlrange changed them (a comment)
    #: how far (m) the geometry this joint carries sweeps over its range at the neutral pose: the farthest geom
    #: centre's distance from a hinge's axis x its range (rad), a slide's travel; picks the ``try:`` joint
    sweep_m: float = 0.0


@dataclass(frozen=True)
class RobotPackage:
    """A generated robot package as data.

    ``texts``: package-relative path -> file text (robot.toml, servos.toml, poses.toml);
    ``copies``: package-relative path -> source file (the MJCF, its includes and assets);
    ``mjcf``: the MJCF's package-relative path; ``notes``: one line each, for the person.
    """

    name: str
    title: str
    source: Path
    mjcf: str
    servos: tuple[GeneratedServo, ...]
    poses: dict[str, tuple[float, ...]]
    floating: bool
    camera: str | None
    texts: dict[str, str]
    copies: dict[str, Path]
    notes: tuple[str, ...] = field(default=())


# --- TOML text --------------------------------------------------------------------------------------


def _tstr(s: str) -> str:
    """A TOML basic string (JSON's escapes are TOML's)."""
    return json.dumps(s, ensure_ascii=False)


def _tkey(s: str) -> str:
    return s if re.fullmatch(r"[A-Za-z0-9_-]+", s) else _tstr(s)


def _tnum(x: float) -> str:
    v = round(float(x), 4)
    return repr(v + 0.0)  # + 0.0: no "-0.0"


# --- reading the MJCF -------------------------------------------------------------------------------


def _at(el: Element | None, fallback: Path) -> str:
    return el.where if el is not None else str(fallback)


def _deg(v: float) -> float:
    return math.degrees(float(v))


def _clamp(v: float, lo: float, hi: float) -> float:
    return min(max(v, lo), hi)


def generate_package(name: str, mjcf: str | Path, *, max_speed_dps: float = DEFAULT_MAX_SPEED_DPS,
                     title: str | None = None) -> RobotPackage:
    """The package for robot ``name`` from ``mjcf`` (rules in the module docstring);
    :class:`RobotDataError` (file:line where there is one) when the MJCF cannot make a robot."""
    import mujoco

    if not NAME_RE.match(name):
        raise RobotDataError(f"robot name {name!r} must match [a-z][a-z0-9_]* (at most 32 characters)")
    if not (math.isfinite(max_speed_dps) and max_speed_dps > 0):
        raise RobotDataError(f"--max-speed-dps must be a number > 0, got {max_speed_dps}")
    src = Path(mjcf).expanduser()
    if not src.is_file():
        raise RobotDataError(f"{src}: no such file")
    src = src.resolve()
    check_meshes(src)  # a missing, huge or foreign mesh file: one line naming it, before MuJoCo reads it
    index = index_mjcf(src)
    check_no_nan(index)  # MuJoCo compiles a NaN (a NaN range as none) and prints a warning line of its own
    try:
        model = mujoco.MjModel.from_xml_path(str(src))
    except (ValueError, OSError) as e:
        raise compile_error(src, e, index) from None
    notes: list[str] = []

    act_elems = [e for e in index.children_of("actuator")]
    act_el = (lambda a: act_elems[a]) if len(act_elems) == model.nu else (lambda a: None)
    hinge, slide = int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)
    servos: list[GeneratedServo] = []
    kps: list[float] = []
    by_joint: dict[int, tuple[str, Element | None]] = {}
    skipped: list[str] = []
    changed: list[tuple[str, str, float, float, float, float, float, float, bool]] = []  # ranges a ctrlrange set
    for a in range(model.nu):
        el = act_el(a)
        aname = model.actuator(a).name
        label = repr(aname) if aname else f"#{a + 1}" + (f" ({el.where})" if el else "")
        kind = el.tag if el is not None else "actuator"
        if int(model.actuator_trntype[a]) != int(mujoco.mjtTrn.mjTRN_JOINT):
            skipped.append(f"{kind} {label}: not a joint transmission")
            continue
        jid = int(model.actuator_trnid[a, 0])
        jtype = int(model.jnt_type[jid])
        jname = model.joint(jid).name
        kp = position_kp(model, a)
        if kp is None:
            skipped.append(f"{kind} {label}: not a position actuator")
            continue
        if jtype not in (hinge, slide):
            skipped.append(f"{kind} {label}: drives a ball or free joint")
            continue
        where = _at(el, src)
        if not aname:
            raise RobotDataError(f"{where}: the position actuator on joint {jname!r} has no name; give it "
                                 "name=\"...\" (the servo table names its actuator)")
        if jid in by_joint:
            other, oel = by_joint[jid]
            raise RobotDataError(f"{where}: actuator {aname!r} drives joint {jname!r}, as actuator {other!r} "
                                 f"({_at(oel, src)}) does; a servo is one position actuator per joint")
        by_joint[jid] = (aname, el)
        jel = index.named("joint", jname)
        lo, hi, how = servo_range(model, a, jid, joint_at=_at(jel, src), actuator_at=where)
        comment = ""
        if how is not None:
            jlo, jhi = (float(v) for v in model.jnt_range[jid])
            clo, chi = (float(v) for v in model.actuator_ctrlrange[a])
            changed.append((how, jname, lo, hi, jlo, jhi, clo, chi, jtype == slide))
            comment = (f"joint range {_deg(jlo):.4g}..{_deg(jhi):.4g} within actuator ctrlrange "
                       f"{_deg(clo):.4g}..{_deg(chi):.4g}" if how == "narrower" else
                       f"the joint range; the actuator's ctrlrange {_deg(clo):.4g}..{_deg(chi):.4g} is wider")
        if len(servos) == MAX_WIRE_SERVOS:
            raise RobotDataError(f"{where}: actuator {aname!r} would be servo {MAX_WIRE_SERVOS + 1}; the wire carries "
                                 f"at most {MAX_WIRE_SERVOS} servos (its servo mask is one u32)")
        servos.append(GeneratedServo(len(servos) + 1, jname, aname, "hinge" if jtype == hinge else "slide",
                                     _deg(lo), _deg(hi), _deg(_clamp(0.0, lo, hi)), comment))
        kps.append(kp)
    if skipped:
        notes.append("skipped actuators (not servos): " + "; ".join(skipped))
    notes.extend(range_notes(changed))
    if not servos:
        first = act_elems[0] if act_elems else index.first("mujoco")
        found = f"its {model.nu} actuator(s) are none ({'; '.join(skipped)})" if model.nu else "it has no actuators"
        raise RobotDataError(f"{_at(first, src)}: no position actuator on a hinge or slide joint, so no servos: "
                             f"{found}; use <position joint=\"...\" kp=\"...\"/>")

    jids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, s.joint) for s in servos]
    qadr = [int(model.jnt_qposadr[j]) for j in jids]
    los = [math.radians(s.min_deg) for s in servos]
    his = [math.radians(s.max_deg) for s in servos]

    # poses
    poses: dict[str, tuple[float, ...]] = {"zero": tuple(s.neutral_deg for s in servos)}
    keyframes: dict[str, tuple[float, ...]] = {}
    for k in range(model.nkey):
        kname = model.key(k).name
        if not kname:
            continue
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]{0,31}", kname) or kname == "zero":
            notes.append(f"keyframe {kname!r} not made a pose (a pose name is [A-Za-z_][A-Za-z0-9_]*, not 'zero')")
            continue
        q = model.key(k).qpos
        values = []
        for s, a, lo, hi in zip(servos, qadr, los, his):
            v = float(q[a])
            if not lo - 1e-9 <= v <= hi + 1e-9:
                notes.append(f"keyframe {kname!r}: {s.joint} = {_deg(v):.2f} deg clamped into [{s.min_deg:.2f}, "
                             f"{s.max_deg:.2f}]")
            values.append(_deg(_clamp(v, lo, hi)))
        keyframes[kname] = tuple(values)
    poses["home"] = keyframes.pop("home", tuple(s.neutral_deg for s in servos))
    poses.update(keyframes)

    # base
    root_body = _floating_root(model, jids)
    floating = root_body is not None
    spawn_height = 0.0
    needs_floor = False
    if floating:
        assert root_body is not None
        first_free = next(j for j in range(model.njnt) if int(model.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_FREE)
                          and int(model.body_parentid[model.jnt_bodyid[j]]) == 0)
        if int(model.jnt_bodyid[first_free]) != root_body:
            body = model.body(root_body).name
            raise RobotDataError(f"{_at(index.named('body', body), src)}: the robot's free-floating body {body!r} must "
                                 "be the first body with a free joint under <worldbody> (the board takes the first one "
                                 "as the robot's base); move it before the others")
        spawn_height = _spawn_height(model, root_body, qadr, [math.radians(s.neutral_deg) for s in servos])
        needs_floor = not any(int(model.geom_bodyid[g]) == 0 and int(model.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_PLANE)
                              for g in range(model.ngeom))

    notes.extend(_sag_notes(model, servos, jids, qadr, kps))
    sweeps = _sweeps(model, jids, qadr, servos)
    servos = [dataclasses.replace(s, sweep_m=w) for s, w in zip(servos, sweeps)]

    camera = None
    for c in range(model.ncam):
        if model.camera(c).name:
            camera = model.camera(c).name
            break
    if camera is None and model.ncam:
        notes.append(f"{model.ncam} camera(s) without a name: no camera (name one to give the robot a camera)")

    mjcf_rel, copies = _package_files(src, index)
    root_el = index.first("mujoco")
    title = title or (root_el.attrs.get("model") if root_el is not None else None) or name
    texts = {
        ROBOT_FILE: _robot_toml(name, title, src, mjcf_rel, servos, floating, spawn_height, needs_floor, camera),
        SERVOS_FILE: _servos_toml(src, servos, max_speed_dps),
        POSES_FILE: _poses_toml(src, servos, poses, "home" in (model.key(k).name for k in range(model.nkey))),
    }
    for path, text in texts.items():
        tomllib.loads(text)  # a bug here would otherwise surface as a loader error about the user's file
        if path in copies:
            raise RobotDataError(f"{src}: the MJCF's file {path!r} would overwrite the package's own {path}")
    return RobotPackage(name, title, src, mjcf_rel, tuple(servos), poses, floating, camera, texts, copies, tuple(notes))


def _floating_root(m: Any, jids: Sequence[int]) -> int | None:
    """The body under the world with a free joint that carries every servo joint (None: fixed base).
    ``m``: a ``mujoco.MjModel``."""
    import mujoco

    for j in range(m.njnt):
        if int(m.jnt_type[j]) != int(mujoco.mjtJoint.mjJNT_FREE):
            continue
        body = int(m.jnt_bodyid[j])
        if int(m.body_parentid[body]) != 0:
            continue
        if all(int(m.body_rootid[m.jnt_bodyid[s]]) == body for s in jids):
            return body
    return None


def _spawn_height(m: Any, root: int, qadr: Sequence[int], q: Sequence[float]) -> float:
    """Root height (m) that puts the lowest collision geom of the robot SPAWN_CLEARANCE_M above z = 0, upright,
    at joint angles ``q`` (geoms bounded by their axis-aligned boxes, ``geom_aabb``)."""
    import mujoco
    import numpy as np

    d = mujoco.MjData(m)
    jfree = int(m.body_jntadr[root])
    r = int(m.jnt_qposadr[jfree])
    d.qpos[r:r + 7] = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
    d.qpos[list(qadr)] = q
    mujoco.mj_kinematics(m, d)
    lowest = math.inf
    for g in range(m.ngeom):
        b = int(m.geom_bodyid[g])
        if int(m.body_rootid[b]) != root or not (m.geom_contype[g] or m.geom_conaffinity[g]):
            continue
        if int(m.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_PLANE):
            continue
        center, half = m.geom_aabb[g, :3], m.geom_aabb[g, 3:]
        rot = d.geom_xmat[g].reshape(3, 3)
        z = float(d.geom_xpos[g, 2] + rot[2] @ center - np.abs(rot[2]) @ half)
        lowest = min(lowest, z)
    if not math.isfinite(lowest):
        return 0.2
    return round(-lowest + SPAWN_CLEARANCE_M, 4)


def _sweeps(m: Any, jids: Sequence[int], qadr: Sequence[int], servos: Sequence[GeneratedServo]) -> list[float]:
    """:attr:`GeneratedServo.sweep_m` of each servo (``m``: a ``mujoco.MjModel``), at the neutral pose."""
    import mujoco
    import numpy as np

    d = mujoco.MjData(m)
    d.qpos[list(qadr)] = [math.radians(s.neutral_deg) for s in servos]
    mujoco.mj_kinematics(m, d)
    out = []
    for s, j in zip(servos, jids):
        span = math.radians(s.max_deg - s.min_deg)
        if s.kind == "slide":
            out.append(span)
            continue
        body = int(m.jnt_bodyid[j])
        carried = []
        for g in range(m.ngeom):
            b = int(m.geom_bodyid[g])
            while b > 0 and b != body:
                b = int(m.body_parentid[b])
            if b == body:
                carried.append(g)
        anchor, axis = d.xanchor[j], d.xaxis[j] / max(float(np.linalg.norm(d.xaxis[j])), 1e-12)
        far = 0.0
        for g in carried:
            r = d.geom_xpos[g] - anchor
            far = max(far, float(np.linalg.norm(r - (r @ axis) * axis)))
        out.append(far * span)
    return out


def _sag_notes(m: Any, servos: Sequence[GeneratedServo], jids: Sequence[int], qadr: Sequence[int],
               kps: Sequence[float]) -> list[str]:
    """Joints whose actuator would hold them more than SAG_NOTE_DEG off target at the neutral pose."""
    import mujoco

    d = mujoco.MjData(m)
    d.qpos[list(qadr)] = [math.radians(s.neutral_deg) for s in servos]
    mujoco.mj_forward(m, d)
    out = []
    for s, j, kp in zip(servos, jids, kps):
        load = float(d.qfrc_bias[m.jnt_dofadr[j]] - d.qfrc_passive[m.jnt_dofadr[j]])
        err = _deg(abs(load) / kp)
        if err > SAG_NOTE_DEG:
            out.append(f"joint {s.joint!r}: its load at the neutral pose ({abs(load):.3g}) over kp {kp:g} leaves it "
                       f"~{err:.1f} deg off target; raise the actuator's kp for tighter tracking")
    return out


# --- the files the MJCF references ------------------------------------------------------------------


def _package_files(src: Path, index: MjcfIndex) -> tuple[str, dict[str, Path]]:
    """(the MJCF's package-relative path, package-relative path -> source) for the MJCF and its files."""
    compiler: dict[str, str] = {}
    for el in index:
        if el.tag == "compiler":
            compiler.update(el.attrs)
    strip = compiler.get("strippath", "false").lower() == "true"
    base = src.parent
    dirs = {}
    for key in ("meshdir", "texturedir"):
        d = compiler.get(key, compiler.get("assetdir", ""))
        if d and Path(d).is_absolute():
            el = next(e for e in index if e.tag == "compiler" and (key in e.attrs or "assetdir" in e.attrs))
            raise RobotDataError(f"{el.where}: {key} {d!r} is an absolute path; the package copies the model's "
                                 f"files, so make it relative to {src.name}'s folder")
        dirs[key] = base / d
    dirs["assetdir"] = base / compiler.get("assetdir", "")
    files: dict[Path, Element | None] = {f: None for f in index.files}
    for el in index:
        spec = _ASSET_FILES.get(el.tag)
        if spec is None or el.parent == "default":
            continue
        attrs, dir_key = spec
        for attr in attrs:
            name = el.attrs.get(attr)
            if not name:
                continue
            p = Path(name)
            if p.is_absolute():
                raise RobotDataError(f"{el.where}: {el.tag} {attr} {name!r} is an absolute path; the package copies "
                                     f"the model's files, so make it relative to {src.name}'s folder")
            if strip:
                p = Path(p.name)
            full = (dirs[dir_key] / p).resolve()
            if not full.is_file():
                raise RobotDataError(f"{el.where}: {el.tag} {attr} {name!r}: no such file ({full})")
            files.setdefault(full, el)
    root = Path(os.path.commonpath([str(f.parent) for f in files]))
    if root == Path(root.anchor):
        raise RobotDataError(f"{src}: its files share no folder but {root}; keep the model and its assets in one folder")
    prefix = Path() if root == base else Path(MODEL_SUBDIR)
    copies = {(prefix / f.relative_to(root)).as_posix(): f for f in files}
    return (prefix / src.relative_to(root)).as_posix(), copies


# --- the three TOML files ---------------------------------------------------------------------------


def _header(src: Path, what: str) -> list[str]:
    return [f"# {what}, generated by `ghostshell robots new` from {src.name} (robots/generate.py states the rules).",
            "# Edit freely: `ghostshell robots show NAME` checks the package again."]


def _robot_toml(name: str, title: str, src: Path, mjcf: str, servos: Sequence[GeneratedServo], floating: bool,
                spawn_height: float, needs_floor: bool, camera: str | None) -> str:
    joints = ", ".join(s.joint for s in servos)
    lines = [*_header(src, "The robot"), "# Every key: robots/loader.py.", "",
             f"name = {_tstr(name)}", f"title = {_tstr(title)}",
             f"description = {_tstr(f'{len(servos)} position-controlled joints ({joints}), from {src.name}')}",
             f"mjcf = {_tstr(mjcf)}", f"servo_table = {_tstr(SERVOS_FILE)}", f"poses = {_tstr(POSES_FILE)}",
             'start_pose = "home"         # where a run starts', 'rest_pose = "home"          # where a reset returns',
             'safe_pose = "home"          # where the board goes when its watchdog latches a fault',
             f"default_scene = {_tstr('floor' if needs_floor else 'empty')}",
             "# interface = \"interface\"   # optional: a module of function stubs (VOCABULARIES), see DEVELOPERS.md",
             "# behaviours = \"behaviours\" # optional: a module of motion generators (BEHAVIOURS)", "",
             "[base]"]
    if floating:
        lines += ["floating = true             # the MJCF's root body has a free joint",
                  f"spawn_height = {_tnum(spawn_height)}  # m: the lowest collision geom 5 mm above the floor at neutral",
                  "feet = []                   # name foot sites here to place the lowest one on the floor instead"]
    else:
        lines += ["floating = false            # fixed to the world where the MJCF puts it"]
    lines += ["", "[channels]                  # none: pose and joint_move run on the generic channel `joints`", "",
              "[peripherals]"]
    lines += [f"camera = {_tstr(camera)}" if camera else "# camera = \"NAME\"          # an MJCF camera the board renders"]
    lines += ["screen = false", "speaker = false"]
    if needs_floor:
        lines += ["", "[scenes.floor]", 'doc = "a floor under the robot (its MJCF has no ground plane)"', "",
                  "[[scenes.floor.objects]]", 'name = "floor"', 'shape = "box"', "size = [5.0, 5.0, 0.005]",
                  "pos = [0.0, 0.0, -0.005]", "free = false", "rgba = [0.55, 0.55, 0.55, 1.0]"]
    return "\n".join(lines) + "\n"


def _servos_toml(src: Path, servos: Sequence[GeneratedServo], max_speed_dps: float) -> str:
    lines = [*_header(src, "The servo table"),
             "# One [[servo]] per position actuator, in actuator order; id N is wire index N-1.",
             "# Joint angles in degrees (a slide joint: metres x 180/pi); min_deg/max_deg are the range the servo reaches:",
             "# the MJCF joint range, within the actuator's ctrlrange (the loader checks it); max_speed_dps is the",
             "# board's speed limit per servo.", "",
             "[model]", "resolution_deg = 0.088   # a generic 12-bit smart servo: 4096 steps per turn",
             "deadband_deg = 0.2       # no drive while |target - position| is below this"]
    for s in servos:
        lines += ["", "[[servo]]"]
        if s.kind == "slide":
            lines += [f"# slide joint: {s.min_deg * math.pi / 180:.4g}..{s.max_deg * math.pi / 180:.4g} m"]
        lines += [f"id = {s.id}", f"name = {_tstr(s.joint)}", f"joint = {_tstr(s.joint)}",
                  f"actuator = {_tstr(s.actuator)}", f"neutral_deg = {_tnum(s.neutral_deg)}",
                  f"min_deg = {_tnum(s.min_deg)}", f"max_deg = {_tnum(s.max_deg)}"
                  + (f"   # {s.range_from}" if s.range_from else ""), "direction = 1",
                  f"max_speed_dps = {_tnum(max_speed_dps)}"]
    return "\n".join(lines) + "\n"


def _poses_toml(src: Path, servos: Sequence[GeneratedServo], poses: dict[str, tuple[float, ...]],
                home_keyframe: bool) -> str:
    lines = [*_header(src, "Named poses"),
             "# [poses.NAME] with one `joint = degrees` per line; a joint left out takes its neutral.", ""]
    why = {"zero": "every joint at 0 (clamped into its range)",
           "home": "the MJCF's keyframe \"home\"" if home_keyframe else "the neutral (0 clamped into each range)"}
    for pname, values in poses.items():
        lines += [f"[poses.{_tkey(pname)}]   # {why.get(pname, f'the MJCF keyframe {pname!r}')}"]
        lines += [f"{_tkey(s.joint)} = {_tnum(v)}" for s, v in zip(servos, values)]
        lines += [""]
    return "\n".join(lines)


# --- installing -------------------------------------------------------------------------------------


def install_package(pkg: RobotPackage, robots_dir: str | Path, *, force: bool = False) -> Path:
    """Write ``pkg`` into ``robots_dir/NAME`` and return that folder.

    The package is written into a hidden staging folder next to it, loaded with the loader (every
    check a robot gets), and only then renamed into place, so a failure leaves nothing behind.
    An existing ``NAME`` folder is refused (:class:`RobotDataError`) unless ``force``; then it is replaced.
    """
    robots_dir = Path(robots_dir).expanduser()
    folder = robots_dir / pkg.name
    if folder.exists() and not force:
        raise RobotDataError(f"{folder}: a robot folder of that name exists; choose another name or pass --force "
                             "to replace it")
    try:
        robots_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise RobotDataError(f"{robots_dir}: cannot create the robot folder ({e.strerror})") from None
    staging = robots_dir / f".{pkg.name}.new-{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    try:
        for rel, text in pkg.texts.items():
            p = staging / rel
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_text(text, encoding="utf-8")
        for rel, source in pkg.copies.items():
            p = staging / rel
            p.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, p)
        try:
            load_robot_dir(staging)
        except RobotDataError as e:
            raise RobotDataError(f"the package generated from {pkg.source} does not load: "
                                 f"{str(e).replace(str(staging.resolve()), str(folder))}") from None
        old = None
        if folder.exists():
            old = robots_dir / f".{pkg.name}.old-{os.getpid()}"
            folder.rename(old)
        staging.rename(folder)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except OSError as e:
        raise RobotDataError(f"{folder}: cannot write the package ({e.strerror or e})") from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return folder
