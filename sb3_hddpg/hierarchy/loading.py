"""
``load_policy(path)``: any policy a user can point the CLI at, loaded safely, with the env it acts in.

- a hierarchy bundle (``hierarchy.zip``): verified and rebuilt by :meth:`Hierarchy.load`;
- an SB3 zip written by ``train-workers`` / ``train-flat``: found in the ``manifest.json`` beside it,
  whose sha256 and rebuild spec make the weights-only load possible;
- a HAM switch (``ham.json``);
- ``random`` or ``scripted``: reference policies that need no file;
- any other SB3 zip only with ``trusted=True`` (SB3's full loader runs code stored in the file).
"""

from __future__ import annotations

import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym

from sb3_hddpg.artifacts.limits import check_env_id, read_json_record
from sb3_hddpg.artifacts.provenance import read_verified
from sb3_hddpg.artifacts.records import ManifestKind, models_manifest_from_json
from sb3_hddpg.artifacts.safe_load import load_model
from sb3_hddpg.artifacts.values import check_env_kwargs
from sb3_hddpg.baselines.ham import load_ham
from sb3_hddpg.baselines.random import RandomPolicy
from sb3_hddpg.envs import SnakeArmEnv
from sb3_hddpg.envs.contract import state_layout_of
from sb3_hddpg.envs.headless import rendering_errors
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
from sb3_hddpg.envs.snake.controllers import JacobianReacher, make_controller
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.policy import Policy

#: Names that stand for reference policies instead of files.
REFERENCE_POLICIES = ("random", "scripted", "ik", "field")


@dataclass
class LoadedPolicy:
    """
    A policy and where it acts.

    :param policy: anything with SB3's ``predict``.
    :param env_id: the env id it was trained on (the one to evaluate it on by default).
    :param env_kwargs: that env's keyword arguments.
    :param kind: ``hierarchy``, ``worker``, ``flat``, ``ham``, ``random`` or ``scripted``.
    :param name: a display name.
    :param meta: what the manifest says about it.
    """

    policy: Policy
    env_id: str
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    kind: str = "worker"
    name: str = ""
    meta: dict[str, Any] = field(default_factory=dict)

    def make_env(self, env_id: str | None = None, /, **kwargs: object) -> gym.Env:
        """
        The env to run this policy in (``env_id`` overrides the trained-on id), checked to fit the policy.

        :param env_id: the env id (default: the one the policy was trained on).
        :param kwargs: env keyword arguments over the trained-on ones.
        :return: the env; raises ``ValueError`` if its spaces are not the policy's.
        """
        env_id = env_id or self.env_id
        with rendering_errors():  # MuJoCo's OpenGL may fail on import, before any frame is asked for
            env = gym.make(env_id, **{**self.env_kwargs, **kwargs})
        for kind in ("observation", "action"):
            expected = getattr(self.policy, f"{kind}_space", None)
            actual = getattr(env, f"{kind}_space")
            if expected is not None and getattr(expected, "shape", None) != actual.shape:
                env.close()
                raise ValueError(
                    f"{self.kind} {self.name!r} expects {kind}s of shape {expected.shape}, but {env_id} with "
                    f"env_kwargs {self.env_kwargs | kwargs} has {actual.shape}"
                )
        return env


def load_policy(
    path: str | Path,
    env_id: str | None = None,
    trusted: bool = False,
    algo: str | None = None,
    allowed_env_ids: Sequence[str] | None = None,
    env_kwargs: dict[str, Any] | None = None,
) -> LoadedPolicy:
    """
    Load the policy at ``path`` (see the module docstring for what it may be).

    An env id read from a file is used only if it is registered, has no ``module:`` prefix (which
    ``gym.make`` would import) and is one of this package's ids or of ``allowed_env_ids`` (any registered
    id with ``trusted``); its env kwargs must be the env's own parameters (:mod:`sb3_hddpg.artifacts.limits`).

    :param path: a file, or ``random`` / ``scripted``.
    :param env_id: the env to act in, for reference policies and untracked zips (default SnakeReach).
    :param trusted: allow SB3's full loader for zips without a manifest, and any registered env id.
    :param algo: the algorithm of an untracked zip loaded with ``trusted``.
    :param allowed_env_ids: registered env ids a file may name besides this package's own.
    :param env_kwargs: ``env_id``'s keyword arguments, for reference policies (an adapter's ``env_id``...).
    """

    text = str(path)
    if text in REFERENCE_POLICIES:
        return _reference_policy(text, env_id or SNAKE_REACH_ENV_ID, dict(env_kwargs or {}))
    path = _policy_file(Path(path))
    text = str(path)
    if path.suffix == ".json":
        ham, meta = load_ham(path, trusted=trusted, allowed_env_ids=allowed_env_ids)
        return LoadedPolicy(ham, meta.env_id, dict(meta.env_kwargs), "ham", path.stem, meta.to_json())
    if _is_bundle(path):
        hierarchy = Hierarchy.load(path, trusted=trusted, allowed_env_ids=allowed_env_ids)
        return LoadedPolicy(
            hierarchy, hierarchy.env_id, hierarchy.env_kwargs, "hierarchy", path.stem, hierarchy.metadata
        )
    entry, kind = _manifest_entry(path)
    if entry is not None:
        data = read_verified(path, entry["sha256"], text)
        where = f"{text}: manifest entry"
        entry_env = check_env_id(entry.get("env_id"), f"{where} env_id", allowed_env_ids, trusted)
        env_kwargs = check_env_kwargs(
            entry_env, entry.get("env_kwargs"), f"{where} env_kwargs", allowed_env_ids, trusted
        )
        model = load_model(data, spec=entry.get("spec"), trusted=trusted)
        return LoadedPolicy(model, entry_env, env_kwargs, kind, entry.get("name", path.stem), entry)
    if not trusted:
        raise ValueError(
            f"{text!r} has no sb3-hddpg manifest beside it, so it cannot be loaded without running code stored "
            "in it; pass --trust (with --algo) only if you trust the file"
        )
    model = load_model(path, trusted=True, algorithm=(algo or "ddpg").upper())
    return LoadedPolicy(model, env_id or SNAKE_REACH_ENV_ID, {}, "flat", path.stem, {})


def _policy_file(path: Path) -> Path:
    """The file to load for ``path``: the path itself, or a run folder's ``hierarchy.zip`` or ``ham.json``."""
    text = str(path)
    if not path.exists():
        raise FileNotFoundError(f"No such file: {text!r}")
    if not path.is_dir() and not path.is_file():
        raise ValueError(f"Expected a model file, got something else (a device or pipe?): {text!r}")
    if path.is_dir():
        for candidate in ("hierarchy.zip", "ham.json"):
            if (path / candidate).exists():
                return _policy_file(path / candidate)
        raise ValueError(f"Expected a model file, got a folder without hierarchy.zip or ham.json: {text!r}")
    return path


def _is_bundle(path: Path) -> bool:
    """Whether the zip at ``path`` is a hierarchy bundle (a manifest and no SB3 ``policy.pth``)."""
    try:
        with zipfile.ZipFile(path) as archive:
            members = set(archive.namelist())
    except (zipfile.BadZipFile, EOFError):
        raise ValueError(f"Not a zip file, or a truncated one: {str(path)!r}") from None
    except OSError as error:  # permission denied, I/O error
        raise ValueError(f"Cannot read {str(path)!r}: {error.strerror or error}") from None
    return "manifest.json" in members and "policy.pth" not in members


def _manifest_entry(path: Path) -> tuple[dict[str, Any] | None, str]:
    """The entry describing ``path`` in the ``manifest.json`` beside it, if any."""
    manifest_path = path.parent / "manifest.json"
    if not manifest_path.exists():
        return None, ""
    value = read_json_record(manifest_path, f"Invalid JSON in {str(manifest_path)!r}")
    if not isinstance(value, dict):
        raise ValueError(f"Not an sb3-hddpg manifest: {str(manifest_path)!r}")
    kinds: tuple[tuple[ManifestKind, str], ...] = (("workers", "worker"), ("models", "flat"))
    for kind, label in kinds:
        if kind not in value:
            continue
        manifest = models_manifest_from_json(value, kind, str(manifest_path))
        for entry in manifest.entries.values():
            if entry.get("file") == path.name:
                return dict(entry), label
    return None, ""


def _reference_policy(name: str, env_id: str, env_kwargs: dict[str, Any]) -> LoadedPolicy:
    env = gym.make(env_id, **env_kwargs)
    layout = state_layout_of(env)
    if name == "random":
        policy: Policy = RandomPolicy(env.action_space, seed=0)
    elif name in ("ik", "field"):
        snake = env.unwrapped
        if not isinstance(snake, SnakeArmEnv):
            raise ValueError(f"The {name} controller drives the snake arm only, not {env_id!r}")
        policy = make_controller(name, layout, max_joint_speed=snake.max_joint_speed)
    else:
        policy = JacobianReacher(layout)
    env.close()
    return LoadedPolicy(policy, env_id, env_kwargs, name, name)
