"""`crowdteleop dataset score` (issue 29, item 2; docs/quality.md): each demo's share of the
state-action mutual information, learned from the dataset alone. Demonstrations whose actions
do not follow from the states score below every consistent one; the scores and their filter
keys are written into the dataset; bad input is a clear error."""

from __future__ import annotations

import shutil
import subprocess
import sys

import h5py
import numpy as np
import pytest

from crowdteleop.dataset.build import BuildOptions, build_dataset
from crowdteleop.dataset.files import DatasetError
from crowdteleop.dataset.score import ScoreConfig, score_dataset

pytestmark = pytest.mark.slow
SEEDS = range(8)
SPOILED = ("demo_3", "demo_6")  # their actions replaced by an unrelated operator's


def crowdteleop(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "crowdteleop", *args], capture_output=True, text=True, timeout=600
    )


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """Eight successful lift demonstrations by the steady scripted operator."""
    from crowdteleop.dataset.scripted import record_scripted_episode, scripted_rig

    directory = tmp_path_factory.mktemp("score")
    with scripted_rig("lift", "osc", robot="Panda") as rig:
        for seed in SEEDS:
            record_scripted_episode(rig, directory / "episodes", f"ep-{seed}", seed)
    output = directory / "demo.hdf5"
    build_dataset([directory / "episodes"], output, BuildOptions(drift_tolerance=None))
    return output


@pytest.fixture
def mixed(clean, tmp_path):
    """Two demos' actions shuffled in time: the same actions, no longer where they belong."""
    path = tmp_path / "mixed.hdf5"
    shutil.copy(clean, path)
    rng = np.random.default_rng(0)
    with h5py.File(path, "a") as file:
        for name in SPOILED:
            actions = file[f"data/{name}/actions"]
            actions[...] = actions[()][rng.permutation(len(actions))]
    return path


def test_demos_whose_actions_do_not_follow_the_states_score_lowest(mixed):
    result = score_dataset(mixed)
    scores = dict(zip(result.names, result.scores, strict=True))
    spoiled = [scores[name] for name in SPOILED]
    consistent = [score for name, score in scores.items() if name not in SPOILED]
    assert max(spoiled) < min(consistent), scores
    with h5py.File(mixed, "r") as file:
        written = {name: file[f"data/{name}"].attrs["deminf_score"] for name in file["data"]}
        bottom = {n.decode() for n in file["mask/deminf_bottom_50"][()]}
        top = {n.decode() for n in file["mask/deminf_top_50"][()]}
        settings = file["data"].attrs["deminf"]
    assert written == pytest.approx(scores)
    assert set(SPOILED) <= bottom and not set(SPOILED) & top and len(top) == len(bottom) == 4
    assert '"k": 5' in settings and "KSG" in settings


def test_scoring_again_replaces_the_scores_and_is_deterministic(mixed):
    first = score_dataset(mixed).scores
    again = score_dataset(mixed, ScoreConfig()).scores
    assert again == pytest.approx(first)
    other = score_dataset(mixed, ScoreConfig(k=3, samples_per_demo=16)).scores
    with h5py.File(mixed, "r") as file:
        assert file["data/demo_1"].attrs["deminf_score"] == pytest.approx(other[0])
        assert len(file["mask/deminf_top_50"][()]) == 4


def test_the_command_scores_and_says_so(mixed):
    run = crowdteleop("dataset", "score", str(mixed))
    assert run.returncode == 0, run.stdout + run.stderr
    output = " ".join(run.stdout.split())
    assert "8 demos scored" in output and "deminf_top_50" in output


def test_bad_input_is_a_clear_error(clean, tmp_path):
    missing = crowdteleop("dataset", "score", str(tmp_path / "nothing.hdf5"))
    assert missing.returncode != 0 and "Traceback" not in missing.stderr
    few = tmp_path / "few.hdf5"
    shutil.copy(clean, few)
    with h5py.File(few, "a") as file:
        for k in range(4, 9):
            del file[f"data/demo_{k}"]
    with pytest.raises(DatasetError, match="3 demos: scoring needs at least 4"):
        score_dataset(few)
    bare = tmp_path / "bare.hdf5"
    shutil.copy(clean, bare)
    with h5py.File(bare, "a") as file:
        del file["data/demo_2/obs/object"]
    with pytest.raises(DatasetError, match="demo_2 has no object"):
        score_dataset(bare)
    run = crowdteleop("dataset", "score", str(bare))
    assert run.returncode == 2 and "error:" in run.stderr and "Traceback" not in run.stderr
    with h5py.File(bare, "a") as file:
        del file["data/demo_1/actions"]
    with pytest.raises(DatasetError, match="demo_1 has no actions"):
        score_dataset(bare)
    foreign = tmp_path / "foreign.hdf5"
    with h5py.File(foreign, "w") as file:
        file["x"] = np.zeros(3)
    run = crowdteleop("dataset", "score", str(foreign))
    assert run.returncode == 2 and "not a crowdteleop dataset" in " ".join(run.stderr.split())
