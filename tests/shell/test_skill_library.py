"""The persistent skill library: file location, names with spaces and non-ASCII, replacement, bad files."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from host.shell.skills import MAX_NAME, SkillError, SkillStore, default_skills_path, skills_path

pytestmark = pytest.mark.anyio


def test_path_resolution_order(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("GHOSTSHELL_SKILLS", str(tmp_path / "env.json"))
    assert skills_path(tmp_path / "arg.json") == tmp_path / "arg.json"
    assert skills_path(None) == tmp_path / "env.json"
    monkeypatch.delenv("GHOSTSHELL_SKILLS")
    assert skills_path(None) == default_skills_path()
    assert default_skills_path().name == "skills.json" and "ghostshell" in str(default_skills_path())


async def test_unicode_names_replace_and_persist(coco, tmp_path: Path) -> None:
    path = tmp_path / "lib" / "skills.json"
    shell, _ = coco(skills=SkillStore(path))
    name = "morning routine ☀ 早安"
    r = await shell.run_text(f'<SAVE name="{name}" description="wake up"><wave/></SAVE>')
    assert any(o.message == f"skill {name!r} saved" for o in r.observations)
    r = await shell.run_text(f'<SAVE name="{name}"><head_act action="nod"/><wave/></SAVE>')
    assert any("replaced" in o.message for o in r.observations), r.observation_text()
    doc = json.loads(path.read_text(encoding="utf-8"))
    assert list(doc) == [name] and "head_act" in doc[name]["program"]
    # a fresh store (a later run) sees it, and a skill may RUN it
    shell2, impl = coco(skills=SkillStore(path))
    r = await shell2.run_text(f'<SAVE name="twice"><RUN id="{name}"/><RUN id="{name}"/></SAVE><RUN id="twice"/>')
    assert [x.function for x in r.timeline if x.function != "RUN"] == ["head_act", "wave", "head_act", "wave"]
    assert all(x.outcome == "done" for x in r.timeline), r.timeline.table()


async def test_recursion_and_bad_names_are_refused(coco, tmp_path: Path) -> None:
    shell, _ = coco(skills=SkillStore(tmp_path / "s.json"))
    await shell.run_text('<SAVE name="a"><wave/></SAVE><SAVE name="b"><RUN id="a"/></SAVE>')
    r = await shell.run_text('<SAVE name="a"><RUN id="b"/></SAVE>')  # a -> b -> a
    assert any("recursive" in o.message for o in r.observations)
    r = await shell.run_text(f'<SAVE name="{"x" * (MAX_NAME + 1)}"><wave/></SAVE>')
    assert any(f"at most {MAX_NAME}" in o.message for o in r.observations)
    assert [s.name for s in shell.skills.list()] == ["a", "b"]


def test_a_broken_library_file_is_a_clear_error_and_left_untouched(tmp_path: Path) -> None:
    path = tmp_path / "skills.json"
    path.write_text("{not json", encoding="utf-8")
    with pytest.raises(SkillError, match="cannot read the skill library"):
        SkillStore(path)
    assert path.read_text(encoding="utf-8") == "{not json"
