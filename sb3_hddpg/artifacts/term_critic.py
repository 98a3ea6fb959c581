"""
A worker's per-term critic (one value head per reward term for its policy), stored in the worker's zip as
:data:`TERM_CRITIC_MEMBER`, an ``.npz`` of plain arrays (SB3's ``load`` would take a ``.pth`` for parameters).

It is of one of three kinds: ``Q(s, a)`` of a continuous worker or ``Q(s, .)`` of a discrete one, over the
worker's own observation (trained on the transitions it collected, a discrete one's also on rollouts of its
final policy), or the state value ``V(s)`` of a continuous worker over the shared env's full observation
(trained on rollouts of its final policy): a worker that sees part of the state cannot value what it does
not see, such as the snake's goal worker the obstacles.
"""

from __future__ import annotations

import io
import json
import math
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.torch_layers import create_mlp
from torch import nn

from sb3_hddpg.artifacts.limits import (
    MAX_CRITIC_BYTES,
    MAX_CRITIC_INPUTS,
    MAX_LAYER_SIZE,
    MAX_LAYERS,
    MAX_PARAMETERS,
    LimitError,
    brief,
    check_zip_directory,
    read_member,
)
from sb3_hddpg.names import check_plain_name

TERM_CRITIC_MEMBER = "term_critic.npz"  #: The worker zip's member that holds its per-term critic.


@dataclass(frozen=True)
class TermCriticSpec:
    """
    What a per-term critic evaluates and how it is built.

    :param terms: the reward terms, in the order of its heads.
    :param obs_dim: the flat size of the worker's observation (of the shared env's, for a state-value critic).
    :param n_actions: a discrete worker's number of actions; 0 for a continuous worker.
    :param action_low: a continuous worker's action bounds (actions are scaled to [-1, 1] as SB3 stores them);
        empty, with no discrete actions, for a state-value critic.
    :param action_high: the upper bounds.
    :param net_arch: the hidden layers' sizes.
    :param gamma: the discount its values are for.
    """

    terms: tuple[str, ...]
    obs_dim: int
    n_actions: int
    action_low: tuple[float, ...]
    action_high: tuple[float, ...]
    net_arch: tuple[int, ...]
    gamma: float

    def __post_init__(self) -> None:
        if not self.terms or len(set(self.terms)) != len(self.terms):
            raise ValueError(f"Expected distinct term names, actually: {list(self.terms)}")
        for term in self.terms:
            check_plain_name(term, "term critic: terms")
        sizes = (self.obs_dim, self.n_actions, len(self.action_low))
        if any(
            isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= MAX_CRITIC_INPUTS for v in sizes
        ):
            raise ValueError(f"Expected sizes in [0, {MAX_CRITIC_INPUTS}], actually: {sizes}")
        if self.obs_dim < 1 or (self.n_actions > 0 and self.action_low):
            raise ValueError("Expected an observation and at most one of discrete actions and action bounds")
        if len(self.action_low) != len(self.action_high) or not all(
            math.isfinite(lo) and math.isfinite(hi) and lo < hi
            for lo, hi in zip(self.action_low, self.action_high)
        ):
            raise ValueError(f"Expected finite action bounds with low < high, actually: {self.action_low}")
        if len(self.net_arch) > MAX_LAYERS or not all(
            isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= MAX_LAYER_SIZE for v in self.net_arch
        ):
            raise ValueError(
                f"Expected at most {MAX_LAYERS} layers of 1..{MAX_LAYER_SIZE}, actually: {self.net_arch}"
            )
        if not 0.0 <= self.gamma < 1.0:
            raise ValueError(f"Expected `gamma` in [0, 1), actually: {self.gamma}")

    @classmethod
    def for_spaces(
        cls,
        terms: Sequence[str],
        observation_space: gym.Space,
        action_space: gym.Space,
        net_arch: Sequence[int],
        gamma: float,
    ) -> TermCriticSpec:
        """The spec of a critic for a worker with these spaces (a Box or Discrete action space)."""
        obs_dim = int(np.prod(observation_space.shape or (1,)))
        if isinstance(action_space, gym.spaces.Discrete):
            return cls(tuple(terms), obs_dim, int(action_space.n), (), (), tuple(net_arch), float(gamma))
        if not isinstance(action_space, gym.spaces.Box):
            raise ValueError(f"Expected a Box or Discrete action space, actually: {action_space}")
        low, high = (tuple(float(v) for v in np.ravel(b)) for b in (action_space.low, action_space.high))
        return cls(tuple(terms), obs_dim, 0, low, high, tuple(int(v) for v in net_arch), float(gamma))

    @property
    def discrete(self) -> bool:
        """Whether the critic's worker acts with discrete actions."""
        return self.n_actions > 0

    @property
    def state_value(self) -> bool:
        """Whether the critic is a state value over the shared env's full observation (no actions)."""
        return not self.discrete and not self.action_low

    @property
    def input_dim(self) -> int:
        return self.obs_dim + len(self.action_low)

    @property
    def output_dim(self) -> int:
        return len(self.terms) * (self.n_actions if self.discrete else 1)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)  # tuples are JSON lists

    @classmethod
    def from_json(cls, data: object, what: str) -> TermCriticSpec:
        """A spec read from a file, checked field by field; a ``LimitError`` names ``what`` otherwise."""
        fields = ("terms", "obs_dim", "n_actions", "action_low", "action_high", "net_arch", "gamma")
        if not isinstance(data, Mapping) or set(data) != set(fields):
            raise LimitError(f"{what}: expected the fields {list(fields)}, got {brief(data)}")
        try:
            lists = {k: tuple(data[k]) for k in ("terms", "action_low", "action_high", "net_arch")}
            if any(len(v) > MAX_CRITIC_INPUTS for v in lists.values()):
                raise ValueError("too many entries")
            return cls(**{**dict(data), **lists})  # type: ignore[arg-type]
        except (TypeError, ValueError) as error:
            raise LimitError(f"{what}: {brief(str(error), 200)}") from None


class TermCritic(nn.Module):
    """
    One value head per reward term for one worker's policy: ``Q(s, a) -> (n_terms,)`` for a continuous
    worker, ``Q(s) -> (n_actions, n_terms)`` for a discrete one, ``V(s) -> (n_terms,)`` for a state-value
    critic, of the normalised terms discounted by ``spec.gamma``.

    :param spec: what it evaluates and its layers.
    """

    def __init__(self, spec: TermCriticSpec) -> None:
        super().__init__()
        self.spec = spec
        self.net = nn.Sequential(*create_mlp(spec.input_dim, spec.output_dim, list(spec.net_arch)))
        if sum(p.numel() for p in self.parameters()) > MAX_PARAMETERS:
            raise LimitError(
                f"A term critic of {spec.net_arch} over {spec.input_dim} inputs is over the size limit"
            )

    def scale_actions(self, actions: np.ndarray) -> np.ndarray:
        """Env actions of a continuous worker scaled to [-1, 1], as SB3's replay buffer stores them."""
        low, high = np.asarray(self.spec.action_low), np.asarray(self.spec.action_high)
        flat = np.asarray(actions, dtype=np.float64).reshape(-1, len(low))
        return (2.0 * (flat - low) / (high - low) - 1.0).astype(np.float32)

    def forward(self, obs: torch.Tensor, actions: torch.Tensor | None = None) -> torch.Tensor:
        """``(batch, n_terms)`` for scaled actions (continuous) or none (state value), or
        ``(batch, n_actions, n_terms)`` (discrete)."""
        obs = obs.reshape(len(obs), -1)
        if self.spec.discrete:
            return self.net(obs).reshape(len(obs), self.spec.n_actions, len(self.spec.terms))
        if self.spec.state_value:
            return self.net(obs)
        if actions is None:
            raise ValueError("A continuous worker's critic needs the actions")
        return self.net(torch.cat([obs, actions.reshape(len(obs), -1)], dim=1))

    @torch.no_grad()
    def values(self, obs: np.ndarray, env_actions: np.ndarray | None = None) -> np.ndarray:
        """The per-term values (numpy): of the given env actions, of every action of a discrete worker, or
        of the state (``env_actions`` unused)."""
        tensor = torch.as_tensor(np.asarray(obs, dtype=np.float32).reshape(-1, self.spec.obs_dim))
        if self.spec.discrete or self.spec.state_value:
            return self(tensor).numpy()
        scaled = torch.as_tensor(self.scale_actions(np.asarray(env_actions)))
        return self(tensor, scaled).numpy()

    def to_bytes(self) -> bytes:
        """The critic as the ``.npz`` member of a worker's zip."""
        arrays = {f"param:{k}": v.detach().cpu().numpy() for k, v in self.state_dict().items()}
        spec = np.frombuffer(json.dumps(self.spec.to_json()).encode(), dtype=np.uint8)
        buffer = io.BytesIO()
        np.savez(buffer, spec=spec, **arrays)
        return buffer.getvalue()

    @classmethod
    def from_bytes(cls, data: bytes, what: str) -> TermCritic:
        """
        A critic from its member's bytes, without running code from them: plain arrays only, the spec checked,
        every parameter's name and shape the spec-built network's (a ``LimitError`` naming ``what`` otherwise).
        """
        try:
            with np.load(io.BytesIO(data), allow_pickle=False) as npz:
                arrays = {name: npz[name] for name in npz.files}
        except (ValueError, OSError, zipfile.BadZipFile, EOFError) as error:
            raise LimitError(
                f"{what}: {TERM_CRITIC_MEMBER} is not a plain array file: {brief(str(error))}"
            ) from None
        raw = arrays.pop("spec", None)
        try:
            spec_json = (
                json.loads(bytes(np.asarray(raw, dtype=np.uint8)).decode()) if raw is not None else None
            )
        except (ValueError, TypeError):
            spec_json = None
        critic = cls(TermCriticSpec.from_json(spec_json, f"{what}: {TERM_CRITIC_MEMBER} spec"))
        expected = {f"param:{k}": tuple(v.shape) for k, v in critic.state_dict().items()}
        found = {k: tuple(v.shape) for k, v in arrays.items()}
        if found != expected or not all(v.dtype == np.float32 for v in arrays.values()):
            raise LimitError(f"{what}: {TERM_CRITIC_MEMBER} holds other parameters than its spec builds")
        critic.load_state_dict(
            {k.removeprefix("param:"): torch.from_numpy(v.copy()) for k, v in arrays.items()}
        )
        critic.eval()
        return critic


def with_term_critic(zip_bytes: bytes, critic: TermCritic) -> bytes:
    """A model zip's bytes with ``critic`` as its :data:`TERM_CRITIC_MEMBER` (replacing one already there)."""
    source = zipfile.ZipFile(io.BytesIO(zip_bytes))
    buffer = io.BytesIO()
    with source, zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as target:
        for info in source.infolist():
            if info.filename != TERM_CRITIC_MEMBER:
                target.writestr(info, source.read(info.filename))
        target.writestr(TERM_CRITIC_MEMBER, critic.to_bytes())
    return buffer.getvalue()


def read_term_critic(source: str | Path | bytes, what: str) -> TermCritic | None:
    """
    The per-term critic in a worker's zip, or ``None`` when it has none.

    :param source: the zip's path or its bytes.
    :param what: names the zip in errors: a ``LimitError`` for a member over the limits or not a critic this
        library wrote.
    """
    opened = zipfile.ZipFile(io.BytesIO(source) if isinstance(source, bytes) else source)
    with opened as archive:
        names = {info.filename for info in check_zip_directory(archive, what)}
        if TERM_CRITIC_MEMBER not in names:
            return None
        data = read_member(archive, TERM_CRITIC_MEMBER, what, limit=MAX_CRITIC_BYTES)
    return TermCritic.from_bytes(data, what)
