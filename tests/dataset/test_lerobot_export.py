"""`crowdteleop dataset export --format lerobot`, loaded by LeRobot's own `LeRobotDataset`.

LeRobot 0.4.4 cannot live in the project's venv (it needs numpy 2 and torch < 2.11; robosuite
pins numpy < 2), so `scripts/lerobot-venv.sh` makes a virtualenv of its own, cached under
~/.cache/crowdteleop (~7 GB, a couple of minutes the first time), and
`tests/fixtures/lerobot_load.py` loads the export there and prints what LeRobot read as JSON.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import av
import h5py
import numpy as np
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from crowdteleop.cli import app
from crowdteleop.dataset import lerobot
from tests.fixtures.episodes import record_lift_episodes

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
CAMERA = "observation.images.agentview"
INSTRUCTION = "Pick up the red cube and lift it above the table."
N_DEMOS = 3
runner = CliRunner()


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Three scripted lift demos, built as `dataset build` builds them."""
    episodes = tmp_path_factory.mktemp("episodes")
    record_lift_episodes(episodes, N_DEMOS)
    output = tmp_path_factory.mktemp("dataset") / "demo.hdf5"
    built = runner.invoke(app, ["dataset", "build", str(episodes), "--output", str(output)])
    assert built.exit_code == 0, built.output
    return output


@pytest.fixture(scope="module")
def exported(dataset, tmp_path_factory):
    output = tmp_path_factory.mktemp("lerobot") / "lift"
    command = ["dataset", "export", str(dataset), "--format", "lerobot", "--output", str(output)]
    result = runner.invoke(
        app, [*command, "--camera", "agentview", "--width", "64", "--height", "48"]
    )
    assert result.exit_code == 0, result.output
    return output


def load_with_lerobot(python: str, root: Path, tmp_path: Path) -> dict:
    """What LeRobotDataset(repo_id, root=root, video_backend="pyav") reads, offline."""
    env = os.environ | {"HF_HUB_OFFLINE": "1", "HF_HOME": str(tmp_path / "hf")}
    script = str(ROOT / "tests" / "fixtures" / "lerobot_load.py")
    loaded = subprocess.run(
        [python, "-W", "ignore::UserWarning", script, str(root)],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )
    assert loaded.returncode == 0, loaded.stdout + loaded.stderr
    return json.loads(loaded.stdout.strip().splitlines()[-1])


def channel_means(video: Path) -> list[list[float]]:
    """Every frame of ``video`` decoded by PyAV here, as per-channel means in [0, 1]."""
    with av.open(str(video)) as container:
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    return [(frame.reshape(-1, 3).mean(axis=0) / 255).tolist() for frame in frames]


def test_lerobot_loads_the_export(dataset, exported, lerobot_python, tmp_path):
    read = load_with_lerobot(lerobot_python, exported, tmp_path)
    info = json.loads((exported / "meta/info.json").read_text())
    assert read["len"] == info["total_frames"] == sum(e["length"] for e in read["episodes"])
    assert read["num_episodes"] == N_DEMOS and read["total_tasks"] == 1
    assert read["fps"] == 20 and read["fps_type"] == "int"
    assert read["robot_type"] == "sawyer" and read["tasks_index_name"] == "task"
    # every frame's task is the instruction, not its index
    assert {frame["task"] for frame in read["frames"]} == {INSTRUCTION}
    assert [frame["index"] for frame in read["frames"]] == list(range(read["len"]))
    # episode boundaries: contiguous, frames numbered from 0 in each, videos back to back
    start, video_start = 0, 0.0
    for e, episode in enumerate(read["episodes"]):
        assert episode["episode_index"] == e and episode["tasks"] == [INSTRUCTION]
        assert episode["dataset_from_index"] == start
        assert episode["dataset_to_index"] == start + episode["length"]
        assert episode[f"videos/{CAMERA}/from_timestamp"] == pytest.approx(video_start)
        frames = read["frames"][start : episode["dataset_to_index"]]
        assert {f["episode_index"] for f in frames} == {e}
        assert [f["frame_index"] for f in frames] == list(range(episode["length"]))
        start, video_start = episode["dataset_to_index"], video_start + episode["length"] / 20
    # each episode's quality score (docs/quality.md), as the dataset gave it its demo
    with h5py.File(dataset, "r") as file:
        scores = [file[f"data/demo_{e + 1}"].attrs["quality_score"] for e in range(N_DEMOS)]
    assert [e["quality_score"] for e in read["episodes"]] == pytest.approx(scores)
    assert all(0 <= score <= 100 for score in scores)
    assert [e["review_decision"] for e in read["episodes"]] == [""] * N_DEMOS  # none decided
    # each frame's subtask (the stage the worker was in), named in meta/subtasks.parquet
    subtasks = pq.read_table(exported / "meta/subtasks.parquet").to_pydict()
    named = dict(zip(subtasks["subtask_index"], subtasks["subtask"], strict=True))
    first = read["frames"][0]["subtask_index"]
    assert named[first] == "reach (cube)" and named[read["frames"][-1]["subtask_index"]] == "done"
    assert read["second_episode_first"]["index"] == read["episodes"][1]["dataset_from_index"]
    assert read["second_episode_first"]["frame_index"] == 0
    assert read["window"] == {
        "action_shape": [3, 8],
        "action_is_pad": [True, False, False],  # the frame before an episode's first is padding
        "image_shape": [2, 3, 48, 64],
        "image_is_pad": [True, False],
    }
    # decoded frames: the right shape, not black, and the very frame PyAV decodes at that index
    here = channel_means(exported / f"videos/{CAMERA}/chunk-000/file-000.mp4")
    assert len(here) == read["len"]
    for index, image in read["images"].items():
        assert image["shape"] == [3, 48, 64] and image["dtype"] == "torch.float32"
        assert 0.05 < image["mean"] < 0.95 and image["max"] > 0.5
        assert image["mean"] == pytest.approx(sum(here[int(index)]) / 3, abs=1e-6)
    # names, and stats LeRobot's quantile normalisation and aggregate_stats accept
    assert (
        len(read["names"]["observation.state"]) == info["features"]["observation.state"]["shape"][0]
    )
    assert read["names"]["action"][-1] == "gripper" and len(read["names"]["action"]) == 8
    for feature in ("observation.state", "action", CAMERA):
        assert {"q01", "q10", "q50", "q90", "q99"} <= set(read["stats_keys"][feature])
        stats = {key: np.array(value).ravel() for key, value in read["stats"][feature].items()}
        order = [stats[key] for key in ("min", "q01", "q10", "q50", "q90", "q99", "max")]
        assert (np.diff(np.stack(order), axis=0) >= -1e-9).all()  # min <= q01 <= ... <= max
        assert (stats["q01"] < stats["q99"]).any()
        assert read["aggregated_mean_error"][feature] < 1e-6
    assert np.array(read["stats"][CAMERA]["mean"]).shape == (3, 1, 1)
    assert "observation.state" in read["episode_stats_columns"]
    assert CAMERA in read["episode_stats_columns"]


def test_episodes_split_across_files_and_chunks_by_size(
    dataset, exported, lerobot_python, tmp_path, monkeypatch
):
    """Tiny size limits and 2 files per chunk: LeRobot still finds every episode's frames."""
    monkeypatch.setattr(lerobot, "CHUNKS_SIZE", 2)
    one_video = exported / f"videos/{CAMERA}/chunk-000/file-000.mp4"
    video_mb = 0.8 * one_video.stat().st_size / 1024**2  # two episodes' clips, not three
    output = tmp_path / "split"
    lerobot.export_lerobot(
        dataset,
        output,
        ["agentview"],
        64,
        48,
        layout=lerobot.LeRobotLayout(data_files_size_in_mb=1e-6, video_files_size_in_mb=video_mb),
    )
    videos = sorted((output / "videos" / CAMERA).glob("*/*.mp4"))
    data = sorted((output / "data").glob("*/*.parquet"))
    assert [p.relative_to(output / "data").as_posix() for p in data] == [
        "chunk-000/file-000.parquet",
        "chunk-000/file-001.parquet",
        "chunk-001/file-000.parquet",
    ]
    assert len(videos) == 2 and len(list((output / "meta/episodes").glob("*/*.parquet"))) == 3
    assert all(pq.read_metadata(p).num_rows for p in data)
    clips = [len(channel_means(p)) for p in videos]
    assert videos[0].stat().st_size <= video_mb * 1024**2  # holds more than one episode
    read = load_with_lerobot(lerobot_python, output, tmp_path)
    whole = load_with_lerobot(lerobot_python, exported, tmp_path)
    assert read["frames"] == whole["frames"] and read["images"] == whole["images"]
    assert json.loads((output / "meta/info.json").read_text())["chunks_size"] == 2
    assert [e["data/file_index"] for e in read["episodes"]] == [0, 1, 0]
    assert [e["meta/episodes/file_index"] for e in read["episodes"]] == [0, 1, 0]
    assert [e[f"videos/{CAMERA}/file_index"] for e in read["episodes"]] == [0, 0, 1]
    assert read["episodes"][2][f"videos/{CAMERA}/from_timestamp"] == 0.0
    assert clips == [sum(e["length"] for e in read["episodes"][:2]), read["episodes"][2]["length"]]
