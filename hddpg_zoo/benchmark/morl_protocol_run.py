"""
One run of MORL-baselines' protocol (:mod:`.morl_protocol`): every side on every seed, each task's record
(:class:`ProtocolRecord`) written as it finishes, kept when the run resumes.

The peers train and are played and scored in MORL-baselines' own environment by
``morl_protocol_runner.py``; the hierarchy's methods (:mod:`.morl_sides`) train and are played here, on the
same weights and the same episodes, and their per-episode returns are scored by the same script, so that
every indicator of both sides is computed by MORL-baselines' own functions. Both sides' records have one
schema, per-episode vector returns included.

Layout of ``out``: ``protocol.json`` (the settings), ``records/<side>/seed-<n>.json`` (the records),
``runs/<method>/seed-<n>/`` (the hierarchy's models), ``runs/<peer>/seed-<n>/checkpoint/`` (a peer's training
state while it trains, so that a resumed run goes on from its last chunk; deleted once its record is written).
"""

from __future__ import annotations

import itertools
import logging
import math
import multiprocessing
import os
import shutil
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from hddpg_zoo.benchmark.morl import run_in_morl_venv
from hddpg_zoo.benchmark.morl_protocol import EU_WEIGHTS, GAMMA, PEERS, ProtocolSettings
from hddpg_zoo.benchmark.morl_protocol_runner import RECORD_KIND, RECORD_VERSION, WEIGHTS_SEED
from hddpg_zoo.benchmark.morl_sides import PROTOCOL_METHODS, SideRun, play_front
from sb3_hddpg.artifacts.io import atomic_write_json
from sb3_hddpg.artifacts.limits import brief, read_json_record
from sb3_hddpg.artifacts.values import is_finite_number

logger = logging.getLogger(__name__)

#: The script run with MORL-baselines' python.
PROTOCOL_RUNNER = Path(__file__).with_name("morl_protocol_runner.py")
#: The indicators every record holds; those of an env whose true front is known.
INDICATORS = ("hypervolume", "expected_utility", "cardinality")
KNOWN_FRONT_INDICATORS = ("igd", "maximum_utility_loss")
#: The most linear systems a known front's convex coverage set may take: it is found by solving every system
#: of as many of its points and simplex faces as there are objectives (minecart's 20 points in 3: 1,771).
MAX_COVERAGE_SYSTEMS = 100_000


@dataclass(frozen=True)
class ProtocolRecord:
    """
    One side's run on one seed under the protocol: the same schema for a peer and for a hierarchy.

    :param side: ``"peer"`` or ``"hierarchy"``.
    :param method: the peer's or the method's name.
    :param weights: the front's weights.
    :param discounted_returns: per weight, per episode, the discounted vector return.
    :param returns: per weight, per episode, the undiscounted vector return.
    :param front: per weight, the mean discounted return (the protocol's front).
    :param non_dominated: the front's distinct non-dominated points, as MORL-baselines' evaluator filters them
        (its indicators are computed on these).
    :param indicators: MORL-baselines' indicators of the front's non-dominated part.
    :param env_steps: model or phase -> its env steps of training.
    :param resumes: times a peer's training went on from its checkpoint in a new process (its env's episode
        and random stream restarted): ``0`` for an uninterrupted run.
    :param chunk_steps: env steps of a chunk of a peer's checkpointed training (``None``: not chunked).
    :param known_front: the env's true front at the protocol's discount, where MO-Gymnasium knows it.
    """

    side: str
    method: str
    env_id: str
    seed: int
    gamma: float
    ref_point: tuple[float, ...]
    eval_seed: int
    weights: list[list[float]]
    discounted_returns: list[list[list[float]]]
    returns: list[list[list[float]]]
    front: list[list[float]]
    non_dominated: list[list[float]]
    indicators: dict[str, float]
    env_steps: dict[str, int]
    wall_time_train_s: float
    wall_time_eval_s: float
    versions: dict[str, str | None]
    resumes: int = 0
    chunk_steps: int | None = None
    known_front: list[list[float]] | None = None

    @property
    def total_env_steps(self) -> int:
        """Env steps of every model and phase together."""
        return sum(self.env_steps.values())

    def to_json(self) -> dict[str, Any]:
        return {"kind": RECORD_KIND, "record_version": RECORD_VERSION, **asdict(self)}


def _numbers(value: object, depth: int, width: int | None = None) -> bool:
    """Whether ``value`` is a list nested ``depth`` deep of finite numbers (the innermost of ``width``)."""
    if not isinstance(value, list):
        return False
    if depth == 1:
        return (width is None or len(value) == width) and all(map(is_finite_number, value))
    return len(value) >= 1 and all(_numbers(v, depth - 1, width) for v in value)


def read_protocol_record(path: Path) -> ProtocolRecord:
    """
    The one reader of a protocol record (written here or by the runner): through the JSON limits, of the
    record's kind and version, every field of its type, one front point and one list of episodes per weight.

    :raises ValueError: one line naming the file and the field.
    """
    data = read_json_record(path, f"{path}: not a readable protocol record")
    if (
        not isinstance(data, dict)
        or data.get("kind") != RECORD_KIND
        or data.get("record_version") != RECORD_VERSION
    ):
        raise ValueError(f"{path}: not a protocol record (kind {RECORD_KIND!r}, version {RECORD_VERSION})")
    ref = data.get("ref_point")
    width = len(ref) if isinstance(ref, list) else 0
    checks: dict[str, Callable[[Any], bool]] = {
        "ref_point": lambda v: _numbers(v, 1) and 1 <= len(v) <= 6,
        "weights": lambda v: _numbers(v, 2, width),
        "discounted_returns": lambda v: _numbers(v, 3, width) and len(v) == len(data.get("weights") or []),
        "returns": lambda v: _numbers(v, 3, width) and len(v) == len(data.get("weights") or []),
        "front": lambda v: _numbers(v, 2, width) and len(v) == len(data.get("weights") or []),
        "non_dominated": lambda v: _numbers(v, 2, width) and len(v) <= len(data.get("weights") or []),
        "indicators": lambda v: (
            isinstance(v, dict) and all(map(is_finite_number, v.values())) and all(k in v for k in INDICATORS)
        ),
        "env_steps": lambda v: isinstance(v, dict) and all(isinstance(n, int) and n >= 0 for n in v.values()),
        "seed": lambda v: isinstance(v, int) and v >= 0,
        "eval_seed": lambda v: isinstance(v, int) and v >= 0,
        "gamma": lambda v: is_finite_number(v) and 0 < v <= 1,
        "wall_time_train_s": lambda v: is_finite_number(v) and v >= 0,
        "wall_time_eval_s": lambda v: is_finite_number(v) and v >= 0,
        "side": lambda v: v in ("peer", "hierarchy"),
        "method": lambda v: isinstance(v, str) and 0 < len(v) <= 64,
        "env_id": lambda v: isinstance(v, str) and 0 < len(v) <= 128,
        "versions": lambda v: isinstance(v, dict),
    }
    optional: dict[str, Callable[[Any], bool]] = {
        "resumes": lambda v: isinstance(v, int) and v >= 0,
        "chunk_steps": lambda v: v is None or (isinstance(v, int) and v >= 1),
        "known_front": lambda v: (
            v is None or (_numbers(v, 2, width) and math.comb(len(v) + width, width) <= MAX_COVERAGE_SYSTEMS)
        ),
    }
    for key, check in optional.items():
        if key in data and not check(data[key]):
            raise ValueError(f"{path}: {key}: not what a protocol record holds, got {brief(data.get(key))}")
    for key, check in checks.items():
        if key not in data or not check(data[key]):
            raise ValueError(f"{path}: {key}: not what a protocol record holds, got {brief(data.get(key))}")
    return ProtocolRecord(
        side=data["side"],
        method=data["method"],
        env_id=data["env_id"],
        seed=data["seed"],
        gamma=float(data["gamma"]),
        ref_point=tuple(float(v) for v in data["ref_point"]),
        eval_seed=data["eval_seed"],
        weights=data["weights"],
        discounted_returns=data["discounted_returns"],
        returns=data["returns"],
        front=data["front"],
        non_dominated=data["non_dominated"],
        indicators={str(k): float(v) for k, v in data["indicators"].items()},
        env_steps={str(k): int(v) for k, v in data["env_steps"].items()},
        wall_time_train_s=float(data["wall_time_train_s"]),
        wall_time_eval_s=float(data["wall_time_eval_s"]),
        versions={str(k): None if v is None else str(v) for k, v in data["versions"].items()},
        resumes=data.get("resumes", 0),
        chunk_steps=data.get("chunk_steps"),
        known_front=data.get("known_front"),
    )


def protocol_weights(objectives: int, n: int) -> list[list[float]]:
    """
    The protocol's equally spaced weights: pymoo's Riesz energy directions with seed 42, the function
    MORL-baselines' ``equally_spaced_weights`` calls (its runner refuses returns played at other weights).
    """
    from pymoo.util.ref_dirs import get_reference_directions  # lazily: pymoo loads slowly

    return get_reference_directions("energy", objectives, n, seed=WEIGHTS_SEED).tolist()


def _invoke(python: str, arguments: Sequence[str], out: Path) -> None:
    """Run the protocol runner with MORL-baselines' python to write ``out``."""
    out.parent.mkdir(parents=True, exist_ok=True)
    run_in_morl_venv(python, PROTOCOL_RUNNER, [*arguments, "--out", str(out), "--force"], "protocol runner")


def _common_arguments(settings: ProtocolSettings) -> list[str]:
    reference = ",".join(f"{v:.17g}" for v in settings.env.ref_point)
    return [
        f"--env={settings.env_id}",
        f"--gamma={GAMMA}",
        f"--ref-point={reference}",
        f"--eval-weights={settings.eval_weights}",
        f"--eval-episodes={settings.eval_episodes}",
        f"--eu-weights={EU_WEIGHTS}",
        f"--eval-seed={settings.eval_seed}",
    ]


def run_peer(settings: ProtocolSettings, peer: str, seed: int, out: Path, folder: Path) -> None:
    """
    Train, play and score one peer on one seed in MORL-baselines' environment; its record at ``out``.

    The runner checkpoints the peer's training in ``folder`` (``checkpoint/``) after every chunk, so that a
    run stopped midway and resumed goes on from the last one; the checkpoint goes once the record is written.
    """
    assert settings.morl_python is not None  # the settings refuse peers without it
    checkpoint, written = folder / "checkpoint", folder / "peer-record.json"
    arguments = ["train", f"--algo={PEERS[peer].algo}", f"--timesteps={settings.budget}", f"--seed={seed}"]
    arguments.append(f"--checkpoint-dir={checkpoint}")
    _invoke(settings.morl_python, [*arguments, *_common_arguments(settings)], written)
    record = read_json_record(written, f"{written}: not readable")
    # The runner names the learner by MORL-baselines' key; the record by the name ``--peers`` takes.
    atomic_write_json(out, {**record, "method": peer})
    if checkpoint.exists():  # none where a budget below GPI's iteration trained nothing
        shutil.rmtree(checkpoint)
    written.unlink()


def run_method(settings: ProtocolSettings, method: str, seed: int, out: Path, folder: Path) -> None:
    """Train one hierarchy method on one seed, play it over the protocol's weights, score it; its record at ``out``."""
    run = SideRun(settings.env_id, settings.env.actions == "discrete", GAMMA, settings.budget, seed, folder)
    trained = PROTOCOL_METHODS[method].train(run)
    weights = protocol_weights(settings.env.objectives, settings.eval_weights)
    env = trained.env.make()
    started = time.perf_counter()
    try:
        discounted, returns = play_front(
            trained.policy, env, weights, settings.eval_episodes, settings.eval_seed, GAMMA
        )
    finally:
        env.close()
    eval_seconds = time.perf_counter() - started
    played = folder / "protocol-returns.json"
    atomic_write_json(played, {"weights": weights, "discounted_returns": discounted})
    scored_path = folder / "protocol-scored.json"
    if settings.morl_python is None:
        raise ValueError("--morl-python: the hierarchy's fronts are scored by MORL-baselines' own indicators")
    _invoke(settings.morl_python, ["score", f"--returns={played}", *_common_arguments(settings)], scored_path)
    scored = read_json_record(scored_path, f"{scored_path}: not readable")
    from importlib.metadata import version

    record = {
        **{
            k: scored[k]
            for k in ("kind", "record_version", "ref_point", "front", "non_dominated", "indicators")
        },
        **{k: scored[k] for k in ("known_front", "episode_steps", "evaluator", "mul_weights")},
        "side": "hierarchy",
        "method": method,
        "env_id": settings.env_id,
        "seed": seed,
        "gamma": GAMMA,
        "eval_seed": settings.eval_seed,
        "weights": weights,
        "discounted_returns": discounted,
        "returns": returns,
        "env_steps": trained.env_steps,
        "wall_time_train_s": trained.wall_time_train_s,
        "wall_time_eval_s": eval_seconds,
        "versions": {"sb3_hddpg": version("sb3-hddpg"), **scored.get("versions", {})},
    }
    atomic_write_json(out, record)


def record_path(out: Path, side: str, seed: int) -> Path:
    """Where a side's record of a seed goes."""
    return out / "records" / side / f"seed-{seed}.json"


def _run_task(settings: ProtocolSettings, side: str, seed: int, out: Path) -> Path:
    """One side on one seed: its record, run unless already written (a resumed run), then read back."""
    path = record_path(out, side, seed)
    folder = out / "runs" / side / f"seed-{seed}"
    if path.exists() and side in PEERS:
        # A checkpoint left by a run stopped between writing the record and deleting it.
        shutil.rmtree(folder / "checkpoint", ignore_errors=True)
    if not path.exists():
        logger.info("protocol: %s, seed %d", side, seed)
        if side in PEERS:
            run_peer(settings, side, seed, path, folder)
        else:
            run_method(settings, side, seed, path, folder)
    read_protocol_record(path)
    return path


#: The settings a resumed run may widen: a side on a seed is a task of its own, scored on the same episodes.
WIDENED = ("seeds", "methods", "peers")


def _continues_run(kept: object, settings: ProtocolSettings) -> bool:
    """
    Whether ``settings`` go on with a saved ``protocol.json``: the same settings, but for seeds and sides
    (:data:`WIDENED`) it may lack (``of_record`` is derived, so not compared).
    """
    current = settings.to_json()
    keys = set(current) - {"of_record"}
    if not isinstance(kept, dict) or set(kept) - {"of_record"} != keys:
        return False
    now: dict[str, list[object]] = {
        "seeds": list(settings.seeds),
        "methods": list(settings.methods),
        "peers": list(settings.peers or ()),
    }
    widened = all(isinstance(kept[k], list) and all(v in now[k] for v in kept[k]) for k in WIDENED)
    return widened and all(kept[k] == current[k] for k in keys - set(WIDENED))


def _check_continues(out: Path, settings: ProtocolSettings) -> None:
    """Refuse (``ValueError``) a folder whose ``protocol.json`` ``settings`` do not go on with."""
    saved = out / "protocol.json"
    if not _continues_run(read_json_record(saved, f"{saved}: not readable"), settings):
        raise ValueError(
            f"{out}: holds a protocol run of other settings (a resumed run may only add seeds and sides to its "
            "own); choose another --out"
        )


def _task_setup(level: int, threads: int) -> None:
    """
    A spawned task's process as its parent: its log lines reach the terminal, and torch has the parent's
    threads (the CLI's one), so that a seed plays the same episodes whether its task runs here or there.
    """
    import torch

    logging.basicConfig(level=level, format="%(message)s")
    torch.set_num_threads(threads)


def _run_in_parallel(
    settings: ProtocolSettings,
    tasks: list[tuple[str, int]],
    out: Path,
    n_jobs: int,
    task: Callable[[ProtocolSettings, str, int, Path], Path] = _run_task,
) -> None:
    """
    ``tasks`` at most ``n_jobs`` at a time, each in its own spawned process (a JAX backend and torch's thread
    pools are not fork-safe). Only as many are handed to the pool as it runs, so that nothing is queued behind
    a failure or an interrupt: after a failure the running tasks finish (their records are kept) and no new
    one starts; then every failure is logged and the first raised.

    :param task: what a process runs for a side on a seed (a module-level function: spawned processes
        import it by name).
    """
    import torch

    pending = list(tasks)
    running: set[Future[Path]] = set()
    failures: list[BaseException] = []
    context = multiprocessing.get_context("spawn")
    setup = (logging.getLogger().level, torch.get_num_threads())
    with ProcessPoolExecutor(n_jobs, mp_context=context, initializer=_task_setup, initargs=setup) as pool:
        try:
            while pending or running:
                while pending and not failures and len(running) < n_jobs:
                    side, seed = pending.pop(0)
                    running.add(pool.submit(task, settings, side, seed, out))
                if not running:
                    break
                done, running = wait(running, return_when=FIRST_COMPLETED)
                failures += [error for f in done if (error := f.exception()) is not None]
        except BaseException:
            # Ctrl-C reaches the tasks too (one process group); nothing new starts.
            pool.shutdown(wait=False, cancel_futures=True)
            raise
    for failure in failures[1:]:
        logger.error("protocol: another task failed: %s", failure)
    if failures:
        raise failures[0]


def run_protocol(settings: ProtocolSettings, out: str | Path, n_jobs: int = 1) -> list[Path]:
    """
    Every side of ``settings`` on every seed, each record written when its task ends; a record already there
    (a resumed run) is read, not run again.

    :param n_jobs: tasks (a side on a seed) at a time, each in its own process; they share nothing but
        ``out``, where each writes only its own record and folder.
    :raises ValueError: ``out`` holds a run of other settings (nothing of it is touched).
    :return: the records, in task order.
    """
    out = Path(out)
    saved = out / "protocol.json"
    if saved.exists():
        _check_continues(out, settings)
    else:
        out.mkdir(parents=True, exist_ok=True)
    # Written again on resume: a run begun before of_record's rule changed gets today's verdict.
    atomic_write_json(saved, settings.to_json())
    tasks = [(side, seed) for seed in settings.seeds for side in (*settings.methods, *(settings.peers or ()))]
    if n_jobs <= 1:
        return [_run_task(settings, side, seed, out) for side, seed in tasks]
    _run_in_parallel(settings, tasks, out, n_jobs)
    return [_run_task(settings, side, seed, out) for side, seed in tasks]  # each reads its record


#: The most records a shipped run may hold for ``--resume`` to take it (a side on a seed each).
MAX_SHIPPED_RECORDS = 10_000


def _plain_entries(folder: Path) -> list[os.DirEntry[str]]:
    """A folder's entries, refused past :data:`MAX_SHIPPED_RECORDS` (its size bounds the walk's time)."""
    with os.scandir(folder) as found:
        entries = list(itertools.islice(found, MAX_SHIPPED_RECORDS + 1))
    if len(entries) > MAX_SHIPPED_RECORDS:
        raise ValueError(f"{folder}: more than {MAX_SHIPPED_RECORDS} entries; not a protocol run's records")
    return entries


def shipped_run(out: Path, settings: ProtocolSettings) -> bool:
    """
    Whether ``out`` holds nothing but a protocol run's records as shipped (``protocol.json`` and
    ``records/<side>/seed-<n>.json``, no run marker: e.g. ``docs/results/morl-dev/<run>`` on another
    machine) that ``settings`` go on with, so that ``--resume`` may take it as its own run folder. Every
    entry is a plain file or folder (a link could lead a record's write out of ``out``), every record
    reads and sits at its own path.

    :return: ``False`` when ``out`` has other entries (it is not such a folder).
    :raises ValueError: it is such a folder, but a record does not read, or ``settings`` change more
        than its seeds and sides.
    """
    top = {e.name: e for e in _plain_entries(out)}
    if set(top) != {"protocol.json", "records"} or any(e.is_symlink() for e in top.values()):
        return False
    if not (top["protocol.json"].is_file() and top["records"].is_dir()):
        return False
    files = []
    for side in _plain_entries(out / "records"):
        if side.is_symlink() or not side.is_dir():
            return False
        files += _plain_entries(Path(side.path))
        if len(files) > MAX_SHIPPED_RECORDS:
            raise ValueError(f"{out}: more than {MAX_SHIPPED_RECORDS} records; not a protocol run's")
    if any(e.is_symlink() or not e.is_file() or not e.name.endswith(".json") for e in files):
        return False
    _check_continues(out, settings)
    for entry in files:
        record = read_protocol_record(Path(entry.path))
        if Path(entry.path) != record_path(out, record.method, record.seed):
            raise ValueError(f"{entry.path}: holds {record.method}'s seed {record.seed}, not its path's")
    return True


def hierarchy_peer_pairs(records: Mapping[str, Mapping[int, ProtocolRecord]]) -> list[tuple[str, str]]:
    """Every (hierarchy method, peer) pair of a run's sides, in the records' order."""
    sides = {method: next(iter(by.values())).side for method, by in records.items()}
    hierarchy = [m for m, side in sides.items() if side == "hierarchy"]
    return [(method, peer) for method in hierarchy for peer in sides if sides[peer] == "peer"]


def read_protocol_run(out: Path) -> tuple[dict[str, Any], dict[str, dict[int, ProtocolRecord]]]:
    """A protocol run's settings and its records: side -> seed -> record."""
    settings = read_json_record(out / "protocol.json", f"{out / 'protocol.json'}: not readable")
    if not isinstance(settings, dict) or settings.get("protocol") != "morl-baselines":
        raise ValueError(f"{out / 'protocol.json'}: not a protocol run's settings")
    records: dict[str, dict[int, ProtocolRecord]] = {}
    for path in sorted((out / "records").glob("*/seed-*.json")):
        record = read_protocol_record(path)
        records.setdefault(record.method, {})[record.seed] = record
    return settings, records


__all__ = [
    "INDICATORS",
    "KNOWN_FRONT_INDICATORS",
    "MAX_SHIPPED_RECORDS",
    "PROTOCOL_RUNNER",
    "WIDENED",
    "ProtocolRecord",
    "hierarchy_peer_pairs",
    "protocol_weights",
    "read_protocol_record",
    "read_protocol_run",
    "record_path",
    "run_method",
    "run_peer",
    "run_protocol",
    "shipped_run",
]
