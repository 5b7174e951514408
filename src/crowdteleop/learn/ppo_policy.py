"""sb3-contrib's recurrent policies with one change that makes training ~10x faster on CPU:
a sequence whose only episode start is its first step runs through the LSTM in one call.

``RecurrentPPO`` cuts its training sequences at episode starts, so every sequence is of that
kind; sb3-contrib's `_process_sequence` still steps the LSTM one step at a time whenever any
sequence starts an episode (its fast path needs no start at all). Zeroing the initial state of
the sequences that start an episode, then running them whole, computes the same thing.
"""

from __future__ import annotations

import torch as th
from sb3_contrib.common.recurrent.policies import (
    RecurrentActorCriticPolicy,
    RecurrentMultiInputActorCriticPolicy,
)
from torch import nn


def process_sequence(
    features: th.Tensor,
    lstm_states: tuple[th.Tensor, th.Tensor],
    episode_starts: th.Tensor,
    lstm: nn.LSTM,
) -> tuple[th.Tensor, tuple[th.Tensor, th.Tensor]]:
    """`RecurrentActorCriticPolicy._process_sequence`, whole sequences at once where the
    episode starts (if any) are at their first step."""
    n_seq = lstm_states[0].shape[1]
    steps = features.reshape((n_seq, -1, lstm.input_size)).swapaxes(0, 1)
    starts = episode_starts.reshape((n_seq, -1)).swapaxes(0, 1)
    if th.any(starts[1:] != 0.0):
        output, states = RecurrentActorCriticPolicy._process_sequence(
            features, lstm_states, episode_starts, lstm
        )
        return output, states  # type: ignore[return-value]  # sb3 annotates it loosely
    keep = (1.0 - starts[0]).view(1, n_seq, 1)
    output, states = lstm(steps, (keep * lstm_states[0], keep * lstm_states[1]))
    return th.flatten(output.transpose(0, 1), start_dim=0, end_dim=1), states


class LstmPolicy(RecurrentActorCriticPolicy):
    """``MlpLstmPolicy`` with whole-sequence LSTM passes."""

    _process_sequence = staticmethod(process_sequence)  # type: ignore[assignment]


class MultiInputLstmPolicy(RecurrentMultiInputActorCriticPolicy):
    """``MultiInputLstmPolicy`` (low-dim and image observations) with whole-sequence passes."""

    _process_sequence = staticmethod(process_sequence)  # type: ignore[assignment]
