"""Emulated peripherals: the screen face, the speaker and the head camera.

Screen and speaker keep what is showing/playing on the board clock (a command
takes effect at ``start_at_us`` and lasts ``duration_ms``, 0 = until replaced).
The camera renders the MJCF camera ``head_cam`` offscreen with ``mujoco.Renderer``
and returns PNG bytes (Pillow) split into CAMERA_CHUNK messages.
"""

from __future__ import annotations

import copy
import io
import queue
import threading
from collections import deque
from dataclasses import dataclass

import mujoco

from protocol.codec import MAX_CHUNK_DATA
from protocol.messages import (
    CameraChunk,
    ScreenCommand,
    ScreenTarget,
    SoundKind,
    SpeakerAction,
    SpeakerCommand,
)

__all__ = ["Camera", "CameraUnavailable", "CameraWorker", "Screen", "Speaker"]

MAX_IMAGE_SIDE = 640


@dataclass(frozen=True)
class Scheduled:
    """A timed peripheral state: active on [start_us, end_us) (end None = until replaced)."""

    name: str
    start_us: int
    end_us: int | None
    detail: str = ""

    def active(self, t_us: int) -> bool:
        return self.start_us <= t_us and (self.end_us is None or t_us < self.end_us)


class Screen:
    """Face, eye and ear-light animations per :class:`ScreenTarget`, on the board clock."""

    def __init__(self, history: int = 256) -> None:
        self._pending: dict[ScreenTarget, list[Scheduled]] = {t: [] for t in ScreenTarget}
        self.history: deque[tuple[int, str, str]] = deque(maxlen=history)

    def command(self, cmd: ScreenCommand) -> None:
        end = cmd.start_at_us + cmd.duration_ms * 1000 if cmd.duration_ms else None
        items = [s for s in self._pending[cmd.target] if s.start_us < cmd.start_at_us][-8:]
        items.append(Scheduled(cmd.name, cmd.start_at_us, end))
        self._pending[cmd.target] = items
        self.history.append((cmd.start_at_us, cmd.target.name, cmd.name))

    def showing(self, target: ScreenTarget, t_us: int) -> str | None:
        """Name shown on ``target`` at board time ``t_us`` (None = default face)."""
        current = None
        for s in self._pending[target]:
            if s.start_us <= t_us:
                current = s
        return current.name if current is not None and current.active(t_us) else None


class Speaker:
    """One sound at a time: PLAY replaces whatever plays from its start time; STOP ends it."""

    def __init__(self, history: int = 256) -> None:
        self._items: list[Scheduled] = []
        self.history: deque[tuple[int, str, str]] = deque(maxlen=history)

    def command(self, cmd: SpeakerCommand) -> None:
        self._items = [s for s in self._items if s.start_us < cmd.start_at_us][-8:]
        if self._items and (self._items[-1].end_us is None or self._items[-1].end_us > cmd.start_at_us):
            last = self._items[-1]
            self._items[-1] = Scheduled(last.name, last.start_us, cmd.start_at_us, last.detail)
        if cmd.action is SpeakerAction.PLAY:
            what = cmd.text if cmd.kind is SoundKind.SPEECH else cmd.name
            end = cmd.start_at_us + cmd.duration_ms * 1000
            self._items.append(Scheduled(cmd.kind.name, cmd.start_at_us, end, what))
        self.history.append((cmd.start_at_us, cmd.action.name, cmd.text or cmd.name))

    def playing(self, t_us: int) -> tuple[str, str] | None:
        """(kind, clip name or speech text) playing at ``t_us``, or None."""
        for s in reversed(self._items):
            if s.start_us <= t_us:
                return (s.name, s.detail) if s.active(t_us) else None
        return None


#: why ``mujoco.Renderer`` could not be made in this process, once it could not: every later camera
#: refuses with the same message and does not try again. MuJoCo's GL set-up is process-wide, and a second
#: attempt after a failed one can abort the process (GLFW without a display, ``MUJOCO_GL`` unset: the
#: bindings' "__cxa_guard_acquire detected recursive initialization"; found by the ``board`` fuzz target,
#: whose every input builds a new board, so a new camera, in one process).
_gl_failure: str | None = None


class CameraUnavailable(RuntimeError):
    """No OpenGL backend: the board NACKs captures with NO_RENDERER and this message."""


class Camera:
    """Offscreen renders of the robot's camera (an MJCF camera name; None: the robot has none, and
    every capture is refused); renderers are created lazily per image size."""

    def __init__(self, model: mujoco.MjModel, camera: str | None, max_renderers: int = 2) -> None:
        self.model = model
        self.camera = camera
        self._renderers: dict[tuple[int, int], mujoco.Renderer] = {}
        self._max = max_renderers
        self._error: str | None = None if camera is not None else "this robot has no camera"

    def _renderer(self, width: int, height: int) -> mujoco.Renderer:
        global _gl_failure
        if self._error is None and _gl_failure is not None:
            self._error = _gl_failure  # an earlier camera of this process could not get GL: do not try again
        if self._error is not None:
            raise CameraUnavailable(self._error)
        key = (width, height)
        if key not in self._renderers:
            if len(self._renderers) >= self._max:
                self._renderers.pop(next(iter(self._renderers))).close()
            try:
                self._renderers[key] = mujoco.Renderer(self.model, height=height, width=width)
            except Exception as e:  # no GL backend, no display, bad MUJOCO_GL ...
                self._error = _gl_failure = f"no OpenGL renderer ({type(e).__name__}: {e}); try MUJOCO_GL=egl"[:200]
                raise CameraUnavailable(self._error) from None
        return self._renderers[key]

    def warm_up(self, width: int = 160, height: int = 120) -> str | None:
        """Create the renderer for the usual image size now (GL setup takes hundreds of ms, which
        would otherwise stall the control loop at the first capture); returns why not, if it can't."""
        try:
            self.capture_png(mujoco.MjData(self.model), width, height)  # first render and PNG encode are slow too
        except CameraUnavailable as e:
            return str(e)
        return None

    def capture_png(self, data: mujoco.MjData, width: int, height: int) -> bytes:
        """Render ``head_cam`` and encode it as PNG."""
        from PIL import Image

        r = self._renderer(width, height)
        r.update_scene(data, camera=self.camera)
        pixels = r.render()
        buf = io.BytesIO()
        Image.fromarray(pixels).save(buf, format="PNG", optimize=False)
        return buf.getvalue()

    @staticmethod
    def chunks(request_id: int, png: bytes) -> list[CameraChunk]:
        """Split ``png`` into CAMERA_CHUNK messages (index 0..total-1)."""
        parts = [png[i : i + MAX_CHUNK_DATA] for i in range(0, len(png), MAX_CHUNK_DATA)] or [b""]
        return [CameraChunk(request_id, i, len(parts), p) for i, p in enumerate(parts)]

    def close(self) -> None:
        for r in self._renderers.values():
            r.close()
        self._renderers.clear()


class CameraWorker:
    """Renders captures off the control loop (a realtime board must not stall ~100 ms per image).

    The worker thread owns its :class:`Camera` (an OpenGL context belongs to the
    thread that made it). :meth:`submit` hands over a snapshot of the simulation
    state; :meth:`results` returns the finished CAMERA_CHUNKs or the error, for
    the control loop to send on its next tick. Both queues are bounded.
    """

    def __init__(self, model: mujoco.MjModel, camera: str | None, width: int = 160, height: int = 120) -> None:
        self._jobs: queue.Queue[tuple[int, int, int, mujoco.MjData] | None] = queue.Queue(maxsize=4)
        self._done: queue.Queue[tuple[int, list[CameraChunk] | str]] = queue.Queue(maxsize=16)
        self._ready = threading.Event()
        self.error: str | None = None
        self._thread = threading.Thread(target=self._run, args=(model, camera, width, height),
                                        name="camera", daemon=True)
        self._thread.start()
        self._ready.wait(30)

    def _run(self, model: mujoco.MjModel, camera: str | None, width: int, height: int) -> None:
        cam = Camera(model, camera)
        self.error = cam.warm_up(width, height)
        self._ready.set()
        while (job := self._jobs.get()) is not None:
            request_id, w, h, data = job
            try:
                out: list[CameraChunk] | str = Camera.chunks(request_id, cam.capture_png(data, w, h))
            except CameraUnavailable as e:
                out = str(e)
            self._done.put((request_id, out))
        cam.close()

    def submit(self, request_id: int, width: int, height: int, data: mujoco.MjData) -> bool:
        """Queue a capture of a copy of ``data``; False when the worker is busy (queue full)."""
        try:
            self._jobs.put_nowait((request_id, width, height, copy.copy(data)))
        except queue.Full:
            return False
        return True

    def results(self) -> list[tuple[int, list[CameraChunk] | str]]:
        """Finished captures since the last call (non-blocking; called every control tick)."""
        if self._done.empty():
            return []
        out = []
        while True:
            try:
                out.append(self._done.get_nowait())
            except queue.Empty:
                return out

    def close(self) -> None:
        self._jobs.put(None)
        self._thread.join(5)
