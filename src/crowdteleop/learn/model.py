"""The BC-RNN network as robomimic 0.3 builds it for low-dim inputs (``RNNGMMActorNetwork``
with no MLP layers): the concatenated observation into an LSTM, its output straight into the
head. The GMM head squashes means with tanh, floors softplus scales at ``min_std``, and at
evaluation samples a mode and takes its mean (robomimic's ``low_noise_eval``); the
deterministic head is tanh(linear) trained with mean squared error (robomimic's BC-RNN)."""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn import functional

from crowdteleop.learn.config import BCConfig

RNNState = tuple[torch.Tensor, torch.Tensor]


class RNNPolicyNet(nn.Module):
    """Observations (B, T, D), in the units training normalised them to, to actions in
    [-1, 1] (the dataset's actions divided by their per-dimension scale)."""

    def __init__(self, obs_dim: int, action_dim: int, config: BCConfig) -> None:
        super().__init__()
        self.action_dim = action_dim
        self.head = config.head
        self.num_modes = config.num_modes if config.head == "gmm" else 1
        self.min_std = config.min_std
        self.rnn = nn.LSTM(obs_dim, config.hidden_dim, config.num_layers, batch_first=True)
        hidden = config.hidden_dim
        if config.head == "gmm":
            self.mean = nn.Linear(hidden, self.num_modes * action_dim)
            self.scale = nn.Linear(hidden, self.num_modes * action_dim)
            self.logits = nn.Linear(hidden, self.num_modes)
        else:
            self.mean = nn.Linear(hidden, action_dim)

    def features(
        self, obs: torch.Tensor, state: RNNState | None = None
    ) -> tuple[torch.Tensor, RNNState]:
        out, new_state = self.rnn(obs, state)
        return out, new_state

    def _means(self, features: torch.Tensor) -> torch.Tensor:
        """(B, T, modes, A) in [-1, 1]."""
        shape = (*features.shape[:-1], self.num_modes, self.action_dim)
        return torch.tanh(self.mean(features)).reshape(shape)

    def log_likelihood(self, features: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """log p(actions) under the mixture of diagonal Gaussians, per step (B, T)."""
        means = self._means(features)
        scales = functional.softplus(self.scale(features)).reshape(means.shape) + self.min_std
        z = (actions[..., None, :] - means) / scales
        per_mode = (-0.5 * z**2 - torch.log(scales) - 0.5 * math.log(2 * math.pi)).sum(-1)
        weights = torch.log_softmax(self.logits(features), dim=-1)
        return torch.logsumexp(weights + per_mode, dim=-1)

    def loss(self, obs: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """GMM: negative log-likelihood of the actions; deterministic: mean squared error."""
        features, _ = self.features(obs)
        if self.head == "gmm":
            return -self.log_likelihood(features, actions).mean()
        return functional.mse_loss(self._means(features)[..., 0, :], actions)

    @torch.no_grad()
    def most_likely(self, obs: torch.Tensor) -> torch.Tensor:
        """The mean of each step's most probable mode (B, T, A): a head-independent error."""
        features, _ = self.features(obs)
        means = self._means(features)
        if self.head != "gmm":
            return means[..., 0, :]
        best = self.logits(features).argmax(dim=-1)
        index = best[..., None, None].expand(*best.shape, 1, self.action_dim)
        return means.gather(-2, index)[..., 0, :]

    @torch.no_grad()
    def act(
        self,
        obs: torch.Tensor,
        state: RNNState | None,
        generator: torch.Generator | None = None,
    ) -> tuple[torch.Tensor, RNNState]:
        """One step for a batch (B, D) of observations: actions (B, A) and the next state.
        The GMM samples its mode from the logits (with ``generator``), as robomimic does."""
        features, new_state = self.features(obs[:, None, :], state)
        features = features[:, 0]
        means = self._means(features)
        if self.head != "gmm":
            return means[:, 0], new_state
        probs = torch.softmax(self.logits(features), dim=-1)
        mode = torch.multinomial(probs, 1, generator=generator)[:, 0]
        return means[torch.arange(len(mode)), mode], new_state
