"""
Cheap frozen workers: a trained policy used for inference only, as a copy that never changes the caller's
model, acting through plain numpy where its actor is a small MLP.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from sb3_hddpg.policy import Policy


class FrozenWorker:
    """
    A worker used for inference only, as cheaply as possible. An SB3 actor of ``Linear`` layers and common
    activations (DDPG/TD3's ``actor.mu``; SAC/TQC's ``latent_pi`` + ``mu`` + tanh without gSDE) is compiled
    into numpy products on copies of its weights, about 10x faster than torch for one observation
    (``benchmarks/manager_env_speed.py``); any other SB3 policy runs a frozen copy under ``torch.no_grad()``.
    Either way the caller's model can keep training.
    Anything else (a ``Hierarchy``, the HAM switch) is called through ``predict(obs, deterministic=True)``.

    :param worker: the worker.
    :param obs_indices: which entries of the shared state the worker sees (``None``: all).
    """

    def __init__(self, worker: Policy, obs_indices: np.ndarray | None = None) -> None:
        self.worker = worker
        self.obs_indices = obs_indices
        #: The state given to a stateful worker's ``predict`` (a nested hierarchy's options of the env acting
        #: now); ``None``: the worker keeps its own.
        self.state: Any = None
        policy = getattr(worker, "policy", None)
        # A discrete SB3 policy (DQN) acts through predict: its integer actions need no scaling.
        acts_in_box = isinstance(getattr(policy, "action_space", None), gym.spaces.Box)
        self._policy = policy if acts_in_box and hasattr(policy, "_predict") else None
        self._layers: (
            list[tuple[np.ndarray, np.ndarray, Callable[[np.ndarray], np.ndarray] | None]] | None
        ) = None
        if self._policy is not None:
            space = self._policy.action_space
            squash = bool(getattr(self._policy, "squash_output", False))
            self._low = space.low.astype(np.float32)
            self._half_range = ((space.high - space.low) / 2.0).astype(np.float32)
            # Unscaling to [-1, 1] (the snake's action space) is the identity: skip it.
            self._squash = squash and not (np.all(space.low == -1.0) and np.all(space.high == 1.0))
            self._clip = not squash  # a Gaussian policy without tanh (PPO) is clipped, as SB3's predict does
            self._layers = _compile_actor(self._policy)
            if self._layers is None:
                self._policy = _frozen_copy(self._policy)
                self._policy.set_training_mode(False)
                for parameter in self._policy.parameters():
                    parameter.requires_grad_(False)
        if self._layers is not None:
            self.act: Callable[[np.ndarray], np.ndarray] = self._act_numpy
        elif self._policy is not None:
            self.act = self._act_torch
        else:
            self.act = self._act_predict

    def _select(self, obs: np.ndarray) -> np.ndarray:
        return obs if self.obs_indices is None else obs[..., self.obs_indices]

    def _unscale(self, action: np.ndarray) -> np.ndarray:
        # The actor outputs [-1, 1]; map to the action space as SB3's unscale_action does.
        if self._clip:
            return np.clip(action, self._low, self._low + 2.0 * self._half_range)
        return self._low + (action + 1.0) * self._half_range if self._squash else action

    def _act_numpy(self, obs: np.ndarray) -> np.ndarray:
        x = self._select(obs).astype(np.float32, copy=False)
        for weight, bias, activation in self._layers:  # type: ignore[union-attr]
            x = np.dot(x, weight)
            x += bias  # in place: one temporary less per layer
            if activation is not None:
                x = activation(x)
        return self._unscale(x)

    def _act_torch(self, obs: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            tensor = torch.as_tensor(self._select(obs), dtype=torch.float32, device=self._policy.device)  # type: ignore[union-attr]
            action = self._policy._predict(tensor.reshape(-1, tensor.shape[-1]), deterministic=True)  # type: ignore[union-attr]
        return self._unscale(action.cpu().numpy().reshape(*obs.shape[:-1], -1))

    def _act_predict(self, obs: np.ndarray) -> np.ndarray:
        if self.state is None:
            action, _ = self.worker.predict(self._select(obs), deterministic=True)
        else:
            action, _ = self.worker.predict(self._select(obs), state=self.state, deterministic=True)
        action = np.asarray(action)
        return action if np.issubdtype(action.dtype, np.integer) else action.astype(np.float32)

    def reset_episode(self) -> None:
        """Forward an episode start to a stateful worker (e.g. a nested hierarchy with options)."""
        reset = getattr(self.worker, "reset_episode", None)
        if reset is not None:
            reset()


def _frozen_copy(policy: Any) -> Any:
    """
    A copy of an SB3 policy with the same weights, built the way ``BasePolicy.load`` builds one (from its
    constructor parameters): ``copy.deepcopy`` fails on policies holding non-leaf tensors (gSDE's noise).
    """
    try:
        clone = type(policy)(**policy._get_constructor_parameters()).to(policy.device)
        clone.load_state_dict(policy.state_dict())
    except (TypeError, AttributeError, RuntimeError):  # not an SB3 BasePolicy after all
        return copy.deepcopy(policy)
    return clone


#: numpy versions of the activations an actor may use; others fall back to torch.
_NUMPY_ACTIVATIONS: dict[type, Callable[[torch.nn.Module], Callable[[np.ndarray], np.ndarray]]] = {
    # Activations get a fresh layer output, so ReLU and tanh may work in place.
    torch.nn.ReLU: lambda m: lambda x: np.maximum(x, 0.0, out=x),
    torch.nn.Tanh: lambda m: lambda x: np.tanh(x, out=x),
    torch.nn.ELU: lambda m: lambda x: np.where(x > 0, x, m.alpha * np.expm1(np.minimum(x, 0.0))),
    torch.nn.LeakyReLU: lambda m: lambda x: np.where(x > 0, x, m.negative_slope * x),
    torch.nn.Sigmoid: lambda m: lambda x: 1.0 / (1.0 + np.exp(-x)),
    torch.nn.SiLU: lambda m: lambda x: x / (1.0 + np.exp(-x)),
}


def _compile_actor(policy: object) -> list[tuple[np.ndarray, np.ndarray, Any]] | None:
    """The actor's deterministic forward pass as numpy layers, or ``None`` if it has parts we do not mirror."""
    actor = getattr(policy, "actor", None)
    extractor = getattr(actor, "features_extractor", None)
    if actor is None or type(extractor).__name__ != "FlattenExtractor":
        return None
    if isinstance(getattr(actor, "mu", None), torch.nn.Sequential):  # DDPG / TD3
        modules = list(actor.mu)
    elif (
        hasattr(actor, "latent_pi")
        and isinstance(actor.mu, torch.nn.Linear)
        and not getattr(actor, "use_sde", True)
    ):
        modules = [*actor.latent_pi, actor.mu, torch.nn.Tanh()]  # SAC / TQC: deterministic = tanh(mean)
    else:
        return None
    layers: list[tuple[np.ndarray, np.ndarray, Any]] = []
    for module in modules:
        if isinstance(module, torch.nn.Linear):
            weight = module.weight.detach().cpu().numpy().T.copy()
            bias = (
                module.bias.detach().cpu().numpy() if module.bias is not None else np.zeros(weight.shape[1])
            ).copy()
            layers.append((weight.astype(np.float32), bias.astype(np.float32), None))
        elif type(module) in _NUMPY_ACTIVATIONS and layers and layers[-1][2] is None:
            weight, bias, _ = layers[-1]
            layers[-1] = (weight, bias, _NUMPY_ACTIVATIONS[type(module)](module))
        else:
            return None
    return layers
