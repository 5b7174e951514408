"""Which geoms and sites go into the cached background and which are drawn every frame.

MuJoCo filters what a scene holds by group (``mjvOption.geomgroup`` / ``sitegroup``), so the
render model's groups are rewritten into layers (its own copy: the physics model keeps its own):

* `STATIC` - opaque, on bodies welded to the world: drawn once per camera and size.
* `STATIC_SEE_THROUGH` - transparent, on static bodies (PickPlace's target markers): in the
  background *and* every frame. MuJoCo draws transparent geoms without writing depth, so a moving
  part seen through one must be drawn with it, blended on top, to look as it does in one pass.
* `MOVING` - everything on a body with a joint or a mocap body above it: every frame.
* `MOVING_SEE_THROUGH` - transparent and moving (robosuite's mocap target boxes and spheres): only
  in one-pass frames. A frame is composited only when none of them can show in front of the
  background (see below), and then none can show in front of a moving part either: in the moving
  pass they would blend over nothing and be dropped by the depth comparison, for ~2k triangles.
* `HIDDEN` - what the original picture does not show (robosuite's collision geoms, group 0).

Some scenes cannot be split without changing the picture; `Layers.composite_ok` says so and the
renderer then draws the whole scene in one pass (still on the simplified meshes):
lights that cast shadows (a moving arm's shadow falls on the static table, the table's on the
arm), skins and flexes (deformable, drawn in neither layer cleanly). robosuite's arenas light the
scene with ``castshadow="false"``, so its scenes composite.

Transparent *moving* things (robosuite's mocap target boxes, its gripper markers when shown) would
be lost against the background; `Layers.see_through_moving_*` lists them so the compositor can check
each frame whether any could be seen (they usually sit under the floor) and draw that frame in
one pass if so.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import numpy.typing as npt

MOVING_SEE_THROUGH, STATIC_SEE_THROUGH, STATIC, MOVING, HIDDEN = 1, 2, 3, 4, 5
SHOWN_BY_DEFAULT = np.array(mujoco.MjvOption().geomgroup, dtype=bool)  # groups 0-2
SITES_SHOWN_BY_DEFAULT = np.array(mujoco.MjvOption().sitegroup, dtype=bool)


@dataclass(frozen=True)
class Layers:
    """The layer of every geom and site, and the options that draw each pass."""

    geom_layer: npt.NDArray[np.int32]
    site_layer: npt.NDArray[np.int32]
    composite_ok: bool
    see_through_moving_geoms: npt.NDArray[np.intp]  # geom ids
    see_through_moving_sites: npt.NDArray[np.intp]  # site ids
    shadows: bool = False  # an active light casts shadows (the GL context needs a shadow map)

    @classmethod
    def of(
        cls,
        model: mujoco.MjModel,
        geom_group: npt.NDArray[np.int32],
        site_group: npt.NDArray[np.int32],
        hidden_geom_groups: tuple[int, ...],
    ) -> Layers:
        """Layers of ``model`` given its current colours (call again when they change).

        ``geom_group`` / ``site_group`` are the groups the model was compiled with: `apply`
        overwrites the model's own.
        """
        moving = moving_bodies(model)
        geom_shown = SHOWN_BY_DEFAULT[np.clip(geom_group, 0, 5)].copy()
        for group in hidden_geom_groups:
            geom_shown &= geom_group != group
        geom_alpha = effective_alpha(model.geom_rgba, model.geom_matid, model.mat_rgba)
        geom_shown &= geom_alpha > 0
        geom_moving = moving[model.geom_bodyid]
        geom_clear = geom_alpha < 1
        geom_layer = _assign(geom_shown, geom_moving, geom_clear)

        site_alpha = effective_alpha(model.site_rgba, model.site_matid, model.mat_rgba)
        site_shown = SITES_SHOWN_BY_DEFAULT[np.clip(site_group, 0, 5)] & (site_alpha > 0)
        site_moving = moving[model.site_bodyid]
        site_clear = site_alpha < 1
        site_layer = _assign(site_shown, site_moving, site_clear)

        shadows = bool(np.any(model.light_castshadow & model.light_active))
        return cls(
            geom_layer=geom_layer,
            site_layer=site_layer,
            composite_ok=not shadows and model.nskin == 0 and model.nflex == 0,
            see_through_moving_geoms=np.flatnonzero(geom_shown & geom_moving & geom_clear),
            see_through_moving_sites=np.flatnonzero(site_shown & site_moving & site_clear),
            shadows=shadows,
        )

    def apply(self, model: mujoco.MjModel) -> None:
        """Write the layers into the render model's group fields."""
        model.geom_group[:] = self.geom_layer
        model.site_group[:] = self.site_layer

    def option(self, *layers: int) -> mujoco.MjvOption:
        """Scene options that draw exactly ``layers`` (MuJoCo's default flags otherwise)."""
        option = mujoco.MjvOption()
        option.geomgroup[:] = 0
        option.sitegroup[:] = 0
        for layer in layers:
            option.geomgroup[layer] = 1
            option.sitegroup[layer] = 1
        if MOVING not in layers:  # tendons hang on moving bodies
            option.flags[mujoco.mjtVisFlag.mjVIS_TENDON] = 0
        return option


def moving_bodies(model: mujoco.MjModel) -> npt.NDArray[np.bool_]:
    """Bodies that can move: a joint or a mocap body on the path to the world."""
    moving = np.zeros(model.nbody, dtype=bool)
    for body in range(1, model.nbody):  # parents come before children
        moving[body] = (
            moving[model.body_parentid[body]]
            or model.body_jntnum[body] > 0
            or model.body_mocapid[body] >= 0
        )
    return moving


def camera_is_static(model: mujoco.MjModel, camera: int) -> bool:
    """A camera whose pose never changes: fixed (or tracking) on a body welded to the world."""
    body = int(model.cam_bodyid[camera])
    mode = int(model.cam_mode[camera])
    fixed_modes = (mujoco.mjtCamLight.mjCAMLIGHT_FIXED, mujoco.mjtCamLight.mjCAMLIGHT_TRACK)
    return not moving_bodies(model)[body] and mode in fixed_modes


def effective_alpha(
    rgba: npt.NDArray[np.float32],
    material: npt.NDArray[np.int32],
    mat_rgba: npt.NDArray[np.float32],
) -> npt.NDArray[np.float32]:
    """The alpha MuJoCo draws a geom or site with: its own rgba wins unless it is the default
    grey, then its material's.

    At most 0 draws nothing, so such parts go in no layer: GL clamps the alpha to 0 and MuJoCo
    draws them blended without writing depth, which leaves every pixel as it was. robosuite hides
    its markers by negating their alpha; drawing them anyway (a 10 m gripper axis cylinder and
    half a dozen finely tessellated spheres) cost ~0.6 ms of a ~4 ms moving pass.
    Strictly between 0 and 1, MuJoCo blends (see-through parts).
    """
    default = np.all(rgba == np.array([0.5, 0.5, 0.5, 1.0], dtype=np.float32), axis=1)
    material_alpha = mat_rgba[np.maximum(material, 0), 3] if len(mat_rgba) else 1.0
    return np.where(default & (material >= 0), material_alpha, rgba[:, 3])


def _assign(
    shown: npt.NDArray[np.bool_], moving: npt.NDArray[np.bool_], clear: npt.NDArray[np.bool_]
) -> npt.NDArray[np.int32]:
    layer = np.full(shown.shape, HIDDEN, dtype=np.int32)
    layer[shown & ~moving & ~clear] = STATIC
    layer[shown & ~moving & clear] = STATIC_SEE_THROUGH
    layer[shown & moving & ~clear] = MOVING
    layer[shown & moving & clear] = MOVING_SEE_THROUGH
    return layer
