"""`crowdteleop dataset build --filter` (issue 29, item 6; docs/review.md): the decisions
reviewers stored beside the episode files choose the demonstrations, and every dataset
carries them as filter keys and attributes; a malformed filter is a clear error."""

from __future__ import annotations

import re
import subprocess
import sys
import time

import h5py
import pytest

from crowdteleop.dataset.build import BuildOptions, build_dataset
from crowdteleop.dataset.files import DatasetError
from crowdteleop.dataset.selection import parse_filter
from crowdteleop.recording.review import ReviewRecord, review_name

pytestmark = pytest.mark.slow


def crowdteleop(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "crowdteleop", *args], capture_output=True, text=True, timeout=600
    )


SEEDS = (0, 1, 2, 3)


@pytest.fixture(scope="module")
def episodes(tmp_path_factory):
    """Four successful lift episodes, oldest first (demo_1-4 of a build of them all)."""
    from crowdteleop.dataset.scripted import record_scripted_episode, scripted_rig

    directory = tmp_path_factory.mktemp("reviewed")
    with scripted_rig("lift", "osc", robot="Panda") as rig:
        recorded = [record_scripted_episode(rig, directory, f"ep-{s}", s) for s in SEEDS]
    assert all(e.outcome == "success" for e in recorded)
    return directory, [e.path for e in recorded]


def decide(path, seq, decision, reason="", reviewer="ana"):
    """What the coordinator stores beside an episode when a reviewer decides."""
    record = ReviewRecord(
        episode_id=path.stem,
        seq=seq,
        decision=decision,
        reason=reason,
        reviewer=reviewer,
        at=time.time(),
    )
    (path.parent / review_name(path.name, seq)).write_text(record.model_dump_json())


@pytest.fixture
def reviewed(episodes, tmp_path):
    """ep-0 accepted; ep-1 rejected; ep-2 accepted, then undone; ep-3 never decided."""
    import shutil

    source, paths = episodes
    directory = tmp_path / "episodes"
    shutil.copytree(source, directory)
    copies = [directory / path.name for path in paths]
    decide(copies[0], 1, "accepted")
    decide(copies[1], 1, "rejected", "the cube slipped twice", reviewer="ben")
    decide(copies[2], 1, "accepted")
    decide(copies[2], 2, None)  # undo
    return directory


def masks_and_attrs(output):
    with h5py.File(output, "r") as file:
        masks = {key: sorted(n.decode() for n in file["mask"][key][()]) for key in file["mask"]}
        attrs = {name: dict(file["data"][name].attrs) for name in file["data"]}
    return masks, attrs


def test_every_dataset_carries_the_decisions_as_filter_keys_and_attributes(reviewed, tmp_path):
    output = tmp_path / "all.hdf5"
    build_dataset([reviewed], output, BuildOptions(drift_tolerance=None))
    masks, attrs = masks_and_attrs(output)
    assert masks["accepted"] == ["demo_1"]
    assert masks["rejected"] == ["demo_2"]
    assert attrs["demo_2"]["review_decision"] == "rejected"
    assert attrs["demo_2"]["review_reason"] == "the cube slipped twice"
    assert attrs["demo_2"]["reviewer"] == "ben"
    assert attrs["demo_3"]["review_decision"] == "", "an undone decision is no decision"
    assert attrs["demo_4"]["review_decision"] == ""


def test_filter_accepted_leaves_out_the_rejected_and_the_undecided(reviewed, tmp_path):
    output = tmp_path / "accepted.hdf5"
    run = crowdteleop(
        "dataset",
        "build",
        str(reviewed),
        "--output",
        str(output),
        "--filter",
        "accepted",
        "--drift-tolerance",
        "-1",
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert "1 demos" in run.stdout and "3 left out by --filter" in run.stdout
    masks, attrs = masks_and_attrs(output)
    assert list(attrs) == ["demo_1"] and attrs["demo_1"]["review_decision"] == "accepted"
    assert masks["accepted"] == ["demo_1"] and masks["rejected"] == []


def test_not_rejected_keeps_the_undecided(reviewed, tmp_path):
    output = tmp_path / "kept.hdf5"
    options = BuildOptions(drift_tolerance=None, filters=[parse_filter("not-rejected")])
    report = build_dataset([reviewed], output, options)
    assert len(report.demos) == 3 and report.filtered_out == 1


def test_filters_combine_and_a_score_filter_keeps_the_better_scored(reviewed, tmp_path):
    everything = build_dataset([reviewed], tmp_path / "a.hdf5", BuildOptions(drift_tolerance=None))
    _, attrs = masks_and_attrs(tmp_path / "a.hdf5")
    scores = sorted(a["quality_score"] for a in attrs.values())
    cut = scores[2]  # the two best
    options = BuildOptions(drift_tolerance=None, filters=[parse_filter(f"score>={cut}")])
    report = build_dataset([reviewed], tmp_path / "b.hdf5", options)
    assert len(report.demos) == 2 == len(everything.demos) - 2
    both = [parse_filter(f"score>={cut}"), parse_filter("not-rejected")]
    combined = build_dataset(
        [reviewed], tmp_path / "c.hdf5", BuildOptions(drift_tolerance=None, filters=both)
    )
    assert len(combined.demos) <= 2


def test_a_filter_nothing_passes_writes_nothing_and_says_so(episodes, tmp_path):
    source, _ = episodes  # never reviewed
    output = tmp_path / "none.hdf5"
    options = BuildOptions(drift_tolerance=None, filters=[parse_filter("accepted")])
    with pytest.raises(DatasetError, match="none of the 4 episodes passes --filter accepted"):
        build_dataset([source], output, options)
    assert not output.exists()


@pytest.mark.parametrize("text", ["acepted", "score>=101", "score>x", "score<=50", ""])
def test_a_malformed_filter_is_a_clear_error_naming_the_forms(episodes, tmp_path, text):
    source, _ = episodes
    output = tmp_path / "bad.hdf5"
    run = crowdteleop("dataset", "build", str(source), "--output", str(output), "--filter", text)
    output_text = " ".join((run.stdout + run.stderr).split())
    assert run.returncode != 0 and "unknown filter" in output_text
    assert "accepted, not-rejected, unflagged, score>=N" in output_text
    assert "Traceback" not in output_text and not output.exists()


def test_an_unreadable_decision_is_named(reviewed, tmp_path):
    (reviewed / review_name("ep-3.hdf5", 1)).write_text("{not json")
    with pytest.raises(DatasetError, match=re.escape("ep-3.review.000001.json")):
        build_dataset([reviewed], tmp_path / "x.hdf5", BuildOptions(drift_tolerance=None))
