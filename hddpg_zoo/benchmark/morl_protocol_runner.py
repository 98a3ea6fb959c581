"""
MORL-baselines' benchmark protocol, on its side: train one of its learners with its published defaults, play
it over the whole weight simplex with its own evaluator, and score the front (or a front sb3-hddpg played)
with its own indicators.

Like :mod:`morl_runner` (whose file helpers it loads by path), this script imports nothing from sb3_hddpg and
runs with MORL-baselines' own python; ``hddpg-cli benchmark --protocol morl-baselines --morl-python PYTHON``
runs it once per peer and seed (:mod:`.morl_protocol_run`), or by hand::

    ~/morl-venv/bin/python morl_protocol_runner.py train --algo envelope --env minecart-v0 \\
        --timesteps 150000 --gamma 0.99 --ref-point=0,0,-200 --seed 0 --out envelope-seed-0.json
    ~/morl-venv/bin/python morl_protocol_runner.py score --returns hierarchy-seed-0.json \\
        --env minecart-v0 --gamma 0.99 --ref-point=0,0,-200 --out scored.json

With ``--checkpoint-dir DIR``, ``train`` trains in chunks and saves the learner's whole training state to
``DIR`` after each, and a later ``train`` of the same settings goes on from there (:mod:`morl_protocol_resume`
says how, learner by learner); the record counts the chunks and the resumes.

The protocol (MORL-baselines' ``launch_experiment.py`` and its learners' ``train``): the registered env and
its time limit; discounted vector returns (``eval_mo``, the agent's gamma); the front is each of
``--eval-weights`` equally spaced weights' mean discounted return over ``--eval-episodes`` episodes
(``policy_evaluation_mo``); its non-dominated part is scored by hypervolume from the reference point, expected
utility over ``--eu-weights`` equally spaced weights, cardinality, and where MO-Gymnasium knows the env's
front (``pareto_front(gamma)``), IGD and maximum utility loss against it.

Two choices differ from ``log_all_multi_policy_metrics``, each written in the record: the episodes of every
weight start from the same seeded stream (the env is reset with ``--eval-seed`` before each weight's
episodes, then ``eval_mo`` resets it unseeded, as it always does), so that two learners meet the same
episodes; and maximum utility loss takes ``equally_spaced_weights`` (seed 42), where that function draws
pymoo's energy directions unseeded, so that a record scores the same twice.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import importlib.util
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

#: This record's kind and schema version.
RECORD_KIND = "sb3-hddpg-morl-protocol"
RECORD_VERSION = 1
#: MORL-baselines' protocol: weights of the front, episodes per weight, weights of expected utility and MUL.
EVAL_WEIGHTS = 100
EVAL_EPISODES = 5
EU_WEIGHTS = 50
#: The seed of ``equally_spaced_weights`` (its own default).
WEIGHTS_SEED = 42
#: Constructor arguments beyond the class defaults, each from MORL-baselines' own benchmark record (its
#: "Performance report issue tracker", issue 43: CAPQL with ``alpha:0.2``, its default too).
PUBLISHED = {"capql": {"alpha": 0.2}}
#: Train arguments: no in-training evaluation or checkpoint files (the front is played once, at the end).
_QUIET_TRAIN = {"checkpoints": False}
#: Most episodes and weights evaluated, and most env steps of training.
MAX_EVAL = 10_000
MAX_TIMESTEPS = 100_000_000
#: Env steps of a chunk of CAPQL and Envelope with ``--checkpoint-dir`` (GPI's chunk is its own iteration).
CHUNK_STEPS = 10_000
#: The exit status of ``train`` stopped by ``--stop-after-chunks`` (its checkpoint saved, no record).
STOPPED_STATUS = 3


@functools.cache
def _sibling(file: str) -> Any:
    """
    A module beside this file, loaded by path (its folder is not on ``sys.path``), once: its exception
    classes are the ones ``main`` catches.
    """
    path = Path(__file__).resolve().with_name(file)
    spec = importlib.util.spec_from_file_location(f"_hddpg_{path.stem}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # where dataclasses and pickle look a class's module up
    spec.loader.exec_module(module)
    return module


def _runner() -> Any:
    """:mod:`morl_runner`: its file helpers and its ``InputError``."""
    return _sibling("morl_runner.py")


def _resume() -> Any:
    """:mod:`morl_protocol_resume`: training in chunks, checkpointed."""
    return _sibling("morl_protocol_resume.py")


class _Counting:
    """An env that counts its steps: a learner's own evaluations during training (GPI-LS's weight search)."""

    def __init__(self, env: Any) -> None:
        self.env, self.steps = env, 0

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)

    def step(self, action: Any) -> Any:
        self.steps += 1
        return self.env.step(action)

    def reset(self, **kwargs: Any) -> Any:
        return self.env.reset(**kwargs)


def _make_env(env_id: str) -> Any:
    import mo_gymnasium as mo_gym

    return mo_gym.make(env_id)


#: Each learner's module and class, as ``morl_baselines.common.experiments.ALGOS`` maps its name (that module
#: also imports the JAX learners, which need flax: not imported here).
_CLASSES = {
    "capql": ("morl_baselines.multi_policy.capql.capql", "CAPQL"),
    "gpi_pd_continuous": (
        "morl_baselines.multi_policy.gpi_pd.gpi_pd_continuous_action",
        "GPIPDContinuousAction",
    ),
    "gpi_pd_discrete": ("morl_baselines.multi_policy.gpi_pd.gpi_pd", "GPIPD"),
    "gpi_ls_discrete": ("morl_baselines.multi_policy.gpi_pd.gpi_pd", "GPILS"),
    "envelope": ("morl_baselines.multi_policy.envelope.envelope", "Envelope"),
}


def _agent(algo: str, env: Any, gamma: float, seed: int) -> Any:
    # The learners draw from the global generators too (network initialisation, minibatches, exploration):
    # MORL-baselines' own seed_everything makes a seed repeat, where the learner's seed alone does not.
    from morl_baselines.common.evaluation import seed_everything

    seed_everything(seed)
    env.reset(seed=seed)
    module, name = _CLASSES[algo]
    learner = getattr(importlib.import_module(module), name)
    return learner(env=env, gamma=gamma, seed=seed, log=False, device="cpu", **PUBLISHED.get(algo, {}))


def play_front(
    agent: Any, env: Any, weights: list[Any], episodes: int, eval_seed: int
) -> tuple[list[list[list[float]]], list[list[list[float]]]]:
    """
    Every weight's episodes through MORL-baselines' ``eval_mo``: per weight, per episode, the discounted and
    the undiscounted vector returns. The env is reset with ``eval_seed`` before each weight's episodes.
    """
    from morl_baselines.common.evaluation import eval_mo

    discounted, returns = [], []
    for w in weights:
        env.reset(seed=eval_seed)
        played = [eval_mo(agent, env, w) for _ in range(episodes)]
        discounted.append([[float(v) for v in p[3]] for p in played])
        returns.append([[float(v) for v in p[2]] for p in played])
    return discounted, returns


def indicators(
    discounted: list[list[list[float]]],
    ref_point: list[float],
    known: list[list[float]] | None,
    eu_weights: int,
) -> dict[str, Any]:
    """
    MORL-baselines' indicators of the front whose points are each weight's mean discounted return.

    :param discounted: per weight, per episode, the discounted vector return.
    :param known: the env's true front (discounted by the same gamma), or ``None``.
    """
    import numpy as np
    from morl_baselines.common.pareto import filter_pareto_dominated
    from morl_baselines.common.performance_indicators import (
        cardinality,
        expected_utility,
        hypervolume,
        igd,
        maximum_utility_loss,
    )
    from morl_baselines.common.weights import equally_spaced_weights

    front = [np.mean(np.asarray(episodes, dtype=np.float64), axis=0) for episodes in discounted]
    kept = list(filter_pareto_dominated(front))
    dim = len(ref_point)
    weights = equally_spaced_weights(dim, eu_weights, seed=WEIGHTS_SEED)
    scores: dict[str, Any] = {
        "hypervolume": float(hypervolume(np.asarray(ref_point, dtype=np.float64), kept)),
        "expected_utility": float(expected_utility(kept, weights_set=weights)),
        "cardinality": float(cardinality(kept)),
    }
    if known is not None:
        reference = [np.asarray(p, dtype=np.float64) for p in known]
        scores["igd"] = float(igd(known_front=reference, current_estimate=kept))
        scores["maximum_utility_loss"] = float(
            maximum_utility_loss(front=kept, reference_set=reference, weights_set=np.asarray(weights))
        )
    return {
        "front": [p.tolist() for p in front],
        "non_dominated": [np.asarray(p).tolist() for p in kept],
        "indicators": scores,
    }


def _known_front(env: Any, gamma: float) -> list[list[float]] | None:
    """MO-Gymnasium's true front of the env, discounted by ``gamma``, where it knows one."""
    front = getattr(env.unwrapped, "pareto_front", None)
    if front is None:
        return None
    return [[float(v) for v in point] for point in front(gamma=gamma)]


def _protocol_fields(args: argparse.Namespace, env: Any, known: list[list[float]] | None) -> dict[str, Any]:
    return {
        "kind": RECORD_KIND,
        "record_version": RECORD_VERSION,
        "env_id": args.env,
        "episode_steps": env.spec.max_episode_steps if env.spec is not None else None,
        "gamma": args.gamma,
        "ref_point": args.ref_point_values,
        "eval_weights": args.eval_weights,
        "eval_episodes": args.eval_episodes,
        "eu_weights": args.eu_weights,
        "eval_seed": args.eval_seed,
        "known_front": known,
        "evaluator": "morl_baselines.common.evaluation.eval_mo, env reset with eval_seed before each weight",
        "mul_weights": f"equally_spaced_weights(dim, eu_weights, seed={WEIGHTS_SEED})",
    }


def train(args: argparse.Namespace) -> dict[str, Any]:
    """Train ``--algo`` for ``--timesteps`` env steps with its published defaults, then play and score it."""
    import numpy as np
    import torch
    from morl_baselines.common.weights import equally_spaced_weights

    torch.set_num_threads(args.threads)
    resume = _resume() if args.checkpoint_dir is not None else None
    env, eval_env = _make_env(args.env), _counting_env(args.env)
    _check_objectives(env, args)
    known = _known_front(env, args.gamma)
    iterated = args.algo not in ("capql", "envelope")
    if args.iteration_steps is not None and not iterated:
        raise _runner().InputError(f"--iteration-steps: {args.algo} trains in no iterations")
    if args.chunk_steps is not None and (iterated or resume is None):
        raise _runner().InputError(
            "--chunk-steps: only CAPQL and Envelope with --checkpoint-dir (GPI's chunk is its iteration)"
        )
    if resume is not None and not iterated:
        env = resume.Continuing(env)
    agent = _agent(args.algo, env, args.gamma, args.seed)
    per_iteration = args.iteration_steps or _resume().train_defaults(agent).get("timesteps_per_iter", 1)
    if iterated and args.timesteps < per_iteration:
        raise _runner().InputError(
            f"--timesteps: {args.algo} trains in iterations of {per_iteration} env steps; {args.timesteps} "
            "would train nothing"
        )
    train_kwargs: dict[str, Any] = dict(_QUIET_TRAIN) if iterated else {}
    if args.iteration_steps is not None:
        train_kwargs["timesteps_per_iter"] = args.iteration_steps
    reference = np.asarray(args.ref_point_values)
    if resume is None:
        started = time.perf_counter()
        agent.train(
            total_timesteps=args.timesteps,
            eval_env=eval_env,
            ref_point=reference,
            known_pareto_front=known,
            **train_kwargs,
        )
        chunking = {"chunk_steps": None, "chunks": 1, "resumes": 0}
        train_seconds = time.perf_counter() - started
    else:
        progress = _train_in_chunks(resume, agent, env, eval_env, args, reference, known)
        chunking = {k: getattr(progress, k) for k in ("chunks", "resumes")}
        chunking["chunk_steps"] = progress.run["chunk_steps"]
        train_seconds = progress.wall_time_train_s
        train_kwargs.pop("checkpoints", None)  # the chunks are the runner's, never the learner's files
    searched = eval_env.steps
    weights = equally_spaced_weights(len(args.ref_point_values), args.eval_weights, seed=WEIGHTS_SEED)
    started = time.perf_counter()
    discounted, returns = play_front(agent, eval_env.env, weights, args.eval_episodes, args.eval_seed)
    eval_seconds = time.perf_counter() - started
    runner = _runner()
    return {
        **_protocol_fields(args, env, known),
        "side": "peer",
        "algorithm": args.algo,
        "seed": args.seed,
        "env_steps": {"learner": int(agent.global_step), "evaluations_in_training": int(searched)},
        "published_kwargs": PUBLISHED.get(args.algo, {}),
        "train_kwargs": train_kwargs,
        **chunking,
        "weights": [[float(v) for v in w] for w in weights],
        "discounted_returns": discounted,
        "returns": returns,
        **indicators(discounted, args.ref_point_values, known, args.eu_weights),
        "wall_time_train_s": train_seconds,
        "wall_time_eval_s": eval_seconds,
        "threads": args.threads,
        "versions": {
            "morl_baselines": runner._version("morl-baselines"),
            "mo_gymnasium": runner._version("mo-gymnasium"),
            "torch": torch.__version__,
            "python": sys.version.split()[0],
        },
    }


def _train_in_chunks(
    resume: Any,
    agent: Any,
    env: Any,
    eval_env: _Counting,
    args: argparse.Namespace,
    reference: Any,
    known: list[list[float]] | None,
) -> Any:
    """Train in chunks through :mod:`morl_protocol_resume`, from ``--checkpoint-dir``'s checkpoint if any."""
    iterated = args.algo in resume.ITERATED
    if iterated:
        chunk = args.iteration_steps or resume.train_defaults(agent)["timesteps_per_iter"]
    else:
        chunk = args.chunk_steps or CHUNK_STEPS
    run = {
        "algo": args.algo,
        "env": args.env,
        "seed": args.seed,
        "timesteps": args.timesteps,
        "gamma": args.gamma,
        "chunk_steps": chunk,
        "stop_after": args.stop_after_chunks,
    }
    train_kwargs = {} if iterated else {"ref_point": reference, "known_pareto_front": known}
    return resume.train_in_chunks(agent, env, eval_env, run, args.checkpoint_dir, train_kwargs)


def _check_weights(given: object, count: int, dim: int) -> None:
    """
    The weights the returns were played at, if given, are the protocol's: ``count`` equally spaced weights
    (a front played at other weights is not the protocol's front).
    """
    import numpy as np
    from morl_baselines.common.weights import equally_spaced_weights

    if given is None:
        return
    expected = np.asarray(equally_spaced_weights(dim, count, seed=WEIGHTS_SEED))
    if (
        not isinstance(given, list)
        or np.shape(given) != expected.shape
        or not np.allclose(given, expected, atol=1e-9)
    ):
        raise _runner().InputError(
            f"--returns: weights: expected the protocol's {count} equally spaced weights of {dim} objectives "
            f"(equally_spaced_weights, seed {WEIGHTS_SEED})"
        )


def _check_objectives(env: Any, args: argparse.Namespace) -> None:
    objectives = int(env.unwrapped.reward_dim)
    if len(args.ref_point_values) != objectives:
        raise _runner().InputError(
            f"--ref-point: {args.env} has {objectives} objectives, got {len(args.ref_point_values)} values"
        )


def _counting_env(env_id: str) -> _Counting:
    return _Counting(_make_env(env_id))


def score(args: argparse.Namespace) -> dict[str, Any]:
    """Score per-episode discounted returns played elsewhere (``--returns``) with the same indicators."""
    runner = _runner()
    given = runner._read_json(args.returns, "--returns")
    discounted = given.get("discounted_returns") if isinstance(given, dict) else None
    dim = len(args.ref_point_values)
    if (
        not isinstance(discounted, list)
        or not 1 <= len(discounted) <= MAX_EVAL
        or not all(
            isinstance(w, list)
            and 1 <= len(w) <= MAX_EVAL
            and all(isinstance(e, list) and len(e) == dim and all(map(runner._is_number, e)) for e in w)
            for w in discounted
        )
    ):
        raise runner.InputError(
            f"--returns: expected discounted_returns: per weight, 1 to {MAX_EVAL} episodes of {dim} finite "
            "numbers (one per objective of --ref-point)"
        )
    _check_weights(given.get("weights"), len(discounted), dim)
    env = _make_env(args.env)
    _check_objectives(env, args)
    known = _known_front(env, args.gamma)
    return {
        **_protocol_fields(args, env, known),
        "side": "given",
        **indicators(discounted, args.ref_point_values, known, args.eu_weights),
        "versions": {"morl_baselines": runner._version("morl-baselines"), "python": sys.version.split()[0]},
    }


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    learn = commands.add_parser("train", help="train a MORL-baselines learner, play its front, score it")
    learn.add_argument("--algo", choices=tuple(_CLASSES), required=True)
    learn.add_argument("--timesteps", type=int, required=True, help="env steps of training")
    learn.add_argument("--seed", type=int, default=0)
    learn.add_argument("--threads", type=int, default=1, help="torch threads")
    learn.add_argument(
        "--iteration-steps",
        type=int,
        default=None,
        help="pilots only: GPI's env steps per iteration (default: its published timesteps_per_iter, 10000)",
    )
    learn.add_argument(
        "--checkpoint-dir",
        default=None,
        help="train in chunks, the learner's whole training state saved here after each; go on from here",
    )
    learn.add_argument(
        "--chunk-steps",
        type=int,
        default=None,
        help=f"CAPQL's and Envelope's env steps per chunk with --checkpoint-dir (default {CHUNK_STEPS})",
    )
    learn.add_argument(
        "--stop-after-chunks",
        type=int,
        default=None,
        help=f"tests: stop (exit {STOPPED_STATUS}, no record) after this many chunks of this process",
    )
    given = commands.add_parser("score", help="score per-episode discounted returns played elsewhere")
    given.add_argument("--returns", required=True, help='JSON: {"discounted_returns": [[[...], ...], ...]}')
    for command in (learn, given):
        command.add_argument("--env", required=True, help="the MO-Gymnasium id, at its registered time limit")
        command.add_argument("--gamma", type=float, default=0.99)
        command.add_argument("--ref-point", required=True, help="hypervolume reference point, e.g. -100,-100")
        command.add_argument("--eval-weights", type=int, default=EVAL_WEIGHTS)
        command.add_argument("--eval-episodes", type=int, default=EVAL_EPISODES)
        command.add_argument("--eu-weights", type=int, default=EU_WEIGHTS)
        command.add_argument("--eval-seed", type=int, default=10_000)
        command.add_argument("--out", required=True)
        command.add_argument("--force", action="store_true", help="replace --out if it exists")
    return parser


def _check(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """The options in their ranges, before anything is imported or trained (exit 2 naming the option)."""
    ranges = {"eval_weights": (1, MAX_EVAL), "eval_episodes": (1, MAX_EVAL), "eu_weights": (1, MAX_EVAL)}
    ranges["eval_seed"] = (0, 2**31 - 1)
    if args.command == "train":
        ranges.update(timesteps=(1, MAX_TIMESTEPS), seed=(0, 2**32 - 1), threads=(1, 256))
        if args.iteration_steps is not None:
            ranges["iteration_steps"] = (1, args.timesteps)
        if args.chunk_steps is not None:
            ranges["chunk_steps"] = (1, MAX_TIMESTEPS)
        if args.stop_after_chunks is not None:
            ranges["stop_after_chunks"] = (1, MAX_TIMESTEPS)
            if args.checkpoint_dir is None:
                parser.error("--stop-after-chunks needs --checkpoint-dir")
        folder = None if args.checkpoint_dir is None else Path(args.checkpoint_dir)
        if folder is not None and (folder.is_symlink() or (folder.exists() and not folder.is_dir())):
            parser.error(f"--checkpoint-dir: {str(folder)!r} is a file or a symbolic link; name a folder")
    for name, (low, high) in ranges.items():
        if not low <= getattr(args, name) <= high:
            parser.error(f"--{name.replace('_', '-')} must be in [{low}, {high}]")
    if not 0.0 < args.gamma <= 1.0:
        parser.error("--gamma must be in (0, 1]")


def main(argv: list[str] | None = None) -> int:
    runner = _runner()
    runner._unshadow_standard_library()
    parser = _parser()
    args = parser.parse_args(argv)
    _check(parser, args)
    # Never a network call or a run folder of wandb's: the record is this script's output.
    os.environ["WANDB_MODE"] = "disabled"
    try:
        args.ref_point_values = runner._floats(args.ref_point, "ref-point")
        import morl_baselines  # noqa: F401
    except runner.InputError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except ImportError:
        print(f"error: morl_baselines is not installed in this python ({sys.executable})", file=sys.stderr)
        return 2
    resume = _resume()
    # Every path is made absolute before the script moves to its scratch folder (relative --out of the CLI).
    out = Path(args.out).absolute()
    for name in ("checkpoint_dir", "returns"):
        if getattr(args, name, None) is not None:
            setattr(args, name, Path(getattr(args, name)).absolute())
    try:
        runner._write_json(out, {}, args.force, check_only=True)
        # Learners that save checkpoints or logs write them in the working folder: a temporary one.
        with tempfile.TemporaryDirectory(prefix="morl-protocol-") as scratch:
            os.chdir(scratch)
            record = train(args) if args.command == "train" else score(args)
        runner._write_json(out, record, args.force)
    except (runner.InputError, resume.CheckpointError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except resume.LoopChanged as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    except resume.Stopped as stopped:
        print(stopped, file=sys.stderr)
        return STOPPED_STATUS
    shown = ", ".join(f"{k} {v:.6g}" for k, v in record["indicators"].items())
    print(f"{record.get('algorithm', 'given front')}: {shown} -> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
