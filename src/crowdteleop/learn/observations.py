"""The form a BC policy sees its observation in: as recorded, or with every quaternion as the
first two columns of its rotation matrix (the continuous "6D" form).

robosuite's quaternions (``robot0_eef_quat``, an object's ``*_quat`` and ``*_to_robot0_eef_quat``
inside ``object``) keep w >= 0 (``transform_utils.mat2quat``), so where w passes 0 the sign of
all four flips while the pose hardly moves, a jump of ~2 in four inputs. pick-place-can's can
sits right there (its x entry is +0.99 in one scene and -0.99 in the next; 100 flips in the
1,620 steps of the 10 scripted sources). The 6D form has no such jump (Zhou et al. 2019;
robomimic's diffusion policy trains rotations in it).

Which entries of ``object`` are quaternions robosuite knows, not the dataset: its observables of
the ``object`` modality, in the order robosuite concatenates them into ``object-state``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from crowdteleop.learn.actions import six_d
from crowdteleop.learn.config import ObsRotation
from crowdteleop.learn.data import DemoArrays, LearnDataError
from crowdteleop.learn.envs import RobosuiteScene

Array = npt.NDArray[np.float64]
QUATERNION_SIZE = 4
SIX_D_SIZE = 6


@dataclass(frozen=True)
class ObservationForm:
    """Raw concatenated observations -> the policy's inputs. ``quaternions`` are the offsets
    of (x, y, z, w) quaternions in the raw vector; none: the raw vector as it is."""

    raw_dim: int
    quaternions: tuple[int, ...] = ()

    @property
    def learned_dim(self) -> int:
        return self.raw_dim + (SIX_D_SIZE - QUATERNION_SIZE) * len(self.quaternions)

    def demo(self, demo: DemoArrays) -> DemoArrays:
        return DemoArrays(demo.name, self.apply(demo.obs), demo.actions)

    def apply(self, raw: Array) -> Array:
        """(N, raw_dim) -> (N, learned_dim), each quaternion replaced in place by its 6D form."""
        if raw.shape[-1] != self.raw_dim:
            raise ValueError(f"observations of size {raw.shape[-1]}, expected {self.raw_dim}")
        if not self.quaternions:
            return raw
        parts, start = [], 0
        for offset in self.quaternions:
            parts.append(raw[:, start:offset])
            quats = raw[:, offset : offset + QUATERNION_SIZE]
            parts.append(six_d(Rotation.from_quat(quats).as_matrix()))
            start = offset + QUATERNION_SIZE
        parts.append(raw[:, start:])
        return np.concatenate(parts, axis=1)


def observation_form(
    rotation: ObsRotation,
    obs_keys: Sequence[str],
    obs_dims: Sequence[int],
    scene: RobosuiteScene | None,
) -> ObservationForm:
    """The form ``rotation`` asks for over these keys: ``robot0_eef_quat``-like keys (a name
    ending in ``quat``, size 4) are quaternions, and inside ``object`` those robosuite's scene
    names so. A 6D form over an ``object`` needs the dataset's robosuite scene."""
    raw_dim = int(sum(obs_dims))
    if rotation == "quaternion":
        return ObservationForm(raw_dim)
    offsets: list[int] = []
    start = 0
    for key, size in zip(obs_keys, obs_dims, strict=True):
        if key.endswith("quat") and size == QUATERNION_SIZE:
            offsets.append(start)
        elif key == "object":
            if scene is None:
                raise LearnDataError(
                    "a 6D observation form needs the dataset's robosuite env_args to tell "
                    "which entries of 'object' are quaternions"
                )
            offsets.extend(start + offset for offset in object_quaternions(scene, size))
        start += size
    return ObservationForm(raw_dim, tuple(offsets))


def object_quaternions(scene: RobosuiteScene, size: int) -> list[int]:
    """Offsets of the quaternions in the scene's ``object-state`` (robosuite's observables of
    the object modality, in its order: each one not a robot's, not an image, not a ``-state``
    concatenation), checked against ``object-state`` itself."""
    os.environ.setdefault("PYNPUT_BACKEND", "dummy")  # robosuite.devices wants a display
    import robosuite

    env = robosuite.make(scene.env_name, **scene.env_kwargs)
    try:
        return _quaternion_offsets(env.observation_spec(), size)
    finally:
        env.close()


def _quaternion_offsets(spec: Mapping[str, object], size: int) -> list[int]:
    names, parts = [], []
    for name, value in spec.items():
        array = np.asarray(value, dtype=np.float64)
        if name.endswith("-state") or name.startswith("robot") or array.ndim > 1:
            continue
        names.append(name)
        parts.append(array.reshape(-1))
    whole = np.asarray(spec.get("object-state", np.zeros(0)), dtype=np.float64)
    joined = np.concatenate(parts) if parts else np.zeros(0)
    if joined.shape != (size,) or not np.array_equal(joined, whole):
        raise LearnDataError(
            f"robosuite's object observables {names} do not make up this dataset's 'object' "
            f"({size} values): cannot tell which of them are quaternions"
        )
    offsets, start = [], 0
    for name, part in zip(names, parts, strict=True):
        if name.endswith("quat") and part.size == QUATERNION_SIZE:
            offsets.append(start)
        start += part.size
    return offsets
