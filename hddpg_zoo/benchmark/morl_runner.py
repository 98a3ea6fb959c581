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
    RUNNER=$(python -c "import hddpg_zoo.benchmark as b, pathlib; print(pathlib.Path(b.__file__).with_name('morl_runner.py'))")

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
import stat
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

#: The record's kind and schema version, so that a reader can refuse what it does not know.
RECORD_KIND = "sb3-hddpg-morl-front"
#: The largest JSON file read: sb3-hddpg's limit for the same records (a front record is about 100 kB).
MAX_JSON_BYTES = 1 << 20
RECORD_VERSION = 1
#: Most points of a front scored. MORL-baselines' Pareto filter compares every pair of points at once
#: (n x n x objectives booleans): 100,000 points of a 1 MB file would take 20 GB.
MAX_FRONT_POINTS = 1_000
#: Most objectives. The hypervolume's cost grows exponentially with them (100 points in 10 objectives
#: already take the better part of a minute); MO-Gymnasium's envs have 2 to 6.
MAX_OBJECTIVES = 6
#: Most evaluation episodes per preference, and most env steps of training (sb3-hddpg's limits).
MAX_EPISODES = 10_000
MAX_TIMESTEPS = 1_000_000_000
#: Weights on which expected utility is averaged (MORL-baselines' own default for its evaluations).
EU_WEIGHTS = 100
#: CAPQL's batch size (its default): learning cannot start before the buffer holds a batch.
CAPQL_BATCH = 128
#: MORL-baselines' reference point for its MuJoCo examples (per-objective lower corner of the hypervolume).
DEFAULT_REF_POINT = (-100.0, -100.0)


class InputError(Exception):
    """A command line or a file this script cannot use: one line on stderr, exit 2 (never a traceback)."""


def _floats(text: str, name: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise InputError(f"--{name}: expected comma-separated numbers, got {text[:80]!r}") from None
    if not 1 <= len(values) <= MAX_OBJECTIVES or not all(math.isfinite(v) for v in values):
        raise InputError(f"--{name}: expected 1 to {MAX_OBJECTIVES} finite numbers, got {text[:80]!r}")
    return values


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _check_front(front: object, preferences: object, objectives: int) -> None:
    """
    The one check of a front before it is scored, given or trained: 1 to :data:`MAX_FRONT_POINTS` points of
    ``objectives`` finite numbers each, and one preference (a list of finite numbers) per point.

    :raises InputError: naming what is wrong.
    """
    if (
        not isinstance(front, list)
        or not 1 <= len(front) <= MAX_FRONT_POINTS
        or not all(isinstance(p, list) and len(p) == objectives and all(map(_is_number, p)) for p in front)
    ):
        raise InputError(
            f"expected a front of 1 to {MAX_FRONT_POINTS} points of {objectives} finite numbers each (one "
            f"per objective of the reference point), got {str(front)[:200]}"
        )
    if (
        not isinstance(preferences, list)
        or len(preferences) != len(front)
        or not all(
            isinstance(w, list) and len(w) <= MAX_OBJECTIVES and all(map(_is_number, w)) for w in preferences
        )
    ):
        raise InputError(
            f"expected one preference (a list of finite numbers) per point, got {str(preferences)[:200]}"
        )


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

    _check_front(front, preferences, len(ref_point))
    points = [np.asarray(p, dtype=np.float64) for p in front]
    kept = [np.asarray(p) for p in filter_pareto_dominated(points)]
    weights = equally_spaced_weights(len(ref_point), EU_WEIGHTS)
    # The extra fields first: a field of a given front never stands in for a score computed here.
    return {
        **(extra or {}),
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
        raise InputError(f"--ref-point: {args.env} has {reward_dim} objectives, got {len(ref_point)} values")
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
        raise InputError(f"--env-kwargs: not JSON: {error}") from None
    if not isinstance(kwargs, dict):
        raise InputError(f"--env-kwargs: expected a JSON object, got {text[:80]!r}")
    return kwargs


def _version(distribution: str) -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(distribution)
    except PackageNotFoundError:
        return None


def _read_json(path: str, option: str) -> Any:
    """
    A JSON file of at most :data:`MAX_JSON_BYTES` (counted as read: a device or a pipe says nothing of its size
    beforehand), strict (no ``NaN`` or ``Infinity``), or a one-line error naming ``option``.
    """
    try:
        # without blocking, and only a regular file: open() of a FIFO would wait for a writer forever
        with os.fdopen(os.open(path, os.O_RDONLY | os.O_NONBLOCK), "rb") as handle:
            if not stat.S_ISREG(os.fstat(handle.fileno()).st_mode):
                raise InputError(f"{option}: {path!r} is not a regular file (a FIFO, socket or device?)")
            data = handle.read(MAX_JSON_BYTES + 1)
        if len(data) > MAX_JSON_BYTES:
            raise InputError(f"{option}: {path!r} is larger than {MAX_JSON_BYTES} bytes")
        return json.loads(data.decode(), parse_constant=_not_a_number)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as error:
        raise InputError(f"{option}: cannot read {path!r}: {type(error).__name__}: {error}") from None


def _not_a_number(name: str) -> Any:
    raise json.JSONDecodeError(f"{name} is not a finite number", name, 0)


def _write_json(path: Path, record: dict[str, Any], force: bool, check_only: bool = False) -> None:
    """
    ``record`` as strict JSON at ``path``, atomically (a temporary file of its own in the same folder, then
    renamed): never a half-written file, never through a link, and an existing file only with ``--force``.

    :param check_only: only check that ``path`` may be written.
    """
    if path.is_symlink() or path.is_dir():
        raise InputError(f"--out: {str(path)!r} is a folder or a symbolic link; name a file")
    if path.exists() and not force:
        raise InputError(f"--out: {str(path)!r} exists; pass --force to replace it")
    if check_only:
        return
    try:
        text = json.dumps(record, indent=2, allow_nan=False) + "\n"
    except ValueError:
        raise InputError("a score or a field is not a finite number; nothing written") from None
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(temporary, 0o644)
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


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
    except (KeyError, TypeError, ValueError, AttributeError) as error:
        fronts = record.get("front") if isinstance(record, dict) else None
        members = [str(m)[:64] for m in fronts][:20] if isinstance(fronts, dict) else []
        raise InputError(
            f"--record: not a front record with a returns plane and member {member[:64]!r} "
            f"(members: {members}): {type(error).__name__}: {str(error)[:200]}"
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
        raise InputError('--front: expected a JSON object with "front": [[objective values...], ...]')
    front = given["front"]
    ref_point = _floats(args.ref_point, "ref-point") if args.ref_point else list(DEFAULT_REF_POINT)
    preferences = given.get("preferences") or [[] for _ in front]
    extra = {k: v for k, v in given.items() if k not in ("front", "preferences")}
    try:
        return front_record(front, preferences, ref_point, {"source": "given front", **extra})
    except InputError as error:
        raise InputError(f"{'--record' if args.record is not None else '--front'}: {error}") from None


def _unshadow_standard_library() -> None:
    """
    Run by its path, this file's folder is first on ``sys.path``, where its neighbours (``statistics.py``)
    would shadow the standard library's modules of those names for everything MORL-baselines imports.
    """
    here = Path(__file__).resolve().parent
    sys.path[:] = [entry for entry in sys.path if Path(entry or ".").resolve() != here]


def _parser() -> argparse.ArgumentParser:
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
    given = commands.add_parser("score", help="score a given front with the same indicators")
    source = given.add_mutually_exclusive_group(required=True)
    source.add_argument("--front", help='JSON: {"front": [[...], ...], "preferences": [...]}')
    source.add_argument("--record", help="a benchmark's front record: records/hddpg-front/seed-N.json")
    given.add_argument("--member", default="conditioned", help="with --record: the member scored")
    given.add_argument("--ref-point", default=None)
    for command in (run, given):
        command.add_argument("--out", required=True)
        command.add_argument("--force", action="store_true", help="replace --out if it exists")
    return parser


#: The ranges of train's integer options (the seeds are numpy's and torch's 32-bit ones).
_TRAIN_RANGES = {
    "timesteps": (1, MAX_TIMESTEPS),
    "preferences": (1, MAX_FRONT_POINTS),
    "episodes": (1, MAX_EPISODES),
    "threads": (1, 256),
    "learning_starts": (CAPQL_BATCH, MAX_TIMESTEPS),
    "seed": (0, 2**32 - 1),
    "eval_seed": (0, 2**32 - 1 - MAX_EPISODES),
}


def _check_train(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """train's options in their ranges, before anything is imported or trained."""
    for name, (low, high) in _TRAIN_RANGES.items():
        if not low <= getattr(args, name) <= high:
            reason = "; CAPQL samples batches of that size from then on" if name == "learning_starts" else ""
            parser.error(f"--{name.replace('_', '-')} must be in [{low}, {high}]{reason}")
    if args.episode_steps is not None and not 1 <= args.episode_steps <= 100_000:
        parser.error("--episode-steps must be in [1, 100000]")


def main(argv: list[str] | None = None) -> int:
    _unshadow_standard_library()
    parser = _parser()
    args = parser.parse_args(argv)
    if args.command == "train":
        _check_train(parser, args)
    try:
        import morl_baselines  # noqa: F401
    except ImportError:
        print(
            "error: morl_baselines is not installed in this python "
            f"({sys.executable}); run this script with the MORL-baselines environment's python",
            file=sys.stderr,
        )
        return 2
    out = Path(args.out)
    try:
        _write_json(out, {}, args.force, check_only=True)  # before the work: an hour of training is not lost
        record = train(args) if args.command == "train" else score(args)
        _write_json(out, record, args.force)
    except InputError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(
        f"{record.get('algorithm', 'front')}: hypervolume {record['hypervolume']:.6g}, expected utility "
        f"{record['expected_utility']:.6g}"
        + (f", trained {record['wall_time_train_s']:.1f} s" if "wall_time_train_s" in record else "")
        + f" -> {out}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
