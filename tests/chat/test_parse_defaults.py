"""A real LLM parses leniently by default; scripted replay stays strict; both flags override."""

from __future__ import annotations

import pytest

from host.cli import build_parser
from host.commands.run import resolve_strict


@pytest.mark.parametrize(("argv", "strict"), [
    (["run", "--xml", "<wave/>"], True),
    (["run", "--prompt", "hi", "--llm", "openai:m"], False),
    (["run", "--prompt", "hi", "--llm", "openai:m", "--strict"], True),
    (["run", "--xml", "<wave/>", "--lenient"], False),
    (["chat", "--llm", "openai:m"], False),
    (["chat", "--llm", "scripted", "--replies", "r.txt"], True),
    (["chat", "--llm", "openai:m", "--strict"], True),
])
def test_strictness_default_follows_the_llm(argv: list[str], strict: bool) -> None:
    args = build_parser(argv).parse_args(argv)
    assert resolve_strict(args) is strict


def test_strict_and_lenient_exclude_each_other() -> None:
    argv = ["run", "--xml", "<wave/>", "--strict", "--lenient"]
    with pytest.raises(SystemExit):
        build_parser(argv).parse_args(argv)
