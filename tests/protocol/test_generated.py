"""protocol.generated.check_or_write: the one "write the generated file or check it" of every generator."""

from __future__ import annotations

import io
from pathlib import Path

from protocol.generated import check_or_write, staleness


def run(files: dict[Path, str], check: bool) -> tuple[int, list[str], list[str]]:
    out, err = io.StringIO(), io.StringIO()
    status = check_or_write(files, check=check, command="python -m gen", out=out, err=err)
    return status, out.getvalue().splitlines(), err.getvalue().splitlines()


def test_writes_then_checks_current(tmp_path: Path) -> None:
    a, b = tmp_path / "a.txt", tmp_path / "sub" / "b.txt"
    assert run({a: "A\n", b: "B\n"}, check=False) == (0, [f"wrote {a}", f"wrote {b}"], [])
    assert a.read_text(encoding="utf-8") == "A\n" and b.read_text(encoding="utf-8") == "B\n"
    assert run({a: "A\n", b: "B\n"}, check=True) == (0, [], [])


def test_check_reports_every_stale_file_and_writes_nothing(tmp_path: Path) -> None:
    a, b, c = tmp_path / "a.txt", tmp_path / "b.txt", tmp_path / "c.txt"
    a.write_text("old\n", encoding="utf-8")
    c.write_text("C\n", encoding="utf-8")
    status, out, err = run({a: "new\n", b: "B\n", c: "C\n"}, check=True)
    assert status == 1 and out == []
    assert err == [f"{a} differs from the generated text: run python -m gen", f"{b} is missing: run python -m gen"]
    assert a.read_text(encoding="utf-8") == "old\n" and not b.exists()
    assert staleness(c, "C\n") is None


def test_a_file_it_cannot_write_is_one_line_and_status_1(tmp_path: Path) -> None:
    """A folder where the file should be (unwritable for root too, unlike a read-only folder)."""
    (tmp_path / "x.txt").mkdir()
    status, out, err = run({tmp_path / "x.txt": "X\n"}, check=False)
    assert status == 1 and out == [] and len(err) == 1 and err[0].startswith(f"cannot write {tmp_path / 'x.txt'}: ")
    assert run({tmp_path / "x.txt": "X\n"}, check=True)[0] == 1  # a folder is not the file: stale
