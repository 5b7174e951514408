"""What a BC-RNN run is: robomimic's stock low-dim ``bc_rnn`` settings, validated on
construction so a bad flag fails before a dataset is read."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from crowdteleop.learn.actions import ActionKey

Head = Literal["gmm", "deterministic"]

# robomimic's stock low-dim observation keys, in the order they are concatenated.
STOCK_OBS_KEYS = ("robot0_eef_pos", "robot0_eef_quat", "robot0_gripper_qpos", "object")


class BCConfig(BaseModel):
    """One training run: robomimic 0.3's BC-RNN (its ``BCConfig`` defaults with ``rnn``
    enabled): LSTM 2 x 400, sequences of 10, batch 100, Adam 1e-4, an epoch of 100 gradient
    steps. The head is deterministic, robomimic's default; ``head="gmm"`` is the 5-mode GMM of
    its low-dim paper configs, which did far worse on our scripted demos (docs/learning.md)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    obs_keys: tuple[str, ...] = Field(STOCK_OBS_KEYS, min_length=1)
    head: Head = "deterministic"
    actions: ActionKey = Field(
        "actions", description="the recorded deltas, or actions_abs: absolute hand targets"
    )
    num_modes: int = Field(5, ge=1, le=64, description="GMM modes")
    min_std: float = Field(1e-4, gt=0, description="GMM standard deviation floor")
    hidden_dim: int = Field(400, ge=1, le=4096)
    num_layers: int = Field(2, ge=1, le=8)
    seq_length: int = Field(10, ge=1, le=1000, description="training sequences; the RNN horizon")
    batch_size: int = Field(100, ge=1, le=100_000)
    learning_rate: float = Field(1e-4, gt=0, le=1)
    weight_decay: float = Field(0.0, ge=0)
    epochs: int = Field(200, ge=1)
    steps_per_epoch: int = Field(100, ge=1, description="gradient steps per epoch (robomimic's)")
    normalize_obs: bool = Field(False, description="standardize observations (robomimic: off)")
    train_filter: str = "train"
    valid_filter: str | None = "valid"
    seed: int = Field(0, ge=0)
    save_every: int = Field(0, ge=0, description="also keep epoch_<n>.pt every n epochs; 0: no")
