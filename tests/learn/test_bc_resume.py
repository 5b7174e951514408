"""BC-RNN runs are resumable: a run stopped after some epochs and resumed reaches the very
weights an unbroken run reaches, its log keeps every epoch once, and ``--demos`` trains on
the first n demos and says so in ``run.json`` for ``learn table``."""

from __future__ import annotations

import csv
import json

import pytest
import torch
from typer.testing import CliRunner

from crowdteleop.cli import app
from crowdteleop.learn.bc import load_checkpoint, train_bc
from crowdteleop.learn.config import BCConfig
from crowdteleop.learn.data import LearnDataError

SMALL = {"hidden_dim": 32, "batch_size": 16, "steps_per_epoch": 10, "learning_rate": 1e-3}


def weights(path):
    return load_checkpoint(path).net.state_dict()


def test_a_resumed_run_reaches_the_weights_of_an_unbroken_one(lift_dataset, tmp_path):
    torch.set_num_threads(1)
    train_bc(lift_dataset, tmp_path / "whole", BCConfig(epochs=4, **SMALL))
    train_bc(lift_dataset, tmp_path / "parts", BCConfig(epochs=2, **SMALL))
    report = train_bc(lift_dataset, tmp_path / "parts", BCConfig(epochs=4, **SMALL), resume=True)
    assert [row.epoch for row in report.epochs] == [3, 4], "only the missing epochs ran"
    whole, parts = weights(tmp_path / "whole/model.pt"), weights(tmp_path / "parts/model.pt")
    for name in whole:
        torch.testing.assert_close(whole[name], parts[name], rtol=0, atol=0)
    rows = list(csv.DictReader((tmp_path / "parts/log.csv").open()))
    assert [int(row["epoch"]) for row in rows] == [1, 2, 3, 4]


def test_demos_and_seeds_train_each_seed_on_the_first_n_and_run_json_says_so(
    lift_dataset, tmp_path
):
    result = CliRunner().invoke(
        app,
        [
            "learn",
            "bc",
            str(lift_dataset),
            "--output",
            str(tmp_path),
            "--epochs",
            "1",
            "--steps-per-epoch",
            "2",
            "--hidden-dim",
            "16",
            "--demos",
            "1",
            "--seeds",
            "2",
        ],
    )
    assert result.exit_code == 0, result.output
    for seed in (0, 1):
        info = json.loads((tmp_path / f"seed_{seed}" / "run.json").read_text())
        assert (info["algo"], info["task"], info["demos"], info["seed"]) == ("bc", "lift", 1, seed)
        checkpoint = load_checkpoint(tmp_path / f"seed_{seed}" / "model.pt")
        assert checkpoint.dataset["train_demos"] == 1 and checkpoint.config.seed == seed


def test_more_demos_than_the_split_holds_are_refused(lift_dataset, tmp_path):
    with pytest.raises(LearnDataError, match="3 training demos were asked for"):
        train_bc(lift_dataset, tmp_path, BCConfig(epochs=1, max_demos=3, **SMALL))
