"""Skill memory: programs saved with ``<SAVE>`` and replayed with ``<RUN id=.../>``.

The skill library persists across runs in a JSON file: ``--skills FILE``, else
the ``GHOSTSHELL_SKILLS`` environment variable, else ``skills.json`` in the
user's data directory (platformdirs: ``~/.local/share/ghostshell`` on Linux);
see :func:`skills_path`. Names may hold spaces and any Unicode (at most
:data:`MAX_NAME` characters); a SAVE with an existing name replaces that skill.

A skill is the original function-token text of the program enclosed by
``<SAVE name="..." description="...">...</SAVE>`` (reconstructed from parser
events, so it is well-formed). The store is a JSON object
``{name: {"description": str, "program": str}}`` written atomically after each
change when a path is given. Recursion (a skill that, directly or through other
skills, RUNs itself) is refused at SAVE time and, defensively, at RUN time.
"""

from __future__ import annotations

import builtins
import json
import os
import re
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path
from xml.sax.saxutils import escape, quoteattr

from host.bounded_read import MAX_SKILLS, read_capped

#: longest skill name (characters)
MAX_NAME = 100
#: environment variable naming the skill library file
ENV = "GHOSTSHELL_SKILLS"

_RUN_RE = re.compile(r"<RUN\b[^>]*?\bid\s*=\s*(\"[^\"]*\"|'[^']*')")


class SkillError(ValueError):
    """An invalid SAVE or RUN (missing name, unknown skill, recursion) or an unreadable library file."""


def default_skills_path() -> Path:
    """``skills.json`` in the user's data directory (platformdirs)."""
    import platformdirs

    return Path(platformdirs.user_data_dir("ghostshell", appauthor=False)) / "skills.json"


def skills_path(arg: str | Path | None = None) -> Path:
    """The library file: ``arg``, else ``$GHOSTSHELL_SKILLS``, else :func:`default_skills_path`."""
    if arg:
        return Path(arg).expanduser()
    env = os.environ.get(ENV)
    return Path(env).expanduser() if env else default_skills_path()


@dataclass(frozen=True)
class Skill:
    """A saved program."""

    name: str
    description: str
    program: str


def run_ids(program: str) -> list[str]:
    """The ids of the ``<RUN id=.../>`` elements in ``program`` (reconstructed text)."""
    out = []
    for m in _RUN_RE.finditer(program):
        raw = m.group(1)[1:-1]
        out.append(raw.replace("&quot;", '"').replace("&apos;", "'").replace("&lt;", "<").replace("&gt;", ">").replace("&amp;", "&"))
    return out


class SkillStore:
    """Named skills, optionally persisted to a JSON file."""

    def __init__(self, path: str | Path | None = None) -> None:
        self.path = Path(path) if path is not None else None
        self._skills: dict[str, Skill] = {}
        if self.path is not None and self.path.exists():
            try:
                data = json.loads(read_capped(self.path, MAX_SKILLS).decode("utf-8") or "{}")
                if not isinstance(data, dict):
                    raise ValueError("not a JSON object")
                for name, d in data.items():
                    self._skills[name] = Skill(name, str(d.get("description", "")), str(d["program"]))
            except IsADirectoryError:
                raise SkillError(f"cannot read the skill library {self.path}: it is a folder; give a skill "
                                 "library file (JSON), e.g. skills.json in it") from None
            except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
                raise SkillError(f"cannot read the skill library {self.path}: {exc} (fix or move the file; "
                                 "it was left untouched)") from None

    def __contains__(self, name: object) -> bool:
        return name in self._skills

    def __len__(self) -> int:
        return len(self._skills)

    def get(self, name: str) -> Skill:
        """The skill called ``name``; :class:`SkillError` if there is none."""
        try:
            return self._skills[name]
        except KeyError:
            known = ", ".join(sorted(self._skills)) or "none saved"
            raise SkillError(f"unknown skill {name!r} (skills: {known})") from None

    def list(self) -> list[Skill]:
        """All skills in save order."""
        return list(self._skills.values())

    def save(self, name: str, description: str, program: str) -> Skill:
        """Save (or replace) a skill; refuses one that would RUN itself."""
        if not name.strip():
            raise SkillError("<SAVE> needs a non-empty name attribute")
        if len(name) > MAX_NAME:
            raise SkillError(f"skill name is {len(name)} characters long; at most {MAX_NAME}")
        if not program.strip():
            raise SkillError(f"<SAVE name={name!r}> encloses an empty program")
        chain = self._reaches(name, program)
        if chain is not None:
            raise SkillError(f"skill {name!r} would be recursive: {' -> '.join([name, *chain])}")
        skill = Skill(name, description, program)
        self._skills[name] = skill
        self._write()
        return skill

    def delete(self, name: str) -> None:
        """Forget the skill called ``name``."""
        self.get(name)
        del self._skills[name]
        self._write()

    def _reaches(self, target: str, program: str) -> builtins.list[str] | None:
        """A RUN chain from ``program`` back to ``target``, or None."""
        seen: set[str] = set()

        def walk(prog: str) -> list[str] | None:
            for rid in run_ids(prog):
                if rid == target:
                    return [rid]
                if rid in seen or rid not in self._skills:
                    continue
                seen.add(rid)
                sub = walk(self._skills[rid].program)
                if sub is not None:
                    return [rid, *sub]
            return None

        return walk(program)

    def _write(self) -> None:
        if self.path is None:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        data = {s.name: {k: v for k, v in asdict(s).items() if k != "name"} for s in self._skills.values()}
        fd, tmp = tempfile.mkstemp(dir=self.path.parent, prefix=".skills-", suffix=".json")
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump(data, f, ensure_ascii=False, indent=1)
        os.replace(tmp, self.path)


def start_tag(name: str, attrs: dict[str, str], empty: bool = False) -> str:
    """Reconstruct a start (or empty-element) tag from a parser event."""
    a = "".join(f" {k}={quoteattr(v)}" for k, v in attrs.items())
    return f"<{name}{a}{'/' if empty else ''}>"


def end_tag(name: str) -> str:
    """Reconstruct an end tag."""
    return f"</{name}>"


def text(data: str) -> str:
    """Reconstruct character data (``<``, ``&``, ``>`` escaped)."""
    return escape(data)
