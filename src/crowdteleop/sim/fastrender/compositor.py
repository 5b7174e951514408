"""Frames as a cached static background plus the moving parts, merged by depth.

Of the ~30 ms a tuned llvmpipe frame costs, most goes to things that never move: the textured
floor, walls and table alone cost ~4 ms, and the robot's pedestal holds 33k triangles. So for a
camera fixed in the world the static layer (`layers.py`) is drawn once per camera and size, at
full quality (skybox, floor reflection), colour and depth kept. Each frame then draws only the
moving layer (skybox and reflection off, nothing else in the scene to reflect) and keeps, per
pixel, whichever of the two is nearer: what one pass with the depth test would have kept.

Everything here runs with the shared GL context current (see `glcontext.py`).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
import numpy.typing as npt

from crowdteleop.sim.fastrender.layers import (
    MOVING,
    MOVING_SEE_THROUGH,
    STATIC,
    STATIC_SEE_THROUGH,
    Layers,
    camera_is_static,
)
from crowdteleop.sim.fastrender.msaa import draw_multisampled
from crowdteleop.sim.fastrender.render_model import RenderModel
from crowdteleop.sim.fastrender.textures import TextureResidency, textures_used
from crowdteleop.sim.rendering import add_markers
from crowdteleop.sim.types import Marker

# The offscreen buffer starts at a common stream size and grows to the largest frame asked for.
# Every pass clears all of it, so a buffer bigger than the frame costs: 640x480 for 320x240
# frames made the moving pass ~0.3 ms slower.
INITIAL_BUFFER = (320, 240)
MAX_BACKGROUNDS = 8  # (camera, width, height) entries kept; each W*H*7 bytes (+4 see-through)
# Background-only textures are parked once this many composited frames followed the last
# single-pass one: a stream on a moving camera (one pass per frame) keeps them resident.
PARK_AFTER_FRAMES = 40
_SKYBOX = mujoco.mjtRndFlag.mjRND_SKYBOX
_REFLECTION = mujoco.mjtRndFlag.mjRND_REFLECTION


@dataclass
class Background:
    """The static layer from one camera at one size, rows bottom-up as OpenGL returns them."""

    rgb_bottom_up: npt.NDArray[np.uint8]  # (H, W, 3), multisampled when the GL allows
    depth: npt.NDArray[np.float32]  # (H, W), MuJoCo's reversed depth: larger is nearer, 0 is empty
    serial: int  # unique per drawing, so answers derived from it can be keyed on it
    distance: npt.NDArray[np.float32] | None = (
        None  # (H, W) metres along the optical axis, on demand
    )


class Compositor:
    """Draws one render model's frames; owns its `MjrContext` inside the shared GL context."""

    def __init__(self, render_model: RenderModel, layers: Layers) -> None:
        """Call with the shared GL context current."""
        self._render = render_model
        model = render_model.model
        self._buffer = INITIAL_BUFFER
        self._shadow_size = int(model.vis.quality.shadowsize)
        self._textures = TextureResidency(model)
        self._context = self._make_context(shadows=layers.shadows)
        self._composited_in_a_row = PARK_AFTER_FRAMES
        self._scene = mujoco.MjvScene(model, maxgeom=2 * (model.ngeom + model.nsite) + 1000)
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._static_camera = [camera_is_static(model, i) for i in range(model.ncam)]
        self._backgrounds: OrderedDict[tuple[int, int, int], Background] = OrderedDict()
        self.background_draws = 0  # counters for tests and benchmarks
        self.single_pass_frames = 0
        self.textures_parked = False  # set when textures were parked; the owner trims the heap
        self._see_through_memo: tuple[tuple[int, bytes, bytes, bytes], bool] | None = None
        self.set_layers(layers)

    def _make_context(self, shadows: bool) -> mujoco.MjrContext:
        """An `MjrContext` for the render model (meshes and textures uploaded).

        The shadow map (``shadowsize``, 4096^2 depth texels: 64 MiB in llvmpipe) is made only
        when a light casts shadows; robosuite's lights do not.
        """
        model = self._render.model
        model.vis.global_.offwidth, model.vis.global_.offheight = self._buffer
        model.vis.quality.shadowsize = self._shadow_size if shadows else 0
        context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_50)
        context.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._textures.context_rebuilt()
        return context

    def set_layers(self, layers: Layers) -> None:
        """Adopt new layers (colours changed); every cached background is stale."""
        self._layers = layers
        model = self._render.model
        if layers.shadows and not self._context.shadowSize:  # a light started casting shadows
            self._context.free()
            self._context = self._make_context(shadows=True)
        self._textures.set_per_frame(
            textures_used(
                model,
                np.isin(layers.geom_layer, (MOVING, STATIC_SEE_THROUGH)),
                np.isin(layers.site_layer, (MOVING, STATIC_SEE_THROUGH)),
                tendons=True,
            )
        )
        layers.apply(model)
        self._background_option = layers.option(STATIC_SEE_THROUGH, STATIC)
        self._moving_option = layers.option(STATIC_SEE_THROUGH, MOVING)
        self._full_option = layers.option(STATIC_SEE_THROUGH, STATIC, MOVING, MOVING_SEE_THROUGH)
        self._backgrounds.clear()
        self._see_through_memo = None

    def frame(
        self, camera: int, width: int, height: int, markers: Sequence[Marker] = ()
    ) -> npt.NDArray[np.uint8]:
        """The picture from ``camera`` for the render model's current pose, rows top-down.

        Opaque markers are drawn with the moving layer and merged by depth like it. A
        see-through marker blends over what is behind it, which the depth merge cannot do (see
        `_see_through_part_visible`), so its frames are drawn in one pass (~5x the cost).
        """
        self._fit_buffer(width, height)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._context)
        see_through = any(marker.rgba[3] < 1 for marker in markers)
        if see_through or not (self._layers.composite_ok and self._static_camera[camera]):
            return self._single_pass(camera, width, height, markers)
        background = self._background(camera, width, height)
        if self._see_through_part_visible(background, camera, width, height):
            return self._single_pass(camera, width, height, markers)
        self._composited_in_a_row += 1
        if self._composited_in_a_row >= PARK_AFTER_FRAMES and self._textures.park(self._context):
            self.textures_parked = True
        rgb, depth = self._draw(
            camera, width, height, self._moving_option, skybox=False, markers=markers
        )
        # Bottom-up like GL; only the (few) pixels the moving layer wins are copied, each as one
        # 3-byte item (a third faster than indexing (N, 3) rows).
        frame = background.rgb_bottom_up.copy()
        nearer = np.flatnonzero(depth > background.depth)
        pixels = frame.reshape(-1, 3).view("V3").ravel()
        pixels[nearer] = rgb.reshape(-1, 3).view("V3").ravel()[nearer]
        return np.ascontiguousarray(frame[::-1])

    def free(self) -> None:
        """Release GL resources (shared context current)."""
        self._context.free()
        self._backgrounds.clear()

    # --- passes ----------------------------------------------------------------------------
    def _draw(
        self,
        camera: int,
        width: int,
        height: int,
        option: mujoco.MjvOption,
        skybox: bool,
        reflection: bool = False,
        markers: Sequence[Marker] = (),
    ) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.float32]]:
        """Render one pass; colour and depth as OpenGL returns them (bottom row first)."""
        self._camera.fixedcamid = camera
        model, data = self._render.model, self._render.data
        mujoco.mjv_updateScene(
            model, data, option, None, self._camera, mujoco.mjtCatBit.mjCAT_ALL, self._scene
        )
        add_markers(self._scene, markers)
        self._scene.flags[_SKYBOX] = skybox
        self._scene.flags[_REFLECTION] = reflection
        viewport = mujoco.MjrRect(0, 0, width, height)
        mujoco.mjr_render(viewport, self._scene, self._context)
        rgb = np.empty((height, width, 3), dtype=np.uint8)
        depth = np.empty((height, width), dtype=np.float32)
        mujoco.mjr_readPixels(rgb, depth, viewport, self._context)
        return rgb, depth

    def _single_pass(
        self, camera: int, width: int, height: int, markers: Sequence[Marker] = ()
    ) -> npt.NDArray[np.uint8]:
        """Everything in one pass: the original picture less MSAA (and meshes simplified).

        Reflections stay on: without them the floor and the table's metal differ visibly
        (MAD 2.7 instead of 1.2 against robosuite's picture at 320x240, for 12 instead of 18 ms).
        This is the fallback (moving cameras, shadows, see-through moving parts in view), where
        the picture's correctness is worth the milliseconds.
        """
        self.single_pass_frames += 1
        self._composited_in_a_row = 0
        self._textures.restore(self._context)
        rgb, _ = self._draw(
            camera, width, height, self._full_option, skybox=True, reflection=True, markers=markers
        )
        return np.ascontiguousarray(rgb[::-1])

    def _background(self, camera: int, width: int, height: int) -> Background:
        key = (camera, width, height)
        cached = self._backgrounds.get(key)
        if cached is not None:
            self._backgrounds.move_to_end(key)
            return cached
        self._textures.restore(self._context)
        rgb, depth = self._draw(
            camera, width, height, self._background_option, skybox=True, reflection=True
        )
        if self._render.samples > 1:  # same scene again, multisampled, for its colour only
            viewport = mujoco.MjrRect(0, 0, width, height)
            multisampled = draw_multisampled(
                lambda: mujoco.mjr_render(viewport, self._scene, self._context),
                self._context,
                width,
                height,
                self._render.samples,
            )
            rgb = rgb if multisampled is None else multisampled
        self.background_draws += 1
        background = Background(rgb, depth, serial=self.background_draws)
        self._backgrounds[key] = background
        while len(self._backgrounds) > MAX_BACKGROUNDS:
            self._backgrounds.popitem(last=False)
        return background

    def _fit_buffer(self, width: int, height: int) -> None:
        """Grow the offscreen buffer when a frame does not fit (never shrink: no churn)."""
        if width <= self._buffer[0] and height <= self._buffer[1]:
            return
        self._buffer = (max(width, self._buffer[0]), max(height, self._buffer[1]))
        mujoco.mjr_resizeOffscreen(*self._buffer, self._context)

    # --- see-through moving parts ------------------------------------------------------------
    def _distance(self, depth: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        """Metric distance along the optical axis from MuJoCo's reversed depth (as Renderer)."""
        model = self._render.model
        near = np.float32(model.vis.map.znear * model.stat.extent)
        far = np.float32(model.vis.map.zfar * model.stat.extent)
        c_coef = -(far + near) / (far - near)
        d_coef = -(np.float32(2) * far * near) / (far - near)
        c_coef = np.float32(-0.5) * c_coef - np.float32(0.5)
        d_coef = np.float32(-0.5) * d_coef
        return (d_coef / (depth.astype(np.float64) + c_coef)).astype(np.float32)

    def _see_through_part_visible(
        self, background: Background, camera: int, width: int, height: int
    ) -> bool:
        """Could a transparent moving geom or site show in this frame?

        MuJoCo blends those over whatever is behind them without writing depth, so in the moving
        pass they would blend over black and then lose to the background. When any of them might
        be in front of the background, the frame is drawn in one pass instead. robosuite's mocap
        target boxes sit under the floor and never trigger this (and, never moving, are checked
        once: the answer is kept for the same poses and background).
        """
        model, data = self._render.model, self._render.data
        geoms = self._layers.see_through_moving_geoms
        sites = self._layers.see_through_moving_sites
        if not len(geoms) and not len(sites):
            return False
        centres = np.concatenate([data.geom_xpos[geoms], data.site_xpos[sites]])
        radii = np.concatenate(
            [model.geom_rbound[geoms], np.linalg.norm(model.site_size[sites], axis=1)]
        )
        key = (
            background.serial,
            centres.tobytes(),
            radii.tobytes(),
            data.cam_xpos[camera].tobytes(),
        )
        if self._see_through_memo is not None and self._see_through_memo[0] == key:
            return self._see_through_memo[1]
        if background.distance is None:
            background.distance = self._distance(background.depth)
        rotation = data.cam_xmat[camera].reshape(3, 3)
        visible = may_show(
            background.distance,
            (centres - data.cam_xpos[camera]) @ rotation,  # camera frame: x right, y up, z back
            radii,
            focal=0.5 * height / np.tan(np.radians(model.cam_fovy[camera]) / 2),
            near=model.vis.map.znear * model.stat.extent,
        )
        self._see_through_memo = (key, visible)
        return visible


_CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)


def may_show(
    distance: npt.NDArray[np.float32],
    centres: npt.NDArray[np.float64],
    radii: npt.NDArray[np.float64],
    focal: float,
    near: float,
) -> bool:
    """Whether any sphere (camera frame) could be seen in front of a background.

    ``distance``: the background's metric depth, rows bottom-up. Each sphere is bounded by its
    cube; the cube's projection is a conservative screen box (padded a pixel), and the sphere is
    hidden when every background pixel in that box is nearer than the cube's nearest point.
    """
    height, width = distance.shape
    nearest = -centres[:, 2] - radii
    if np.any((radii <= 0) | (nearest <= near)):
        return True  # a plane, or reaching the camera: cannot bound it, be safe
    boxes = centres[:, None, :] + radii[:, None, None] * _CORNERS  # (n, 8, 3)
    columns = 0.5 * width + focal * boxes[..., 0] / -boxes[..., 2]
    rows = 0.5 * height + focal * boxes[..., 1] / -boxes[..., 2]  # bottom-up, like `distance`
    left = np.maximum(np.floor(columns.min(axis=1)).astype(int) - 1, 0)
    right = np.minimum(np.ceil(columns.max(axis=1)).astype(int) + 2, width)
    bottom = np.maximum(np.floor(rows.min(axis=1)).astype(int) - 1, 0)
    top = np.minimum(np.ceil(rows.max(axis=1)).astype(int) + 2, height)
    for index in np.flatnonzero((left < right) & (bottom < top)):  # on screen
        region = distance[bottom[index] : top[index], left[index] : right[index]]
        if np.any(region > nearest[index]):
            return True
    return False
