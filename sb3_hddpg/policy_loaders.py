"""
The registry of policy loaders: what :func:`~sb3_hddpg.hierarchy.loading.load_policy` opens besides bundles
and SB3 zips, registered by entry point as gymnasium registers env ids, so that the core imports no baseline.
Only code registers a loader: a file can pick one only by its suffix, never name a module.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium as gym

from sb3_hddpg.envs.headless import private_runtime_dir, rendering_errors

if TYPE_CHECKING:
    from sb3_hddpg.policy import Policy


@dataclass
class LoadedPolicy:
    """
    A policy and where it acts.

    :param policy: anything with SB3's ``predict``.
    :param env_id: the env id it was trained on (the one to evaluate it on by default).
    :param env_kwargs: that env's keyword arguments.
    :param kind: ``hierarchy``, ``worker``, ``flat``, or a registered loader's kind (``ham``, ``random``...).
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
        The env to run this policy in, checked to fit it (a ``ValueError`` otherwise).

        :param env_id: the env id (default: the one the policy was trained on).
        :param kwargs: env keyword arguments over the trained-on ones.
        """
        env_id = env_id or self.env_id
        if kwargs.get("render_mode") is not None:
            private_runtime_dir()  # else SDL and GLFW print an alarming line on a machine without a session
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


#: A loader of a file: ``(path, trusted, allowed_env_ids) -> LoadedPolicy``.
FileLoader = Callable[[Path, bool, Sequence[str] | None], LoadedPolicy]
#: A loader of a policy named instead of a file: ``(name, env_id, env_kwargs) -> LoadedPolicy``.
NamedLoader = Callable[[str, str, dict[str, Any]], LoadedPolicy]


@dataclass(frozen=True)
class PolicyLoader:
    """One registered loader (see :func:`register_policy_loader`)."""

    kind: str
    entry_point: str | Callable[..., LoadedPolicy]
    suffixes: tuple[str, ...] = ()
    names: tuple[str, ...] = ()

    def load(self) -> Callable[..., LoadedPolicy]:
        """The loader function, its module imported if named by a string."""
        if callable(self.entry_point):
            return self.entry_point
        module, _, attribute = self.entry_point.partition(":")
        return getattr(importlib.import_module(module), attribute)  # type: ignore[no-any-return]


#: Kind -> its loader, in registration order.
POLICY_LOADERS: dict[str, PolicyLoader] = {}


def register_policy_loader(
    kind: str,
    entry_point: str | Callable[..., LoadedPolicy],
    *,
    suffixes: Sequence[str] = (),
    names: Sequence[str] = (),
) -> PolicyLoader:
    """
    Register a loader of policy files (by suffix) or of policies named instead of a file.

    :param kind: the loader's name (unique).
    :param entry_point: ``"module:function"`` (imported on first use) or the function: a :data:`FileLoader`
        for ``suffixes``, a :data:`NamedLoader` for ``names``.
    :param suffixes: file suffixes it opens, each starting with a dot and claimed by no other loader.
    :param names: policy names it makes, each claimed by no other loader.
    :return: the registered record.
    :raises ValueError: one line naming what is malformed or already claimed.
    """
    if not isinstance(kind, str) or not kind:
        raise ValueError(f"Expected `kind` to be a non-empty string, actually: {kind!r}")
    if kind in POLICY_LOADERS:
        raise ValueError(f"Policy loader {kind!r} is already registered")
    if isinstance(entry_point, str):
        module, colon, attribute = entry_point.partition(":")
        if not (module and colon and attribute.isidentifier()):
            raise ValueError(f"Expected `entry_point` as 'module:function', actually: {entry_point!r}")
    elif not callable(entry_point):
        raise ValueError(
            f"Expected `entry_point` to be 'module:function' or a function, actually: {entry_point!r}"
        )
    for suffix in suffixes:
        if not (suffix.startswith(".") and len(suffix) > 1):
            raise ValueError(f"Expected a file suffix such as '.json', actually: {suffix!r}")
        if file_loader(suffix) is not None:
            raise ValueError(f"The suffix {suffix!r} already has a policy loader")
    for name in names:
        if named_loader(name) is not None:
            raise ValueError(f"The policy name {name!r} already has a loader")
    record = PolicyLoader(kind, entry_point, tuple(suffixes), tuple(names))
    POLICY_LOADERS[kind] = record
    return record


def file_loader(suffix: str) -> PolicyLoader | None:
    """The loader registered for files with ``suffix`` (``None``: none)."""
    return next((loader for loader in POLICY_LOADERS.values() if suffix in loader.suffixes), None)


def named_loader(name: str) -> PolicyLoader | None:
    """The loader registered for the policy ``name`` (``None``: none)."""
    return next((loader for loader in POLICY_LOADERS.values() if name in loader.names), None)


def policy_names() -> list[str]:
    """Every name that stands for a policy instead of a file."""
    return [name for loader in POLICY_LOADERS.values() for name in loader.names]
