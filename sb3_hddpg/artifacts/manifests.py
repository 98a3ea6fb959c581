"""The manifests beside trained models: an entry built, written under a lock, the workers listed loaded."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Protocol

from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_hddpg.artifacts.io import atomic_write_json, locked_file
from sb3_hddpg.artifacts.limits import brief, check_count, read_json_file
from sb3_hddpg.artifacts.provenance import library_versions, read_verified, sha256_file
from sb3_hddpg.artifacts.records import JsonValue, ModelEntry, ModelsManifest, read_workers_manifest
from sb3_hddpg.artifacts.safe_load import load_model
from sb3_hddpg.artifacts.spec import model_spec
from sb3_hddpg.artifacts.term_critic import TermCritic, read_term_critic
from sb3_hddpg.artifacts.workers import Workers, observed_components, shared_env_of
from sb3_hddpg.envs.ids import WORKER_ENV_IDS


def save_manifest(path: str | Path, manifest: ModelsManifest | Mapping[str, object]) -> Path:
    """
    Write a manifest atomically, read-modify-write under a lock: the entries (``workers`` or ``models``)
    already in the file are kept unless ``manifest`` replaces them.

    :param path: the manifest file.
    :param manifest: the new content; its entries win over the file's.
    """
    path = Path(path)
    merged = manifest.to_json() if isinstance(manifest, ModelsManifest) else dict(manifest)
    with locked_file(path):
        try:
            current = read_json_file(path) if path.is_file() else {}
        except ValueError:  # damaged or not JSON: the new content replaces it
            current = {}
        if isinstance(current, dict):
            for key in ("workers", "models"):
                if isinstance(current.get(key), dict) and isinstance(merged.get(key), dict):
                    merged[key] = {**current[key], **merged[key]}
        if isinstance(merged.get("workers"), dict):
            # One order whichever worker finished first: the manager's action order follows it.
            entries = merged["workers"]
            known = [n for n in WORKER_ENV_IDS if n in entries]
            merged["workers"] = {n: entries[n] for n in known + sorted(set(entries) - set(known))}
        return atomic_write_json(path, merged)


def load_workers(
    workers_dir: str | Path,
    names: Sequence[str] | None = None,
    trusted: bool = False,
    allowed_env_ids: Sequence[str] | None = None,
) -> Workers:
    """
    Load workers written by ``train_workers``, verifying each zip's sha256 against the manifest.

    Each worker comes with the state components it was trained on, and the record with the shared env
    they were trained for, so that ``WorkerSelectionWrapper(workers.make_env(), workers)`` needs nothing
    more::

        workers = load_workers("runs/quickstart/workers")
        env = WorkerSelectionWrapper(workers.make_env(), workers)

    :param workers_dir: a run folder (containing ``workers/manifest.json``) or the ``workers`` folder itself.
    :param names: which workers, in order (default: all, in manifest order).
    :param trusted: use SB3's full loader instead of the weights-only rebuild (only for files you trust),
        and accept any registered env id as the shared env.
    :param allowed_env_ids: registered env ids the manifest's shared env may be besides this package's own
        (a user's env; otherwise ``make_env()`` says how to allow it, and the models load all the same).
    :return: name -> SB3 model, a :class:`~sb3_hddpg.artifacts.workers.Workers` mapping that also holds
        each worker's observed components, the shared env, the manifest and per-term critics.
    """
    folder = Path(workers_dir)
    if not folder.exists():
        raise FileNotFoundError(f"No such folder: {str(workers_dir)!r}")
    if not folder.is_dir():
        raise NotADirectoryError(
            f"Expected a folder of workers (from train-workers), got a file: {str(workers_dir)!r}"
        )
    if (folder / "workers" / "manifest.json").exists():
        folder = folder / "workers"
    manifest_path = folder / "manifest.json"
    if not manifest_path.exists():
        raise FileNotFoundError(
            f"No workers manifest in {str(workers_dir)!r} (expected {manifest_path}); run train-workers first"
        )
    manifest = read_workers_manifest(manifest_path)
    entries = manifest.entries
    names = list(names) if names else list(entries)
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise ValueError(f"Duplicate worker names {duplicates} in {names}: name each worker once")
    unknown = [n for n in names if n not in entries]
    if unknown:
        raise ValueError(f"Unknown workers {unknown} in {str(manifest_path)!r}; it has {list(entries)}")
    # The count is checked before any model is read: a manifest of 400 entries costs nothing.
    check_count("manifest_entries", len(names), f"{str(manifest_path)!r}: workers listed")
    models = {}
    critics: dict[str, TermCritic] = {}
    for name in names:
        entry = entries[name]
        if Path(entry["file"]).name != entry["file"]:
            # A manifest travels with shared files: it may only name files in its own folder.
            raise ValueError(
                f"{str(manifest_path)!r}: worker {name!r} names a file outside its folder: {entry['file']!r}"
            )
        path = folder / entry["file"]
        if not path.is_file():
            raise FileNotFoundError(f"Worker file missing: {str(path)!r}")
        verified = read_verified(path, entry["sha256"])
        models[name] = load_model(verified, spec=entry.get("spec"), trusted=trusted)
        critic = read_term_critic(verified.getvalue(), str(path))
        if critic is not None:
            critics[name] = critic
    states = observed_components(manifest, names)
    try:
        env_id, env_kwargs = shared_env_of(manifest, None, None, trusted, allowed_env_ids)
    except ValueError as error:  # an env outside the allow-list: the caller may name the env itself
        return Workers(models, states, None, {}, manifest, folder, env_problem=str(error), critics=critics)
    return Workers(models, states, env_id, env_kwargs, manifest, folder, critics=critics)


class TrainedModel(Protocol):
    """What :func:`model_entry` reads of a training outcome (``training.TrainingOutcome``)."""

    @property
    def model(self) -> BaseAlgorithm: ...
    @property
    def model_path(self) -> Path: ...
    @property
    def num_timesteps(self) -> int: ...
    @property
    def backend(self) -> str: ...
    @property
    def metrics(self) -> Mapping[str, object]: ...


def model_entry(
    name: str,
    outcome: TrainedModel,
    algo: str,
    env_id: str,
    env_kwargs: Mapping[str, object],
    config: Mapping[str, object],
    seed: int,
    timesteps_requested: int,
    **facts: object,
) -> ModelEntry:
    """
    A trained model's manifest entry: the one builder for workers, flat baselines and the quickstart's agents.

    :param name: the entry's name; the model file is ``NAME.zip`` beside the manifest.
    :param outcome: the training outcome.
    :param algo: the algorithm name.
    :param env_id: the env the model was trained on.
    :param env_kwargs: its keyword arguments.
    :param config: ``{"file": ..., "block": ...}``: the config the model was trained with.
    :param seed: the training seed.
    :param timesteps_requested: the budget asked for.
    :param facts: more facts for this kind of model (reward term and bounds, preferences, threads...).
    :return: the entry, with the file's sha256, the library versions and the model's rebuild spec.
    """
    return ModelEntry(
        name=name,
        sha256=sha256_file(outcome.model_path),
        algo=algo,
        env_id=env_id,
        env_kwargs=env_kwargs,
        config=config,
        seed=seed,
        timesteps_requested=timesteps_requested,
        timesteps_trained=outcome.num_timesteps,
        backend=outcome.backend,
        versions=library_versions(),
        metrics=outcome.metrics,
        spec=model_spec(outcome.model),
        facts=facts,
    )


class ResumeMismatch(ValueError):
    """A resumed run asked for an env or term setting other than the one its saved agents were trained with."""


def check_resumed_env(
    stored: object, env_id: str, env_kwargs: Mapping[str, object], what: str = "--resume"
) -> None:
    """
    The one comparison of a run's recorded env settings with the ones a resumed command asks for: the env
    id and every env keyword argument must be the same, else agents of two envs would share one manifest.

    :param stored: the recorded ``{"env_id": ..., "env_kwargs": ...}`` (a manifest's ``shared_env`` or a
        model entry); ``None``: nothing recorded, nothing to compare.
    :param env_id: the env id asked for now.
    :param env_kwargs: its keyword arguments.
    :param what: the option named in the message.
    :raises ResumeMismatch: one line naming the first differences.
    """
    if not isinstance(stored, dict):
        return
    differences = []
    if stored.get("env_id") != env_id:
        differences.append(f"env was {brief(stored.get('env_id'))} in the run, now {env_id!r}")
    differences += _changes(as_json(stored.get("env_kwargs") or {}), as_json(env_kwargs))
    if differences:
        more = f" (and {len(differences) - 2} more)" if len(differences) > 2 else ""
        raise ResumeMismatch(
            f"{what}: {'; '.join(differences[:2])}{more}; resume with the run's settings, or start a new run"
        )


#: What a resumed agent may be asked to change on purpose (``resume_changes``, ``--resume-changing``).
RESUME_CHANGES = ("algo", "seed", "config")


def check_resumed_agent(
    stored: object,
    name: str,
    algo: str,
    seed: int,
    block: Mapping[str, object],
    what: str = "--resume",
    accept: Sequence[str] = (),
) -> None:
    """
    The one comparison of what an agent of a run was trained with and what a resumed command asks for: its
    algorithm (``--algo``), seed (``--seed``) and config block (``--config``) must be the ones recorded.

    :param stored: the agent's manifest entry (anything but a mapping: nothing recorded, nothing to compare).
    :param name: the agent, for the message.
    :param algo: the algorithm asked for now.
    :param seed: the seed asked for now.
    :param block: the config block asked for now (as read, before defaults).
    :param what: the option named in the message.
    :param accept: which of :data:`RESUME_CHANGES` the user asked to change on purpose (not compared).
    :raises ResumeMismatch: one line naming the option and both values.
    """
    unknown = sorted(set(accept) - set(RESUME_CHANGES))
    if unknown:
        raise ValueError(f"--resume-changing: expected some of {list(RESUME_CHANGES)}, got {brief(unknown)}")
    if not isinstance(stored, Mapping):
        return
    accepting = " (or accept the change with --resume-changing {}), or start a new run"
    if "algo" not in accept and "algo" in stored and stored["algo"] != algo:
        raise ResumeMismatch(
            f"{what}: --algo of {name!r} was {brief(stored['algo'])} in the run, now {algo!r}; resume with "
            f"--algo {name}={brief(stored['algo'])}" + accepting.format("algo")
        )
    if "seed" not in accept and "seed" in stored and stored["seed"] != seed:
        raise ResumeMismatch(
            f"{what}: --seed was {brief(stored['seed'])} in the run ({name!r}), now {seed!r}; resume with "
            f"--seed {brief(stored['seed'])}" + accepting.format("seed")
        )
    config = stored.get("config")
    before = config.get("block") if isinstance(config, Mapping) else None
    now = as_json(dict(block))
    if "config" not in accept and before is not None and as_json(before) != now:
        shown = next(iter(_changes(as_json(before), now)), "the block differs")
        raise ResumeMismatch(
            f"{what}: --config block of {name!r}: {shown}; resume with the run's config"
            + accepting.format("config")
        )


def _changes(before: JsonValue, now: JsonValue) -> list[str]:
    """``KEY was X in the run, now Y`` for each key whose value differs between two JSON objects."""
    if not isinstance(before, dict) or not isinstance(now, dict):
        return []
    keys = sorted(set(before) | set(now))
    return [
        f"{k[:64]} was {brief(before.get(k))} in the run, now {brief(now.get(k))}"
        for k in keys
        if before.get(k) != now.get(k)
    ]


def as_json(value: object) -> JsonValue:
    """``value`` as JSON would store it (tuples become lists), so that a recorded and a new setting compare equal."""
    return json.loads(json.dumps(value, default=str))
