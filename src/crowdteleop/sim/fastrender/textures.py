"""Textures that only the cached background samples leave GL memory between background draws.

robosuite's scenes carry big textures: the table's ceramic cube map alone is 1181 px a face, and
llvmpipe keeps every texture as RGBA with its mipmaps, ~70 MiB per render model (Lift). Nearly
all of them sit on static geoms (table, legs, walls, floor, skybox), which are drawn only into the
cached backgrounds (`compositor.py`) and in single-pass fallback frames; the per-frame moving
pass samples only the task objects' textures. So between full-quality draws the others are
*parked*: replaced in GL by a 1x1 texture of the same kind. Right before the next background or
single-pass frame they are uploaded again from the render model's own copy (``tex_data``, ~20
MiB for all of them): the same data gives the same mipmaps, so every picture is bit-identical.

A texture name is deleted before each upload: re-specifying only level 0 of a mipmapped texture
(what `mjr_uploadTexture` does) leaves Mesa holding the old storage through the other levels.
Everything here runs with the shared GL context current.
"""

from __future__ import annotations

import mujoco
import numpy as np
import numpy.typing as npt


def textures_used(
    model: mujoco.MjModel, geoms: npt.NDArray[np.bool_], sites: npt.NDArray[np.bool_], tendons: bool
) -> npt.NDArray[np.bool_]:
    """Which textures (bool per texture) the materials of these geoms / sites (masks) use;
    with ``tendons``, also those of every tendon's material."""
    materials = [model.geom_matid[geoms], model.site_matid[sites]]
    if tendons and model.ntendon:
        materials.append(model.tendon_matid)
    ids = np.concatenate(materials)
    ids = ids[ids >= 0]
    used = np.zeros(model.ntex, dtype=bool)
    if len(ids) and model.ntex:
        textures = model.mat_texid[ids].ravel()
        used[textures[textures >= 0]] = True
    return used


class TextureResidency:
    """Keeps the textures a frame needs in GL and parks the rest (see the module docstring)."""

    def __init__(self, model: mujoco.MjModel) -> None:
        self._model = model
        self._per_frame = np.ones(model.ntex, dtype=bool)  # until told otherwise: park nothing
        self._parked: set[int] = set()
        self.uploads = 0  # full-size re-uploads, for tests and benchmarks

    @property
    def parked(self) -> frozenset[int]:
        return frozenset(self._parked)

    def set_per_frame(self, used: npt.NDArray[np.bool_]) -> None:
        """The textures every frame samples (bool per texture); they are never parked."""
        self._per_frame = np.asarray(used, dtype=bool).copy()

    def context_rebuilt(self) -> None:
        """A new `MjrContext` uploaded every texture at full size."""
        self._parked.clear()

    def restore(self, context: mujoco.MjrContext) -> None:
        """Upload every parked texture at full size again (before a full-quality draw)."""
        for texture in sorted(self._parked):
            self._upload(context, texture, full=True)
            self.uploads += 1
        self._parked.clear()

    def park(self, context: mujoco.MjrContext) -> bool:
        """Shrink every texture no frame samples to 1x1 in GL; True when any was parked."""
        parked_any = False
        for texture in np.flatnonzero(~self._per_frame):
            texture = int(texture)
            if texture in self._parked:
                continue
            self._upload(context, texture, full=False)
            self._parked.add(texture)
            parked_any = True
        return parked_any

    def _upload(self, context: mujoco.MjrContext, texture: int, full: bool) -> None:
        from OpenGL import GL  # PyOpenGL, a dependency of mujoco; same platform as MuJoCo's

        GL.glDeleteTextures(1, [int(context.texture[texture])])
        model = self._model
        width, height = int(model.tex_width[texture]), int(model.tex_height[texture])
        if not full:  # the texture's first texel, as a 1x1 texture (a cube of six 1x1 faces)
            model.tex_width[texture] = model.tex_height[texture] = 1
        try:
            mujoco.mjr_uploadTexture(model, context, texture)
        finally:
            model.tex_width[texture], model.tex_height[texture] = width, height
