"""
``package_policy``: a folder laid out like ``huggingface_sb3.package_to_hub``'s, made offline (no upload).

For an SB3 model (a worker or the flat baseline)::

    DIR/
      ddpg-hddpg-SnakeGoal-v0.zip     the model, named <algo>-<env id with / as ->, as package_to_hub names it
      ddpg-hddpg-SnakeGoal-v0/        the same zip unpacked (package_to_hub does this too)
      manifest.json                   sb3-hddpg's entry (sha256, rebuild spec): loads without unpickling
      config.json                     the model's "data" JSON from the zip (package_to_hub's config.json)
      results.json                    mean_reward, std_reward, is_deterministic, n_eval_episodes, eval_datetime
      replay.mp4                      the policy at work
      README.md                       model card: YAML metadata (library_name, tags, model-index) and usage

For a hierarchy bundle, the bundle itself (``hierarchy.zip``) and its ``manifest.json`` take the model's
place, and ``config.json`` holds the selection settings and every member's SB3 data.
"""

from __future__ import annotations

import io
import os
import re
import shutil
import tempfile
import zipfile
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import yaml

from hddpg_zoo.media.video import record_video
from sb3_hddpg import __version__ as version
from sb3_hddpg.artifacts.io import UMASK, atomic_write_bytes, atomic_write_json
from sb3_hddpg.artifacts.limits import (
    MAX_JSON_BYTES,
    MAX_MODEL_FILE_BYTES,
    LoadBudget,
    brief,
    check_count,
    check_name,
    check_run_file,
    check_zip_directory,
    parse_json,
    read_file_bytes,
    read_member,
)
from sb3_hddpg.artifacts.records import ManifestKind, models_manifest
from sb3_hddpg.artifacts.run_folder import (
    RunFolderError,
    check_clearable,
    check_out_folder,
    clear_run_folder,
    mark_run_folder,
    protected_reason,
)
from sb3_hddpg.evaluation import EVAL_SEED_BASE, evaluate
from sb3_hddpg.hierarchy.bundle import read_bundle
from sb3_hddpg.hierarchy.loading import LoadedPolicy
from sb3_hddpg.metric_labels import summary_rows

#: The keys of ``results.json``: huggingface_sb3's five, then ours.
RESULTS_KEYS = (
    "mean_reward",
    "std_reward",
    "is_deterministic",
    "n_eval_episodes",
    "eval_datetime",
    "env_id",
    "eval_seeds",
    "metrics",
)


@dataclass
class PackageResult:
    """
    What :func:`package_policy` wrote.

    :param folder: the package folder.
    :param model_file: the model zip or bundle inside it.
    :param results: the content of ``results.json``.
    """

    folder: Path
    model_file: Path
    results: dict[str, Any]


def hub_env_name(env_id: str) -> str:
    """An env id as huggingface_sb3 and RL Zoo put it in file names: ``/`` becomes ``-``."""
    return env_id.replace("/", "-")


def package_policy(
    loaded: LoadedPolicy,
    source: str | Path,
    out_dir: str | Path,
    n_eval_episodes: int = 10,
    seed: int = EVAL_SEED_BASE,
    deterministic: bool = True,
    video_steps: int | None = None,
    force: bool = False,
) -> PackageResult:
    """
    Evaluate, record and lay out a policy for sharing, like ``huggingface_sb3.package_to_hub`` but offline.
    The folder is built beside ``out_dir`` and renamed into place, so it appears whole or not at all.

    :param loaded: the policy, from :func:`~sb3_hddpg.hierarchy.loading.load_policy`.
    :param source: the file it was loaded from (copied into the package).
    :param out_dir: the package folder; must not exist (or be empty) unless ``force``.
    :param n_eval_episodes: evaluation episodes for ``results.json`` and the model card.
    :param seed: the first evaluation episode's seed.
    :param deterministic: deterministic actions in evaluation and replay.
    :param video_steps: the length of ``replay.mp4`` in steps, one episode cut short (default: one full
        episode; huggingface_sb3's ``video_length``).
    :param force: replace an existing folder.
    :return: the folder, the model file and the results.
    """

    if loaded.kind not in ("worker", "flat", "hierarchy"):
        raise ValueError(
            f"Expected an SB3 model zip or a hierarchy bundle to package, actually a {loaded.kind!r} "
            f"({str(source)!r})"
        )
    check_count("episodes", n_eval_episodes, "n_eval_episodes")
    if video_steps is not None:
        check_count("video_steps", video_steps, "video_steps")
    source = Path(source)
    if source.is_dir():
        source = source / "hierarchy.zip"
    out_dir = check_package_folder(out_dir, force)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
    # mkdtemp makes the folder private (0700); the package is meant to be shared: give it the permissions
    # any other new folder gets (as atomic_write does for files).
    os.chmod(staging, 0o777 & ~UMASK)
    try:
        results = _evaluation_results(loaded, n_eval_episodes, seed, deterministic)
        if loaded.kind == "hierarchy":
            model_file, config = _lay_out_bundle(source, staging)
            algo_name = "HDDPG"
        else:
            model_file, config = _lay_out_model(loaded, source, staging)
            algo_name = str(loaded.meta.get("algo", "ddpg")).upper()
        atomic_write_json(staging / "config.json", config)
        atomic_write_json(staging / "results.json", results)
        _record_replay(loaded, staging / "replay.mp4", video_steps, seed, deterministic)
        card = model_card(loaded, algo_name, model_file.name, results)
        atomic_write_bytes(staging / "README.md", card.encode())
        _move_into_place(staging, out_dir)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return PackageResult(out_dir, out_dir / model_file.name, results)


def _evaluation_results(
    loaded: LoadedPolicy, n_eval_episodes: int, seed: int, deterministic: bool
) -> dict[str, Any]:
    """The package's ``results.json``: the policy evaluated on its own env, in huggingface_sb3's keys."""
    env = loaded.make_env()
    try:
        evaluation = evaluate(
            loaded.policy, env, n_episodes=n_eval_episodes, seed=seed, deterministic=deterministic
        )
    finally:
        env.close()
    summary = evaluation.summary()
    return {
        "mean_reward": summary["mean_reward"],
        "std_reward": summary["std_reward"],
        "is_deterministic": deterministic,
        "n_eval_episodes": n_eval_episodes,
        "eval_datetime": datetime.now(timezone.utc).isoformat(),
        "env_id": loaded.env_id,
        "eval_seeds": list(range(seed, seed + n_eval_episodes)),
        "metrics": summary,
    }


def _record_replay(
    loaded: LoadedPolicy, path: Path, video_steps: int | None, seed: int, deterministic: bool
) -> None:
    """The package's ``replay.mp4``: one episode, cut to ``video_steps`` when given."""
    env_kwargs: dict[str, Any] = {"render_mode": "rgb_array"}
    if video_steps:
        env_kwargs["max_episode_steps"] = video_steps
    replay_env = loaded.make_env(**env_kwargs)
    try:
        record_video(
            loaded.policy,
            replay_env,
            path,
            episodes=1,
            seed=seed,
            deterministic=deterministic,
            title=loaded.name,
        )
    finally:
        replay_env.close()


def check_package_folder(out_dir: str | Path, force: bool) -> Path:
    """
    Refuse a package folder that cannot be (re)placed, before any work: the current folder, one above it,
    the home or root folder, a file, and a folder that is not empty unless ``force``, and then only a package
    or run folder of this tool that no live run holds
    (:func:`~sb3_hddpg.artifacts.run_folder.check_clearable`).

    :param out_dir: the package folder.
    :param force: whether the tool's own files there may be replaced.
    :return: the folder; raises :class:`~sb3_hddpg.artifacts.run_folder.RunFolderError` otherwise.
    """
    out_dir = Path(out_dir)
    reason = "the current folder" if str(out_dir) in ("", ".") else protected_reason(out_dir)
    if reason is not None:
        raise RunFolderError(f"Expected a folder for the package, actually {str(out_dir)!r} ({reason})")
    if out_dir.is_symlink():
        check_out_folder(out_dir)  # the one refusal of a symbolic link, naming where it leads
    if out_dir.exists() and not out_dir.is_dir():
        raise RunFolderError(f"Expected a folder for the package, actually a file: {str(out_dir)!r}")
    if out_dir.exists() and any(out_dir.iterdir()):
        if not force:
            raise RunFolderError(f"{str(out_dir)!r} is not empty; pass force=True (--force) to replace it")
        check_clearable(out_dir)
    return out_dir


def _move_into_place(staging: Path, out_dir: Path) -> None:
    """
    Put the finished package where it belongs: one rename into a new or empty folder; into an existing
    one (``force``) after :func:`~sb3_hddpg.artifacts.run_folder.clear_run_folder` removed the tool's own
    files, entry by entry, keeping the files the tool did not write.
    """
    mark_run_folder(staging, "package", entries=[entry.name for entry in staging.iterdir()])
    if out_dir.exists() and any(out_dir.iterdir()):
        clear_run_folder(out_dir)
        for entry in staging.iterdir():
            os.replace(entry, out_dir / entry.name)
        staging.rmdir()
        return
    os.replace(staging, out_dir)


#: The members an SB3 zip holds (``save_util.save_to_zip_file``): the only ones a package unpacks.
SB3_MEMBERS = (
    "data",
    "policy.pth",
    "pytorch_variables.pth",
    "policy.optimizer.pth",
    "actor.optimizer.pth",
    "critic.optimizer.pth",
    "ent_coef_optimizer.pth",
    "_stable_baselines3_version",
    "system_info.txt",
)
#: A package's file and folder names: built from checked names, checked again before use.
_PACKAGE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}-[A-Za-z0-9_.-]{1,129}$")


def _zip_data(data: bytes | Path) -> dict[str, Any]:
    """The ``data`` JSON of an SB3 zip (what package_to_hub writes as config.json), read within limits."""
    what = "<bundle member>" if isinstance(data, bytes) else str(data)
    with zipfile.ZipFile(io.BytesIO(data) if isinstance(data, bytes) else data) as archive:
        check_zip_directory(archive, what)
        return parse_json(read_member(archive, "data", what, limit=MAX_JSON_BYTES), f"{what}: data")


def _unpack_model(model_file: Path, folder: Path) -> None:
    """
    Unpack the SB3 members of ``model_file`` into ``folder`` (what package_to_hub does), never
    ``extractall``: only the names in :data:`SB3_MEMBERS`, each read within the size limits, so a member
    named ``../x`` or a zip bomb cannot write outside the package or fill the disk.
    """
    budget = LoadBudget()
    folder.mkdir()
    check_run_file(model_file)
    with zipfile.ZipFile(model_file) as archive:
        present = {info.filename for info in check_zip_directory(archive, str(model_file))}
        for member in SB3_MEMBERS:
            if member in present:
                data = read_member(archive, member, str(model_file), budget=budget)
                (folder / member).write_bytes(data)


def _lay_out_model(loaded: LoadedPolicy, source: Path, staging: Path) -> tuple[Path, dict[str, Any]]:
    algo = check_name(loaded.meta.get("algo", "ddpg"), "manifest entry algo")
    name = f"{algo}-{hub_env_name(loaded.env_id)}"
    if not _PACKAGE_NAME.match(name) or ".." in name:
        raise ValueError(f"Cannot name a package {brief(name)}: not a plain file name")
    model_file = staging / f"{name}.zip"
    shutil.copyfile(source, model_file)
    _unpack_model(model_file, staging / name)
    if loaded.meta:
        # The manifest entry, renamed to the packaged file, keeps the safe (weights-only) loading path.
        kind: ManifestKind = "workers" if loaded.kind == "worker" else "models"
        entry = {**loaded.meta, "file": model_file.name}
        manifest = models_manifest(kind, {entry.get("name", name): entry})
        atomic_write_json(staging / "manifest.json", manifest.to_json())
    return model_file, _zip_data(model_file)


def _lay_out_bundle(source: Path, staging: Path) -> tuple[Path, dict[str, Any]]:
    manifest, members = read_bundle(source)
    model_file = staging / "hierarchy.zip"
    shutil.copyfile(source, model_file)
    atomic_write_json(staging / "manifest.json", manifest.to_json())
    config = {
        "kind": "sb3-hddpg-hierarchy",
        "env_id": manifest.env_id,
        "env_kwargs": manifest.env_kwargs,
        "worker_names": manifest.worker_names,
        "selection": manifest.selection,
        "manager": _zip_data(members[manifest.manager["file"]]) if manifest.manager is not None else None,
        "workers": {
            name: _zip_data(members[entry["file"]])
            for name, entry in manifest.workers.items()
            if entry.get("kind") != "hierarchy"
        },
    }
    return model_file, config


def model_card(loaded: LoadedPolicy, algo_name: str, model_file: str, results: dict[str, Any]) -> str:
    """
    A model card like huggingface_sb3's: YAML metadata (``library_name``, ``tags``, ``model-index`` with the
    mean reward) between ``---`` lines, then a description and how to use the files.

    :param loaded: the packaged policy.
    :param algo_name: e.g. ``DDPG`` or ``HDDPG``.
    :param model_file: the model file's name in the package.
    :param results: the content of ``results.json``.
    """
    env_id = loaded.env_id
    value = f"{results['mean_reward']:.2f} +/- {results['std_reward']:.2f}"
    metadata = _card_metadata(loaded, algo_name, value)
    what, python = _card_usage(loaded, algo_name, model_file)
    front = yaml.safe_dump(metadata, sort_keys=False)
    # Whatever the evaluation measured on this env (the snake's touch and collision rates, another env's
    # own terms), in the words and units every table uses.
    shown = {k: v for k, v in results["metrics"].items() if k not in ("mean_reward", "std_reward")}
    metric_rows = "\n".join(
        f"| {label} | {text}{' ' + unit if unit else ''} |" for label, text, unit in summary_rows(shown)
    )
    return f"""---
{front}---

# **{algo_name}** agent on **{env_id}**

This is {what}

| metric | value |
|---|---|
| mean reward | {value} |
{metric_rows}
| evaluation | {results["n_eval_episodes"]} episodes, seeds {results["eval_seeds"][0]}..{results["eval_seeds"][-1]}, deterministic={results["is_deterministic"]} |

## Usage

```bash
# sb3-hddpg {version} is not on the package index yet: install it from a checkout of its repository,
pip install ./sb3-hddpg                                  # (add extras: "./sb3-hddpg[render]")
# or from the wheel built there with `python -m build` (dist/sb3_hddpg-{version}-py3-none-any.whl):
pip install sb3_hddpg-{version}-py3-none-any.whl
hddpg-cli evaluate {model_file} --episodes 20
hddpg-cli record {model_file} --out replay.gif
```

```python
import sb3_hddpg  # registers {env_id}
{python}
```

Files: `{model_file}`, `manifest.json`, `config.json`, `results.json` (huggingface_sb3's keys), `replay.mp4`.
"""


def _card_metadata(loaded: LoadedPolicy, algo_name: str, value: str) -> dict[str, Any]:
    """A model card's YAML metadata, as huggingface_sb3 writes it: library, tags and the mean reward."""
    env_id = loaded.env_id
    tags = [env_id, "deep-reinforcement-learning", "reinforcement-learning", "stable-baselines3", "sb3-hddpg"]
    if loaded.kind == "hierarchy":
        tags.append("hierarchical-reinforcement-learning")
    return {
        "library_name": "stable-baselines3",
        "tags": tags,
        "model-index": [
            {
                "name": algo_name,
                "results": [
                    {
                        "task": {"type": "reinforcement-learning", "name": "reinforcement-learning"},
                        "dataset": {"name": env_id, "type": env_id},
                        "metrics": [
                            {"type": "mean_reward", "value": value, "name": "mean_reward", "verified": False}
                        ],
                    }
                ],
            }
        ],
    }


def _card_usage(loaded: LoadedPolicy, algo_name: str, model_file: str) -> tuple[str, str]:
    """A model card's description of the policy, and the Python that loads and runs it."""
    if loaded.kind == "hierarchy":
        names = list(getattr(loaded.policy, "names", []))
        what = (
            f"a **Hierarchical DDPG** (sb3-hddpg): a DDPG manager that picks, at every step, which of the "
            f"workers {names} acts. Every member is a plain Stable-Baselines3 DDPG; `{model_file}` holds them "
            "with a manifest of sha256 hashes (`manifest.json` is a copy)."
        )
        python = (
            "from sb3_hddpg.hierarchy.hierarchy import Hierarchy\n\n"
            f'policy = Hierarchy.load("{model_file}")  # verified; rebuilt without unpickling\n'
            "action, _ = policy.predict(obs, deterministic=True)"
        )
        return what, python
    what = f"a **{algo_name}** agent (a plain Stable-Baselines3 model) trained with sb3-hddpg."
    python = (
        "from sb3_hddpg.hierarchy.loading import load_policy\n\n"
        f'loaded = load_policy("{model_file}")  # checks manifest.json; loads weights only\n'
        "action, _ = loaded.policy.predict(obs, deterministic=True)\n\n"
        "# or, trusting the file, with SB3 itself:\n"
        f'# from stable_baselines3 import {algo_name}; model = {algo_name}.load("{model_file}")'
    )
    return what, python


def write_zoo_layout(
    models: dict[str, str | Path],
    folder: str | Path,
    algo: str = "ddpg",
    exp_id: int = 1,
    env_kwargs: dict[str, dict[str, Any]] | None = None,
) -> Path:
    """
    Copy SB3 model zips into RL Zoo's log layout, ``FOLDER/<algo>/<env name>_<exp_id>/<env name>.zip``, so
    that ``python -m rl_zoo3.enjoy --algo ddpg --env ENV_ID --gym-packages sb3_hddpg -f FOLDER --exp-id 1``
    finds them (see docs/RL_ZOO.md). One model per env id: that is how RL Zoo names its runs.

    :param models: env id -> model zip trained on it.
    :param folder: RL Zoo's ``-f`` folder.
    :param algo: the algorithm's RL Zoo name.
    :param exp_id: the experiment number in the folder name.
    :param env_kwargs: env id -> the keyword arguments its model was trained with (e.g. the goal worker's
        ``observe``), written where ``rl_zoo3.enjoy`` reads them (``<env name>/args.yml``).
    :return: ``folder``.
    """
    folder = Path(folder)
    for env_id, path in models.items():
        name = hub_env_name(env_id)
        data = read_file_bytes(path, MAX_MODEL_FILE_BYTES)
        run = folder / algo / f"{name}_{exp_id}"
        atomic_write_bytes(run / f"{name}.zip", data)
        kwargs = (env_kwargs or {}).get(env_id)
        if kwargs:
            text = yaml.safe_dump({"env_kwargs": dict(kwargs)})
            atomic_write_bytes(run / name / "args.yml", text.encode())
    return folder
