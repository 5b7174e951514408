"""`FastSceneRenderer`: robosuite's picture at a fraction of the CPU, and nothing when idle.

Drop-in for `CameraRenderer` (same `render` / `cameras` / `close`, same errors). What it does
differently, each part in its own module:

* draws a render-only copy of the model with simplified robot meshes (`render_model.py`,
  `simplify.py`), never touching the physics model or data;
* keeps the static scene as a cached background and draws only what moves (`compositor.py`,
  `layers.py`);
* shares one GL context with every other instance in the process (`glcontext.py`);
* returns the previous frame, without any GL work, when nothing that moves has moved: an idle
  operator costs a comparison of a few dozen floats per frame.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import platform
import threading
from collections import OrderedDict
from collections.abc import Sequence

import mujoco
import numpy as np
import numpy.typing as npt

from crowdteleop.errors import UnknownCameraError
from crowdteleop.gl import render_backend_error
from crowdteleop.sim.fastrender.compositor import Compositor
from crowdteleop.sim.fastrender.glcontext import SharedGLContext
from crowdteleop.sim.fastrender.layers import SHOWN_BY_DEFAULT
from crowdteleop.sim.fastrender.render_model import RenderModel
from crowdteleop.sim.fastrender.simplify import SimplifiedMesh, SimplifyParams
from crowdteleop.sim.rendering import validate_resolution
from crowdteleop.sim.types import Marker

MAX_CACHED_FRAMES = 8  # one per (camera, width, height) in use; a stream uses one or two


class FastSceneRenderer:
    """Renders RGB frames of a physics model's named cameras (uint8, (H, W, 3), top row first)."""

    def __init__(
        self,
        physics_model: mujoco.MjModel,
        physics_xml: str,
        hidden_geom_groups: tuple[int, ...] = (0,),
        simplify: bool = True,
        simplify_params: SimplifyParams | None = None,
    ) -> None:
        """``physics_xml``: the MJCF ``physics_model`` was compiled from (absolute mesh paths).

        ``hidden_geom_groups`` are not drawn (robosuite keeps collision geoms in group 0).
        Building may simplify meshes on the first run on a machine (seconds, then cached).
        """
        self._physics_model = physics_model
        self._hidden = tuple(int(group) for group in hidden_geom_groups)
        self.cameras = tuple(physics_model.camera(i).name for i in range(physics_model.ncam))
        self._camera_ids = {name: index for index, name in enumerate(self.cameras)}
        visible = SHOWN_BY_DEFAULT[np.clip(physics_model.geom_group, 0, 5)]
        visible &= ~np.isin(physics_model.geom_group, self._hidden)
        self._render = RenderModel.build(
            physics_model, physics_xml, visible, simplify=simplify, params=simplify_params
        )
        self._lock = threading.Lock()  # frame cache and render model; taken before the GL lock
        self._frames: OrderedDict[
            tuple[int, int, int], tuple[npt.NDArray[np.float64], npt.NDArray[np.uint8]]
        ] = OrderedDict()
        self.renders_performed = 0  # frames that needed GL work (cache misses)
        self._gl: SharedGLContext | None = SharedGLContext.acquire()
        try:
            layers = self._render.layers(self._hidden)
            with self._gl.current():
                self._compositor = Compositor(self._render, layers)
        except Exception as exc:
            self._gl.release()
            self._gl = None
            raise render_backend_error(exc) from exc
        _return_freed_heap()

    # --- public ----------------------------------------------------------------------------
    def render(
        self,
        physics_data: mujoco.MjData,
        camera: str,
        width: int,
        height: int,
        markers: Sequence[Marker] = (),
    ) -> npt.NDArray[np.uint8]:
        """The frame from ``camera`` for the state in ``physics_data`` (read, never written),
        with ``markers`` drawn in (see `Compositor.frame`)."""
        if camera not in self._camera_ids:
            raise UnknownCameraError(
                f"unknown camera {camera!r}; this scene has: {', '.join(self.cameras)}"
            )
        validate_resolution(width, height)
        key = (self._camera_ids[camera], int(width), int(height))
        with self._lock:
            if self._gl is None:
                raise RuntimeError("render() called after close()")
            if self._render.sync_appearance(self._physics_model):
                self._compositor.set_layers(self._render.layers(self._hidden))
                self._frames.clear()
            pose = np.concatenate([_pose_fingerprint(physics_data), _marker_fingerprint(markers)])
            cached = self._frames.get(key)
            if cached is not None and np.array_equal(cached[0], pose):
                self._frames.move_to_end(key)
                return cached[1].copy()
            self._render.sync(physics_data)
            with self._gl.current():
                frame = self._compositor.frame(*key, markers=markers)
            if self._compositor.textures_parked:  # tens of MiB just freed: give them back
                self._compositor.textures_parked = False
                _return_freed_heap()
            self.renders_performed += 1
            self._frames[key] = (pose, frame)
            while len(self._frames) > MAX_CACHED_FRAMES:
                self._frames.popitem(last=False)
            return frame.copy()

    def close(self) -> None:
        """Free GL resources; the shared context goes with the last renderer. Idempotent."""
        with self._lock:
            if self._gl is None:
                return
            gl, self._gl = self._gl, None
            with gl.current():
                self._compositor.free()
            gl.release()
            self._frames.clear()

    # --- introspection (benchmarks, docs, tests) ------------------------------------------
    @property
    def render_model(self) -> mujoco.MjModel:
        return self._render.model

    @property
    def simplified_meshes(self) -> list[SimplifiedMesh]:
        return list(self._render.meshes)

    @property
    def background_draws(self) -> int:
        return self._compositor.background_draws

    @property
    def single_pass_frames(self) -> int:
        return self._compositor.single_pass_frames

    @property
    def gl_context(self) -> SharedGLContext | None:
        return self._gl


def _return_freed_heap() -> None:
    """Hand the compiler's freed scratch memory back to the OS (glibc keeps it otherwise).

    Compiling the render model and uploading it to GL leave ~60 MiB of freed heap resident
    per renderer, parking textures (`textures.py`) frees ~70 MiB; `malloc_trim` is
    process-wide but only releases memory nobody uses.
    """
    name = ctypes.util.find_library("c")
    if name and platform.system() == "Linux":
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(name).malloc_trim(0)


def _pose_fingerprint(data: mujoco.MjData) -> npt.NDArray[np.float64]:
    """Everything a picture depends on that changes while the model does not: the pose.

    Body, camera and light poses all follow from qpos and the mocap poses via kinematics.
    """
    return np.concatenate([data.qpos, data.mocap_pos.ravel(), data.mocap_quat.ravel()])


def _marker_fingerprint(markers: Sequence[Marker]) -> npt.NDArray[np.float64]:
    """What a picture depends on of its markers: a frame cached without them is not theirs."""
    return np.array(
        [len(markers), *(v for m in markers for v in (*m.position_m, m.radius_m, *m.rgba))],
        dtype=np.float64,
    )
