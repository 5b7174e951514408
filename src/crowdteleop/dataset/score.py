"""A learned score over a whole dataset, with no rollouts (`crowdteleop dataset score`,
docs/quality.md): how much each demonstration contributes to the mutual information between
states and actions, after DemInf (Hejna et al., "Robot Data Curation with Mutual Information
Estimators", 2025).

Why mutual information: in a consistent demonstration the action follows from the state (high
I(S; A)); a hesitant, noisy or erratic operator's actions are less predictable from where the
robot is, and policies trained on them learn that noise. DemInf estimates the per-sample term
of the Kraskov-Stoegbauer-Grassberger (KSG) k-nearest-neighbour estimator in a learned
embedding and averages it per demonstration; this module does the same with two simplifications
that keep a 1,000-demonstration campaign within seconds on 2 cores:

- the embedding is linear: each side (the low-dim observations, the actions) standardized,
  then projected on its leading principal components (`dims`), instead of DemInf's VAEs;
- each demonstration contributes `samples_per_demo` evenly spaced steps.

Per sample i of N, with eps_i the max-norm distance to its k-th neighbour in the joint
(state, action) space and n_s, n_a the samples strictly within eps_i in each marginal:
``psi(k) + psi(N) - psi(n_s + 1) - psi(n_a + 1)`` (KSG's first estimator). A demo's score is
the mean over its samples, in nats; higher is better.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial import cKDTree
from scipy.special import digamma

from crowdteleop.dataset.files import DatasetError
from crowdteleop.dataset.quality import halves

Floats = npt.NDArray[np.float64]
OBS_KEYS = ("robot0_eef_pos", "robot0_eef_quat", "robot0_gripper_qpos", "object")
MIN_DEMOS = 4
ATTR = "deminf_score"
MASKS = ("deminf_top_50", "deminf_bottom_50")


class ScoreConfig(BaseModel):
    """The estimator's settings (written into the dataset beside the scores)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    k: int = Field(5, ge=1, le=50, description="neighbours of the KSG estimator")
    samples_per_demo: int = Field(64, ge=4, le=10_000, description="steps taken per demo")
    dims: int = Field(8, ge=1, le=64, description="principal components kept per side")
    seed: int = Field(0, description="of the tie-breaking jitter")


@dataclass(frozen=True)
class DemoScores:
    names: list[str]
    scores: list[float]  # nats, per demo
    samples: int
    seconds: float = 0.0


def score_dataset(
    path: Path,
    config: ScoreConfig | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> DemoScores:
    """Score every demo of the dataset at `path` and write the scores into it."""
    import time

    config = config or ScoreConfig()
    started = time.perf_counter()
    with h5py.File(path, "a") as file:
        names, states, actions, owner = _samples(file, config.samples_per_demo, progress)
        per_sample = ksg_terms(embed(states, config.dims), embed(actions, config.dims), config)
        scores = [float(per_sample[owner == i].mean()) for i in range(len(names))]
        _write(file, names, scores, config)
    return DemoScores(names, scores, len(owner), time.perf_counter() - started)


def _samples(
    file: h5py.File, per_demo: int, progress: Callable[[int, int], None] | None
) -> tuple[list[str], Floats, Floats, npt.NDArray[np.int64]]:
    """Evenly spaced (state, action) samples of every demo, and which demo each is from."""
    if "data" not in file:
        raise DatasetError(f"{file.filename} has no data group: not a dataset")
    names = sorted(file["data"], key=lambda name: int(name.rpartition("_")[2]))
    if len(names) < MIN_DEMOS:
        raise DatasetError(f"{len(names)} demos: scoring needs at least {MIN_DEMOS}")
    states, actions, owner = [], [], []
    for i, name in enumerate(names):
        demo = file["data"][name]
        missing = [k for k in OBS_KEYS if f"obs/{k}" not in demo] + (
            [] if "actions" in demo else ["actions"]
        )
        if missing:
            raise DatasetError(
                f"{name} has no {', '.join(missing)}: build the dataset with low-dim "
                "observations (`dataset build --obs low-dim`)"
            )
        n = len(demo["actions"])
        steps = np.unique(np.linspace(0, n - 1, min(per_demo, n)).round().astype(int))
        states.append(np.concatenate([demo[f"obs/{k}"][()][steps] for k in OBS_KEYS], axis=1))
        actions.append(demo["actions"][()][steps])
        owner.append(np.full(len(steps), i))
        if progress is not None:
            progress(i + 1, len(names))
    return names, np.concatenate(states), np.concatenate(actions), np.concatenate(owner)


def embed(values: Floats, dims: int) -> Floats:
    """Standardized, then on the leading `dims` principal components (all if fewer)."""
    values = np.asarray(values, dtype=np.float64)
    spread = values.std(axis=0)
    standard: Floats = (values - values.mean(axis=0)) / np.where(spread > 1e-12, spread, 1.0)
    if standard.shape[1] <= dims:
        return standard
    _, _, components = np.linalg.svd(standard, full_matrices=False)
    projected: Floats = standard @ components[:dims].T
    return projected


def ksg_terms(states: Floats, actions: Floats, config: ScoreConfig) -> Floats:
    """Each sample's term of the KSG estimate of I(S; A) (nats)."""
    rng = np.random.default_rng(config.seed)
    # a tiny jitter breaks the ties of repeated samples (a robot holding still), as KSG needs
    states = states + 1e-9 * rng.standard_normal(states.shape)
    actions = actions + 1e-9 * rng.standard_normal(actions.shape)
    joint = np.concatenate([states, actions], axis=1)
    n = len(joint)
    k = min(config.k, n - 1)
    distances, _ = cKDTree(joint).query(joint, k=k + 1, p=np.inf, workers=-1)
    radius = np.nextafter(distances[:, -1], 0)  # strictly within the k-th neighbour
    n_s = _counts(states, radius)
    n_a = _counts(actions, radius)
    terms: Floats = digamma(k) + digamma(n) - digamma(n_s) - digamma(n_a)
    return terms


def _counts(points: Floats, radius: Floats) -> Floats:
    """Per point, the points within its radius, itself included (n + 1 of KSG)."""
    tree = cKDTree(points)
    counts = tree.query_ball_point(points, radius, p=np.inf, return_length=True, workers=-1)
    return np.asarray(counts, dtype=np.float64)


def _write(file: h5py.File, names: list[str], scores: list[float], config: ScoreConfig) -> None:
    for name, score in zip(names, scores, strict=True):
        file["data"][name].attrs[ATTR] = score
    file["data"].attrs["deminf"] = json.dumps(
        {"method": "KSG mutual information per demo (DemInf), linear embedding"}
        | config.model_dump()
    )
    masks = file.require_group("mask")
    for key, members in zip(MASKS, halves(names, scores), strict=True):
        if key in masks:
            del masks[key]
        masks.create_dataset(key, data=np.array(members, dtype="S"))
