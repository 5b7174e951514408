"""Offscreen rendering of a MuJoCo model from its named cameras, shared by every backend."""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np
import numpy.typing as npt

from crowdteleop.errors import InvalidResolutionError, UnknownCameraError
from crowdteleop.gl import render_backend_error
from crowdteleop.sim.types import Marker

MIN_SIDE = 16
MAX_WIDTH = 1920
MAX_HEIGHT = 1080


def validate_resolution(width: int, height: int) -> None:
    """Reject sizes a video stream cannot use before any GL work happens."""
    for name, value, limit in (("width", width, MAX_WIDTH), ("height", height, MAX_HEIGHT)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer):
            raise InvalidResolutionError(f"{name} must be an integer, got {value!r}")
        if not MIN_SIDE <= value <= limit:
            raise InvalidResolutionError(
                f"{name} must be between {MIN_SIDE} and {limit} pixels, got {value}"
            )


def add_markers(scene: mujoco.MjvScene, markers: Sequence[Marker]) -> None:
    """Append `markers` to a scene already updated from the model: drawn like geoms, but
    nothing in the model or its data knows of them. Markers beyond the scene's room are left
    out (a picture without its hint beats no picture)."""
    for marker in markers:
        if scene.ngeom >= scene.maxgeom:
            return
        mujoco.mjv_initGeom(
            scene.geoms[scene.ngeom],
            mujoco.mjtGeom.mjGEOM_SPHERE,
            np.full(3, marker.radius_m),
            np.asarray(marker.position_m, dtype=np.float64),
            np.eye(3).ravel(),
            np.asarray(marker.rgba, dtype=np.float32),
        )
        scene.ngeom += 1


class CameraRenderer:
    """Renders RGB frames; keeps one `mujoco.Renderer` per resolution, made on first use."""

    def __init__(self, model: mujoco.MjModel, hidden_geom_groups: tuple[int, ...] = ()) -> None:
        """`hidden_geom_groups`: geom groups not drawn (robosuite keeps collision geoms in 0)."""
        self._model = model
        self._renderers: dict[tuple[int, int], mujoco.Renderer] = {}
        self._option = mujoco.MjvOption()
        for group in hidden_geom_groups:
            self._option.geomgroup[group] = 0
        self.cameras = tuple(model.camera(i).name for i in range(model.ncam))
        # The offscreen buffer bounds the largest frame; size it for any resolution we accept.
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, MAX_WIDTH)
        model.vis.global_.offheight = max(model.vis.global_.offheight, MAX_HEIGHT)

    def render(
        self,
        data: mujoco.MjData,
        camera: str,
        width: int,
        height: int,
        markers: Sequence[Marker] = (),
    ) -> npt.NDArray[np.uint8]:
        if camera not in self.cameras:
            raise UnknownCameraError(
                f"unknown camera {camera!r}; this scene has: {', '.join(self.cameras)}"
            )
        validate_resolution(width, height)
        renderer = self._renderer(width, height)
        renderer.update_scene(data, camera=camera, scene_option=self._option)
        add_markers(renderer.scene, markers)
        image: npt.NDArray[np.uint8] = renderer.render()
        return image

    def _renderer(self, width: int, height: int) -> mujoco.Renderer:
        key = (int(width), int(height))
        if key not in self._renderers:
            try:
                self._renderers[key] = mujoco.Renderer(self._model, height=key[1], width=key[0])
            except Exception as exc:  # GL context creation fails in many library-specific ways
                raise render_backend_error(exc) from exc
        return self._renderers[key]

    def close(self) -> None:
        for renderer in self._renderers.values():
            renderer.close()
        self._renderers.clear()


STRONG_DIFFERENCE = 48  # a channel difference this large is not shading noise


def picture_difference(
    ours: npt.NDArray[np.uint8], reference: npt.NDArray[np.uint8]
) -> dict[str, float]:
    """Two pictures of one state compared: MAD overall (0-255), MAD over the pixels that
    differ, their share, and the share inside a strongly differing 3x3 block (a missing or
    misplaced part; edge aliasing cannot make one)."""
    diff = np.abs(ours.astype(np.int16) - reference.astype(np.int16))
    differs = diff.max(axis=2) > 0
    strong = diff.max(axis=2) > STRONG_DIFFERENCE
    height, width = strong.shape
    solid = np.ones((height - 2, width - 2), dtype=bool)
    for dy in range(3):
        for dx in range(3):
            solid &= strong[dy : dy + height - 2, dx : dx + width - 2]
    return {
        "mad": float(diff.mean()),
        "mad_differing": float(diff[differs].mean()) if differs.any() else 0.0,
        "differing": float(differs.mean()),
        "blob": float(solid.mean()),
    }
