"""
Warm starts of a new worker on a weighting of the terms from its nearest neighbour in a support: the
neighbour's network parameters, and its stored transitions relabelled with the new weights (a transition's
reward for a weighting is its normalised terms times the weights, which the stored term vectors make
possible without an env step).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.buffers import ReplayBuffer

from sb3_hddpg.artifacts.transitions import Transitions
from sb3_hddpg.callbacks.term_record import TermRecorder

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class WarmStart:
    """
    What a new worker starts from.

    :param neighbour: the neighbour's name (for the record).
    :param model: the neighbour's model (loaded through the safe loader).
    :param weights: the new worker's weighting, term -> weight, in the order of ``transitions.terms``' columns.
    :param transitions: the neighbour's stored transitions (``None``: parameters only).
    """

    neighbour: str
    model: BaseAlgorithm
    weights: Mapping[str, float]
    transitions: Transitions | None = None

    def prepare(self, model: BaseAlgorithm, recorder: TermRecorder | None) -> dict[str, object]:
        """
        Give a freshly built ``model`` the neighbour's parameters (when both are torch models of the same
        shapes) and its relabelled transitions (when ``model`` has a plain single-env replay buffer).

        :return: what was given: ``{"parameters": bool, "replay": count}``.
        """
        given: dict[str, object] = {
            "parameters": _copy_parameters(self.model, model, self.neighbour),
            "replay": 0,
        }
        buffer = getattr(model, "replay_buffer", None)
        if self.transitions is None or len(self.transitions) == 0:
            return given
        fits = isinstance(buffer, ReplayBuffer) and self.transitions.obs[0].size == int(
            np.prod(buffer.obs_shape)
        )
        if not fits or type(buffer) is not ReplayBuffer or buffer.n_envs != 1 or buffer.optimize_memory_usage:
            # A relabelling or multi-env buffer keeps more than rows: filling its arrays would break it.
            logger.warning("No replay warm start for a %s: parameters only", type(buffer).__name__)
            return given
        names = list(recorder.term_names) if recorder is not None else list(self.weights)
        count = fill_buffer(buffer, self.transitions, [self.weights.get(t, 0.0) for t in names])
        if recorder is not None:
            recorder.preload(buffer, self.transitions.last(count).terms)
        given["replay"] = count
        return given


def fill_buffer(buffer: ReplayBuffer, transitions: Transitions, weights: Sequence[float]) -> int:
    """
    Put the last transitions that fit into an empty single-env ``buffer``, each rewarded ``terms @ weights``.

    :return: how many were put in.
    """
    kept = transitions.last(buffer.buffer_size)
    count = len(kept)
    buffer.observations[:count, 0] = kept.obs.reshape(count, *buffer.obs_shape)
    buffer.next_observations[:count, 0] = kept.next_obs.reshape(count, *buffer.obs_shape)
    buffer.actions[:count, 0] = kept.actions.reshape(count, buffer.action_dim)
    buffer.rewards[:count, 0] = kept.terms @ np.asarray(weights, dtype=np.float32)
    buffer.dones[:count, 0] = 1.0 - kept.continues
    buffer.timeouts[:count, 0] = 0.0
    buffer.pos = count % buffer.buffer_size
    buffer.full = count == buffer.buffer_size
    return count


def _copy_parameters(source: BaseAlgorithm, target: BaseAlgorithm, name: str) -> bool:
    """Load ``source``'s policy parameters into ``target``'s where both are torch policies of the same shapes."""
    source_policy, target_policy = getattr(source, "policy", None), getattr(target, "policy", None)
    if not isinstance(source_policy, torch.nn.Module) or not isinstance(target_policy, torch.nn.Module):
        return False
    state = source_policy.state_dict()
    own = target_policy.state_dict()
    if set(state) != set(own) or any(state[k].shape != own[k].shape for k in own):
        logger.warning("Neighbour %r has other networks: the new worker starts from fresh parameters", name)
        return False
    target_policy.load_state_dict(state)
    return True
