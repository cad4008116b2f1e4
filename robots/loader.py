"""Read a robot folder into one :class:`robots.description.Robot`, checking it against its MJCF.

``robot.toml`` (every path relative to the folder)::

    name = "arm"                      # [a-z][a-z0-9_]*, the name --robot takes
    title = "Desk arm"                # for people
    description = "..."
    mjcf = "arm.xml"
    servo_table = "servos.toml"       # [[servo]] entries, see below
    poses = "poses.toml"              # [poses] name = [deg per servo] or {joint = deg, ...}
    tasks = "tasks.json"              # optional: {"tasks": [{"id", "category", "instruction", "ground_truth"}]}
    interface = "interface"           # optional module: VOCABULARIES (robots.interface)
    behaviours = "behaviours"         # optional module: BEHAVIOURS (robots.description.Behaviour)
    default_vocabulary = "default"    # a key of VOCABULARIES
    start_pose = "home"               # where a run starts
    rest_pose = "home"                # a channel's reset returns its servos here
    safe_pose = "rest"                # the board's latched-watchdog pose
    default_scene = "table"
    demo_task = 3                     # the task ``ghostshell demo`` shows (default: the first)
    tour = ["home", "rest", "home"]   # the poses ``ghostshell tour`` drives through (default: all)
    [base]      floating = false | true, feet = [site, ...], foot_radius = m, spawn_height = m
    [channels.NAME]  servos = [servo name, ...], doc = "..."
    [peripherals]    camera = "mjcf camera", camera_label, screen = bool, speaker = bool, voices, clips
    [scenes.NAME]    doc = "..."; [[scenes.NAME.objects]] name, shape, size, pos, rgba, mass, free,
                     friction, topples, euler_deg
    [data]      KEY = "file"          # further files the robot's own tools read
    [view]      distance_m, azimuth_deg, elevation_deg, lookat_z   # run.mp4's follow camera

Servo table (``servo_table``)::

    [model]  resolution_deg = 0.088, deadband_deg = 0.2, stall_torque_nm = 1.9, model = "STS3215"
    [[servo]] id, name, joint, actuator, neutral_deg, min_deg, max_deg, direction (+-1), max_speed_dps,
              further keys kept as tags (e.g. leg = 1)

What is checked (each refusal is a :class:`RobotDataError` naming file:line where there is one):
ids run 1..N in order with N <= :data:`robots.description.MAX_WIRE_SERVOS`; names and joints are
unique; min < max with the neutral inside; direction +-1; speed > 0; every joint exists in the
MJCF as a hinge or slide with a valid range; every actuator exists, is a position actuator (affine
bias, ``biasprm[1] = -kp``) and drives its servo's joint, and its ``ctrlrange`` (if any) is a valid
range that overlaps the joint's; the table's min/max equal (0.05 deg) the range the servo reaches
(:func:`servo_range`: the joint range, narrowed by a narrower ctrlrange) or the joint range itself; poses give
one in-range value per servo (or name joints that exist); the start/rest/safe poses exist; channel
servos exist and no servo is in two channels; the camera exists in the MJCF; scene objects have
valid shapes and sizes.

Mesh files (:func:`check_meshes`, before MuJoCo reads them, so a bad one is one line naming it and no
board starts): every ``<mesh file=...>`` (includes followed, the path resolved as MuJoCo does: the
compiler's ``meshdir``/``assetdir`` from the main model's folder, ``strippath``) exists; is a binary
STL (``84 + 50 N`` bytes, 1 <= N <= :data:`MAX_STL_TRIANGLES`: MuJoCo's STL decoder reads no more, and
no ASCII STL), an OBJ (text with ``v`` lines) or a MuJoCo MSH (its four counts give its size), by
suffix and content (a Git LFS pointer checked out in place of a mesh is named as one); is at most
:data:`MAX_MESH_FILE_BYTES`; and all of them together at most :data:`MAX_MESH_TOTAL_BYTES`. Other formats (``.ply``, ``.dae``, ``.glb``...) are refused, with the
formats that work: MuJoCo 4 has no decoder for them, and the run's 3D scene (:mod:`host.run.scene3d`)
sends what MuJoCo compiled, as STL, so STL, OBJ and MSH all show.
"""

from __future__ import annotations

import math
import re
import sys
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from robots import mjcf_check_cache
from robots.description import (
    MAX_WIRE_SERVOS,
    Base,
    Channel,
    Peripherals,
    Robot,
    RobotDataError,
    SceneObjectSpec,
    SceneSpec,
    Servo,
    ServoModelParams,
    ServoTable,
)

__all__ = ["MAX_MESH_FILE_BYTES", "MAX_MESH_TOTAL_BYTES", "MESH_SUFFIXES", "ROBOT_FILE", "check_against_mjcf",
           "check_meshes", "check_no_nan", "compile_error", "load_robot_dir", "mesh_files", "mjcf_notes", "mjcf_servo_ranges",
           "position_kp", "range_notes", "read_poses", "read_servo_table", "servo_range"]

ROBOT_FILE = "robot.toml"
NAME_RE = re.compile(r"^[a-z][a-z0-9_]{0,31}$")
#: joint range in the MJCF vs the servo table: equal within this (degrees)
RANGE_TOL_DEG = 0.05
SHAPES = {"box": 3, "cylinder": 2, "sphere": 1}
#: mesh file formats a robot may use (what MuJoCo decodes: binary/ASCII STL, Wavefront OBJ, MuJoCo MSH)
MESH_SUFFIXES = (".stl", ".obj", ".msh")
#: one mesh file larger than this is refused (32 MiB: ~670 000 triangles of binary STL; a robot's visual
#: meshes are a few MB, and decimated meshes look the same in a run's video and 3D view)
MAX_MESH_FILE_BYTES = 32 << 20
#: a robot's mesh files together larger than this are refused (MuJoCo compiles them at every run start)
#: triangles MuJoCo 4 reads from one binary STL file at most (its STL decoder refuses more)
MAX_STL_TRIANGLES = 200_000
MAX_MESH_TOTAL_BYTES = 128 << 20


# --- file helpers ---------------------------------------------------------------------------------


def _read_toml(path: Path) -> tuple[dict[str, Any], str]:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise RobotDataError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise RobotDataError(f"{path}: cannot read it ({e})") from None
    try:
        return tomllib.loads(text), text
    except tomllib.TOMLDecodeError as e:
        m = re.search(r"line (\d+)", str(e))
        where = f"{path}:{m.group(1)}" if m else str(path)
        raise RobotDataError(f"{where}: not valid TOML ({e})") from None


def _line(text: str, pattern: str, occurrence: int = 0) -> int | None:
    """1-based line of the ``occurrence``-th match of regex ``pattern`` in ``text`` (None if absent)."""
    for k, m in enumerate(re.finditer(pattern, text, flags=re.MULTILINE)):
        if k == occurrence:
            return text.count("\n", 0, m.start()) + 1
    return None


def _key_line(text: str, section_line: int | None, key: str) -> int | None:
    """Line of ``key = ...`` in the table that starts at ``section_line`` (before the next ``[...]``)."""
    if section_line is None:
        return None
    lines = text.splitlines()
    for n in range(section_line, len(lines)):  # lines[section_line] is the line after the header
        stripped = lines[n].strip()
        if stripped.startswith("["):
            break
        if re.match(rf"^\"?{re.escape(key)}\"?\s*=", stripped):
            return n + 1
    return section_line


def _at(path: Path, line: int | None) -> str:
    return f"{path}:{line}" if line else str(path)


def _num(v: Any, what: str, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise RobotDataError(f"{where}: {what} must be a finite number, got {v!r}")
    return float(v)


def _str(v: Any, what: str, where: str) -> str:
    if not isinstance(v, str) or not v:
        raise RobotDataError(f"{where}: {what} must be a non-empty string, got {v!r}")
    return v


# --- servo table ----------------------------------------------------------------------------------

_SERVO_KEYS = {"id", "name", "joint", "actuator", "neutral_deg", "min_deg", "max_deg", "direction", "max_speed_dps"}


def read_servo_table(path: Path) -> ServoTable:
    """Read and check a servo table file (everything but the MJCF cross-check)."""
    data, text = _read_toml(path)
    rows = data.get("servo", [])
    if not isinstance(rows, list) or not rows:
        raise RobotDataError(f"{path}: no [[servo]] entries")
    if len(rows) > MAX_WIRE_SERVOS:
        where = _at(path, _line(text, r"^\[\[servo\]\]", MAX_WIRE_SERVOS))
        raise RobotDataError(f"{where}: {len(rows)} servos; the wire carries at most {MAX_WIRE_SERVOS} "
                             "(its servo mask is one u32)")
    servos: list[Servo] = []
    seen_ids: dict[int, int] = {}
    seen: dict[str, dict[str, int]] = {"name": {}, "joint": {}, "actuator": {}}
    for n, row in enumerate(rows, start=1):
        where = _at(path, _line(text, r"^\[\[servo\]\]", n - 1))
        if not isinstance(row, dict):
            raise RobotDataError(f"{where}: servo entry {n} is not a table")
        missing = [k for k in ("id", "name", "joint", "min_deg", "max_deg") if k not in row]
        if missing:
            raise RobotDataError(f"{where}: servo entry {n} lacks {', '.join(repr(k) for k in missing)}")
        sid = row["id"]
        if isinstance(sid, bool) or not isinstance(sid, int):
            raise RobotDataError(f"{where}: servo id must be a whole number, got {sid!r}")
        if sid in seen_ids:
            raise RobotDataError(f"{where}: duplicate servo id {sid} (also servo entry {seen_ids[sid]})")
        seen_ids[sid] = n
        if sid != n:
            raise RobotDataError(f"{where}: servo entry {n} has id {sid}; ids must run 1..{len(rows)} in order "
                                 "(id N is wire index N-1)")
        name = _str(row["name"], "name", where)
        joint = _str(row["joint"], "joint", where)
        actuator = _str(row.get("actuator", joint), "actuator", where)
        for key, value in (("name", name), ("joint", joint), ("actuator", actuator)):
            if value in seen[key]:
                raise RobotDataError(f"{where}: {key} {value!r} is used by servo {seen[key][value]} too")
            seen[key][value] = sid
        lo = math.radians(_num(row["min_deg"], "min_deg", where))
        hi = math.radians(_num(row["max_deg"], "max_deg", where))
        neutral = math.radians(_num(row.get("neutral_deg", 0.0), "neutral_deg", where))
        direction = row.get("direction", 1)
        speed = math.radians(_num(row.get("max_speed_dps", 300.0), "max_speed_dps", where))
        if not lo < hi or not lo <= neutral <= hi:
            raise RobotDataError(f"{where}: servo {name}: need min_deg < max_deg and neutral_deg inside them")
        if direction not in (-1, 1) or isinstance(direction, bool):
            raise RobotDataError(f"{where}: servo {name}: direction must be 1 or -1, got {direction!r}")
        if not speed > 0:
            raise RobotDataError(f"{where}: servo {name}: max_speed_dps must be > 0")
        tags = {k: v for k, v in row.items() if k not in _SERVO_KEYS}
        servos.append(Servo(sid, name, joint, actuator, neutral, lo, hi, int(direction), speed, tags))
    model = data.get("model", {})
    where = _at(path, _line(text, r"^\[model\]"))
    if not isinstance(model, dict):
        raise RobotDataError(f"{where}: [model] must be a table")
    stall = model.get("stall_torque_nm")
    params = ServoModelParams(
        resolution=math.radians(_num(model.get("resolution_deg", 0.088), "resolution_deg", where)),
        deadband=math.radians(_num(model.get("deadband_deg", 0.2), "deadband_deg", where)),
        stall_torque=None if stall is None else _num(stall, "stall_torque_nm", where),
        model=str(model.get("model", "")),
    )
    if not params.resolution >= 0 or not params.deadband >= 0:
        raise RobotDataError(f"{where}: resolution_deg and deadband_deg must be >= 0")
    return ServoTable(tuple(servos), params)


# --- poses ----------------------------------------------------------------------------------------


def read_poses(path: Path, table: ServoTable) -> dict[str, tuple[float, ...]]:
    """Named poses, radians in servo order. A pose is a list (degrees per servo, id order) or a table
    ``{servo-or-joint name = degrees}`` (servos it leaves out take their neutral)."""
    data, text = _read_toml(path)
    entries = data.get("poses", {})
    if not isinstance(entries, dict) or not entries:
        raise RobotDataError(f"{path}: no [poses] table")
    names = {s.name: s.index for s in table} | {s.joint: s.index for s in table}
    out: dict[str, tuple[float, ...]] = {}
    for name, value in entries.items():
        # [poses.NAME], or NAME = ... ([ \t], not \s: a match must not start on an earlier, blank line)
        section = _line(text, rf"^[ \t]*\[[ \t]*poses[ \t]*\.[ \t]*\"?{re.escape(name)}\"?[ \t]*\]")
        where = _at(path, section or _line(text, rf"^[ \t]*\"?{re.escape(name)}\"?[ \t]*="))
        at: dict[int, str] = {}  # servo index -> where its value is written
        if isinstance(value, list):
            if len(value) != len(table):
                raise RobotDataError(f"{where}: pose {name!r} has {len(value)} values; it needs {len(table)} "
                                     "(degrees per servo in id order)")
            q = [math.radians(_num(v, f"pose {name!r}", where)) for v in value]
        elif isinstance(value, dict):
            q = list(table.neutral)
            for joint, v in value.items():
                jwhere = _at(path, _key_line(text, section, joint)) if section else where
                if joint not in names:
                    raise RobotDataError(f"{jwhere}: pose {name!r} names {joint!r}, which is no servo or joint of "
                                         f"this robot (servos: {', '.join(table.names)})")
                q[names[joint]] = math.radians(_num(v, f"pose {name!r} {joint}", jwhere))
                at[names[joint]] = jwhere
        else:
            raise RobotDataError(f"{where}: pose {name!r} must be a list of degrees or a table of joint = degrees")
        for s, v in zip(table, q):
            if not s.min - 1e-9 <= v <= s.max + 1e-9:
                raise RobotDataError(f"{at.get(s.index, where)}: pose {name!r}: {s.name} = {math.degrees(v):.1f} deg "
                                     f"outside [{math.degrees(s.min):.0f}, {math.degrees(s.max):.0f}]")
        out[name] = tuple(q)
    return out


# --- the MJCF cross-check -------------------------------------------------------------------------


def position_kp(model: Any, aid: int) -> float | None:
    """``kp`` of actuator ``aid`` when it is a position actuator (fixed gain ``kp > 0``, affine bias with
    ``biasprm[1] = -kp``: ``<position>`` or the equivalent ``<general>``), else None."""
    import mujoco

    kp = float(model.actuator_gainprm[aid, 0])
    if (int(model.actuator_gaintype[aid]) != int(mujoco.mjtGain.mjGAIN_FIXED)
            or int(model.actuator_biastype[aid]) != int(mujoco.mjtBias.mjBIAS_AFFINE) or not kp > 0
            or abs(float(model.actuator_biasprm[aid, 1]) + kp) > 1e-9 * max(1.0, kp)):
        return None
    return kp


def _span(lo: float, hi: float, slide: bool) -> str:
    """A range for people: degrees for a hinge, metres for a slide joint."""
    if slide:
        return f"[{lo:.4g}, {hi:.4g}] m"
    return f"[{math.degrees(lo):.4g}, {math.degrees(hi):.4g}] deg"


def _bad_pair(lo: float, hi: float) -> str | None:
    """Why ``(lo, hi)`` is no range (NaN, infinite, inverted, empty), or None."""
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return "is not a pair of finite numbers"
    if lo > hi:
        return "is inverted (lo > hi)"
    if lo == hi:
        return "is empty (lo = hi)"
    return None


def servo_range(model: Any, aid: int, jid: int, *, joint_at: str, actuator_at: str) -> tuple[float, float, str | None]:
    """The range a servo can reach (radians, metres for a slide): its joint's ``range`` (the mechanical stop,
    which MuJoCo enforces) intersected with its position actuator's ``ctrlrange`` (the software limit on the
    targets, which MuJoCo clamps to), and how the ctrlrange changed it: None (no ctrlrange, or equal within
    :data:`RANGE_TOL_DEG`), ``"narrower"`` (the servo range is the intersection) or ``"wider"`` (clamped to
    the joint range). An actuator without a ctrlrange (``ctrllimited`` off) leaves the joint range.

    :class:`RobotDataError` (``joint_at``/``actuator_at``: their file:line) when the joint has no range
    (there is no default: a made-up limit would let the LLM drive the joint where the model says it cannot
    go), when a range given is NaN, infinite, inverted or empty (MuJoCo compiles those as *no* limit), or
    when the ctrlrange lies wholly outside the joint range (no target could be reached)."""
    import mujoco

    slide = int(model.jnt_type[jid]) == int(mujoco.mjtJoint.mjJNT_SLIDE)
    jname, aname = model.joint(jid).name, model.actuator(aid).name
    lo, hi = (float(v) for v in model.jnt_range[jid])
    clo, chi = (float(v) for v in model.actuator_ctrlrange[aid])
    climited = bool(model.actuator_ctrllimited[aid])
    if not model.jnt_limited[jid] or not lo < hi or not (math.isfinite(lo) and math.isfinite(hi)):
        why = _bad_pair(lo, hi) if (lo, hi) != (0.0, 0.0) else None
        if why is not None:
            raise RobotDataError(f"{joint_at}: joint {jname!r} range {lo:g} {hi:g} {why}; give range=\"lo hi\" "
                                 "with lo < hi")
        hint = (f"; its actuator {aname!r} has ctrlrange {clo:g} {chi:g}, so range=\"{clo:g} {chi:g}\" would do"
                if climited else "")
        raise RobotDataError(f"{joint_at}: joint {jname!r} (driven by actuator {aname!r}) has no range; give it "
                             f"range=\"lo hi\", its mechanical stops (the servo table's limits come from it){hint}")
    if not climited:
        if (clo, chi) != (0.0, 0.0):  # given, but MuJoCo compiled it as no limit
            why = _bad_pair(clo, chi) or "was not applied"
            raise RobotDataError(f"{actuator_at}: actuator {aname!r} ctrlrange {clo:g} {chi:g} {why}; give "
                                 "ctrlrange=\"lo hi\" with lo < hi, or leave it out (the joint range is used)")
        return lo, hi, None
    if math.isnan(clo) or math.isnan(chi) or not clo < chi:
        why = _bad_pair(clo, chi) or "is not a range"
        raise RobotDataError(f"{actuator_at}: actuator {aname!r} ctrlrange {clo:g} {chi:g} {why}")
    slo, shi = max(lo, clo), min(hi, chi)
    if not slo < shi:
        raise RobotDataError(f"{actuator_at}: actuator {aname!r} ctrlrange {_span(clo, chi, slide)} lies outside joint "
                             f"{jname!r}'s range {_span(lo, hi, slide)} ({joint_at}): no target could be reached; "
                             "make them overlap")
    tol = math.radians(RANGE_TOL_DEG)
    if slo > lo + tol or shi < hi - tol:
        return slo, shi, "narrower"
    if clo < lo - tol or chi > hi + tol:
        return lo, hi, "wider"
    return lo, hi, None


def range_notes(changed: Sequence[tuple[str, str, float, float, float, float, float, float, bool]]) -> list[str]:
    """At most two notes (one a kind) on servo ranges a ctrlrange changed: ``changed`` holds
    ``(how, joint, servo lo, servo hi, joint lo, joint hi, ctrl lo, ctrl hi, slide)`` as :func:`servo_range`
    found them (radians / metres)."""
    notes = []
    narrower = [c for c in changed if c[0] == "narrower"]
    wider = [c for c in changed if c[0] == "wider"]
    if narrower:
        items = ", ".join(f"{j} {_span(a, b, sl)} (joint {_span(jl, jh, sl)}"
                          + (f", ctrlrange {_span(cl, ch, sl)})" if not _same(a, b, cl, ch) else ")")
                          for _, j, a, b, jl, jh, cl, ch, sl in narrower)
        notes.append(f"ctrlrange narrower than the joint range on {len(narrower)} servo(s), so the servo range is the "
                     f"intersection: {items}")
    if wider:
        items = ", ".join(f"{j} {_span(a, b, sl)} (ctrlrange {_span(cl, ch, sl)})"
                          for _, j, a, b, _jl, _jh, cl, ch, sl in wider)
        radians = any(not sl and max(abs(cl), abs(ch)) > 2 * math.pi + 1e-9 for *_, cl, ch, sl in wider)
        hint = "; MuJoCo reads a hinge's ctrlrange in radians, even with angle=\"degree\"" if radians else ""
        notes.append(f"ctrlrange wider than the joint range on {len(wider)} servo(s), so the servo range is the joint "
                     f"range: {items}{hint}")
    return notes


#: attributes that name things (a body may be called "nan"); every other attribute is numbers or a keyword
_NAME_ATTRS = frozenset({"name", "class", "childclass", "joint", "joint1", "joint2", "body", "body1", "body2", "site",
                         "site1", "site2", "tendon", "tendon1", "tendon2", "mesh", "material", "texture", "hfield",
                         "file", "target", "objname", "actuator", "geom", "geom1", "geom2", "prefix", "model",
                         "camera", "key", "refname", "slidersite", "cranksite", "flex", "skin"})


def check_no_nan(index: Any) -> None:
    """A number attribute holding NaN (MuJoCo compiles it, printing a warning line of its own, and a NaN range
    as no range): :class:`RobotDataError` at its file:line. ``index``: the MJCF's
    :class:`robots.mjcf_index.MjcfIndex`."""
    for el in index:
        for key, value in el.attrs.items():
            if key in _NAME_ATTRS:
                continue
            tokens = value.replace(",", " ").split()
            try:
                numbers = [float(t) for t in tokens]
            except ValueError:
                continue  # a keyword ("true", "degree", ...), not numbers
            if any(math.isnan(v) for v in numbers):
                what = f"{el.tag} {el.attrs['name']!r}" if el.attrs.get("name") else f"<{el.tag}>"
                raise RobotDataError(f"{el.where}: {what} {key}=\"{value}\" holds NaN; give numbers")


def compile_error(mjcf: Path, error: Exception, index: Any = None) -> RobotDataError:
    """MuJoCo's compile error as one line, at the element's file:line where it can be found (MuJoCo names
    the element and a line, but the line of an included file's element comes as 0)."""
    text = " ".join(str(error).split())
    where = str(mjcf)
    m = re.search(r"Element name '([^']+)'", text)
    if m and index is not None:
        named = [e for e in index if e.attrs.get("name") == m.group(1)]
        # a joint and its actuator often share a name: the one whose kind the message names
        said = set(re.findall(r"[a-z]+", text[:m.start()]))
        kind = [e for e in named if {e.tag, e.parent} & said] if len(named) > 1 else named
        if kind:
            where = kind[0].where
    if where == str(mjcf):
        m = re.search(r"line (\d+)", text)
        if m and int(m.group(1)) > 0:
            where = f"{mjcf}:{m.group(1)}"
    return RobotDataError(f"{where}: MuJoCo cannot compile it: {text}")


def mjcf_servo_ranges(mjcf: Path, table: ServoTable, model: Any = None, index: Any = None
                      ) -> list[tuple[float, float, str | None]]:
    """:func:`servo_range` of every servo of ``table`` in ``mjcf`` (compiled unless ``model`` is given)."""
    import mujoco

    from robots.mjcf_index import index_mjcf

    index = index_mjcf(mjcf) if index is None else index
    if model is None:
        try:
            model = mujoco.MjModel.from_xml_path(str(mjcf))
        except (ValueError, OSError) as e:
            raise compile_error(mjcf, e, index) from None
    actuators = {e.attrs.get("name"): e for e in index.children_of("actuator")}
    out = []
    for s in table:
        jel, ael = index.named("joint", s.joint), actuators.get(s.actuator)
        out.append(servo_range(model, model.actuator(s.actuator).id, model.joint(s.joint).id,
                               joint_at=jel.where if jel is not None else str(mjcf),
                               actuator_at=ael.where if ael is not None else str(mjcf)))
    return out


def mjcf_notes(robot: Any) -> list[str]:
    """Notes on a loaded robot's servo ranges against its MJCF (what ``ghostshell robots check`` prints):
    ctrlranges narrower or wider than the joint ranges, and a servo table that keeps the joint range where
    the ctrlrange is narrower (targets beyond the ctrlrange are not reached)."""
    import mujoco

    model = mujoco.MjModel.from_xml_path(str(robot.mjcf))
    changed = []
    table_wide = []
    for s, (lo, hi, how) in zip(robot.servos, mjcf_servo_ranges(robot.mjcf, robot.servos, model)):
        jid, aid = model.joint(s.joint).id, model.actuator(s.actuator).id
        slide = int(model.jnt_type[jid]) == int(mujoco.mjtJoint.mjJNT_SLIDE)
        jl, jh = (float(v) for v in model.jnt_range[jid])
        cl, ch = (float(v) for v in model.actuator_ctrlrange[aid])
        if how is not None:
            changed.append((how, s.joint, lo, hi, jl, jh, cl, ch, slide))
        if how == "narrower" and not _same(s.min, s.max, lo, hi):
            table_wide.append(f"{s.name} {_span(s.min, s.max, slide)} (reachable {_span(lo, hi, slide)})")
    notes = range_notes(changed)
    if table_wide:
        notes.append("the servo table keeps the joint range where the ctrlrange is narrower, so targets beyond the "
                     f"ctrlrange are not reached: {', '.join(table_wide)}; set min_deg/max_deg to the reachable range")
    return notes


def _same(a_lo: float, a_hi: float, b_lo: float, b_hi: float) -> bool:
    return abs(math.degrees(a_lo - b_lo)) <= RANGE_TOL_DEG and abs(math.degrees(a_hi - b_hi)) <= RANGE_TOL_DEG


def check_against_mjcf(mjcf: Path, table: ServoTable, servo_path: Path, servo_text: str,
                       camera: str | None = None, feet: Sequence[str] = (), *, camera_at: str | None = None,
                       feet_at: str | None = None) -> list[str]:
    """Compile ``mjcf`` and check the servo table (and camera, foot sites) against it; returns the notes a
    load prints: servos whose table keeps the joint range where the actuator's ctrlrange is narrower (their
    targets beyond the ctrlrange are not reached).

    ``camera_at``/``feet_at``: where robot.toml names them (file:line), for the messages. MJCF places
    come from :func:`robots.mjcf_index.index_mjcf` (includes followed)."""
    from robots.mjcf_index import index_mjcf

    import mujoco

    index = index_mjcf(mjcf)
    check_no_nan(index)
    try:
        model = mujoco.MjModel.from_xml_path(str(mjcf))
    except (ValueError, OSError) as e:
        raise compile_error(mjcf, e, index) from None
    actuators = {e.attrs.get("name"): e for e in index.children_of("actuator")}
    unreached: list[str] = []
    hinge_slide = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    for s in table:
        where = _at(servo_path, _line(servo_text, r"^\[\[servo\]\]", s.id - 1))
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, s.joint)
        if jid < 0:
            raise RobotDataError(f"{where}: servo {s.name}: joint {s.joint!r} is not in {mjcf.name}")
        jel = index.named("joint", s.joint)
        jline = jel.where if jel is not None else str(mjcf)
        if int(model.jnt_type[jid]) not in hinge_slide:
            raise RobotDataError(f"{jline}: joint {s.joint!r} (servo {s.name}) must be a hinge or slide joint")
        aid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, s.actuator)
        if aid < 0:
            raise RobotDataError(f"{where}: servo {s.name}: actuator {s.actuator!r} is not in {mjcf.name}")
        ael = actuators.get(s.actuator)
        aline = ael.where if ael is not None else str(mjcf)
        if int(model.actuator_trntype[aid]) != int(mujoco.mjtTrn.mjTRN_JOINT) or int(model.actuator_trnid[aid, 0]) != jid:
            raise RobotDataError(f"{aline}: actuator {s.actuator!r} does not drive joint {s.joint!r} (servo {s.name})")
        if position_kp(model, aid) is None:
            raise RobotDataError(f"{aline}: actuator {s.actuator!r} (servo {s.name}) is not a position actuator "
                                 "(use <position kp=...>)")
        lo, hi, how = servo_range(model, aid, jid, joint_at=jline, actuator_at=aline)
        jlo, jhi = (float(v) for v in model.jnt_range[jid])
        if how == "narrower" and not _same(s.min, s.max, lo, hi):
            unreached.append(f"{s.name} [{math.degrees(s.min):.4g}, {math.degrees(s.max):.4g}] (reachable "
                             f"[{math.degrees(lo):.4g}, {math.degrees(hi):.4g}])")
        # the reachable range (joint range, narrowed by a narrower ctrlrange), or the joint range itself
        # (a table written before ctrlranges were taken into account: `robots check` notes it)
        if not _same(s.min, s.max, lo, hi) and not _same(s.min, s.max, jlo, jhi):
            said = f"{where}: servo {s.name}: the table says [{math.degrees(s.min):.2f}, {math.degrees(s.max):.2f}] deg"
            if how == "narrower":
                raise RobotDataError(
                    f"{said} but it reaches [{math.degrees(lo):.2f}, {math.degrees(hi):.2f}] deg: {jline} joint "
                    f"{s.joint!r}'s range [{math.degrees(jlo):.2f}, {math.degrees(jhi):.2f}] deg within {aline} actuator "
                    f"{s.actuator!r}'s ctrlrange")
            raise RobotDataError(f"{said} but {jline} joint {s.joint!r} has range [{math.degrees(jlo):.2f}, "
                                 f"{math.degrees(jhi):.2f}] deg")
    if camera is not None and mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0:
        raise RobotDataError(f"{camera_at or 'robot.toml [peripherals]'}: camera = {camera!r}: {mjcf.name} has no "
                             "camera of that name")
    for site in feet:
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, site) < 0:
            raise RobotDataError(f"{feet_at or 'robot.toml [base]'}: feet names site {site!r}, which {mjcf.name} "
                                 "does not have")
    if not unreached:
        return []
    return [f"{servo_path}: the servo table keeps the joint range where the actuator's ctrlrange is narrower, so "
            f"targets beyond the ctrlrange are not reached: {', '.join(unreached)} deg; set min_deg/max_deg to the "
            "reachable range"]


# --- meshes ---------------------------------------------------------------------------------------


def mesh_files(mjcf: Path, index: Any = None) -> list[tuple[Any, Path]]:
    """``(element, path)`` of every ``<mesh file=...>`` of ``mjcf`` (includes followed; ``index``: its
    :class:`robots.mjcf_index.MjcfIndex` if read already), the path resolved as MuJoCo does (module docstring)."""
    from robots.mjcf_index import index_mjcf

    index = index_mjcf(mjcf) if index is None else index
    compiler: dict[str, str] = {}
    for el in index:
        if el.tag == "compiler":
            compiler.update(el.attrs)
    strip = compiler.get("strippath", "false").lower() == "true"
    meshdir = Path(compiler.get("meshdir", compiler.get("assetdir", "")))
    base = Path(index.main).parent
    out = []
    for el in index:
        name = el.attrs.get("file") if el.tag == "mesh" and el.parent != "default" else None
        if not name:
            continue
        p = Path(name)
        if strip:
            p = Path(p.name)
        out.append((el, p if p.is_absolute() else (meshdir if meshdir.is_absolute() else base / meshdir) / p))
    return out


def _mesh_problem(path: Path, size: int) -> str | None:
    """Why ``path`` (``size`` bytes) is not a mesh MuJoCo reads, or None (formats: module docstring)."""
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        return (f"{suffix or 'a file without a suffix'} is not a mesh format MuJoCo reads; give "
                f"{', '.join(MESH_SUFFIXES)} (convert it, e.g. with trimesh or Blender)")
    try:
        with open(path, "rb") as f:
            head = f.read(64 * 1024)
    except OSError as e:
        return f"cannot read it ({e.strerror or e})"
    if head.startswith(b"version https://git-lfs"):
        return "a Git LFS pointer, not the mesh (fetch it: git lfs pull)"
    if suffix == ".stl":
        n = int.from_bytes(head[80:84], "little") if size >= 84 else -1
        if 84 + 50 * n == size:
            if 1 <= n <= MAX_STL_TRIANGLES:
                return None
            return (f"a binary STL of {n} triangles; MuJoCo reads 1 to {MAX_STL_TRIANGLES} from an STL "
                    "(decimate it, or split it into several meshes)")
        if head.lstrip().lower().startswith(b"solid") and (b"facet" in head or b"endsolid" in head):
            return "an ASCII STL; MuJoCo reads binary STL only (convert it, e.g. with trimesh or Blender)"
        return "not an STL file (a binary STL is 84 + 50 bytes per triangle)"
    if suffix == ".obj":
        if b"\0" not in head and re.search(rb"(?m)^\s*v\s", head):
            return None
        return "not an OBJ file (no 'v x y z' vertex lines in its text)"
    counts = [int.from_bytes(head[i:i + 4], "little", signed=True) for i in range(0, 16, 4)] if size >= 16 else []
    if len(counts) == 4 and min(counts) >= 0 and 16 + 12 * (counts[0] + counts[1] + counts[3]) + 8 * counts[2] == size:
        return None
    return "not a MuJoCo MSH file (its four counts do not give its size)"


def check_meshes(mjcf: Path, index: Any = None) -> None:
    """Every mesh file of ``mjcf`` exists, is STL/OBJ/MSH and within the byte caps (module docstring);
    else :class:`RobotDataError`: one line naming the ``<mesh>`` (file:line) and the file."""
    total = 0
    sizes: dict[Path, int] = {}
    for el, path in mesh_files(mjcf, index):
        where = f"{el.where}: mesh {el.attrs.get('name') or path.stem!r} file {path}"
        try:
            st = path.stat()
        except OSError:
            raise RobotDataError(f"{where}: no such file") from None
        if not path.is_file():
            raise RobotDataError(f"{where}: not a file")
        if st.st_size > MAX_MESH_FILE_BYTES:
            raise RobotDataError(f"{where}: {st.st_size / 2**20:.1f} MiB, over the {MAX_MESH_FILE_BYTES >> 20} MiB a "
                                 "mesh file may have; decimate it (e.g. Blender's Decimate, trimesh's "
                                 "simplify_quadric_decimation)")
        problem = _mesh_problem(path, st.st_size)
        if problem is not None:
            raise RobotDataError(f"{where}: {problem}")
        if path.resolve() not in sizes:
            sizes[path.resolve()] = st.st_size
            total += st.st_size
    if total > MAX_MESH_TOTAL_BYTES:
        big = sorted(sizes.items(), key=lambda kv: -kv[1])[:3]
        raise RobotDataError(f"{mjcf}: its {len(sizes)} mesh files hold {total / 2**20:.1f} MiB, over the "
                             f"{MAX_MESH_TOTAL_BYTES >> 20} MiB a robot may have (largest: "
                             f"{', '.join(f'{p.name} {n / 2**20:.1f} MiB' for p, n in big)}); decimate them")


# --- robot.toml -----------------------------------------------------------------------------------


def _names(v: Any, what: str, where: str) -> tuple[str, ...]:
    if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
        raise RobotDataError(f"{where}: {what} must be a list of names")
    return tuple(v)


def _file(root: Path, doc: Mapping[str, Any], key: str, path: Path, text: str, *,
          required: bool = True) -> Path | None:
    v = doc.get(key)
    if v is None:
        if required:
            raise RobotDataError(f"{path}: {key} = \"FILE\" is missing")
        return None
    where = _at(path, _line(text, "^" + key + r"\s*="))
    p = root / _str(v, key, where)
    if not p.is_file():
        raise RobotDataError(f"{where}: {key} = {v!r}: no such file in {root}")
    return p


def _scenes(doc: Mapping[str, Any], path: Path, text: str) -> dict[str, SceneSpec]:
    scenes: dict[str, SceneSpec] = {"empty": SceneSpec("empty", "the robot alone")}
    raw = doc.get("scenes", {})
    if not isinstance(raw, dict):
        raise RobotDataError(f"{path}: [scenes] must be a table")
    for name, sc in raw.items():
        where = _at(path, _line(text, rf"^\[scenes\.{re.escape(name)}\]"))
        if not isinstance(sc, dict):
            raise RobotDataError(f"{where}: scene {name!r} must be a table")
        objects = []
        for k, o in enumerate(sc.get("objects", [])):
            owhere = _at(path, _line(text, rf"^\[\[scenes\.{re.escape(name)}\.objects\]\]", k))
            try:
                shape = str(o["shape"])
                size = tuple(_num(v, "size", owhere) for v in o["size"])
                pos = tuple(_num(v, "pos", owhere) for v in o["pos"])
                obj = SceneObjectSpec(
                    name=_str(o["name"], "name", owhere), shape=shape, size=size, pos=pos,  # type: ignore[arg-type]
                    rgba=tuple(_num(v, "rgba", owhere) for v in o.get("rgba", (0.6, 0.6, 0.6, 1.0))),  # type: ignore[arg-type]
                    mass=None if o.get("mass") is None else _num(o["mass"], "mass", owhere),
                    free=bool(o.get("free", True)),
                    friction=tuple(_num(v, "friction", owhere) for v in o.get("friction", (1.0, 0.005, 0.0001))),  # type: ignore[arg-type]
                    topples=bool(o.get("topples", False)),
                    euler_deg=tuple(_num(v, "euler_deg", owhere) for v in o.get("euler_deg", (0.0, 0.0, 0.0))),  # type: ignore[arg-type]
                )
            except (KeyError, TypeError) as e:
                raise RobotDataError(f"{owhere}: scene object needs name, shape, size and pos ({e})") from None
            if shape not in SHAPES or len(obj.size) != SHAPES[shape] or len(obj.pos) != 3 or min(obj.size) <= 0:
                raise RobotDataError(f"{owhere}: object {obj.name!r}: shape must be one of {', '.join(SHAPES)} with "
                                     "positive size values (box: 3 half sizes, cylinder: radius and half height, "
                                     "sphere: radius) and pos = [x, y, z]")
            if len(obj.rgba) != 4 or len(obj.friction) != 3 or len(obj.euler_deg) != 3:
                raise RobotDataError(f"{owhere}: object {obj.name!r}: rgba needs 4 values, friction 3, euler_deg 3")
            objects.append(obj)
        scenes[name] = SceneSpec(name, str(sc.get("doc", "")), tuple(objects))
    return scenes


def _tour(doc: Mapping[str, Any], poses: Mapping[str, Any], path: Path, text: str) -> tuple[str, ...]:
    where = _at(path, _line(text, r"^tour\s*="))
    names = _names(doc.get("tour", []), "tour", where)
    for n in names:
        if n not in poses:
            raise RobotDataError(f"{where}: tour names pose {n!r}, which is not a pose ({', '.join(poses)})")
    return names


def load_robot_dir(root: Path, *, builtin: bool = False, check_mjcf: bool = True, fresh: bool = False,
                   show_notes: bool = True) -> Robot:
    """Read the robot in folder ``root`` (its ``robot.toml``); :class:`RobotDataError` says what and where.
    ``fresh``: check it against its MJCF even when a pass is recorded (``ghostshell robots check``).
    ``show_notes``: print the check's notes (:func:`check_against_mjcf`) on stderr, ``note: robot NAME: ...``;
    only a load that runs the check has any, so a package says them once, not on every command.

    A value of the wrong TOML type that no check names (``base = 3``, ``voices = 7``) is a
    :class:`RobotDataError` naming robot.toml too, never a traceback."""
    try:
        return _load_robot_dir(Path(root).resolve(), builtin=builtin, check_mjcf=check_mjcf, fresh=fresh,
                               show_notes=show_notes)
    except RobotDataError:
        raise
    except (TypeError, AttributeError, KeyError, IndexError, ValueError) as e:
        raise RobotDataError(f"{Path(root).resolve() / ROBOT_FILE}: a value has the wrong type or shape "
                             f"({type(e).__name__}: {e}); robots/loader.py documents every key") from None


#: notes a load printed in this process (a robot loaded again with the check cache off says them once)
_NOTED: set[str] = set()


def _load_robot_dir(root: Path, *, builtin: bool, check_mjcf: bool, fresh: bool = False,
                    show_notes: bool = True) -> Robot:
    path = root / ROBOT_FILE
    doc, text = _read_toml(path)
    name = doc.get("name")
    if not isinstance(name, str) or not NAME_RE.match(name):
        where = _at(path, _line(text, r"^name\s*="))
        raise RobotDataError(f"{where}: name must match [a-z][a-z0-9_]* (at most 32 characters), got {name!r}")
    mjcf = _file(root, doc, "mjcf", path, text)
    servo_path = _file(root, doc, "servo_table", path, text)
    poses_path = _file(root, doc, "poses", path, text)
    assert mjcf and servo_path and poses_path
    table = read_servo_table(servo_path)
    poses = read_poses(poses_path, table)
    for key, default in (("start_pose", None), ("rest_pose", None), ("safe_pose", None)):
        pose = doc.get(key, default)
        if pose not in poses:
            where = _at(path, _line(text, "^" + key + r"\s*="))
            raise RobotDataError(f"{where}: {key} = {pose!r} is not a pose in {poses_path.name} "
                                 f"(poses: {', '.join(poses)})")
    base_doc = doc.get("base", {})
    base_at = {k: _at(path, _line(text, rf"^{k}\s*=") or _line(text, r"^\[base\]"))
               for k in ("feet", "foot_radius", "spawn_height")}
    base = Base(floating=bool(base_doc.get("floating", False)),
                feet=_names(base_doc.get("feet", []), "feet", base_at["feet"]),
                foot_radius=_num(base_doc.get("foot_radius", 0.0), "foot_radius", base_at["foot_radius"]),
                spawn_height=_num(base_doc.get("spawn_height", 0.2), "spawn_height", base_at["spawn_height"]))
    channels: dict[str, Channel] = {}
    owner: dict[int, str] = {}
    for cname, c in (doc.get("channels") or {}).items():
        where = _at(path, _line(text, rf"^\[channels\.{re.escape(cname)}\]"))
        idx = []
        for sname in _names(c.get("servos", []), f"channel {cname} servos", where):
            try:
                i = table.by_name(sname).index
            except KeyError as e:
                raise RobotDataError(f"{where}: channel {cname!r}: {e.args[0]}") from None
            if i in owner:
                raise RobotDataError(f"{where}: servo {sname!r} is in channels {owner[i]!r} and {cname!r}")
            owner[i] = cname
            idx.append(i)
        channels[cname] = Channel(cname, tuple(sorted(idx)), str(c.get("doc", "")))
    per = doc.get("peripherals", {})
    peripherals = Peripherals(
        camera=per.get("camera"), camera_label=str(per.get("camera_label", "camera")),
        screen=bool(per.get("screen", False)), speaker=bool(per.get("speaker", False)),
        voices=tuple(per.get("voices", ("robot",))),
        clips=None if per.get("clips") is None else tuple(per["clips"]))
    scenes = _scenes(doc, path, text)
    default_scene = str(doc.get("default_scene", "empty"))
    if default_scene not in scenes:
        where = _at(path, _line(text, r"^default_scene\s*="))
        raise RobotDataError(f"{where}: default_scene {default_scene!r} is not a scene ({', '.join(scenes)})")
    for key in ("interface", "behaviours"):
        mod = doc.get(key)
        if mod is not None and not (root / f"{mod}.py").is_file():
            where = _at(path, _line(text, "^" + key + r"\s*="))
            raise RobotDataError(f"{where}: {key} = {mod!r}: no {mod}.py in {root}")
    data = {k: root / str(v) for k, v in (doc.get("data") or {}).items()}
    view = {str(k): _num(v, f"view {k}", str(path)) for k, v in (doc.get("view") or {}).items()}
    inputs = (table, peripherals.camera, tuple(base.feet))
    if check_mjcf and (fresh or not mjcf_check_cache.passed(mjcf, inputs)):  # a pass is recorded: MuJoCo is not imported again
        before = mjcf_check_cache.snapshot(mjcf)
        check_meshes(mjcf)  # before MuJoCo reads them: a missing, huge or foreign mesh is one line
        notes = check_against_mjcf(mjcf, table, servo_path, servo_path.read_text(encoding="utf-8"),
                                   peripherals.camera, base.feet, camera_at=_at(path, _line(text, r"^camera\s*=")),
                                   feet_at=base_at["feet"]) or []
        mjcf_check_cache.record(mjcf, inputs, before)
        for note in notes if show_notes else ():  # once: the next load finds the pass recorded and checks nothing
            if note not in _NOTED:
                _NOTED.add(note)
                print(f"note: robot {name}: {note}", file=sys.stderr)
    return Robot(
        name=name, title=str(doc.get("title", name)), description=str(doc.get("description", "")), root=root,
        mjcf=mjcf, servos=table, poses=poses, channels=channels, peripherals=peripherals, scenes=scenes,
        default_scene=default_scene, base=base, start_pose=str(doc["start_pose"]), rest_pose=str(doc["rest_pose"]),
        safe_pose=str(doc["safe_pose"]), tasks_path=_file(root, doc, "tasks", path, text, required=False),
        behaviours_module=doc.get("behaviours"), interface_module=doc.get("interface"),
        default_vocabulary=str(doc.get("default_vocabulary", "default")),
        demo_task_id=None if doc.get("demo_task") is None else int(doc["demo_task"]),
        tour_poses=_tour(doc, poses, path, text),
        data=data, view=view, builtin=builtin,
        sources={"robot": path, "servo_table": servo_path, "poses": poses_path, "mjcf": mjcf},
    )
