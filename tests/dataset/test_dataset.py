"""Scripted demonstrations -> `crowdteleop dataset build | replay | stats | export`, read back by
robomimic's own loader, robosuite's playback, PyAV and pyarrow."""

from __future__ import annotations

import hashlib
import json
import shutil

import av
import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from crowdteleop.cli import app
from crowdteleop.dataset.build import BuildOptions, build_dataset
from crowdteleop.dataset.files import DatasetError, dataset_demos
from crowdteleop.dataset.scripted import record_scripted_episode, scripted_rig
from tests.fixtures.episodes import record_lift_episodes

runner = CliRunner()
N_SUCCESS = 6


@pytest.fixture(scope="module")
def episodes(tmp_path_factory):
    """Six successful scripted lift demos (two workers, two interfaces, two network
    conditions) and one that ran out of time."""
    directory = tmp_path_factory.mktemp("episodes")
    with scripted_rig("lift") as rig:
        recorded = record_lift_episodes(directory, N_SUCCESS, rig=rig)
        failed = record_scripted_episode(
            rig,
            directory,
            "lift-timeout",
            99,
            {"interface": "phone", "worker_id": "w1", "network_condition": "baseline"},
            time_limit_s=0.5,
        )
    assert [e.outcome for e in recorded] == ["success"] * N_SUCCESS
    assert failed.outcome == "timeout"
    return directory


@pytest.fixture(scope="module")
def dataset(episodes, tmp_path_factory):
    output = tmp_path_factory.mktemp("dataset") / "demo.hdf5"
    result = runner.invoke(
        app, ["dataset", "build", str(episodes), "--output", str(output), "--fastest", "3"]
    )
    assert result.exit_code == 0, result.output
    assert f"{N_SUCCESS} demos" in result.output
    return output


def test_the_dataset_has_robomimic_layout_and_our_metadata(dataset):
    with h5py.File(dataset, "r") as file:
        data = file["data"]
        env_args = json.loads(data.attrs["env_args"])
        assert env_args["env_name"] == "Lift" and env_args["type"] == 1
        assert env_args["env_kwargs"]["robots"] == ["Sawyer"]
        demos = sorted(data, key=lambda n: int(n.split("_")[1]))
        assert demos == [f"demo_{i}" for i in range(1, N_SUCCESS + 1)]
        assert data.attrs["total"] == sum(data[d].attrs["num_samples"] for d in demos)
        demo = data["demo_2"]
        n = demo.attrs["num_samples"]
        for name, width in (("states", 32), ("actions", 8)):
            assert demo[name].shape == (n, width)
        assert demo["rewards"].shape == demo["dones"].shape == (n,)
        assert demo["dones"][-1] == 1
        assert demo.attrs["model_file"].startswith("<mujoco")
        assert demo.attrs["worker"] == "w2" and demo.attrs["interface"] == "keyboard"
        assert demo.attrs["network_condition"] == "high-delay"
        assert demo.attrs["campaign"] == "tests" and demo.attrs["outcome"] == "success"
        assert demo.attrs["completion_time_s"] == pytest.approx(n / 20)
        assert json.loads(demo.attrs["simulator_versions"])["robosuite"] == "1.5.2"
        assert demo.attrs["schema_version"] == 1 and demo.attrs["action_replay_drift"] == 0.0
        mask = {key: sorted(v.decode() for v in file["mask"][key][()]) for key in file["mask"]}
    assert len(mask["valid"]) == 1 and len(mask["train"]) == N_SUCCESS - 1
    assert set(mask["train"]).isdisjoint(mask["valid"])
    assert mask["interface_phone"] == ["demo_1", "demo_3", "demo_5"]
    assert mask["worker_w2"] == ["demo_2", "demo_4", "demo_6"]
    assert mask["network_high-delay"] == mask["worker_w2"]
    assert len(mask["fastest_3"]) == 3 and len(mask["replay_ok"]) == N_SUCCESS


def test_robomimic_sequence_dataset_loads_it(dataset):
    import robomimic.utils.obs_utils as obs_utils
    from robomimic.utils.dataset import SequenceDataset

    obs_utils.initialize_obs_utils_with_obs_specs({"obs": {"low_dim": [], "rgb": []}})
    loaded = SequenceDataset(
        hdf5_path=str(dataset),
        obs_keys=(),
        dataset_keys=("actions", "rewards", "dones"),
        load_next_obs=False,
        frame_stack=1,
        seq_length=10,
        pad_frame_stack=True,
        pad_seq_length=True,
        get_pad_mask=False,
        goal_mode=None,
        hdf5_cache_mode="all",
        hdf5_use_swmr=True,
        hdf5_normalize_obs=False,
        filter_by_attribute="train",
    )
    with h5py.File(dataset, "r") as file:
        train = [d.decode() for d in file["mask/train"][()]]
        expected = sum(file["data"][d].attrs["num_samples"] for d in train)
        first_actions = file["data"][train[0]]["actions"][:10]
    assert len(loaded) == expected
    sample = loaded[0]
    assert sample["actions"].shape == (10, 8)
    np.testing.assert_array_equal(sample["actions"], first_actions.astype(np.float32))


def test_robosuite_playback_replays_its_states(dataset):
    from crowdteleop.dataset.robosuite_replay import play_states_in_robosuite

    playback = play_states_in_robosuite(str(dataset), "demo_3")
    assert playback.max_state_error == 0.0
    assert playback.success_at_end, "the last recorded state lifts the cube in plain robosuite"


def test_replay_writes_a_playable_mp4_and_checks_fidelity(dataset, tmp_path):
    video = tmp_path / "demo_2.mp4"
    result = runner.invoke(
        app,
        [
            "dataset",
            "replay",
            str(dataset),
            "--demo",
            "demo_2",
            "--camera",
            "agentview",
            "--width",
            "160",
            "--height",
            "120",
            "--output",
            str(video),
        ],
    )
    assert result.exit_code == 0, result.output
    assert "state replay exact" in result.output
    assert "each action from its recorded state: exact" in result.output
    assert "drift: max 0," in result.output
    with av.open(str(video)) as container:
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    with h5py.File(dataset, "r") as file:
        steps = file["data/demo_2"].attrs["num_samples"]
    assert len(frames) == steps and frames[0].shape == (120, 160, 3)
    assert np.abs(frames[-1].astype(int) - frames[0].astype(int)).mean() > 1, "the arm moved"


def test_stats_prints_the_papers_tables(episodes, tmp_path):
    out = tmp_path / "stats"
    result = runner.invoke(app, ["dataset", "stats", str(episodes), "--output", str(out)])
    assert result.exit_code == 0, result.output
    text = result.output
    assert "| All | 7 | 6 | 85.7% |" in text, "six of seven demonstrations succeeded"
    assert "across different interfaces" in text and "across different workers" in text
    assert "| | Mean | Standard Deviation | Num. Demonstrations | Success rate |" in text
    assert "| phone |" in text and "| keyboard |" in text
    assert "Kolmogorov-Smirnov statistic" in text
    report = json.loads((out / "stats.json").read_text())
    interfaces = report["tasks"]["lift"]["by"]["interface"]
    phone = interfaces["groups"][1]
    assert (phone["group"], phone["count"], phone["successes"]) == ("phone", 4, 3)
    ks = interfaces["ks"]["phone"]["keyboard"]
    assert 0 <= ks["statistic"] <= 1 and 0 <= ks["p_value"] <= 1
    assert len(list(out.glob("*.png"))) == 3


def test_action_replay_drift_is_flagged_at_ingestion(episodes, tmp_path):
    tampered = tmp_path / "in"
    tampered.mkdir()
    for name in ("lift-0.hdf5", "lift-1.hdf5"):
        shutil.copy(episodes / name, tampered / name)
    with h5py.File(tampered / "lift-1.hdf5", "a") as file:
        file["data/demo_0/actions"][5:, 0] += 0.5  # what a lossy action log would do
    report = build_dataset([tampered], tmp_path / "out.hdf5")
    assert report.flagged == ["demo_2"]
    demos = dataset_demos(tmp_path / "out.hdf5")
    assert demos[0].drift == 0.0 and demos[1].drift > 1e-3
    with h5py.File(tmp_path / "out.hdf5", "r") as file:
        assert file["data/demo_2"].attrs["action_replay_flagged"]
        assert [d.decode() for d in file["mask/replay_ok"][()]] == ["demo_1"]


def _sha(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_bad_inputs_give_a_clear_error_and_touch_nothing(episodes, dataset, tmp_path):
    inputs = tmp_path / "in"
    inputs.mkdir()
    shutil.copy(episodes / "lift-0.hdf5", inputs / "good.hdf5")
    truncated = inputs / "truncated.hdf5"
    truncated.write_bytes((episodes / "lift-1.hdf5").read_bytes()[:5000])
    existing = tmp_path / "existing.hdf5"
    shutil.copy(dataset, existing)
    before = _sha(existing), _sha(inputs / "good.hdf5")

    result = runner.invoke(
        app, ["dataset", "build", str(inputs), "--output", str(existing), "--overwrite"]
    )
    assert result.exit_code == 2
    assert "truncated.hdf5 is not a readable HDF5 file" in result.output
    assert (_sha(existing), _sha(inputs / "good.hdf5")) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["existing.hdf5", "in"], "no leftovers"

    truncated.unlink()
    with h5py.File(inputs / "foreign.hdf5", "w") as file:
        file.create_dataset("data/demo_0/states", data=np.zeros((3, 3)))
    with pytest.raises(DatasetError, match=r"foreign\.hdf5 is an HDF5 file but not a crowdteleop"):
        build_dataset([inputs], existing, overwrite=True)
    assert _sha(existing) == before[0]

    report = build_dataset([inputs], tmp_path / "skipped.hdf5", BuildOptions(skip_bad=True))
    assert len(report.demos) == 1 and "foreign.hdf5" in report.skipped[0][0]

    for command in (
        ["replay", str(inputs / "foreign.hdf5")],
        ["stats", str(inputs / "foreign.hdf5")],
        ["export", str(inputs / "foreign.hdf5"), "--output", str(tmp_path / "x")],
    ):
        result = runner.invoke(app, ["dataset", *command])
        assert result.exit_code == 2, result.output
        assert "not a crowdteleop" in result.output
    assert not (tmp_path / "x").exists()


@pytest.mark.slow
def test_export_rerenders_images_for_robomimic_and_lerobot(dataset, tmp_path):
    import pyarrow.parquet as pq
    import robomimic.utils.obs_utils as obs_utils
    from robomimic.utils.dataset import SequenceDataset

    exported = tmp_path / "image.hdf5"
    result = runner.invoke(
        app,
        [
            "dataset",
            "export",
            str(dataset),
            "--format",
            "robomimic",
            "--output",
            str(exported),
            "--camera",
            "agentview",
            "--camera",
            "frontview",
            "--width",
            "64",
            "--height",
            "48",
        ],
    )
    assert result.exit_code == 0, result.output
    assert "rendering agentview, frontview" in result.output
    obs_utils.initialize_obs_utils_with_obs_specs(
        {"obs": {"low_dim": ["robot0_eef_pos"], "rgb": ["agentview_image"]}}
    )
    loaded = SequenceDataset(
        hdf5_path=str(exported),
        obs_keys=("agentview_image", "robot0_eef_pos"),
        dataset_keys=("actions",),
        load_next_obs=True,
        frame_stack=1,
        seq_length=1,
        pad_frame_stack=True,
        pad_seq_length=True,
        get_pad_mask=False,
        goal_mode=None,
        hdf5_cache_mode="low_dim",
        hdf5_use_swmr=True,
        hdf5_normalize_obs=False,
        filter_by_attribute="valid",
    )
    sample = loaded[3]
    assert sample["obs"]["agentview_image"].shape == (1, 48, 64, 3)
    assert sample["obs"]["robot0_eef_pos"].shape == (1, 3)
    with h5py.File(exported, "r") as file:
        images = file["data/demo_1/obs/frontview_image"]
        assert images.dtype == np.uint8 and images.shape[1:] == (48, 64, 3)
        assert images.shape[0] == file["data/demo_1"].attrs["num_samples"]

    lerobot = tmp_path / "lerobot"
    result = runner.invoke(
        app,
        [
            "dataset",
            "export",
            str(dataset),
            "--format",
            "lerobot",
            "--output",
            str(lerobot),
            "--camera",
            "agentview",
            "--width",
            "64",
            "--height",
            "48",
        ],
    )
    assert result.exit_code == 0, result.output
    # the layout lerobot 0.4.4 reads (its own loader: tests/dataset/test_lerobot_export.py)
    info = json.loads((lerobot / "meta/info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["total_episodes"] == N_SUCCESS
    assert info["fps"] == 20 and isinstance(info["fps"], int)
    assert (info["data_files_size_in_mb"], info["video_files_size_in_mb"]) == (100, 200)
    video_feature = info["features"]["observation.images.agentview"]
    assert video_feature["dtype"] == "video" and video_feature["shape"] == [48, 64, 3]
    assert video_feature["info"]["video.fps"] == 20
    assert isinstance(video_feature["info"]["video.fps"], int)
    assert len(info["features"]["action"]["names"]) == 8
    state = info["features"]["observation.state"]
    assert len(state["names"]) == state["shape"][0] and "robot0_eef_pos.x" in state["names"]
    frames = pq.read_table(lerobot / "data/chunk-000/file-000.parquet")
    assert frames.num_rows == info["total_frames"]
    assert {
        "observation.state",
        "action",
        "timestamp",
        "episode_index",
        "index",
        "task_index",
        "frame_index",
    } <= set(frames.column_names)
    episodes = pq.read_table(lerobot / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [e["episode_index"] for e in episodes] == list(range(N_SUCCESS))
    assert episodes[-1]["dataset_to_index"] == frames.num_rows
    assert len(episodes[0]["stats/action/q01"]) == 8  # per-episode stats, as LeRobot writes them
    # the task string is the (pandas) index LeRobot names each frame's task by
    tasks = pq.read_table(lerobot / "meta/tasks.parquet")
    assert json.loads(tasks.schema.metadata[b"pandas"])["index_columns"] == ["task"]
    instruction = "Pick up the red cube and lift it above the table."
    assert tasks.to_pylist() == [{"task_index": 0, "task": instruction}]
    stats = json.loads((lerobot / "meta/stats.json").read_text())
    assert len(stats["action"]["mean"]) == 8
    for feature in ("observation.state", "action", "observation.images.agentview"):
        assert {"q01", "q10", "q50", "q90", "q99"} <= set(stats[feature])
    assert np.array(stats["observation.images.agentview"]["q99"]).shape == (3, 1, 1)
    video = lerobot / "videos/observation.images.agentview/chunk-000/file-000.mp4"
    with av.open(str(video)) as container:
        keyframes = [f.key_frame for f in container.decode(video=0)]
    assert len(keyframes) == frames.num_rows
    assert np.diff(np.flatnonzero(keyframes)).max() <= 2  # random access decodes <= 2 frames
    assert episodes[1]["videos/observation.images.agentview/from_timestamp"] == pytest.approx(
        episodes[0]["length"] / info["fps"]
    )


@pytest.mark.slow
def test_replay_measures_action_replay_drift_in_plain_robosuite(tmp_path):
    """The playback complaint, measured: an OSC demo's actions stepped in plain robosuite."""
    from crowdteleop.dataset.replay import ReplayChecker, load_demo

    with scripted_rig("lift", controller="osc") as rig:
        episode = record_scripted_episode(rig, tmp_path, "osc-demo", 5, {"interface": "phone"})
    assert episode.outcome == "success"
    with ReplayChecker() as checker:
        drift = checker.robosuite_drift(load_demo(episode.path))
    assert drift is not None and drift.steps == episode.steps
    assert drift.per_step_median_m < 0.001, "each action means the same in robosuite"
    assert drift.open_loop_final_m > drift.per_step_max_m, "open loop, small errors compound"
    result = runner.invoke(
        app,
        [
            "dataset",
            "replay",
            str(episode.path),
            "--robosuite",
            "--output",
            str(tmp_path / "osc.mp4"),
        ],
    )
    assert result.exit_code == 0, result.output
    assert "plain robosuite: hand drift per step median" in result.output
    # ours replays bit for bit: the recorded reset_seed restores the OSC's null-space posture
    assert "each action from its recorded state: exact" in result.output
    assert "drift: max 0," in result.output
