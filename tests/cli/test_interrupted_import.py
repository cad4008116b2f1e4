"""Ctrl-C while a C extension initialises (new-user test, 2026-12-04: a Ctrl-C 0.35-0.45 s after
``ghostshell run`` started, during ``import mujoco``, printed a 50-line traceback ending in
``ImportError: initialization failed`` and exited 1). It is an interruption: one line, status 130."""

from __future__ import annotations

from types import ModuleType

import pytest

import host.cli
from host.cli import Terminated, main


@pytest.mark.parametrize(("interrupt", "said"), [(KeyboardInterrupt(), "SIGINT (Ctrl-C)"), (Terminated(), "SIGTERM")])
def test_an_import_a_signal_cut_short_is_an_interruption(interrupt: KeyboardInterrupt, said: str,
                                                         monkeypatch: pytest.MonkeyPatch,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    def cut(name: str) -> ModuleType:
        try:
            raise interrupt
        except KeyboardInterrupt:
            raise ImportError("initialization failed")  # noqa: B904 - as the extension does: context, no cause

    monkeypatch.setattr(host.cli.importlib, "import_module", cut)
    assert main(["run", "--task", "1"]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"ghostshell run: interrupted by {said}"], err


def test_any_other_import_error_still_surfaces(monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(name: str) -> ModuleType:
        raise ImportError("no module named whatever")

    monkeypatch.setattr(host.cli.importlib, "import_module", broken)
    with pytest.raises(ImportError, match="whatever"):
        main(["run", "--task", "1"])
