"""A second MuJoCo model that only ever draws: same bodies and joints, lighter meshes.

The physics model stays untouched (its meshes, its data, its step). The render model is compiled
from the same MJCF with three changes: big visual meshes of moving bodies point to simplified
copies (`simplify.py`), the arena shrinks (``njmax=5000`` reserves 1.2 GiB of address space that
kinematics never uses), and multisampling is off (``offsamples=0``: per frame MSAA doubles
llvmpipe's time; the once-drawn background gets it separately, see `msaa.py`).
``stat.extent`` / ``stat.center`` are copied from the physics model because they set the clip
planes, which would otherwise move with the lighter meshes and shift every depth value.

Before each frame `sync` copies the configuration (qpos, mocap poses) and runs kinematics, a few
microseconds. `sync_appearance` mirrors what robosuite changes at run time (it hides its sites by
negating their alpha after the model is built, so the XML alone shows markers robosuite does not).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
import numpy.typing as npt

from crowdteleop.sim.fastrender.layers import Layers, moving_bodies
from crowdteleop.sim.fastrender.simplify import (
    SUPPORTED_SUFFIXES,
    SimplifiedMesh,
    SimplifyParams,
    simplified_mesh,
)
from crowdteleop.sim.mjcf import with_arena

# What robosuite (or a user) changes on the physics model at run time and the picture shows:
# colours (robosuite hides its markers this way), cameras, lights, and the placement of bodies
# without joints (PickPlace moves its target markers by editing `body_pos` at every reset).
APPEARANCE_FIELDS = (
    "geom_rgba", "site_rgba", "mat_rgba", "cam_pos", "cam_quat", "cam_fovy",
    "light_pos", "light_dir", "light_active", "light_diffuse", "light_ambient",
    "light_specular", "light_castshadow", "body_pos", "body_quat",
    "site_pos", "site_quat", "site_size",
)  # fmt: skip
# Per-geom placement and size, mirrored for geoms whose mesh was not replaced (a simplified
# mesh has its own centroid, so MuJoCo compiles its geom to a slightly different frame).
GEOM_FIELDS = ("geom_pos", "geom_quat", "geom_size")
RENDER_ARENA = "2M"  # kinematics and mjv_updateScene need next to no arena


@dataclass
class RenderModel:
    """The render-only model and data, kept in step with a physics model."""

    model: mujoco.MjModel
    data: mujoco.MjData
    meshes: list[SimplifiedMesh] = field(default_factory=list)
    samples: int = 4  # MSAA samples of the original picture (the physics model's offsamples)
    mirrored_geoms: npt.NDArray[np.intp] = field(default_factory=lambda: np.zeros(0, dtype=int))
    # Groups as compiled: the compositor reuses the group fields for its layers.
    geom_group: npt.NDArray[np.int32] = field(default_factory=lambda: np.zeros(0, dtype=int))
    site_group: npt.NDArray[np.int32] = field(default_factory=lambda: np.zeros(0, dtype=int))
    _seen: dict[str, bytes] = field(default_factory=dict)  # physics fields at the last sync

    @classmethod
    def build(
        cls,
        physics_model: mujoco.MjModel,
        physics_xml: str,
        visible_geom: npt.NDArray[np.bool_],
        simplify: bool = True,
        params: SimplifyParams | None = None,
    ) -> RenderModel:
        """Compile the render model; ``visible_geom`` marks geoms the picture shows."""
        root = ET.fromstring(physics_xml)
        meshes: dict[str, SimplifiedMesh] = {}
        if simplify:
            targets = simplifiable_meshes(physics_model, visible_geom, params or SimplifyParams())
            meshes = _point_meshes_to_simplified(root, targets, params or SimplifyParams())
        xml = with_arena(ET.tostring(root, encoding="unicode"), RENDER_ARENA)
        model = mujoco.MjModel.from_xml_string(xml)
        _check_same_structure(physics_model, model)
        model.vis.quality.offsamples = 0
        model.stat.extent = physics_model.stat.extent
        model.stat.center[:] = physics_model.stat.center
        for name in APPEARANCE_FIELDS:
            getattr(model, name)[:] = getattr(physics_model, name)
        replaced = [model.mesh(name).id for name, got in meshes.items() if got.path != got.source]
        on_replaced = (model.geom_type == mujoco.mjtGeom.mjGEOM_MESH) & np.isin(
            model.geom_dataid, replaced
        )
        mirrored = np.flatnonzero(~on_replaced)
        for name in GEOM_FIELDS:
            getattr(model, name)[mirrored] = getattr(physics_model, name)[mirrored]
        samples = int(physics_model.vis.quality.offsamples)
        return cls(
            model,
            mujoco.MjData(model),
            list(meshes.values()),
            samples,
            mirrored,
            model.geom_group.copy(),
            model.site_group.copy(),
        )

    def layers(self, hidden_geom_groups: tuple[int, ...]) -> Layers:
        """The compositor's layers for the current colours."""
        return Layers.of(self.model, self.geom_group, self.site_group, hidden_geom_groups)

    def sync(self, physics_data: mujoco.MjData) -> None:
        """Pose every body as in ``physics_data`` (read-only access to it)."""
        data = self.data
        data.qpos[:] = physics_data.qpos
        if self.model.nmocap:
            data.mocap_pos[:] = physics_data.mocap_pos
            data.mocap_quat[:] = physics_data.mocap_quat
        mujoco.mj_kinematics(self.model, data)
        mujoco.mj_comPos(self.model, data)  # cameras and lights that track a subtree's centre
        if self.model.ntendon:
            mujoco.mj_tendon(self.model, data)
        mujoco.mj_camlight(self.model, data)

    def sync_appearance(self, physics_model: mujoco.MjModel) -> bool:
        """Copy what changed of `APPEARANCE_FIELDS` / `GEOM_FIELDS`; True when anything did.

        A few dozen small array comparisons: cheap enough to run before every frame.
        """
        changed = False
        for name in (*APPEARANCE_FIELDS, *GEOM_FIELDS):
            source = getattr(physics_model, name)
            seen = source.tobytes()  # bytes compare: ~1 us per field, a third of array_equal
            if seen == self._seen.get(name):
                continue
            self._seen[name] = seen
            target = getattr(self.model, name)
            if name in GEOM_FIELDS:
                rows = self.mirrored_geoms
                if not np.array_equal(target[rows], source[rows]):
                    target[rows] = source[rows]
                    changed = True
            elif not np.array_equal(target, source):
                target[:] = source
                changed = True
        return changed


def simplifiable_meshes(
    model: mujoco.MjModel, visible_geom: npt.NDArray[np.bool_], params: SimplifyParams
) -> set[str]:
    """Names of meshes worth simplifying: big, untextured, drawn only on moving bodies.

    Meshes of static bodies are drawn once into the cached background (`compositor.py`), so
    they keep every triangle; textured meshes keep theirs because decimation drops texture
    coordinates.
    """
    moving = moving_bodies(model)
    eligible: dict[int, bool] = {}
    drawn_moving: set[int] = set()
    for geom in range(model.ngeom):
        if model.geom_type[geom] != mujoco.mjtGeom.mjGEOM_MESH:
            continue
        mesh = int(model.geom_dataid[geom])
        ok = eligible.get(mesh, True)
        if visible_geom[geom]:
            if moving[model.geom_bodyid[geom]]:
                drawn_moving.add(mesh)
            else:
                ok = False
        material = int(model.geom_matid[geom])
        if material >= 0 and np.any(model.mat_texid[material] >= 0):
            ok = False
        eligible[mesh] = ok
    return {
        model.mesh(mesh).name
        for mesh, ok in eligible.items()
        if ok and mesh in drawn_moving and model.mesh_facenum[mesh] >= params.min_faces
    }


def _point_meshes_to_simplified(
    root: ET.Element, names: set[str], params: SimplifyParams
) -> dict[str, SimplifiedMesh]:
    """Rewrite ``file`` of the named meshes to their simplified copies; by mesh name."""
    results = {}
    for element in root.iter("mesh"):
        file = element.get("file")
        if not file:
            continue
        source = Path(file)
        name = element.get("name") or source.stem
        if name not in names or not source.is_absolute():
            continue  # relative paths depend on a base directory we do not know: leave as is
        if source.suffix.lower() not in SUPPORTED_SUFFIXES or not source.exists():
            continue
        scale = np.abs(np.array(element.get("scale", "1 1 1").split(), dtype=float)).max()
        result = simplified_mesh(source, float(scale), params)
        element.set("file", str(result.path))
        results[name] = result
    return results


def _check_same_structure(physics: mujoco.MjModel, render: mujoco.MjModel) -> None:
    for name in ("nq", "nmocap", "nbody", "ngeom", "nsite", "ncam", "nlight", "nmat"):
        if getattr(physics, name) != getattr(render, name):
            raise ValueError(
                f"the MJCF does not describe the physics model ({name}: "
                f"{getattr(physics, name)} vs {getattr(render, name)}); pass the XML it was "
                "compiled from"
            )
