"""
MORL-baselines beside the hierarchy: train CAPQL on an MO-Gymnasium env for a total env-step budget,
evaluate its front over a preference sweep, and score it, or any other front, with MORL-baselines' own
indicators (hypervolume, expected utility).

MORL-baselines pins its own torch and pulls wandb, pymoo and more, so it lives in its own virtual environment,
never in sb3-hddpg's. This file imports nothing from sb3_hddpg and runs with that environment's python, by
its path: ``hddpg-cli benchmark --scenario front --morl-python PYTHON`` runs it for every seed (:mod:`.morl`),
or by hand::

    python3 -m venv ~/morl-venv
    ~/morl-venv/bin/pip install torch --index-url https://download.pytorch.org/whl/cpu   # CPU wheel first
    ~/morl-venv/bin/pip install morl-baselines "mujoco>=3"
    RUNNER=$(python -c "import sb3_hddpg.experiments.benchmark as b, pathlib; print(pathlib.Path(b.__file__).with_name('morl_runner.py'))")

    # CAPQL for as many env steps as the hierarchy used; its front over 11 preferences, 5 episodes each
    ~/morl-venv/bin/python $RUNNER train --env mo-halfcheetah-v5 --algo capql \\
        --timesteps 300000 --seed 0 --out runs/morl/capql-seed-0.json

    # the hierarchy's front on the same indicators: its conditioned manager's vector returns per preference,
    # from the record of `hddpg-cli benchmark --env mo-halfcheetah-v5 --scenario front` (or --front JSON)
    ~/morl-venv/bin/python $RUNNER score \\
        --record runs/hc/records/hddpg-front/seed-0.json --member conditioned \\
        --ref-point=-100,-100 --out runs/morl/hierarchy-seed-0.json

Both write the same record (:func:`front_record`): the front (vector returns per preference, raw per-episode
sums of the env's objectives), the non-dominated part of it, hypervolume and expected utility from
``morl_baselines.common.performance_indicators`` with the reference point and weights named in the record,
and for ``train`` each preference's mean episode length, the wall-clock of training and of the evaluation,
the env steps and the library versions. Evaluation episode ``i`` of every preference is reset with seed
``--eval-seed`` + ``i``, as the benchmark's test episodes are.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

#: The record's kind and schema version, so that a reader can refuse what it does not know.
RECORD_KIND = "sb3-hddpg-morl-front"
#: The largest JSON file read (a front record is a few hundred kilobytes).
MAX_JSON_BYTES = 64 * 1024 * 1024
RECORD_VERSION = 1
#: Weights on which expected utility is averaged (MORL-baselines' own default for its evaluations).
EU_WEIGHTS = 100
#: CAPQL's batch size (its default): learning cannot start before the buffer holds a batch.
CAPQL_BATCH = 128
#: MORL-baselines' reference point for its MuJoCo examples (per-objective lower corner of the hypervolume).
DEFAULT_REF_POINT = (-100.0, -100.0)


def _floats(text: str, name: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise SystemExit(f"error: --{name}: expected comma-separated numbers, got {text!r}") from None
    if not values or not all(math.isfinite(v) for v in values):
        raise SystemExit(f"error: --{name}: expected finite numbers, got {text!r}")
    return values


def front_record(
    front: list[list[float]],
    preferences: list[list[float]],
    ref_point: list[float],
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """
    A front scored with MORL-baselines' indicators: its non-dominated points, hypervolume from ``ref_point``
    and expected utility over :data:`EU_WEIGHTS` equally spaced weights (linear utility).

    :param front: one vector return per preference (raw per-episode sums of the objectives).
    :param preferences: the preference weights that produced each point (same order).
    :param ref_point: the hypervolume's reference point, one value per objective.
    :param extra: more fields (algorithm, budget, wall-clock...).
    """
    import numpy as np
    from morl_baselines.common.pareto import filter_pareto_dominated
    from morl_baselines.common.performance_indicators import expected_utility, hypervolume
    from morl_baselines.common.weights import equally_spaced_weights

    points = [np.asarray(p, dtype=np.float64) for p in front]
    if not points or any(p.shape != (len(ref_point),) for p in points):
        raise ValueError(f"Expected a front of {len(ref_point)}-objective points, actually {front!r:.200}")
    kept = [np.asarray(p) for p in filter_pareto_dominated(points)]
    weights = equally_spaced_weights(len(ref_point), EU_WEIGHTS)
    return {
        "kind": RECORD_KIND,
        "record_version": RECORD_VERSION,
        "front": [p.tolist() for p in points],
        "preferences": [list(map(float, w)) for w in preferences],
        "non_dominated": [p.tolist() for p in kept],
        "ref_point": list(map(float, ref_point)),
        "hypervolume": float(hypervolume(np.asarray(ref_point, dtype=np.float64), kept)),
        "expected_utility": float(expected_utility(kept, weights_set=weights)),
        "expected_utility_weights": EU_WEIGHTS,
        "indicators": "morl_baselines.common.performance_indicators (hypervolume, expected_utility)",
        **(extra or {}),
    }


def _make_env(env_id: str, episode_steps: int | None, env_kwargs: dict[str, Any]) -> Any:
    import mo_gymnasium as mo_gym

    kwargs = {**env_kwargs, **({"max_episode_steps": episode_steps} if episode_steps else {})}
    return mo_gym.make(env_id, **kwargs)


def _agent(env: Any, seed: int, args: argparse.Namespace) -> Any:
    from morl_baselines.multi_policy.capql.capql import CAPQL

    return CAPQL(env, learning_starts=args.learning_starts, seed=seed, log=False, device="cpu")


def _evaluate_front(
    agent: Any, env: Any, preferences: list[Any], episodes: int, seed: int
) -> tuple[list[list[float]], list[float]]:
    """
    Each preference's mean vector return and mean episode length over ``episodes``, episode ``i`` reset with
    ``seed + i`` (the same episodes at every preference, as MORL-baselines' ``eval_mo`` plays them).
    """
    import numpy as np

    returns, lengths = [], []
    for weights in preferences:
        sums, steps = [], []
        for episode in range(episodes):
            obs, _ = env.reset(seed=seed + episode)
            total, length, done = np.zeros(int(env.unwrapped.reward_dim)), 0, False
            while not done:
                obs, reward, terminated, truncated, _ = env.step(agent.eval(obs, weights))
                total = total + np.asarray(reward, dtype=np.float64)
                length += 1
                done = terminated or truncated
            sums.append(total)
            steps.append(length)
        returns.append([float(v) for v in np.mean(sums, axis=0)])
        lengths.append(float(np.mean(steps)))
    return returns, lengths


def train(args: argparse.Namespace) -> dict[str, Any]:
    """Train the algorithm for ``--timesteps`` env steps, then evaluate and score its front."""
    import morl_baselines
    import numpy as np
    import torch
    from morl_baselines.common.weights import equally_spaced_weights

    torch.set_num_threads(args.threads)
    env_kwargs = _env_kwargs(args.env_kwargs)
    env = _make_env(args.env, args.episode_steps, env_kwargs)
    eval_env = _make_env(args.env, args.episode_steps, env_kwargs)
    reward_dim = int(env.unwrapped.reward_dim)
    ref_point = _floats(args.ref_point, "ref-point") if args.ref_point else list(DEFAULT_REF_POINT)
    if len(ref_point) != reward_dim:
        raise SystemExit(
            f"error: --ref-point: {args.env} has {reward_dim} objectives, got {len(ref_point)} values"
        )
    agent = _agent(env, args.seed, args)
    started = time.perf_counter()
    # No evaluation inside training (its eval_freq beyond the budget): the wall-clock is training's alone.
    agent.train(
        total_timesteps=args.timesteps,
        eval_env=eval_env,
        ref_point=np.asarray(ref_point),
        eval_freq=args.timesteps + 1,
    )
    train_seconds = time.perf_counter() - started
    preferences = equally_spaced_weights(reward_dim, args.preferences)
    started = time.perf_counter()
    front, lengths = _evaluate_front(agent, eval_env, preferences, args.episodes, args.eval_seed)
    eval_seconds = time.perf_counter() - started
    return front_record(
        front,
        [list(w) for w in preferences],
        ref_point,
        {
            "source": "morl-baselines",
            "algorithm": args.algo,
            "env_id": args.env,
            "env_kwargs": env_kwargs,
            "episode_steps": args.episode_steps,
            "mean_lengths": lengths,
            "total_timesteps": args.timesteps,
            "seed": args.seed,
            "eval_seed": args.eval_seed,
            "episodes_per_preference": args.episodes,
            "wall_time_train_s": train_seconds,
            "wall_time_eval_s": eval_seconds,
            "threads": args.threads,
            "versions": {
                "morl_baselines": getattr(morl_baselines, "__version__", _version("morl-baselines")),
                "torch": torch.__version__,
                "mo_gymnasium": _version("mo-gymnasium"),
                "python": platform.python_version(),
            },
        },
    )


def _env_kwargs(text: str | None) -> dict[str, Any]:
    """The inner env's keyword arguments, a JSON object of plain values, or a one-line error."""
    if not text:
        return {}
    try:
        kwargs = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as error:
        raise SystemExit(f"error: --env-kwargs: not JSON: {error}") from None
    if not isinstance(kwargs, dict):
        raise SystemExit(f"error: --env-kwargs: expected a JSON object, got {text[:80]!r}")
    return kwargs


def _version(distribution: str) -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(distribution)
    except PackageNotFoundError:
        return None


def _read_json(path: str, option: str) -> Any:
    """A JSON file of at most :data:`MAX_JSON_BYTES`, or a one-line error naming ``option``."""
    try:
        if Path(path).stat().st_size > MAX_JSON_BYTES:
            raise SystemExit(f"error: {option}: {path!r} is larger than {MAX_JSON_BYTES} bytes")
        return json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as error:
        raise SystemExit(f"error: {option}: cannot read {path!r}: {error}") from None


def front_of_record(record: Any, member: str) -> dict[str, Any]:
    """
    One member's front from a benchmark's front record (``records/hddpg-front/seed-N.json`` of
    ``hddpg-cli benchmark --env ... --scenario front``): each point's vector return, read from its
    ``returns`` plane (the per-episode sums of the env's objectives, as MORL-baselines evaluates them).
    """
    try:
        objectives = [str(key) for key, _ in record["planes"]["returns"]]
        points = record["front"][member]["points"]
        front = [[float(point[key]) for key in objectives] for point in points]
        labels = [str(point["label"]) for point in points]
    except (KeyError, TypeError, ValueError) as error:
        members = list(record.get("front", {})) if isinstance(record, dict) else []
        raise SystemExit(
            f"error: --record: not a front record with a returns plane and member {member!r} "
            f"(members: {members}): {type(error).__name__}: {error}"
        ) from None
    return {"front": front, "labels": labels, "member": member, "objectives": objectives}


def score(args: argparse.Namespace) -> dict[str, Any]:
    """
    Score a front given as JSON, ``{"front": [[...], ...], "preferences": [[...], ...]}`` (any extra keys
    kept), or one member of a benchmark's front record (:func:`front_of_record`).
    """
    if args.record is not None:
        given = front_of_record(_read_json(args.record, "--record"), args.member)
    else:
        given = _read_json(args.front, "--front")
    if not isinstance(given, dict) or not isinstance(given.get("front"), list):
        raise SystemExit('error: --front: expected a JSON object with "front": [[objective values...], ...]')
    front = given["front"]
    ref_point = _floats(args.ref_point, "ref-point") if args.ref_point else list(DEFAULT_REF_POINT)
    preferences = given.get("preferences") or [[] for _ in front]
    extra = {k: v for k, v in given.items() if k not in ("front", "preferences")}
    try:
        return front_record(front, preferences, ref_point, {"source": "given front", **extra})
    except ValueError as error:
        raise SystemExit(f"error: --front: {error}") from None


def _unshadow_standard_library() -> None:
    """
    Run by its path, this file's folder is first on ``sys.path``, where its neighbours (``statistics.py``)
    would shadow the standard library's modules of those names for everything MORL-baselines imports.
    """
    here = Path(__file__).resolve().parent
    sys.path[:] = [entry for entry in sys.path if Path(entry or ".").resolve() != here]


def main(argv: list[str] | None = None) -> int:
    _unshadow_standard_library()
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("train", help="train CAPQL, evaluate its front, score it")
    run.add_argument("--env", default="mo-halfcheetah-v5")
    # CAPQL: MORL-baselines' preference-conditioned continuous-action learner, one policy for every preference
    # (PGMORL keeps a population of policies, evaluated differently: not run here).
    run.add_argument("--algo", choices=("capql",), default="capql")
    run.add_argument("--timesteps", type=int, required=True, help="total env steps of training")
    run.add_argument("--seed", type=int, default=0)
    run.add_argument(
        "--episode-steps", type=int, default=None, help="the env's time limit (default: its own)"
    )
    run.add_argument("--env-kwargs", default=None, help="the env's keyword arguments, a JSON object")
    run.add_argument("--learning-starts", type=int, default=1000, help="CAPQL's random steps before learning")
    run.add_argument("--preferences", type=int, default=11, help="equally spaced preferences of the front")
    run.add_argument("--episodes", type=int, default=5, help="evaluation episodes per preference")
    run.add_argument(
        "--eval-seed",
        type=int,
        default=10_000,
        help="seed of the first evaluation episode (then + 1, + 2...)",
    )
    run.add_argument("--threads", type=int, default=1, help="torch threads")
    run.add_argument("--ref-point", default=None, help="hypervolume reference point, e.g. -100,-100")
    run.add_argument("--out", required=True)
    given = commands.add_parser("score", help="score a given front with the same indicators")
    source = given.add_mutually_exclusive_group(required=True)
    source.add_argument("--front", help='JSON: {"front": [[...], ...], "preferences": [...]}')
    source.add_argument("--record", help="a benchmark's front record: records/hddpg-front/seed-N.json")
    given.add_argument("--member", default="conditioned", help="with --record: the member scored")
    given.add_argument("--ref-point", default=None)
    given.add_argument("--out", required=True)
    args = parser.parse_args(argv)
    if args.command == "train":
        for name in ("timesteps", "preferences", "episodes", "threads"):
            if getattr(args, name) < 1:
                parser.error(f"--{name.replace('_', '-')} must be >= 1")
        if args.learning_starts < CAPQL_BATCH:
            parser.error(
                f"--learning-starts must be >= {CAPQL_BATCH}: CAPQL samples batches of that size from then on"
            )
        if args.episode_steps is not None and args.episode_steps < 1:
            parser.error("--episode-steps must be >= 1")
    try:
        import morl_baselines  # noqa: F401
    except ImportError:
        print(
            "error: morl_baselines is not installed in this python "
            f"({sys.executable}); run this script with the MORL-baselines environment's python",
            file=sys.stderr,
        )
        return 2
    record = train(args) if args.command == "train" else score(args)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    temporary = out.with_suffix(out.suffix + ".tmp")
    temporary.write_text(json.dumps(record, indent=2) + "\n")
    os.replace(temporary, out)
    print(
        f"{record.get('algorithm', 'front')}: hypervolume {record['hypervolume']:.6g}, expected utility "
        f"{record['expected_utility']:.6g}"
        + (f", trained {record['wall_time_train_s']:.1f} s" if "wall_time_train_s" in record else "")
        + f" -> {out}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
