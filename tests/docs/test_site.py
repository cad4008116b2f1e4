"""The documentation site builds with ``mkdocs build --strict`` (mkdocs-material, offline), and the
short README keeps its promises (issue 20 item 5).

Strict: any warning fails the build, so a broken link or anchor between pages, a page missing from
the nav, or a missing snippet (``DEVELOPERS.md`` is included, not copied) fails this test. The build
goes to a temporary folder and needs no network (no plugin that fetches; ``theme.font: false``).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: the README a newcomer reads
README = ROOT / "README.md"


def test_mkdocs_build_strict(tmp_path: Path) -> None:
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}  # mkdocs-material's end-of-life banner, not a build warning
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(ROOT / "mkdocs.yml"),
                        "--site-dir", str(tmp_path / "site")], cwd=ROOT, env=env, capture_output=True, text=True,
                       timeout=240)
    assert r.returncode == 0, f"mkdocs build --strict failed:\n{r.stdout[-3000:]}\n{r.stderr[-6000:]}"
    site = tmp_path / "site"
    for page in ("index.html", "getting-started/index.html", "cli/index.html", "wire-protocol/index.html",
                 "reference/developers/index.html"):
        assert (site / page).is_file(), page
    # the generated pages are in the site as generated, and DEVELOPERS.md is included, not copied
    assert "CLI reference" in (site / "cli" / "index.html").read_text(encoding="utf-8")
    assert "Contracts between parts" in (site / "reference" / "developers" / "index.html").read_text(encoding="utf-8")
    assert not (ROOT / "docs" / "reference" / "developers.md").read_text(encoding="utf-8").count("\n## ")


def test_every_page_is_in_the_nav() -> None:
    nav = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    pages = {p.relative_to(ROOT / "docs").as_posix() for p in (ROOT / "docs").rglob("*.md")}
    missing = sorted(p for p in pages if f": {p}" not in nav)
    assert not missing, f"pages not in mkdocs.yml's nav: {missing}"


def test_readme_is_short_and_opens_with_the_two_commands() -> None:
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 200, f"{README.name}: {len(text.splitlines())} lines"
    first = re.search(r"```sh\n(.*?)```", text, re.S)
    assert first, "no sh block"
    commands = [re.split(r"\s+#", ln)[0].strip() for ln in first[1].splitlines() if ln.strip()]
    assert commands == ["bash .ci/setup && .venv/bin/ghostshell demo", ".venv/bin/python -m pytest -n 3 --dist loadfile"], commands
    images = re.findall(r"!\[[^\]]*\]\(([^)\s]+)", text)
    assert images, "no picture"
    for image in images:
        assert (ROOT / image).is_file(), f"{README.name} shows {image}, which is not in the repository"
    assert "docs/index.md" in text or "mkdocs" in text, "no link to the docs"
