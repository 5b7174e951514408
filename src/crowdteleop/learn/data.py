"""A built dataset read for learning: each demo's low-dim observations concatenated in a fixed
key order, its actions, the train / valid split, and what rebuilds its environments.

Sequences are drawn as robomimic's ``SequenceDataset`` draws them (``pad_seq_length``): any
step may start one, and a sequence running past the demo's end repeats its last step, so the
policy learns the final steps as often as the first.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import numpy.typing as npt

from crowdteleop.errors import CrowdteleopError
from crowdteleop.learn.actions import ActionKey, to_learned

Array = npt.NDArray[np.float64]


class LearnDataError(CrowdteleopError, ValueError):
    """A dataset that cannot train a policy (no observations, unknown keys, empty split)."""


@dataclass(frozen=True)
class DemoArrays:
    name: str
    obs: Array  # (N, D): the observation keys concatenated in order
    actions: Array  # (N, A): in the form the policy learns (`learn.actions.to_learned`)


@dataclass(frozen=True)
class LearnData:
    """Everything training needs of a dataset, read once into memory (low-dim data is small)."""

    path: Path
    obs_keys: tuple[str, ...]
    obs_dims: tuple[int, ...]
    train: list[DemoArrays]
    valid: list[DemoArrays]
    env_args: dict[str, object]
    sim_config: dict[str, object]
    task: str
    controller: str
    action_key: ActionKey = "actions"
    # robosuite's controller that reads ``actions_abs`` (``actions_abs_controller_configs``)
    abs_controller_configs: dict[str, object] | None = None

    @property
    def action_dim(self) -> int:
        return int(self.train[0].actions.shape[1])


def load_learn_data(
    path: Path,
    obs_keys: tuple[str, ...],
    train_filter: str = "train",
    valid_filter: str | None = "valid",
    action_key: ActionKey = "actions",
) -> LearnData:
    """The dataset's demos under the two filter keys; refuses a dataset without ``obs/`` (or
    without ``action_key``)."""
    with open_learn_dataset(path) as file:
        data = file["data"]
        first = data[demo_names(data)[0]]
        if "obs" not in first:
            raise LearnDataError(
                f"{path} has no observations (data/demo_*/obs); rebuild it with "
                "`crowdteleop dataset build ... --obs low-dim`"
            )
        missing = [key for key in obs_keys if key not in first["obs"]]
        if missing:
            raise LearnDataError(
                f"{path} lacks observation keys {missing}; it has {sorted(first['obs'])}"
            )
        if action_key not in first:
            raise LearnDataError(
                f"{path} has no {action_key!r} per demo; rebuild it with `crowdteleop dataset "
                "build` (it writes actions_abs for osc and ik-velocity demos)"
            )
        train = [
            _read_demo(data[name], obs_keys, action_key)
            for name in filter_members(file, train_filter)
        ]
        if not train:
            raise LearnDataError(f"{path}: filter key {train_filter!r} lists no demos")
        valid = (
            [
                _read_demo(data[name], obs_keys, action_key)
                for name in filter_members(file, valid_filter)
            ]
            if valid_filter is not None and f"mask/{valid_filter}" in file
            else []
        )
        metadata = json.loads(attr_text(first.attrs.get("metadata", "{}")))
        return LearnData(
            path=Path(path),
            obs_keys=obs_keys,
            obs_dims=tuple(int(first["obs"][key].shape[1]) for key in obs_keys),
            train=train,
            valid=valid,
            env_args=json.loads(attr_text(data.attrs.get("env_args", "{}"))),
            sim_config=dict(metadata.get("sim_config") or {}),
            task=attr_text(first.attrs.get("task", metadata.get("task", ""))),
            controller=attr_text(first.attrs.get("controller", metadata.get("controller") or "")),
            action_key=action_key,
            abs_controller_configs=json.loads(
                attr_text(data.attrs.get("actions_abs_controller_configs", "null"))
            ),
        )


def dataset_env_args(path: Path) -> dict[str, object]:
    """robomimic's ``env_args`` of a built dataset (empty if it names none)."""
    with open_learn_dataset(path) as file:
        return dict(json.loads(attr_text(file["data"].attrs.get("env_args", "{}"))))


def open_learn_dataset(path: Path) -> h5py.File:
    """The dataset open for reading; refused clearly if it is no HDF5 or holds no demos."""
    try:
        file = h5py.File(path, "r")
    except OSError as exc:
        raise LearnDataError(f"{path}: not a readable HDF5 dataset ({exc})") from exc
    if "data" not in file or not len(file["data"]):
        file.close()
        raise LearnDataError(f"{path} holds no demonstrations (no data/demo_*)")
    return file


def demo_names(data: h5py.Group) -> list[str]:
    """``data/demo_<k>`` names by their number."""
    return sorted(data, key=lambda name: int(name.rpartition("_")[2]))


def filter_members(file: h5py.File, filter_key: str | None) -> list[str]:
    """The demos ``mask/<filter_key>`` lists (none for None); an unknown key is refused."""
    if filter_key is None:
        return []
    if f"mask/{filter_key}" not in file:
        raise LearnDataError(
            f"no filter key {filter_key!r}; the dataset has {sorted(file.get('mask', {}))}"
        )
    return [attr_text(name) for name in file[f"mask/{filter_key}"][()]]


def _read_demo(group: h5py.Group, obs_keys: tuple[str, ...], action_key: ActionKey) -> DemoArrays:
    obs = np.concatenate(
        [
            np.asarray(group["obs"][key], dtype=np.float64).reshape(len(group["actions"]), -1)
            for key in obs_keys
        ],
        axis=1,
    )
    actions = to_learned(np.asarray(group[action_key], dtype=np.float64), action_key)
    return DemoArrays(group.name.rpartition("/")[2], obs, actions)


def attr_text(value: object) -> str:
    """An HDF5 attribute as text (h5py gives bytes or str)."""
    return value.decode() if isinstance(value, bytes) else str(value)


class SequenceSampler:
    """Random fixed-length windows from a list of demos, padded past each demo's end."""

    def __init__(self, demos: list[DemoArrays], seq_length: int) -> None:
        self.seq_length = seq_length
        self._obs = [d.obs for d in demos]
        self._actions = [d.actions for d in demos]
        # every (demo, start) pair: robomimic samples windows uniformly over them
        self._starts = np.array(
            [(i, t) for i, d in enumerate(demos) for t in range(len(d.actions))], dtype=np.int64
        )

    def __len__(self) -> int:
        return len(self._starts)

    def windows(self, rows: npt.NDArray[np.int64]) -> tuple[Array, Array]:
        """The windows starting at ``self._starts[rows]``: obs (B, T, D), actions (B, T, A)."""
        obs, actions = [], []
        offsets = np.arange(self.seq_length)
        for demo, start in self._starts[rows]:
            steps = np.minimum(start + offsets, len(self._actions[demo]) - 1)
            obs.append(self._obs[demo][steps])
            actions.append(self._actions[demo][steps])
        return np.stack(obs), np.stack(actions)

    def sample(self, batch_size: int, rng: np.random.Generator) -> tuple[Array, Array]:
        return self.windows(rng.integers(0, len(self._starts), size=batch_size))

    def all_rows(self) -> npt.NDArray[np.int64]:
        return np.arange(len(self._starts))
