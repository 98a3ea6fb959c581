"""
Limits on input from files someone else made, and the checks that enforce them before the content reaches
memory, a path, an import or a constructor (docs/ROBUSTNESS.md lists them with the tests that hold them).
"""

from __future__ import annotations

import contextlib
import errno
import itertools
import json
import numbers
import os
import re
import reprlib
import stat
import zipfile
import zlib
from collections import Counter
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from gymnasium.envs.registration import registry

from sb3_hddpg.artifacts.containment import run_folder_escape
from sb3_hddpg.artifacts.io import first_not_finite
from sb3_hddpg.envs import OWN_ENV_IDS
from sb3_hddpg.envs import adapters as _adapters
from sb3_hddpg.envs.snake import params as _snake
from sb3_hddpg.names import MAX_NAME_CHARS as _MAX_NAME_CHARS
from sb3_hddpg.names import PLAIN_NAME

MAX_JSON_BYTES = 1 << 20  #: Largest JSON document read from a file (a manifest, ham.json): ours are a few KB.
MAX_CSV_BYTES = 64 << 20  #: Largest CSV of records read back (episodes.csv: ~200 bytes per episode).
MAX_CSV_CELLS = 4_000_000  #: Most cells of such a CSV read (a run of record: ~60,000 x ~40).
MAX_JSON_DEPTH = 64  #: Deepest nesting of a JSON document or a config value (json.loads recurses).
MAX_CONFIG_NODES = 100_000  #: Most values in one config file, YAML aliases expanded (ours: a few hundred).
MAX_ZIP_MEMBERS = 256  #: Most members in one zip (a bundle: manifest, manager and one per worker).
MAX_MEMBER_BYTES = 128 << 20  #: Largest zip member read, uncompressed (a 256x256 worker's policy: ~1 MB).
MAX_LOAD_BYTES = 256 << 20  #: Most uncompressed bytes one load may read, over all members and nested bundles.
MAX_COMPRESSION_RATIO = 100  #: Largest compression ratio of a member over 1 MiB (weights: ~1.1x).
MAX_PARAMETERS = 20_000_000  #: Most parameters of one model, targets and critics included (ours: ~0.2 M).
#: Largest replay buffer a spec or config may ask for, in transitions and in (lazily committed) bytes.
MAX_BUFFER_SIZE = 10_000_000
MAX_BUFFER_BYTES = 4 << 30
MAX_NESTING = 4  #: Deepest nesting of bundles (a hierarchy of hierarchies: ours are 2 deep).
MAX_MODELS = 64  #: Most models (manager and workers, over all nested bundles) one load may build.
MAX_WORKERS = 32  #: Most workers one manager may select between.
MAX_ITEMS = 64  #: Most items of a list or mapping value from a file (env kwargs, a list, term bounds).
MAX_SEED = 2**32 - 1  #: Largest seed (numpy's ``SeedSequence`` takes any, SB3's ``set_random_seed`` 32 bits).
MAX_BENCHMARK_SEEDS = 1_000  #: Most seeds of one benchmark (each a run of every method; a run of record: 10).
#: Most bytes of a run folder's marker read, and most entries it may list (a package writes about ten).
MAX_MARKER_BYTES = 1 << 16
MAX_MARKER_ENTRIES = 256
MAX_SHOWN = 200  #: Longest message fragment showing a value from a file.

# Hyperparameters (a config block, a bundle's saved spec): each far above what the bundled configs use.
MAX_BATCH_SIZE = 65_536  #: Largest minibatch (a 65536 x 64-float batch is 16 MB per tensor).
MAX_GRADIENT_STEPS = 1_000  #: Most gradient steps per rollout (SB3's -1, "as many as env steps", too).
MAX_TRAIN_FREQ = 100_000  #: Longest rollout between updates, in steps or episodes.
MAX_N_ENVS = 64  #: Most parallel training environments (each a process with ``SubprocVecEnv``).
MAX_TIMESTEPS = 1_000_000_000  #: Largest training budget of one agent, in timesteps.
MAX_LEARNING_STARTS = MAX_BUFFER_SIZE  #: Most warm-up steps before learning starts.
MAX_LAYER_SIZE = 4_096  #: Widest hidden layer of a network in a config file.
MAX_LAYERS = 16  #: Most hidden layers of a network in a config file.
MAX_CRITICS = 64  #: Most critics of an actor-critic network (``policy_kwargs.n_critics``).
MAX_QUANTILES = 4_096  #: Most quantiles of a distributional critic (``policy_kwargs.n_quantiles``).
MAX_CRITIC_BYTES = 64 << 20  #: The largest per-term critic member read from a worker's zip.
MAX_CRITIC_INPUTS = 1 << 16  #: The most observation or action entries a per-term critic reads.
#: The observation and action widths that stand in for a config's env when its networks are sized
#: before the env exists (the snake's are 39 and 6).
STAND_IN_OBS_DIM = 64
STAND_IN_ACT_DIM = 8

# A saved model's spec: far above anything trained here, so that MAX_PARAMETERS refuses a network too large.
MAX_SPEC_LAYER_WIDTH = 1 << 16  #: Widest hidden layer a spec may describe.
MAX_SPEC_LAYERS = 64  #: Most hidden layers a spec may describe.
MAX_DISCRETE_ACTIONS = 1 << 16  #: Most actions of a Discrete action space in a spec.
MAX_DISCRETE_START = 1 << 31  #: Largest magnitude of a Discrete space's ``start`` in a spec.
MAX_SPACE_SIZE = 1 << 16  #: Most elements of an observation or action space in a spec (ours: 27 and 6).
MAX_RENORM_WARMUP_STEPS = 1 << 40  #: Most warm-up steps of CrossQ's batch renormalisation.
SBX_SNIFF_BYTES = 4096  #: Bytes of a zip's ``data`` member read to tell whether SBX saved it.
MAX_MAGNITUDE = 1e6  #: Largest magnitude of a noise parameter, an action penalty or another float setting.
MAX_OPTION_STEPS = 10_000  #: Most env steps one manager decision may last (``option_steps``).
MAX_EVAL_EPISODES = 10_000  #: Most episodes of one evaluation.
MAX_EVALUATIONS = 10_000  #: Most evaluations of one training run or tuning trial (``--n-evaluations``).
MAX_THREADS = 256  #: Most torch threads of one process.
MAX_PREFERENCE = 1e6  #: Largest preference factor that weights a reward (its sums stay far from overflow).
MAX_MANAGER_MOTION = 1e6  #: Largest scale of the motion a manager observes (``--manager-motion``).
SIMPLEX_TOLERANCE = 1e-6  #: How far the worker probabilities of one manager action may sum from 1.
MAX_MODEL_FILE_BYTES = MAX_LOAD_BYTES  #: Largest model file read into memory to be hashed and loaded.
MAX_VIDEO_STEPS = 100_000  #: Most frames of one video (``package --video-steps``, ``record``).
MAX_SEEDS_PER_TRIAL = 100  #: Most seeds one tuning trial trains (each a full training run).
MAX_TRIALS = 100_000  #: Most trials of one tuning invocation.

# Env settings (env kwargs from a file, a manifest's ``shared_env``, a bundle, ``--env`` options).
MAX_EPISODE_LENGTH = 100_000  #: Longest episode (``episode_steps``, ``max_episode_steps``): ours are 200.
MAX_ENV_INTEGER = 1_000  #: Largest integer env setting (a count or size: ``n_obstacles``, ``frame_skip``...).
MAX_ENV_FLOAT = 1e6  #: Largest magnitude of a float env setting (a speed, a radius, a time step...).
MIN_ENV_FLOAT = 1e-9  #: Least magnitude of a float env setting other than 0: an env divides by its settings.
FILE_RENDER_MODES = (None, "rgb_array")  #: The render modes a file may ask for (never a window).


def max_processes() -> int:
    """Most processes one command starts side by side (``--n-jobs``, ``--processes``): the usable cores."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


#: The one table of counts a user, a config or a file may ask for: name -> least and largest value (a
#: callable for bounds that depend on the machine), checked by :func:`check_count` where the count enters.
COUNTS: dict[str, tuple[int, int | Any]] = {
    "episodes": (1, MAX_EVAL_EPISODES),
    "evaluations": (1, MAX_EVALUATIONS),
    "episode_steps": (1, MAX_EPISODE_LENGTH),
    "video_steps": (1, MAX_VIDEO_STEPS),
    "seeds_per_trial": (1, MAX_SEEDS_PER_TRIAL),
    "n_trials": (1, MAX_TRIALS),
    "n_jobs": (1, max_processes),
    "processes": (1, max_processes),
    "option_steps": (1, MAX_OPTION_STEPS),
    "workers": (2, MAX_WORKERS),
    "manifest_entries": (0, MAX_MODELS),
}


def count_bounds(name: str) -> tuple[int, int]:
    """The least and largest value of the count ``name`` of :data:`COUNTS`."""
    low, high = COUNTS[name]
    return low, int(high() if callable(high) else high)


def check_count(name: str, value: object, what: str | None = None) -> int:
    """
    A count of :data:`COUNTS`: an integer (not a bool) within its bounds.

    :param name: the count's name in :data:`COUNTS`.
    :param value: the value asked for.
    :param what: the option or field, for the message (default: ``name``).
    :return: the value; raises :class:`LimitError` naming ``what``, the bounds and the value otherwise.
    """
    low, high = count_bounds(name)
    # numbers.Integral: numpy's integers too (a count computed from an array is one)
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not low <= int(value) <= high:
        raise LimitError(f"{what or name}: expected an integer in [{low}, {high}], actually: {brief(value)}")
    return int(value)


NAME_PATTERN = PLAIN_NAME  #: Worker names, algorithm names: what may become part of a file name.
#: Env ids: gymnasium's ``[namespace/]name-vN`` without a ``module:`` prefix.
ENV_ID_PATTERN = re.compile(r"^[A-Za-z0-9_.-]{1,64}(/[A-Za-z0-9_.-]{1,64})?$")

_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxdict, _REPR.maxlist, _REPR.maxtuple = 3, 6, 8, 8
_REPR.maxstring, _REPR.maxother, _REPR.maxlong = 80, 80, 40


#: What :func:`parse_json` strips before counting brackets: strings (to the end if unterminated), the rest.
_NOT_BRACKETS = re.compile(r'"(?:[^"\\]|\\.)*"?|[^\[\]{}"]+', re.DOTALL)


class LimitError(ValueError):
    """Input from a file exceeds one of this module's limits; the message names the file or field."""


def brief(value: object, limit: int = MAX_SHOWN) -> str:
    """
    ``repr(value)`` bounded in time (:mod:`reprlib` cuts nested containers) and truncated to ``limit``.

    :param value: anything, typically a value read from a file.
    :param limit: the longest result.
    """
    text = _REPR.repr(value)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def check_name(value: object, what: str) -> str:
    """
    A name that becomes part of a path or a member name: letters, digits, ``_`` and ``-``, at most 64.

    :param value: the name from a file.
    :param what: the field, for the message.
    :return: the name; raises :class:`LimitError` otherwise.
    """
    if not isinstance(value, str) or not NAME_PATTERN.match(value):
        raise LimitError(
            f"{what}: expected a name of letters, digits, '_' and '-' (at most 64), got {brief(value)}"
        )
    return value


def check_env_id(
    env_id: object, what: str, allowed_env_ids: Sequence[str] | None = None, trusted: bool = False
) -> str:
    """
    An env id read from a file, before it reaches ``gym.make``: registered already, without a ``module:``
    prefix (which would import that module), and in the allow-list.

    :param env_id: the id from the file.
    :param what: the field, for the message.
    :param allowed_env_ids: more ids to accept besides this package's own (they must be registered).
    :param trusted: accept any registered id (still no module prefix).
    :return: the id; raises :class:`LimitError` naming it otherwise.
    """
    if not isinstance(env_id, str) or not ENV_ID_PATTERN.match(env_id):
        raise LimitError(
            f"{what}: {brief(env_id)} is not a plain env id ('namespace/Name-vN' without a module prefix)"
        )
    if env_id not in registry:
        raise LimitError(f"{what}: env id {env_id!r} is not registered")
    allowed = frozenset(OWN_ENV_IDS) | frozenset(allowed_env_ids or ())
    if not trusted and env_id not in allowed:
        raise LimitError(
            f"{what}: env id {env_id!r} is not one of the {len(allowed)} allowed ids (this package's, and "
            "Gymnasium's and MO-Gymnasium's for an adapter); pass allowed_env_ids=[...] (CLI: name it with "
            "--env) or --trust to use another registered env"
        )
    return env_id


def parse_json(data: bytes | str, what: str) -> Any:
    """
    Parse a JSON document from a file someone else made: at most :data:`MAX_JSON_BYTES` and
    :data:`MAX_JSON_DEPTH` deep (``json.loads`` would recurse until ``RecursionError``).

    :param data: the document.
    :param what: the file, for the message.
    :return: the parsed value; raises :class:`LimitError` (too big or deep) or ``ValueError`` (not JSON).
    """
    if len(data) > MAX_JSON_BYTES:
        raise LimitError(f"{what}: {len(data)} bytes is more than the {MAX_JSON_BYTES}-byte limit for JSON")
    text = data.decode("utf-8") if isinstance(data, bytes) else data
    # Brackets outside strings bound the depth; counting them first keeps json.loads from recursing deep.
    brackets = _NOT_BRACKETS.sub("", text)
    deepest = max(itertools.accumulate((1 if char in "[{" else -1 for char in brackets), initial=0))
    if deepest > MAX_JSON_DEPTH:
        raise LimitError(f"{what}: JSON nested {deepest} deep, more than the limit of {MAX_JSON_DEPTH}")
    try:
        return json.loads(text)
    except RecursionError:  # pragma: no cover - the count above refuses these first
        raise LimitError(f"{what}: JSON nested too deeply") from None


def read_file_bytes(path: str | os.PathLike[str], limit: int, what: str | None = None) -> bytes:
    """
    The bytes of a file someone else may have made, read once: a regular file (a FIFO would block forever,
    ``/dev/zero`` never ends) of at most ``limit`` bytes, both checked on the open descriptor so that what is
    checked is what is read, and not leading out of its run folder (:func:`check_run_file`).

    :param path: the file.
    :param limit: the largest size accepted.
    :param what: how messages name the file (default: its path).
    :return: the bytes; raises :class:`LimitError` (not a regular file, too big), ``FileNotFoundError``,
        ``IsADirectoryError``, or another ``OSError``.
    """
    name = what or str(path)
    check_run_file(path)
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0))
    try:
        info = os.fstat(fd)
        if stat.S_ISDIR(info.st_mode):
            raise IsADirectoryError(errno.EISDIR, f"Expected a file, got a folder: {name!r}")
        if not stat.S_ISREG(info.st_mode):
            raise LimitError(f"{name}: expected a regular file, got a FIFO, socket or device; refused")
        if info.st_size > limit:
            raise LimitError(f"{name}: {info.st_size} bytes is over the {limit}-byte limit for this file")
        return _read_within(
            lambda size: os.read(fd, size),
            limit,
            f"{name}: grew past the {limit}-byte limit while being read",
        )
    finally:
        os.close(fd)


def _read_within(read: Callable[[int], bytes], limit: int, refusal: str) -> bytes:
    """All that ``read`` gives, in chunks of at most 1 MiB, refused with ``refusal`` past ``limit`` bytes."""
    chunks, total = [], 0
    while chunk := read(min(1 << 20, limit + 1 - total)):
        total += len(chunk)
        if total > limit:
            raise LimitError(refusal)
        chunks.append(chunk)
    return b"".join(chunks)


def check_run_file(path: str | os.PathLike[str]) -> None:
    """Refuse (:class:`LimitError`) a file inside one of the tool's run folders that leads outside it."""
    reason = run_folder_escape(path)
    if reason is not None:
        raise LimitError(reason)


def read_json_file(path: str | os.PathLike[str], what: str | None = None) -> Any:
    """:func:`parse_json` of a file read by :func:`read_file_bytes`; NaN and infinities refused."""
    name = what or str(path)
    value = parse_json(read_file_bytes(path, MAX_JSON_BYTES, what), name)
    where = first_not_finite(value)
    if where is not None:
        raise LimitError(f"{name}: {where} is not a finite number")
    return value


def read_json_record(path: str | os.PathLike[str], unreadable: str) -> Any:
    """:func:`read_json_file`; a file that cannot be read, decoded or parsed: ``ValueError(unreadable)``."""
    try:
        return read_json_file(path)
    except LimitError:
        raise
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"{unreadable} ({type(error).__name__})") from None


def count_nodes(value: object, limit: int = MAX_CONFIG_NODES) -> int:
    """
    The number of values in ``value``, shared sub-objects (YAML aliases) counted every time they appear
    but sized once (linear time even for an alias bomb), stopping past ``limit``.
    """
    sizes: dict[int, int] = {}

    def size(node: object, depth: int) -> int:
        if depth > MAX_JSON_DEPTH:
            return limit + 1
        key = id(node)
        if key in sizes:
            return sizes[key]
        total = 1
        children = node.items() if isinstance(node, Mapping) else node if isinstance(node, list) else ()
        for child in children:
            parts = child if isinstance(node, Mapping) else (child,)
            for part in parts:
                total += size(part, depth + 1)
                if total > limit:
                    break
        total = min(total, limit + 1)
        if isinstance(node, (Mapping, list)):
            sizes[key] = total
        return total

    return size(value, 0)


@dataclass
class LoadBudget:
    """
    What one load (a bundle with all its nested bundles) may still spend, shared by the nested loads.

    :param bytes_left: uncompressed bytes that may still be read.
    :param models_left: models that may still be built.
    :param depth: the current nesting depth (0: the outer bundle).
    """

    bytes_left: int = MAX_LOAD_BYTES
    models_left: int = MAX_MODELS
    depth: int = 0

    @contextlib.contextmanager
    def nested(self, what: str) -> Iterator[None]:
        """One level deeper for the duration; raises past :data:`MAX_NESTING`."""
        if self.depth + 1 > MAX_NESTING:
            raise LimitError(f"{what}: bundles nested more than {MAX_NESTING} deep")
        self.depth += 1
        try:
            yield
        finally:
            self.depth -= 1

    def spend_model(self, what: str) -> None:
        """Count one model built; raises past :data:`MAX_MODELS`."""
        self.models_left -= 1
        if self.models_left < 0:
            raise LimitError(f"{what}: more than {MAX_MODELS} models in one bundle")

    def spend_bytes(self, size: int, what: str) -> None:
        """Count ``size`` bytes read; raises past :data:`MAX_LOAD_BYTES`."""
        self.bytes_left -= size
        if self.bytes_left < 0:
            raise LimitError(f"{what}: more than {MAX_LOAD_BYTES} bytes read for one bundle")


def check_zip_directory(archive: zipfile.ZipFile, what: str) -> list[zipfile.ZipInfo]:
    """The members of ``archive``, refused past :data:`MAX_ZIP_MEMBERS` or when two share a name."""
    infos = archive.infolist()
    if len(infos) > MAX_ZIP_MEMBERS:
        raise LimitError(f"{what}: {len(infos)} members is more than the limit of {MAX_ZIP_MEMBERS}")
    twice = [name for name, count in Counter(info.filename for info in infos).items() if count > 1]
    if twice:
        raise LimitError(f"{what}: two members are named {brief(twice[0])}; refused as ambiguous")
    return infos


def read_member(
    archive: zipfile.ZipFile,
    name: str,
    what: str,
    limit: int = MAX_MEMBER_BYTES,
    budget: LoadBudget | None = None,
) -> bytes:
    """
    Read one zip member within limits: its declared size and compression ratio before reading, the actual
    bytes while reading (a member whose header lies costs no more than the limit).

    :param archive: the open zip.
    :param name: the member.
    :param what: the file, for the message.
    :param limit: the largest uncompressed size accepted.
    :param budget: a load's budget to spend the bytes from.
    :return: the bytes; raises :class:`LimitError` (too big) or ``ValueError`` (missing, corrupt).
    """
    try:
        info = archive.getinfo(name)
    except KeyError:
        raise ValueError(f"{what}: no member {name!r}") from None
    declared = info.file_size
    if declared > limit:
        raise LimitError(f"{what}: member {name!r} is {declared} bytes, over the {limit}-byte limit")
    if declared > 1 << 20 and declared > MAX_COMPRESSION_RATIO * max(info.compress_size, 1):
        raise LimitError(
            f"{what}: member {name!r} inflates {declared // max(info.compress_size, 1)}x "
            f"(limit {MAX_COMPRESSION_RATIO}x): refused as a zip bomb"
        )
    if budget is not None:
        budget.spend_bytes(declared, what)
    refusal = f"{what}: member {name!r} holds more than its declared {declared} bytes"
    try:
        with archive.open(info) as handle:
            return _read_within(handle.read, declared, refusal)
    except (zipfile.BadZipFile, EOFError, zlib.error, NotImplementedError, RuntimeError) as error:
        raise ValueError(f"{what}: member {name!r} is corrupt or unreadable: {error}") from None


#: The largest ratio ``ratio-sweep:MAX`` takes (a weight of 1/1025 is as good as none).
MAX_SWEEP_RATIO = 1024

# Limits enforced below the artefacts, where the value is first read, named here with every other.
MAX_JOINTS = _snake.MAX_JOINTS  #: The snake arm's most joints.
MAX_OBSTACLES = _snake.MAX_OBSTACLES  #: The snake arm's most obstacles.
MAX_SUBSTEPS = _snake.MAX_SUBSTEPS  #: The snake arm's most physics substeps per step.
#: The most reward terms of an adapted env (MO-Gymnasium objectives or info terms).
MAX_TERMS = _adapters.MAX_TERMS
MAX_NAME_CHARS = _MAX_NAME_CHARS  #: The longest plain name (a worker, a method, a term).
