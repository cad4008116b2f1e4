"""Board fuzz target finding (issue 46 campaign, 65 551 inputs in): without a GL backend (GLFW, no display,
``MUJOCO_GL`` unset) a second board in one process that renders a capture aborted the whole process
(MuJoCo's bindings: "__cxa_guard_acquire detected recursive initialization"): the first failed
``mujoco.Renderer`` left the GL set-up half made. A failed renderer is now remembered for the process."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
INPUT = Path(__file__).resolve().parent / "board" / "regressions" / "second-camera-without-gl"


def test_the_input_runs_twice_in_one_process_without_gl() -> None:
    drop = ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY", "PYOPENGL_PLATFORM")
    env = {k: v for k, v in os.environ.items() if k not in drop}
    code = (
        "import sys\nfrom firmware_sim.fuzz import load\n"
        "f = load(False)\ndata = open(sys.argv[1], 'rb').read()\n"
        "for _ in range(3):\n    f(data)\nprint('three runs')\n"
    )
    proc = subprocess.run([sys.executable, "-c", code, str(INPUT)], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=300, check=False)
    assert proc.returncode == 0 and "three runs" in proc.stdout, proc.stderr[-2000:]


def test_a_failed_renderer_is_not_tried_again_by_a_later_camera(monkeypatch: pytest.MonkeyPatch) -> None:
    import mujoco

    from firmware_sim import peripherals

    monkeypatch.setattr(peripherals, "_gl_failure", None)
    tries: list[int] = []

    def no_gl(*args: object, **kwargs: object) -> None:
        tries.append(1)
        raise mujoco.FatalError("gladLoadGL error")

    monkeypatch.setattr(mujoco, "Renderer", no_gl)
    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><camera name='c'/></worldbody></mujoco>")
    data = mujoco.MjData(model)
    for _ in range(2):  # a new camera each time, as a new board in the same process
        with pytest.raises(peripherals.CameraUnavailable, match="no OpenGL renderer"):
            peripherals.Camera(model, "c").capture_png(data, 32, 24)
    assert tries == [1]
