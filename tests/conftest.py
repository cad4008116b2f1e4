"""Suite-wide settings: headless MuJoCo rendering unless the caller chose a backend."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
