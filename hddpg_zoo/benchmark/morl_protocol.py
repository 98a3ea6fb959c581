"""
MORL-baselines' benchmark protocol (``hddpg-cli benchmark --protocol morl-baselines``): its envs, their
reference points and budgets, its peers, and the settings of one run.

The protocol is MORL-baselines' (Felten et al., "A Toolkit for Reliable Benchmarking and Research in
Multi-Objective Reinforcement Learning", NeurIPS 2023): each env at its registered version and time limit,
discounted vector returns (gamma 0.99), a front of 100 equally spaced weights' mean returns over 5 episodes,
scored by hypervolume from the env's reference point, expected utility over 50 equally spaced weights,
cardinality, and IGD and maximum utility loss where MO-Gymnasium knows the true front; 10 seeds. The facts
below are each checked against MORL-baselines 1.3 and MO-Gymnasium 1.3 (docs/MORL.md lists where each comes
from and where the published runs differ).

The hierarchy's side is a list of methods (:data:`~.morl_sides.PROTOCOL_METHODS`), so that a method added
there runs under the same protocol without a change here beyond importing its module (:mod:`.morl_gpi`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

# Imported for what they register: the hddpg-gpi methods, and the hddpg-gpi-raw ones.
import hddpg_zoo.benchmark.morl_gpi
import hddpg_zoo.benchmark.morl_gpi_raw  # noqa: F401
from hddpg_zoo.benchmark.morl_sides import PROTOCOL_METHODS
from sb3_hddpg.artifacts.limits import MAX_BENCHMARK_SEEDS, MAX_SEED, brief

#: The protocol's name, as ``--protocol`` takes it.
PROTOCOL = "morl-baselines"
#: The protocol's discount: MORL-baselines' benchmark runs use 0.99 (its examples use 0.98 on minecart).
GAMMA = 0.99
#: Weights of the front, episodes per weight (``num_eval_weights_for_front``, ``num_eval_episodes_for_front``),
#: and weights of expected utility and maximum utility loss (``num_eval_weights_for_eval``).
EVAL_WEIGHTS = 100
EVAL_EPISODES = 5
EU_WEIGHTS = 50
#: Seeds of a run of record (MORL-baselines' benchmark runs 10 per learner and env).
RECORD_SEEDS = 10
#: The smallest share of the protocol's budget a run of record may take (below it, a learner's figures say
#: little of what it learns at the protocol's budget).
RECORD_MIN_SHARE = 0.1
#: Seed of the first evaluation episode; ``FINAL_TEST`` of the protocol: development seeds start elsewhere.
DEVELOPMENT_EVAL_SEED = 20_000
FINAL_TEST_EVAL_SEED = 10_000


@dataclass(frozen=True)
class Peer:
    """
    A MORL-baselines learner: its name in MORL-baselines' ``experiments.ALGOS`` and the actions it takes.

    :param algo: its key in ``morl_baselines.common.experiments.ALGOS``.
    :param actions: ``"continuous"`` or ``"discrete"``.
    :param iteration: env steps of one of its training iterations (GPI's ``timesteps_per_iter`` default):
        a budget below it trains nothing.
    """

    algo: str
    actions: str
    iteration: int = 1


#: The peers, by the names ``--peers`` takes.
PEERS: dict[str, Peer] = {
    "capql": Peer("capql", "continuous"),
    "gpi-pd-continuous": Peer("gpi_pd_continuous", "continuous", iteration=10_000),
    "gpi-pd": Peer("gpi_pd_discrete", "discrete", iteration=10_000),
    "gpi-ls": Peer("gpi_ls_discrete", "discrete", iteration=10_000),
    "envelope": Peer("envelope", "discrete"),
}


@dataclass(frozen=True)
class ProtocolEnv:
    """
    One env of the protocol.

    :param env_id: MO-Gymnasium's id, made at its registered time limit.
    :param actions: ``"continuous"`` or ``"discrete"``.
    :param objectives: the number of objectives.
    :param episode_steps: its registered time limit (checked when the env is made).
    :param ref_point: the hypervolume's reference point.
    :param env_steps: the budget of every side, in env steps.
    :param peers: the strongest peers, names of :data:`PEERS`.
    :param known_front: whether MO-Gymnasium knows its true front (IGD and maximum utility loss).
    """

    env_id: str
    actions: str
    objectives: int
    episode_steps: int
    ref_point: tuple[float, ...]
    env_steps: int
    peers: tuple[str, ...]
    known_front: bool


#: The protocol's envs.
PROTOCOL_ENVS: dict[str, ProtocolEnv] = {
    env.env_id: env
    for env in (
        ProtocolEnv(
            "mo-halfcheetah-v4",
            "continuous",
            2,
            1000,
            (-100.0, -100.0),
            200_000,
            ("capql", "gpi-pd-continuous"),
            False,
        ),
        ProtocolEnv(
            "mo-hopper-2d-v4",
            "continuous",
            2,
            1000,
            (-100.0, -100.0),
            200_000,
            ("capql", "gpi-pd-continuous"),
            False,
        ),
        ProtocolEnv(
            "minecart-v0", "discrete", 3, 1000, (0.0, 0.0, -200.0), 150_000, ("gpi-pd", "envelope"), True
        ),
        ProtocolEnv(
            "deep-sea-treasure-concave-v0",
            "discrete",
            2,
            100,
            (0.0, -50.0),
            200_000,
            ("gpi-ls", "envelope"),
            True,
        ),
    )
}


@dataclass
class ProtocolSettings:
    """
    One run of the protocol on one env: every side over the same seeds and the same evaluation episodes.

    :param env_id: an env of :data:`PROTOCOL_ENVS`.
    :param seeds: the training seeds (a run of record has at least :data:`RECORD_SEEDS`).
    :param methods: the hierarchy's side, names of :data:`~.morl_sides.PROTOCOL_METHODS`.
    :param peers: MORL-baselines' side (default: the env's peers); ``()`` runs the hierarchy alone.
    :param timesteps: every side's budget in env steps (``None``: the protocol's); a pilot takes fewer, never
        more than the protocol's.
    :param eval_weights: weights of the front.
    :param eval_episodes: episodes per weight.
    :param final_test: evaluate on the final test episodes (runs of record only); else development ones.
    :param morl_python: MORL-baselines' python (its own environment), which trains the peers and scores every side.
    """

    env_id: str
    seeds: tuple[int, ...]
    methods: tuple[str, ...] = ("hddpg-conditioned",)
    peers: tuple[str, ...] | None = None
    timesteps: int | None = None
    eval_weights: int = EVAL_WEIGHTS
    eval_episodes: int = EVAL_EPISODES
    final_test: bool = False
    morl_python: str | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if self.env_id not in PROTOCOL_ENVS:
            raise ValueError(
                f"--env: the protocol's envs are {list(PROTOCOL_ENVS)}, got {brief(self.env_id)}"
            )
        env = PROTOCOL_ENVS[self.env_id]
        self.seeds = tuple(self.seeds)
        if not 1 <= len(self.seeds) <= MAX_BENCHMARK_SEEDS or len(set(self.seeds)) != len(self.seeds):
            raise ValueError(
                f"--seeds: expected 1 to {MAX_BENCHMARK_SEEDS} distinct seeds, got {brief(self.seeds)}"
            )
        if not all(isinstance(s, int) and 0 <= s <= MAX_SEED for s in self.seeds):
            raise ValueError(f"--seeds: expected integers in [0, {MAX_SEED}], got {brief(self.seeds)}")
        self.peers = env.peers if self.peers is None else tuple(self.peers)
        strangers = [p for p in self.peers if p not in env.peers]
        if strangers:
            raise ValueError(
                f"--methods: {self.env_id}'s peers (MORL-baselines' learners) are {list(env.peers)}, got {strangers}"
            )
        self.methods = tuple(self.methods)
        unknown = [m for m in self.methods if m not in PROTOCOL_METHODS]
        if not self.methods or unknown:
            raise ValueError(
                f"--methods: expected some of {list(PROTOCOL_METHODS)}, got {brief(list(self.methods))}"
            )
        foreign = [m for m in self.methods if PROTOCOL_METHODS[m].actions not in (None, env.actions)]
        if foreign:
            raise ValueError(
                f"--methods: {foreign} take {PROTOCOL_METHODS[foreign[0]].actions} actions only, and "
                f"{self.env_id}'s are {env.actions}"
            )
        if self.timesteps is not None and not 1 <= self.timesteps <= env.env_steps:
            raise ValueError(
                f"--timesteps: every side's budget is at most the protocol's {env.env_steps} env steps on "
                f"{self.env_id}, got {self.timesteps}"
            )
        idle = [p for p in self.peers if self.budget < PEERS[p].iteration]
        if idle:
            raise ValueError(
                f"--timesteps: {idle} train in iterations of {PEERS[idle[0]].iteration} env steps: a budget of "
                f"{self.budget} trains nothing (leave them out of --methods, or give more)"
            )
        for name, value in (("--eval-weights", self.eval_weights), ("--eval-episodes", self.eval_episodes)):
            if not 1 <= value <= 1000:
                raise ValueError(f"{name}: expected 1 to 1000, got {brief(value)}")
        if self.morl_python is None:
            raise ValueError(
                "--morl-python: the peers train and every side is scored in MORL-baselines' own environment; "
                "name its python"
            )

    @property
    def env(self) -> ProtocolEnv:
        """The protocol's env of this run."""
        return PROTOCOL_ENVS[self.env_id]

    @property
    def budget(self) -> int:
        """Every side's env steps."""
        return self.timesteps if self.timesteps is not None else self.env.env_steps

    @property
    def eval_seed(self) -> int:
        """Seed of the first evaluation episode: the final test set's, or the development set's."""
        return FINAL_TEST_EVAL_SEED if self.final_test else DEVELOPMENT_EVAL_SEED

    @property
    def of_record(self) -> bool:
        """
        Whether this run can be a run of record: the protocol's evaluation on the final test episodes, >= 10
        seeds, and every side's budget the protocol's or, where a peer cannot train at the protocol's budget
        on this machine, a smaller one (at least :data:`RECORD_MIN_SHARE` of it) stated beside every figure
        (:attr:`full_budget`).
        """
        return (
            self.final_test
            and len(self.seeds) >= RECORD_SEEDS
            and (self.eval_weights, self.eval_episodes) == (EVAL_WEIGHTS, EVAL_EPISODES)
            and self.budget >= RECORD_MIN_SHARE * self.env.env_steps
        )

    @property
    def full_budget(self) -> bool:
        """Whether every side trains for the protocol's own budget on this env."""
        return self.budget == self.env.env_steps

    def to_json(self) -> dict[str, object]:
        """The settings as ``protocol.json`` keeps them (no path of this machine: the python is not kept)."""
        return {
            "protocol": PROTOCOL,
            "env_id": self.env_id,
            "seeds": list(self.seeds),
            "methods": list(self.methods),
            "peers": list(self.peers or ()),
            "budget": self.budget,
            "gamma": GAMMA,
            "ref_point": list(self.env.ref_point),
            "eval_weights": self.eval_weights,
            "eval_episodes": self.eval_episodes,
            "eu_weights": EU_WEIGHTS,
            "eval_seed": self.eval_seed,
            "final_test": self.final_test,
            "of_record": self.of_record,
        }


__all__ = [
    "EU_WEIGHTS",
    "EVAL_EPISODES",
    "EVAL_WEIGHTS",
    "GAMMA",
    "PEERS",
    "PROTOCOL",
    "PROTOCOL_ENVS",
    "Peer",
    "ProtocolEnv",
    "ProtocolSettings",
]
