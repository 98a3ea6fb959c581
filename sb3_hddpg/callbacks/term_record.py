"""
:class:`TermRecorder`: the normalised reward terms of every transition an off-policy learner stores, kept
beside its replay buffer (SB3's buffer keeps no ``info``), so that a per-term critic can be trained on them
and the transitions relabelled with any weighting of the terms.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence

import numpy as np
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback

from sb3_hddpg.envs.contract import TermNormaliser

logger = logging.getLogger(__name__)


class TermRecorder(BaseCallback):
    """
    Records ``normalise(info["reward_terms"])`` of each env step at the replay buffer's position it is
    about to be stored at (SB3's off-policy loop calls ``on_step`` just before ``_store_transition``), so
    ``terms[i, e]`` belongs to the transition at ``buffer.observations[i, e]``; ``filled`` marks the rows
    this run wrote. SB3 and SBX learners alike.

    :param bounds: term name -> per-step ``(low, high)``: the env contract's bounds, in term order.
    """

    def __init__(self, bounds: Mapping[str, Sequence[float]]) -> None:
        super().__init__()
        self.normaliser = TermNormaliser(bounds)
        self.term_names = tuple(self.normaliser.bounds)
        self.buffer: ReplayBuffer | None = None
        self.terms = np.zeros((0, 0, len(self.term_names)), dtype=np.float32)
        self.filled = np.zeros((0, 0), dtype=bool)

    def _on_training_start(self) -> None:
        buffer = getattr(self.model, "replay_buffer", None)
        if not isinstance(buffer, ReplayBuffer):  # a dict-observation buffer stores rows differently
            logger.warning(
                "No per-term record for a %s: its worker gets no per-term critic", type(buffer).__name__
            )
            self.buffer = None
            return
        if buffer is not self.buffer:
            self._attach(buffer)

    def _on_step(self) -> bool:
        if self.buffer is None:
            return True
        position = self.buffer.pos
        for index, info in enumerate(self.locals["infos"]):
            normalised = self.normaliser(info["reward_terms"])
            self.terms[position, index] = [normalised[name] for name in self.term_names]
            self.filled[position, index] = True
        return True

    def preload(self, buffer: ReplayBuffer, terms: np.ndarray) -> None:
        """
        Record the terms of transitions put into ``buffer`` before training (a warm start's relabelled
        replay, in rows ``0..len(terms)-1`` of env 0), so that the critic learns from them too.
        """
        self._attach(buffer)
        self.terms[: len(terms), 0] = terms
        self.filled[: len(terms), 0] = True

    def _attach(self, buffer: ReplayBuffer) -> None:
        self.buffer = buffer
        self.terms = np.zeros((buffer.buffer_size, buffer.n_envs, len(self.term_names)), dtype=np.float32)
        self.filled = np.zeros((buffer.buffer_size, buffer.n_envs), dtype=bool)
