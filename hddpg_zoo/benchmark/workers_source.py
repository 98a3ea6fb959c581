"""
A benchmark's workers taken from another benchmark (``workers_from``): checked to be the workers this one
would train (same config blocks, budget, backend, seed and evaluation schedule) before anything runs, and
copied seed by seed with their hashes checked; a front's flat baselines taken from the same benchmark
(:func:`copy_flat_runs`), where they were scored on the same test episodes.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hddpg_zoo.benchmark.benchmark_file import (
    read_benchmark_file,
)
from hddpg_zoo.benchmark.machine_paths import relative_to_run
from hddpg_zoo.benchmark.methods import (
    METHOD_REGISTRY,
    WORKERS,
)
from hddpg_zoo.benchmark.record_files import COPIED_FROM, as_stored, read_record, record_path, seed_dir
from hddpg_zoo.benchmark.settings import BenchmarkSettings
from hddpg_zoo.benchmark.tasks import Task
from sb3_hddpg.artifacts.io import atomic_write_bytes, atomic_write_json
from sb3_hddpg.artifacts.limits import read_json_file
from sb3_hddpg.artifacts.manifests import read_workers_manifest, save_manifest
from sb3_hddpg.artifacts.provenance import read_verified
from sb3_hddpg.envs import REWARD_TERMS
from sb3_hddpg.training.workers import worker_hyperparams


def worker_names(settings: BenchmarkSettings) -> list[str]:
    """The workers a seed trains: one per reward term of the env."""
    return list(settings.terms_env.terms) if settings.terms_env is not None else list(REWARD_TERMS)


def check_workers_source(settings: BenchmarkSettings) -> None:
    """
    Check that ``settings.workers_from`` holds, for every seed, the workers this benchmark would train: a
    finished workers record, a manifest whose every worker was trained from the same config block, with the
    same budget, backend and seed, and its learning curve on the same evaluation schedule (which picked
    the checkpoint kept). Then copying them changes nothing but the time
    (on the CPU a seed's training is deterministic), and a mismatch is refused before anything runs.

    :param settings: the benchmark's settings (nothing to check when ``workers_from`` is ``None``).
    :raises ValueError: naming the folder, the seed and what differs (``FileNotFoundError`` when the
        folder is not a benchmark folder).
    """
    if settings.workers_from is None:
        return
    source = Path(settings.workers_from)
    stored = source / "benchmark.json"
    if not stored.is_file():
        raise FileNotFoundError(f"not a benchmark folder (no benchmark.json): {str(source)!r}")
    theirs = read_benchmark_file(stored)["settings"]
    for key in ("backend", "env", "worker_timesteps", "worker_algo"):
        if theirs.get(key, getattr(BenchmarkSettings, key, None)) != getattr(settings, key):
            raise ValueError(
                f"The workers in {str(source)!r} were trained with {key}={theirs.get(key)!r}, this benchmark "
                f"uses {getattr(settings, key)!r}: train them here instead (without --workers-from)"
            )
    names = worker_names(settings)
    blocks = worker_hyperparams(names, None, settings.terms_env, settings.worker_algos)
    for seed in settings.seeds:
        folder = seed_dir(source, seed)
        manifest_path = folder / "workers" / "manifest.json"
        if read_record(source, Task(WORKERS, seed)) is None or not manifest_path.is_file():
            raise ValueError(f"{str(source)!r} has no finished workers for seed {seed}")
        entries = read_workers_manifest(manifest_path).entries
        for name in names:
            block = blocks[name]
            budget = settings.worker_timesteps or int(block.n_timesteps)
            entry = entries.get(name)
            entry = entry if isinstance(entry, dict) else {}
            config = entry.get("config")
            expected = {
                "config block": as_stored(block.raw),
                "timesteps_requested": budget,
                "backend": settings.backend,
                "seed": seed,
            }
            actual = {
                "config block": as_stored(config.get("block")) if isinstance(config, dict) else None,
                **{key: entry.get(key) for key in ("timesteps_requested", "backend", "seed")},
            }
            differ = [key for key in expected if actual[key] != expected[key]]
            if differ:
                raise ValueError(
                    f"{str(manifest_path)!r}: worker {name!r} was not trained as this benchmark trains it "
                    f"({', '.join(differ)} differ): train them here instead (without --workers-from)"
                )
            _check_worker_curve(folder / "evaluations" / f"{name}.json", settings, name, seed)


def _check_worker_curve(path: Path, settings: BenchmarkSettings, name: str, seed: int) -> None:
    """
    A reused worker's learning curve must come from this benchmark's evaluation schedule: a worker is its
    best checkpoint on that curve, so other evaluation steps or episodes would have picked another one.
    """
    if not path.is_file():
        raise ValueError(f"{str(path)!r}: worker {name!r} of seed {seed} has no learning curve")
    curve = read_json_file(path)
    every = settings.eval_freq_for(settings.worker_timesteps or settings.workers_budget)
    points = curve if isinstance(curve, list) else []
    first = (
        (points[0].get("timesteps"), points[0].get("episodes"))
        if points and isinstance(points[0], dict)
        else None
    )
    if first != (every, settings.eval_episodes):
        shown = f"every {first[0]} steps on {first[1]} episodes" if first else "without a readable curve"
        raise ValueError(
            f"{str(path)!r}: worker {name!r} was evaluated {shown}, this benchmark evaluates every {every} "
            f"on {settings.eval_episodes}: its best checkpoint would differ; train the workers here instead"
        )


def copy_workers(source: Path, folder: Path) -> None:
    """
    Copy a seed's workers (zips checked against their sha256, learning curves) from another benchmark's
    seed folder, the manifest last: until it is written, the copy does not count as finished.
    """
    manifest = read_workers_manifest(source / "workers" / "manifest.json")
    for name, entry in manifest.entries.items():
        path = source / "workers" / entry["file"]
        data = read_verified(path, entry["sha256"]).getvalue()
        atomic_write_bytes(folder / "workers" / entry["file"], data)
        history = source / "evaluations" / f"{name}.json"
        atomic_write_json(folder / "evaluations" / f"{name}.json", read_json_file(history))
    save_manifest(folder / "workers" / "manifest.json", manifest)


def flat_baselines() -> list[str]:
    """The methods that learn alone, without the seed's workers: the flat agents a front can be set beside."""
    return [name for name, method in METHOD_REGISTRY.items() if method.baseline and not method.needs_workers]


def copy_flat_runs(settings: BenchmarkSettings, out: Path) -> list[dict[str, Any]]:
    """
    The flat baselines of a front's workers' benchmark, beside the front: a front scenario trains no flat
    agent, yet its equal-weighting point answers the question "as good as one agent trained on the summed
    reward?". Where ``settings.workers_from`` holds finished flat runs of this benchmark's seeds, scored on
    this benchmark's test episodes (the same seeds, so pairs by seed hold), their records are copied to
    ``out``'s ``records/`` (each naming its source) and returned; others are left out, not rescored.

    :param settings: the benchmark's settings (nothing is copied unless it is a front with ``workers_from``).
    :param out: the benchmark folder.
    :return: the copied records.
    """
    if settings.workers_from is None or settings.scenario != "front":
        return []
    source = Path(settings.workers_from)
    copied = []
    for method in flat_baselines():
        for seed in settings.seeds:
            task = Task(method, seed)
            record = read_record(source, task)
            if record is None or record.get("test_episode_set") != settings.test_episode_set:
                continue
            if not record.get("episodes"):  # its episodes are in the source's episodes.csv: not copied
                continue
            record[COPIED_FROM] = relative_to_run(str(record_path(source, task).absolute()), out)
            atomic_write_json(record_path(out, task), record)
            copied.append(record)
    return copied
