"""
MORL-baselines' CAPQL as a member of the front scenario (``benchmark --scenario front --morl-python PYTHON``).

MORL-baselines pins its own torch, so it runs in its own virtual environment: per seed, :data:`RUNNER` (a
script that imports nothing from sb3_hddpg) is run with that environment's python. It trains CAPQL, one
preference-conditioned policy, for the env steps the hierarchy spent on one policy for every preference (the
seed's workers and its conditioned manager), evaluates it at as many equally spaced preferences as the front's
sweep has, on the same test episodes, and scores its front and the conditioned manager's with MORL-baselines'
own indicators (hypervolume, expected utility). Its points join the front as the member ``capql``: the pymoo
hypervolumes and the paired comparisons treat it as every other member.

The runner's records are written next to the seed's managers and reused when the task resumes.
"""

from __future__ import annotations

import json
import os
import subprocess
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypedDict

from hddpg_zoo.benchmark.front_points import FrontPoint, FrontSpec, preference_label
from hddpg_zoo.benchmark.morl_runner import MAX_FRONT_POINTS, RECORD_KIND, RECORD_VERSION
from hddpg_zoo.records.results_leaves import MorlResults
from hddpg_zoo.stats import summarise
from sb3_hddpg.artifacts.io import atomic_write_json
from sb3_hddpg.artifacts.limits import MAX_TERMS, brief, read_json_record
from sb3_hddpg.artifacts.records.base import check_version
from sb3_hddpg.artifacts.values import is_finite_number
from sb3_hddpg.envs.adapters import MULTI_OBJECTIVE_ENV_ID
from sb3_hddpg.envs.terms_env import TermsEnv
from sb3_hddpg.training.agent import sigterm_as_interrupt

#: The script run with MORL-baselines' python.
RUNNER = Path(__file__).with_name("morl_runner.py")
#: The front member MORL-baselines' learner adds.
MORL_MEMBER = "capql"
#: The adapter's own keyword arguments; the rest are the MO-Gymnasium env's.
_ADAPTER_KWARGS = ("env_id", "terms", "term_bounds", "term", "episode_steps", "render_mode")
#: A runner's record's scores (MORL-baselines' indicators), and its wall times.
_SCORES = ("hypervolume", "expected_utility")
_SECONDS = ("wall_time_train_s", "wall_time_eval_s")


class MorlScore(TypedDict):
    """One front scored by MORL-baselines' indicators, from the runner's record."""

    hypervolume: float
    expected_utility: float


class MorlRun(TypedDict):
    """What a seed's front record keeps of MORL-baselines' run (key ``morl``)."""

    algorithm: str
    #: CAPQL's training env steps: the seed's workers' and conditioned manager's together
    env_steps: int
    #: the reference point of both scores (the ``returns`` plane's)
    ref_point: list[float]
    wall_time_train_s: float
    wall_time_eval_s: float
    #: seconds the conditioned manager trained (the workers' seconds are in their own record)
    conditioned_train_s: float
    #: member (``capql``, ``conditioned``) -> its front scored by MORL-baselines' indicators
    scores: dict[str, MorlScore]
    versions: dict[str, str | None]


def check_morl_python(path: str) -> str:
    """
    The python of MORL-baselines' environment, as an absolute path.

    :raises ValueError: it is not an executable file.
    """
    resolved = Path(path).expanduser()
    if not resolved.is_file() or not os.access(resolved, os.X_OK):
        raise ValueError(f"Expected --morl-python to be an executable python, actually: {path!r:.200}")
    return str(resolved.absolute())


def morl_python_version(python: str) -> str:
    """
    The version of MORL-baselines' python (e.g. ``3.11.7``): what a record states of it in place of its path,
    which is the writer machine's.

    :raises ValueError: it does not run as a python.
    """
    try:
        done = subprocess.run(
            [python, "-c", "import platform; print(platform.python_version())"],
            capture_output=True,
            text=True,
            timeout=60,
            check=True,
        )
    except (OSError, subprocess.SubprocessError):
        raise ValueError(
            f"Expected --morl-python to be a python that runs, actually: {python!r:.200}"
        ) from None
    return done.stdout.strip()[:40]


def mo_gymnasium_env(env: TermsEnv) -> tuple[str, int | None, dict[str, Any]]:
    """
    The MO-Gymnasium env behind ``env`` (``hddpg/MultiObjective-v0``): its id, time limit and keyword arguments.

    :raises ValueError: ``env`` adapts no MO-Gymnasium env (MORL-baselines learns on MO-Gymnasium's vector reward).
    """
    if env.env_id != MULTI_OBJECTIVE_ENV_ID or not isinstance(env.env_kwargs.get("env_id"), str):
        raise ValueError(
            f"MORL-baselines learns on an MO-Gymnasium env; {env.env_id!r} is not one (use --env with an "
            "MO-Gymnasium id)"
        )
    steps = env.env_kwargs.get("episode_steps")
    inner = {k: v for k, v in env.env_kwargs.items() if k not in _ADAPTER_KWARGS}
    return str(env.env_kwargs["env_id"]), int(steps) if steps is not None else None, inner


def run_in_morl_venv(python: str, script: Path, arguments: Sequence[str], what: str) -> None:
    """
    Run ``script`` with MORL-baselines' ``python``, one thread and wandb off (no network call, no wandb
    folder), so that a benchmark's other process keeps its core.

    :param python: MORL-baselines' interpreter.
    :param script: the script to run.
    :param arguments: its command-line arguments.
    :param what: the script, as the error names it (``runner``, ``protocol runner``).
    :raises RuntimeError: the script failed; its last line of output says why.
    """
    environment = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "WANDB_MODE": "disabled"}
    # A benchmark being stopped (SIGTERM to its pool's processes) must not leave the script training on:
    # subprocess.run kills its child on the KeyboardInterrupt this turns SIGTERM into.
    with sigterm_as_interrupt():
        done = subprocess.run(
            [python, str(script), *arguments], capture_output=True, text=True, env=environment, check=False
        )
    if done.returncode != 0:
        lines = (done.stderr or done.stdout).strip().splitlines() or ["no output"]
        raise RuntimeError(f"MORL-baselines' {what} failed (exit {done.returncode}): {lines[-1][:300]}")


def _run(python: str, arguments: Sequence[str], out: Path, keys: Sequence[str]) -> dict[str, Any]:
    """
    The runner's record at ``out``: read if an earlier invocation wrote it, else run the runner to write it.

    :raises ValueError: the record lacks one of ``keys`` or holds a non-number where a score goes.
    """
    if not out.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
        run_in_morl_venv(python, RUNNER, [*arguments, "--out", str(out)], "runner")
    return read_morl_record(out, keys)


#: A runner's record's fields that are lists of one entry per point of its front, each checked as ``check``.
_PER_POINT: dict[str, Callable[[Any], bool]] = {
    "preferences": lambda w: isinstance(w, list) and len(w) <= MAX_TERMS and all(map(is_finite_number, w)),
    "mean_lengths": lambda length: is_finite_number(length) and length > 0,
}


def read_morl_record(path: Path, keys: Sequence[str]) -> dict[str, Any]:
    """
    The one reader of a runner's record (:data:`RUNNER` writes it, a resumed task reads it back): through the
    JSON size and depth limits, of the runner's kind and a version this library reads, holding ``keys``; its
    ``front`` 1 to :data:`MAX_FRONT_POINTS` points of as many finite numbers each, the scores and wall times
    finite numbers, ``preferences`` and ``mean_lengths`` (when present) one finite entry per point.

    :raises ValueError: one line naming the file and the field (the task fails, and says why).
    """
    record = read_json_record(path, f"{path}: not a readable MORL runner's record")
    if not isinstance(record, dict) or record.get("kind") != RECORD_KIND:
        raise ValueError(f"{path}: not a MORL runner's record (kind {RECORD_KIND!r})")
    check_version(record.get("record_version"), RECORD_VERSION, str(path))
    missing = [k for k in ("front", *keys) if k not in record]
    front = record.get("front")
    if missing or not isinstance(front, list) or not 1 <= len(front) <= MAX_FRONT_POINTS:
        raise ValueError(f"{path}: expected a front of 1 to {MAX_FRONT_POINTS} points and {list(keys)}")
    width = len(front[0]) if isinstance(front[0], list) else 0
    if not 1 <= width <= MAX_TERMS or not all(
        isinstance(p, list) and len(p) == width and all(map(is_finite_number, p)) for p in front
    ):
        raise ValueError(f"{path}: front: expected points of as many finite numbers each, got {brief(front)}")
    for key in keys:
        value = record[key]
        if key in _PER_POINT:
            shaped = isinstance(value, list) and len(value) == len(front) and all(map(_PER_POINT[key], value))
        elif key in _SCORES or key in _SECONDS:
            shaped = is_finite_number(value) and (key in _SCORES or value >= 0)
        else:
            shaped = True
        if not shaped:
            raise ValueError(f"{path}: {key}: not what a MORL runner writes, got {brief(value)}")
    return record


def _score(record: Mapping[str, Any]) -> MorlScore:
    return {
        "hypervolume": float(record["hypervolume"]),
        "expected_utility": float(record["expected_utility"]),
    }


def morl_points(
    record: Mapping[str, Any], spec: FrontSpec, bounds: Mapping[str, Sequence[float]]
) -> list[FrontPoint]:
    """
    The front points of a runner's ``train`` record: per preference, its vector return as each term's episode
    sum and the normalised return the benchmark scores (each term's per-step value normalised by ``bounds``).
    """
    points = []
    for weights, returns, length in zip(record["preferences"], record["front"], record["mean_lengths"]):
        if len(returns) != len(spec.terms) or length <= 0:
            raise ValueError(f"Expected {len(spec.terms)} returns per point and episodes of >= 1 step")
        summary = {f"mean_{t}_reward": float(r) for t, r in zip(spec.terms, returns)}
        summary["mean_length"] = float(length)
        summary["mean_reach_reward"] = sum(
            (float(r) - bounds[t][0] * length) / (bounds[t][1] - bounds[t][0])
            for t, r in zip(spec.terms, returns)
        )
        label = preference_label(dict(zip(spec.terms, weights)))
        points.append(FrontPoint.of(label, summary, bounds, spec.terms))
    return points


def morl_member(
    python: str,
    env: TermsEnv,
    spec: FrontSpec,
    bounds: Mapping[str, Sequence[float]],
    conditioned: Sequence[FrontPoint],
    budget: int,
    seed: int,
    test_seeds: range,
    run_dir: Path,
    conditioned_train_s: float,
) -> tuple[list[FrontPoint], MorlRun]:
    """
    CAPQL's front for one seed, trained for ``budget`` env steps, and both fronts' MORL-baselines scores.

    :param python: MORL-baselines' python (:func:`check_morl_python`).
    :param env: the benchmark's env (an MO-Gymnasium env's adapter).
    :param spec: the front's spec (its ``returns`` plane's reference is the scores' reference point).
    :param bounds: the env's per-step term bounds.
    :param conditioned: the conditioned manager's points.
    :param budget: CAPQL's env steps.
    :param seed: the training seed.
    :param test_seeds: the test episodes' seeds (consecutive).
    :param run_dir: where the runner's records go.
    :param conditioned_train_s: seconds the conditioned manager trained, kept beside CAPQL's.
    :return: CAPQL's points, and what the seed's record keeps of the run.
    """
    if "returns" not in spec.references:
        raise ValueError(
            "MORL-baselines' scores need the returns plane: an env whose episodes have a time limit"
        )
    env_id, steps, kwargs = mo_gymnasium_env(env)
    reference = ",".join(f"{v:.17g}" for v in spec.references["returns"])
    options: dict[str, object] = {
        "env": env_id,
        "episode-steps": steps,
        "env-kwargs": json.dumps(kwargs) if kwargs else None,
        "timesteps": budget,
        "seed": seed,
        "preferences": len(spec.sweep.points),
        "episodes": len(test_seeds),
        "eval-seed": test_seeds.start,
        "ref-point": reference,
    }
    # --option=value: one argument each, so that a negative reference point does not read as an option.
    arguments = ["train", *(f"--{k}={v}" for k, v in options.items() if v is not None)]
    trained = _run(
        python,
        arguments,
        run_dir / f"{MORL_MEMBER}.json",
        ("preferences", "mean_lengths", "wall_time_train_s", "wall_time_eval_s", *_SCORES),
    )
    if len(trained["front"]) != len(spec.sweep.points):
        raise ValueError(
            f"{run_dir / MORL_MEMBER}.json: expected a front at the sweep's {len(spec.sweep.points)} preferences, "
            f"got {len(trained['front'])} points"
        )
    scored = _score_front(python, spec, conditioned, reference, run_dir)
    run: MorlRun = {
        "algorithm": str(trained.get("algorithm", MORL_MEMBER)),
        "env_steps": budget,
        "ref_point": [float(v) for v in spec.references["returns"]],
        "wall_time_train_s": float(trained["wall_time_train_s"]),
        "wall_time_eval_s": float(trained["wall_time_eval_s"]),
        "conditioned_train_s": conditioned_train_s,
        "scores": {MORL_MEMBER: _score(trained), "conditioned": _score(scored)},
        "versions": {
            str(k): None if v is None else str(v) for k, v in (trained.get("versions") or {}).items()
        },
    }
    return morl_points(trained, spec, bounds), run


def _score_front(
    python: str, spec: FrontSpec, points: Sequence[FrontPoint], reference: str, run_dir: Path
) -> dict[str, Any]:
    """The conditioned manager's ``points`` in the returns plane, scored by the runner's ``score``."""
    front = run_dir / "conditioned-returns.json"
    objectives = [key for key, _ in spec.planes["returns"]]
    atomic_write_json(
        front,
        {
            "front": [[float(p.values[k]) for k in objectives] for p in points],
            "labels": [p.label for p in points],
        },
    )
    arguments = ["score", "--front", str(front), f"--ref-point={reference}"]
    return _run(python, arguments, run_dir / "conditioned-morl.json", _SCORES)


def morl_results(
    runs: Mapping[int, Mapping[str, Any]], workers: Mapping[int, Mapping[str, Any]]
) -> MorlResults | None:
    """
    The MORL learner's figures over the seeds whose front records have them (``None``: none has): each
    member's indicators, and the seconds each side trained, the hierarchy's being its workers' task (its
    record's ``wall_time_s_total``) and its conditioned manager's.

    :param runs: seed -> the ``hddpg-front`` record.
    :param workers: seed -> the workers' task record.
    """
    seeds = [s for s in sorted(runs) if "morl" in runs[s] and s in workers]
    if not seeds:
        return None
    kept: list[Mapping[str, Any]] = [runs[s]["morl"] for s in seeds]
    members = list(kept[0]["scores"])
    hierarchy_seconds = [
        float(workers[s]["wall_time_s_total"]) + float(runs[s]["morl"]["conditioned_train_s"]) for s in seeds
    ]
    return {
        "algorithm": str(kept[0]["algorithm"]),
        "env_steps": [int(m["env_steps"]) for m in kept],
        "ref_point": [float(v) for v in kept[0]["ref_point"]],
        "scores": {
            member: {
                indicator: summarise([float(m["scores"][member][indicator]) for m in kept])
                for indicator in _SCORES
            }
            for member in members
        },
        "train_seconds": {
            MORL_MEMBER: summarise([float(m["wall_time_train_s"]) for m in kept]),
            "conditioned": summarise(hierarchy_seconds),
        },
        "versions": dict(kept[0].get("versions") or {}),
    }


__all__ = [
    "MORL_MEMBER",
    "RUNNER",
    "MorlRun",
    "MorlScore",
    "check_morl_python",
    "mo_gymnasium_env",
    "morl_member",
    "morl_points",
    "morl_python_version",
    "morl_results",
]
