"""Run a one-input function under atheris (libFuzzer); used by every host-side target's ``__main__``.

``firmware_sim.fuzz`` carries a copy of these few lines because the board never imports the host.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

__all__ = ["run_atheris"]


def run_atheris(load: Callable[[bool], Callable[[bytes], None]], module: str) -> None:
    """``load(True)`` imports the code under test inside ``atheris.instrument_imports()``; then fuzz.

    ``argv[0]`` becomes ``python -m MODULE``: libFuzzer's ``-fork``/``-jobs`` modes re-run it through
    the shell, and a module's ``.py`` path is not executable.
    """
    import atheris  # type: ignore[import-not-found,unused-ignore]

    one_input = load(True)
    atheris.Setup([f"{sys.executable} -m {module}", *sys.argv[1:]], one_input)
    atheris.Fuzz()
