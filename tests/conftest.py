"""Suite-wide settings: headless MuJoCo rendering unless the caller chose a backend."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import pytest  # noqa: E402

#: under pytest-xdist, tests marked ``realtime`` run one at a time and first in line for the cores
#: (tests/support/realtime_lock.py) and the
#: longest files start first (tests/support/file_order.py)
pytest_plugins = ["support.realtime_lock", "support.file_order"]


@pytest.fixture(autouse=True)
def _private_skill_library(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """Never read or write the user's real skill library (subprocesses inherit the variable)."""
    monkeypatch.setenv("GHOSTSHELL_SKILLS", str(tmp_path_factory.mktemp("skills") / "skills.json"))


@pytest.fixture(scope="session")
def _mjcf_check_folder(tmp_path_factory: pytest.TempPathFactory) -> str:
    return str(tmp_path_factory.mktemp("mjcf-checks"))


@pytest.fixture(autouse=True)
def _private_mjcf_check_cache(_mjcf_check_folder: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Never read or write the user's record of checked robots (robots.mjcf_check_cache); one folder per
    test process, so its subprocesses load a robot its earlier tests checked without MuJoCo."""
    monkeypatch.setenv("GHOSTSHELL_MJCF_CHECK_CACHE", _mjcf_check_folder)
