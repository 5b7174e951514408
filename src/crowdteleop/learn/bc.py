"""Behaviour cloning with an RNN policy (robomimic's BC-RNN): training, checkpoints, and the
stateful policy the evaluators step.

A checkpoint is a plain dict in one ``torch.save`` file, loadable with ``weights_only=True``:
the config, the observation keys and their sizes, the normalisation, the weights, and what
rebuilds the dataset's environments (``env_args``, ``sim_config``), so evaluating needs
nothing but the checkpoint.
"""

from __future__ import annotations

import csv
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import numpy.typing as npt
import torch

from crowdteleop.learn.actions import from_learned
from crowdteleop.learn.config import BCConfig
from crowdteleop.learn.data import (
    DemoArrays,
    LearnData,
    LearnDataError,
    SequenceSampler,
    load_learn_data,
)
from crowdteleop.learn.envs import robosuite_scene
from crowdteleop.learn.model import RNNPolicyNet, RNNState
from crowdteleop.learn.observations import ObservationForm, observation_form

CHECKPOINT_FORMAT = "crowdteleop-bc-rnn"
CHECKPOINT_VERSION = 1
LOG_FIELDS = ("epoch", "train_loss", "valid_loss", "valid_action_mse", "seconds")


@dataclass(frozen=True)
class EpochLog:
    epoch: int
    train_loss: float
    valid_loss: float | None  # None without valid demos
    valid_action_mse: float | None  # most likely action vs the demo's, normalised units
    seconds: float  # since training began


@dataclass(frozen=True)
class TrainReport:
    checkpoint: Path
    log: Path
    epochs: list[EpochLog] = field(default_factory=list)
    seconds: float = 0.0
    train_demos: int = 0
    valid_demos: int = 0
    task: str = ""  # the dataset's, for run.json


@dataclass(frozen=True)
class Normalisation:
    """obs -> (obs - mean) / std; actions -> actions / scale, so the tanh head reaches them."""

    obs_mean: npt.NDArray[np.float64]
    obs_std: npt.NDArray[np.float64]
    action_scale: npt.NDArray[np.float64]

    @classmethod
    def fit(cls, demos: list[DemoArrays], standardize_obs: bool) -> Normalisation:
        obs = np.concatenate([d.obs for d in demos])
        actions = np.concatenate([d.actions for d in demos])
        mean, std = np.zeros(obs.shape[1]), np.ones(obs.shape[1])
        if standardize_obs:
            mean, std = obs.mean(axis=0), np.maximum(obs.std(axis=0), 1e-3)
        # OSC actions already lie in [-1, 1] and stay as robomimic trains them; joint
        # velocities (rad/s) beyond it are divided by their largest magnitude.
        scale = np.maximum(np.abs(actions).max(axis=0), 1.0)
        return cls(mean, std, scale)

    def demo(self, demo: DemoArrays) -> DemoArrays:
        return DemoArrays(
            demo.name, (demo.obs - self.obs_mean) / self.obs_std, demo.actions / self.action_scale
        )


def _training_data(dataset: Path, config: BCConfig) -> LearnData:
    """The dataset's train and valid demos, the train ones cut to ``config.max_demos``."""
    data = load_learn_data(
        dataset, config.obs_keys, config.train_filter, config.valid_filter, config.actions
    )
    if config.max_demos is None:
        return data
    if config.max_demos > len(data.train):
        raise LearnDataError(
            f"{dataset}: {config.max_demos} training demos were asked for; "
            f"mask/{config.train_filter} lists {len(data.train)}"
        )
    return replace(data, train=data.train[: config.max_demos])


def _observation_form(data: LearnData, config: BCConfig) -> ObservationForm:
    """How the policy sees the dataset's observations (`BCConfig.obs_rotation`)."""
    scene = None
    if config.obs_rotation != "quaternion" and data.env_args:
        scene = robosuite_scene(data.env_args)
    return observation_form(config.obs_rotation, data.obs_keys, data.obs_dims, scene)


def _train_epoch(
    net: RNNPolicyNet,
    optimizer: torch.optim.Optimizer,
    train: SequenceSampler,
    config: BCConfig,
    rng: np.random.Generator,
) -> float:
    """``config.steps_per_epoch`` gradient steps; the mean training loss."""
    net.train()
    losses = []
    for _ in range(config.steps_per_epoch):
        obs, actions = train.sample(config.batch_size, rng)
        loss = net.loss(_tensor(obs), _tensor(actions))
        optimizer.zero_grad()
        loss.backward()  # type: ignore[no-untyped-call]  # torch leaves it untyped
        optimizer.step()
        losses.append(loss.item())
    return float(np.mean(losses))


def train_bc(
    dataset: Path,
    output: Path,
    config: BCConfig,
    on_epoch: Callable[[EpochLog], None] | None = None,
    threads: int = 1,
    resume: bool = False,
) -> TrainReport:
    """Train on the dataset's ``config.train_filter`` demos, log every epoch to
    ``output/log.csv`` and write ``output/model.pt`` (plus ``model_best_valid.pt`` when there
    are valid demos, and ``epoch_<n>.pt`` every ``save_every`` epochs). ``resume.pt`` holds
    what continuing needs (weights, optimizer, random states) after every epoch: with
    ``resume`` a run continues from it to the same weights an unbroken run reaches."""
    torch.set_num_threads(threads)
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    data = _training_data(dataset, config)
    form = _observation_form(data, config)
    data = replace(
        data, train=[form.demo(d) for d in data.train], valid=[form.demo(d) for d in data.valid]
    )
    norm = Normalisation.fit(data.train, config.normalize_obs)
    train = SequenceSampler([norm.demo(d) for d in data.train], config.seq_length)
    valid = SequenceSampler([norm.demo(d) for d in data.valid], config.seq_length)
    net = RNNPolicyNet(form.learned_dim, data.action_dim, config)
    optimizer = torch.optim.Adam(
        net.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay
    )
    output.mkdir(parents=True, exist_ok=True)
    log_path = output / "log.csv"
    report = TrainReport(
        output / "model.pt", log_path, [], 0.0, len(data.train), len(data.valid), data.task
    )
    progress = _Progress()
    if resume and (output / RESUME_FILE).exists():
        progress = _restore(output / RESUME_FILE, net, optimizer, rng)
    started = time.perf_counter() - progress.seconds
    best_valid = progress.best_valid
    kept = _log_rows(log_path, progress.epoch)
    with open(log_path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, LOG_FIELDS)
        writer.writeheader()
        writer.writerows(kept)
        for epoch in range(progress.epoch + 1, config.epochs + 1):
            train_loss = _train_epoch(net, optimizer, train, config, rng)
            valid_loss, valid_mse = _validate(net, valid)
            row = EpochLog(epoch, train_loss, valid_loss, valid_mse, time.perf_counter() - started)
            report.epochs.append(row)
            if valid_loss is not None and valid_loss < best_valid:
                best_valid = valid_loss
                _save(output / "model_best_valid.pt", net, (config, data, form), norm, _meta(row))
            if config.save_every and epoch % config.save_every == 0:
                _save(output / f"epoch_{epoch}.pt", net, (config, data, form), norm, _meta(row))
            _keep(
                output / RESUME_FILE, net, optimizer, rng, _Progress(epoch, best_valid, row.seconds)
            )
            writer.writerow({k: "" if v is None else v for k, v in vars(row).items()})
            handle.flush()
            if on_epoch is not None:
                on_epoch(row)
    seconds = time.perf_counter() - started
    meta = {"epoch": config.epochs, "train_seconds": seconds}
    _save(report.checkpoint, net, (config, data, form), norm, meta)
    return replace(report, seconds=seconds)


RESUME_FILE = "resume.pt"


@dataclass(frozen=True)
class _Progress:
    epoch: int = 0
    best_valid: float = float("inf")
    seconds: float = 0.0


def _meta(row: EpochLog) -> dict[str, float]:
    return {"epoch": row.epoch, "train_seconds": row.seconds}


def _keep(
    path: Path,
    net: RNNPolicyNet,
    optimizer: torch.optim.Optimizer,
    rng: np.random.Generator,
    progress: _Progress,
) -> None:
    state = {
        "net": net.state_dict(),
        "optimizer": optimizer.state_dict(),
        "numpy_rng": rng.bit_generator.state,
        "torch_rng": torch.get_rng_state(),
        "progress": vars(progress),
    }
    tmp = path.with_name(f".{path.name}.tmp")
    torch.save(state, tmp)
    tmp.replace(path)


def _restore(
    path: Path, net: RNNPolicyNet, optimizer: torch.optim.Optimizer, rng: np.random.Generator
) -> _Progress:
    state = torch.load(path, map_location="cpu", weights_only=False)  # our own file
    net.load_state_dict(state["net"])
    optimizer.load_state_dict(state["optimizer"])
    rng.bit_generator.state = state["numpy_rng"]
    torch.set_rng_state(state["torch_rng"])
    return _Progress(**state["progress"])


def _log_rows(path: Path, up_to_epoch: int) -> list[dict[str, str]]:
    """The log's rows of the epochs a resumed run keeps (none for a fresh run)."""
    if not up_to_epoch or not path.exists():
        return []
    with open(path, newline="") as handle:
        return [row for row in csv.DictReader(handle) if int(row["epoch"]) <= up_to_epoch]


def _tensor(array: npt.NDArray[np.float64]) -> torch.Tensor:
    return torch.as_tensor(array, dtype=torch.float32)


def _validate(net: RNNPolicyNet, valid: SequenceSampler) -> tuple[float | None, float | None]:
    """Loss and most-likely-action error over every valid window (None without any)."""
    if not len(valid):
        return None, None
    net.eval()
    losses, errors, weights = [], [], []
    rows = valid.all_rows()
    with torch.no_grad():
        for chunk in np.array_split(rows, max(1, len(rows) // 1000)):
            obs, actions = valid.windows(chunk)
            obs_t, actions_t = _tensor(obs), _tensor(actions)
            losses.append(float(net.loss(obs_t, actions_t)))
            errors.append(float(((net.most_likely(obs_t) - actions_t) ** 2).mean()))
            weights.append(len(chunk))
    return float(np.average(losses, weights=weights)), float(np.average(errors, weights=weights))


def _save(
    path: Path,
    net: RNNPolicyNet,
    run: tuple[BCConfig, LearnData, ObservationForm],
    norm: Normalisation,
    meta: Mapping[str, float],
) -> None:
    config, data, form = run
    checkpoint = {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "config": config.model_dump(mode="json"),
        "obs_keys": list(data.obs_keys),
        "obs_dims": list(data.obs_dims),
        "obs_quaternions": list(form.quaternions),  # offsets in the raw vector made 6D
        "action_dim": data.action_dim,
        "obs_mean": norm.obs_mean.tolist(),
        "obs_std": norm.obs_std.tolist(),
        "action_scale": norm.action_scale.tolist(),
        "state_dict": net.state_dict(),
        "dataset": {
            "path": str(data.path),
            "env_args": data.env_args,
            "sim_config": data.sim_config,
            "task": data.task,
            "controller": data.controller,
            "abs_controller_configs": data.abs_controller_configs,
            "train_demos": len(data.train),
            "valid_demos": len(data.valid),
        },
        **meta,
    }
    tmp = path.with_name(f".{path.name}.tmp")
    torch.save(checkpoint, tmp)
    tmp.replace(path)  # a reader never sees half a checkpoint


@dataclass(frozen=True)
class Checkpoint:
    """A trained policy read back; ``net`` is in eval mode."""

    path: Path
    config: BCConfig
    obs_keys: tuple[str, ...]
    obs_dims: tuple[int, ...]
    form: ObservationForm
    norm: Normalisation
    net: RNNPolicyNet
    dataset: dict[str, object]  # what rebuilds its environments (`learn.evaluation`)
    epoch: int
    train_seconds: float


def load_checkpoint(path: Path) -> Checkpoint:
    from crowdteleop.learn.data import LearnDataError

    try:
        raw = torch.load(path, map_location="cpu", weights_only=True)
    except (OSError, RuntimeError) as exc:
        raise LearnDataError(f"{path}: not a readable checkpoint ({exc})") from exc
    if not isinstance(raw, dict) or raw.get("format") != CHECKPOINT_FORMAT:
        raise LearnDataError(f"{path} is not a {CHECKPOINT_FORMAT} checkpoint")
    config = BCConfig.model_validate(raw["config"])
    form = ObservationForm(sum(raw["obs_dims"]), tuple(raw.get("obs_quaternions", ())))
    net = RNNPolicyNet(form.learned_dim, int(raw["action_dim"]), config)
    net.load_state_dict(raw["state_dict"])
    net.eval()
    norm = Normalisation(
        np.asarray(raw["obs_mean"]), np.asarray(raw["obs_std"]), np.asarray(raw["action_scale"])
    )
    return Checkpoint(
        Path(path),
        config,
        tuple(raw["obs_keys"]),
        tuple(raw["obs_dims"]),
        form,
        norm,
        net,
        dict(raw["dataset"]),
        int(raw["epoch"]),
        float(raw["train_seconds"]),
    )


class Policy:
    """A checkpoint stepped one observation at a time. As robomimic's ``BC_RNN.get_action``,
    the LSTM state starts from zero every ``rnn_horizon`` steps (the trained sequence length
    unless told; 0: carried through the whole episode) and at every ``reset``."""

    def __init__(self, checkpoint: Checkpoint, rnn_horizon: int | None = None) -> None:
        self.checkpoint = checkpoint
        self.rnn_horizon = checkpoint.config.seq_length if rnn_horizon is None else rnn_horizon
        self._state: RNNState | None = None
        self._steps = 0
        self._generator = torch.Generator().manual_seed(0)

    def reset(self, seed: int = 0) -> None:
        self._state, self._steps = None, 0
        self._generator.manual_seed(seed)

    def act(
        self, obs: Mapping[str, npt.NDArray[np.generic]] | npt.NDArray[np.generic]
    ) -> npt.NDArray[np.float64]:
        """The action for one observation, in the layout of the dataset's ``config.actions``
        array: a dict by robomimic's keys (extra keys are ignored), or those keys already
        concatenated in order (a `learn.envs` environment's low-dim observation)."""
        ckpt = self.checkpoint
        if isinstance(obs, np.ndarray):
            flat = np.asarray(obs, dtype=np.float64).ravel()
        else:
            flat = np.concatenate(
                [np.asarray(obs[k], dtype=np.float64).ravel() for k in ckpt.obs_keys]
            )
        if flat.shape != (sum(ckpt.obs_dims),):
            raise ValueError(f"observation of size {flat.shape} for keys of sizes {ckpt.obs_dims}")
        learned = ckpt.form.apply(flat[None])[0]
        x = _tensor(((learned - ckpt.norm.obs_mean) / ckpt.norm.obs_std)[None])
        if self.rnn_horizon and self._steps % self.rnn_horizon == 0:
            self._state = None
        action, self._state = ckpt.net.act(x, self._state, self._generator)
        self._steps += 1
        row = action[0].double().numpy() * ckpt.norm.action_scale
        return from_learned(row, ckpt.config.actions)
