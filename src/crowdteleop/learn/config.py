"""What a BC-RNN run is: robomimic's stock low-dim ``bc_rnn`` settings, validated on
construction so a bad flag fails before a dataset is read."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from crowdteleop.learn.actions import ActionKey

Head = Literal["gmm", "deterministic"]
# how a BC policy sees quaternions: as recorded, or as 6D rotations (`learn.observations`)
ObsRotation = Literal["quaternion", "6d"]
# what `learn rl --algo` trains: the paper's PPO, SAC with demos in its buffer, SAC with IBRL
RlAlgo = Literal["ppo", "sac", "ibrl"]

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
    obs_rotation: ObsRotation = Field(
        "quaternion", description="quaternion inputs as recorded, or as 6D rotations"
    )
    train_filter: str = "train"
    valid_filter: str | None = "valid"
    max_demos: int | None = Field(None, ge=1, description="train on the first n train demos")
    seed: int = Field(0, ge=0)
    save_every: int = Field(0, ge=0, description="also keep epoch_<n>.pt every n epochs; 0: no")


VecKind = Literal["subproc", "dummy", "ray"]


class PPOConfig(BaseModel):
    """One demonstration-guided PPO run as the paper's Appendix sets it: 100-step training
    episodes, sparse reward, a start from a demonstration's state with probability 0.9, an
    actor and a critic each of LSTM 100 then fully connected 300 and 200, a Gaussian with a
    learned state-independent log-std. The paper leaves the rest to SURREAL (Fan et al. 2018),
    whose PPO starts that log-std at -1.0 (``init_log_sig`` in its ``ppo_configs.py``: a
    standard deviation of 0.37 in actions of [-1, 1]); the others are PPO's usual settings
    (sb3's defaults). The critic learns from rewards scaled by a running estimate of the
    return's spread (sb3's ``VecNormalize``): unscaled, a return of up to 100 per episode
    stalls the learner (lift, 100 demos: the training return flat at ~30 of 100 for a million
    steps, against 40-48 and successes from normal resets with it; benchmarks/learning.md).
    Curves and evaluation count the task's own reward."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    demos: int = Field(0, ge=0, description="demonstrations to start episodes from; 0: pure RL")
    demo_reset_p: float = Field(0.9, ge=0, le=1, description="chance a reset starts in a demo")
    horizon: int = Field(100, ge=1, description="steps per training episode (myopic horizon)")
    obs_keys: tuple[str, ...] = Field(STOCK_OBS_KEYS, min_length=1)
    total_steps: int = Field(200_000, ge=1, description="environment steps to train for")
    budget_s: float | None = Field(None, gt=0, description="also stop after this wall time")
    n_envs: int = Field(4, ge=1, le=1024, description="environments stepping in parallel")
    vec: VecKind = Field("subproc", description="where they run: subprocesses, inline, Ray")
    ray_address: str | None = Field(None, description="Ray cluster to join (vec=ray)")
    ray_actor_cpus: float = Field(1.0, gt=0, description="CPUs each Ray actor asks for")
    lstm_hidden: int = Field(100, ge=1)
    net_arch: tuple[int, ...] = (300, 200)
    n_steps: int = Field(256, ge=2, description="steps per environment per rollout")
    batch_size: int = Field(256, ge=2)
    n_epochs: int = Field(10, ge=1)
    learning_rate: float = Field(3e-4, gt=0, le=1)
    gamma: float = Field(0.99, gt=0, le=1)
    gae_lambda: float = Field(0.95, gt=0, le=1)
    clip_range: float = Field(0.2, gt=0)
    ent_coef: float = Field(0.0, ge=0)
    log_std_init: float = Field(-1.0, description="initial log standard deviation (SURREAL's)")
    normalize_obs: bool = Field(True, description="running observation standardization")
    normalize_reward: bool = Field(
        True, description="scale rewards by the running std of the discounted return"
    )
    eval_every: int = Field(10_000, ge=1, description="env steps between learning-curve points")
    eval_episodes: int = Field(10, ge=1, description="normal-reset episodes per curve point")
    checkpoint_every: int = Field(20_000, ge=1, description="env steps between checkpoints")
    seed: int = Field(0, ge=0)
    threads: int = Field(1, ge=1, description="torch CPU threads")


class SACConfig(BaseModel):
    """One run of SAC with the demonstrations in its replay buffer: RLPD's symmetric sampling
    (half of every batch from the demos, half from the run's own experience; Ball et al. 2023),
    the actor first fit to the demos (BC, the mean by squared error, as robomimic's
    deterministic head), and the critic trained alone for ``warmup_steps`` before the actor
    follows it, so a random critic does not first undo what BC taught. The reward is the
    task's sparse one; a training episode ends at its first solved step. With no demos it is
    plain SAC (random actions for ``learning_starts`` steps first), its entropy weight as
    fixed."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    demos: int = Field(0, ge=0, description="demonstrations in the buffer; 0: pure RL")
    demo_fraction: float = Field(0.5, ge=0, lt=1, description="share of each batch from demos")
    horizon: int = Field(200, ge=1, description="steps per training episode")
    obs_keys: tuple[str, ...] = Field(STOCK_OBS_KEYS, min_length=1)
    total_steps: int = Field(200_000, ge=1, description="environment steps to train for")
    budget_s: float | None = Field(None, gt=0, description="also stop after this wall time")
    net_arch: tuple[int, ...] = (256, 256)
    batch_size: int = Field(256, ge=2)
    buffer_size: int = Field(1_000_000, ge=1)
    learning_rate: float = Field(3e-4, gt=0, le=1)
    # a tenth of the critic's: the critic's guesses about the few-percent differences between
    # actions under a sparse reward are noisier than those differences at first
    actor_learning_rate: float | None = Field(3e-5, gt=0, le=1, description="None: the critic's")
    gamma: float = Field(0.99, gt=0, le=1)
    tau: float = Field(0.005, gt=0, le=1)
    # Fixed and small: the reward is 1 once per episode, and sb3's tuned weight (toward an
    # entropy of -7) grew to 0.05, an entropy bonus worth more than the task, whose pull on
    # squashed actions away from +-1 undid the cloned grasp within 10k steps.
    ent_coef: float = Field(1e-4, ge=0, description="entropy weight")
    learning_starts: int = Field(1000, ge=0, description="without demos: random steps first")
    bc_steps: int = Field(5000, ge=0, description="gradient steps fitting the actor to demos")
    bc_learning_rate: float = Field(1e-3, gt=0, le=1)
    bc_log_std: float = Field(-1.5, description="the exploration the BC actor starts with")
    warmup_steps: int = Field(5000, ge=0, description="env steps the critic learns alone")
    bc_weight: float = Field(10.0, ge=0, description="a BC step on demos after each actor step")
    imitation_bootstrap: bool = Field(
        False, description="IBRL: the cloned actor, frozen, proposes beside the learner"
    )
    max_return: float | None = Field(
        None, gt=0, description="IBRL's TD targets clipped to [0, this]; None: unclipped"
    )
    eval_every: int = Field(10_000, ge=1, description="env steps between learning-curve points")
    eval_episodes: int = Field(10, ge=1, description="normal-reset episodes per curve point")
    checkpoint_every: int = Field(20_000, ge=1, description="env steps between checkpoints")
    seed: int = Field(0, ge=0)
    threads: int = Field(1, ge=1, description="torch CPU threads")


# IBRL (Hu et al. 2023): SAC whose cloned actor, kept frozen, proposes an action beside the
# learner's at every step and in every TD target, the critic taking the better. The learner
# keeps SAC's cloning step and slow pace: freed of them (IBRL's own choice) it drifted onto
# actions the critic overrated, and lift with 10 demos fell from 30 % to 0-10 % (2 seeds).
# Targets are clipped to the task's returns (a reward of 1 that ends the episode): the max
# over two proposals overrates, and unclipped the estimates reached 100 within 60k steps.
IBRL_SETTINGS: dict[str, object] = {"imitation_bootstrap": True, "max_return": 1.0}
