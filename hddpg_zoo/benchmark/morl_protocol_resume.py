"""
A MORL-baselines learner trained in chunks, its whole training state saved after each chunk, so that a peer
seed of the protocol that was stopped goes on from its last chunk (``morl_protocol_runner.py train
--checkpoint-dir DIR``). The runner loads this file by path, in MORL-baselines' own python: it imports
nothing of sb3_hddpg.

How each learner goes on (read from MORL-baselines 1.3's ``train`` of each):

- CAPQL and Envelope train in chunks of ``--chunk-steps`` env steps, one ``train(chunk,
  reset_num_timesteps=False)`` call each, so that ``global_step`` (which learning starts read, and Envelope's
  epsilon and homotopy schedules with their own decay steps, never ``total_timesteps``), ``num_episodes``
  and the replay buffer carry on. Every ``train`` call resets the env first: within one process the env is
  held (:class:`Continuing`), so that the episode a chunk ended in goes on as in one call; Envelope's
  ``train`` draws a weight on entry, which is then the running episode's own instead (a wrapper of its
  module's ``random_weights``, :func:`_keep_envelope_weight`), so that it acts and draws as in one call.
- GPI-PD (discrete and continuous actions) and GPI-LS train one chunk per iteration of their ``train``
  (``timesteps_per_iter`` env steps): :func:`gpi_iteration` runs the body of ``train``'s loop for its default
  ``weight_selection_algo="gpi-ls"`` (next weight of the linear support, ``train_iteration`` on the support,
  the corner weights and the new weight, each of them evaluated and added to the support), since ``train``
  keeps its linear support in a local variable, which is saved here with the learner.

What is saved is the learner object (its attributes, by ``torch.save``): networks, target networks,
optimisers, replay buffers with their priorities, dynamics models, weight support, counters and its
``np_random``; less its env (and the env's action space) and the functions its constructor sets (GPI-PD's
``dynamics_train_freq``), which a learner built the same way holds again. The learners' own ``save`` and
``load`` do not keep everything: Envelope's and GPI-PD's ``load`` set the target networks to the online
ones, and none keeps ``global_step`` or the linear support. Python's, numpy's and torch's global random
states are saved and restored too. The training env is not: a resumed run starts a new episode from an
unseeded reset and a new env random stream, so it is not an uninterrupted run, and its record counts resumes.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import os
import random
import re
import time
import types
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium

#: A checkpoint's state file: its kind and version.
CHECKPOINT_KIND = "sb3-hddpg-morl-peer-checkpoint"
CHECKPOINT_VERSION = 1
STATE_FILE = "state.json"
#: The learners that train in iterations of their own, between which GPI-LS searches its next weight.
ITERATED = ("gpi_pd_continuous", "gpi_pd_discrete", "gpi_ls_discrete")
#: The settings a checkpoint belongs to: a checkpoint of other settings is refused.
RUN_KEYS = ("algo", "env", "seed", "timesteps", "gamma", "chunk_steps")
#: The first 16 hex digits of the sha256 of the source of each iterated learner's ``train``, as MORL-baselines
#: 1.3.0 has it: :func:`gpi_iteration` re-runs that loop's body, so a learner whose ``train`` is another is
#: refused rather than trained by a loop it may no longer have.
LOOP_SOURCES = {"GPIPD.train": "d28d70f84e8384b5", "GPIPDContinuousAction.train": "ca63389db86e3fc4"}
_LEARNER_FILE = re.compile(r"learner-[0-9]{1,9}\.pt")
_MAX_STATE_BYTES = 1 << 16


class CheckpointError(Exception):
    """A checkpoint folder that cannot be used: one line, naming ``--checkpoint-dir``."""


class LoopChanged(Exception):
    """The installed learner's ``train`` is not the one whose loop :func:`gpi_iteration` re-runs: one line."""


def check_loop_source(learner: type) -> None:
    """
    Refuse an iterated learner's class whose ``train`` is not the one :data:`LOOP_SOURCES` names.

    :raises LoopChanged: naming the method and what to re-read.
    """
    train = learner.train  # type: ignore[attr-defined]
    digest = hashlib.sha256(inspect.getsource(train).encode()).hexdigest()[:16]
    if LOOP_SOURCES.get(train.__qualname__) != digest:
        raise LoopChanged(
            f"{train.__qualname__} of the installed MORL-baselines is not 1.3.0's, whose loop the chunked "
            "training re-runs (morl_protocol_resume.gpi_iteration): re-read it against that loop, then update "
            "LOOP_SOURCES"
        )


class Stopped(Exception):
    """Training stopped after ``--stop-after-chunks`` chunks of this process (a test's interruption)."""


class Continuing(gymnasium.Wrapper):
    """
    The training env, which a learner's ``train`` resets on entry: after :meth:`hold`, that one reset gives
    back the running episode's last observation (or the last reset's) instead, so that chunked ``train``
    calls play one stream of episodes as a single call does.

    :ivar went_on: the last reset went on with the running episode.
    :ivar unweighted: a reset came since the last weight was drawn for an episode (Envelope's).
    """

    def __init__(self, env: Any) -> None:
        super().__init__(env)
        self._running: Any = None
        self._held = False
        self.went_on = False
        self.unweighted = False

    def hold(self) -> None:
        """Let the next reset go on with the running episode (if one runs)."""
        self._held = True

    def step(self, action: Any) -> Any:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._running = None if terminated or truncated else obs
        return obs, reward, terminated, truncated, info

    def reset(self, **kwargs: Any) -> Any:
        held, self._held = self._held, False
        self.went_on, self.unweighted = held and self._running is not None and not kwargs, True
        if self.went_on:
            return self._running, {}
        # A chunk may end just after its episode's last step, where train has reset already: the episode
        # that reset began is the running one.
        obs, info = self.env.reset(**kwargs)
        self._running = obs
        return obs, info


@dataclass
class Progress:
    """
    A checkpoint's state file: the run it belongs to and how far it went.

    :param run: the settings (:data:`RUN_KEYS`).
    :param env_steps: the learner's ``global_step``.
    :param evaluations_in_training: env steps of the learner's own evaluations (GPI-LS's weight search).
    :param wall_time_train_s: seconds of training of every process, up to the last chunk saved.
    :param chunks: chunks trained.
    :param resumes: times a process went on from a checkpoint.
    :param ended: GPI-LS found no next weight: ``train``'s loop ended before its last iteration.
    :param learner: the file of the learner's state, in the checkpoint's folder.
    """

    run: dict[str, Any]
    env_steps: int = 0
    evaluations_in_training: int = 0
    wall_time_train_s: float = 0.0
    chunks: int = 0
    resumes: int = 0
    ended: bool = False
    learner: str | None = None
    kind: str = field(default=CHECKPOINT_KIND)
    version: int = field(default=CHECKPOINT_VERSION)


def _refuse(name: str) -> Any:
    raise ValueError(f"{name} is not a finite number")


def read_progress(folder: Path, run: dict[str, Any]) -> Progress | None:
    """
    The checkpoint in ``folder``, if it holds one, checked to be of ``run``.

    :raises CheckpointError: unreadable, not a checkpoint, of other settings, or its learner file missing.
    """
    path = folder / STATE_FILE
    if not path.exists():
        return None
    where = f"--checkpoint-dir: {str(path)!r}"
    try:
        with open(path, "rb") as handle:
            data = json.loads(handle.read(_MAX_STATE_BYTES + 1).decode(), parse_constant=_refuse)
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as error:
        raise CheckpointError(f"{where}: cannot read: {type(error).__name__}: {error}") from None
    if not isinstance(data, dict) or (data.get("kind"), data.get("version")) != (
        CHECKPOINT_KIND,
        CHECKPOINT_VERSION,
    ):
        raise CheckpointError(f"{where}: not a checkpoint ({CHECKPOINT_KIND}, version {CHECKPOINT_VERSION})")
    saved: dict[str, Any] = data["run"] if isinstance(data.get("run"), dict) else {}
    for key in RUN_KEYS:
        if saved.get(key) != run[key]:
            raise CheckpointError(
                f"{where}: a checkpoint of another run ({key} {saved.get(key)!r}, this run's {run[key]!r}); "
                "delete the folder or run with its settings"
            )
    counts = ("env_steps", "evaluations_in_training", "chunks", "resumes")
    if (
        not all(isinstance(data.get(k), int) and data[k] >= 0 for k in counts)
        or data["env_steps"] > run["timesteps"]
        or not isinstance(data.get("wall_time_train_s"), (int, float))
        or data["wall_time_train_s"] < 0
        or not isinstance(data.get("ended"), bool)
        or not isinstance(data.get("learner"), str)
        or not _LEARNER_FILE.fullmatch(data["learner"])
        or not (folder / data["learner"]).is_file()
    ):
        raise CheckpointError(f"{where}: its counts or its learner file are not a checkpoint's")
    return Progress(
        run=saved,
        env_steps=data["env_steps"],
        evaluations_in_training=data["evaluations_in_training"],
        wall_time_train_s=float(data["wall_time_train_s"]),
        chunks=data["chunks"],
        resumes=data["resumes"],
        ended=data["ended"],
        learner=data["learner"],
    )


def _learner_state(agent: Any) -> dict[str, Any]:
    """The learner's attributes less its env's objects and the functions its constructor sets."""
    env = agent.env
    own = (env, env.action_space, env.observation_space)
    return {
        name: value
        for name, value in vars(agent).items()
        if not any(value is o for o in own) and not isinstance(value, types.FunctionType)
    }


def save(folder: Path, agent: Any, support: Any, progress: Progress) -> None:
    """
    The learner (and GPI's linear ``support``) to a new file, then the state file naming it, each written to
    a temporary name and renamed: a process stopped at any point leaves the last whole checkpoint.
    """
    import numpy as np
    import torch

    folder.mkdir(parents=True, exist_ok=True)
    name = f"learner-{progress.chunks}.pt"
    rng = {"python": random.getstate(), "numpy": np.random.get_state(), "torch": torch.get_rng_state()}
    temporary = folder / f".{name}.tmp"
    torch.save({"learner": _learner_state(agent), "support": support, "rng": rng}, temporary)
    os.replace(temporary, folder / name)
    progress.learner = name
    temporary = folder / f".{STATE_FILE}.tmp"
    with open(temporary, "w") as handle:
        handle.write(json.dumps(asdict(progress), indent=2, allow_nan=False) + "\n")
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(temporary, folder / STATE_FILE)
    for old in folder.glob("learner-*.pt"):
        if old.name != name:
            old.unlink()


def load(folder: Path, agent: Any, progress: Progress) -> Any:
    """
    Set ``agent`` (built as the checkpoint's was, on a new env) to the checkpoint's learner and the global
    random states to its; return GPI's linear support (``None`` for the others).
    """
    import numpy as np
    import torch

    assert progress.learner is not None  # read_progress checked it
    # Our own file, written by save() into this run's folder (the state file checked first).
    saved = torch.load(folder / progress.learner, map_location="cpu", weights_only=False)
    vars(agent).update(saved["learner"])
    if agent.global_step != progress.env_steps:
        raise CheckpointError(
            f"--checkpoint-dir: {str(folder)!r}: the learner's {agent.global_step} steps are not the state "
            f"file's {progress.env_steps}"
        )
    random.setstate(saved["rng"]["python"])
    np.random.set_state(saved["rng"]["numpy"])
    torch.set_rng_state(saved["rng"]["torch"])
    return saved["support"]


def gpi_iteration(agent: Any, support: Any, eval_env: Any, steps: int, defaults: dict[str, Any]) -> bool:
    """
    One pass of the loop of GPI-PD's ``train`` (``weight_selection_algo="gpi-ls"``, no logging), as its source
    runs it; ``False`` where the linear support has no next weight (``train``'s loop ends there).

    :param defaults: ``train``'s defaults (``num_eval_episodes_for_front``, ``eval_freq``).
    """
    from morl_baselines.common.evaluation import policy_evaluation_mo

    episodes = defaults["num_eval_episodes_for_front"]
    agent.set_weight_support(support.get_weight_support())
    use_gpi, agent.use_gpi = agent.use_gpi, True
    w = support.next_weight(algo="gpi-ls", gpi_agent=agent, env=eval_env, rep_eval=episodes)
    agent.use_gpi = use_gpi
    if w is None:
        return False
    weights = support.get_weight_support() + support.get_corner_weights(top_k=4) + [w]
    # The two classes name the same switch differently; the discrete one's reset arguments, as train passes them.
    if "change_w_every_episode" in inspect.signature(agent.train_iteration).parameters:
        own = {"change_w_every_episode": True, "reset_num_timesteps": False, "reset_learning_starts": False}
    else:
        own = {"change_weight_every_episode": True}
    agent.train_iteration(
        total_timesteps=steps,
        weight=w,
        weight_support=weights,
        eval_env=eval_env,
        eval_freq=defaults["eval_freq"],
        **own,
    )
    for wcw in weights:
        support.add_solution(policy_evaluation_mo(agent, eval_env, wcw, rep=episodes)[3], wcw)
    return True


def _keep_envelope_weight(env: Continuing) -> Callable[[], None]:
    """
    Envelope's ``train`` draws an episode's weight (``random_weights``, from the learner's ``np_random``) first
    after each reset (its ``update`` draws others): when the reset went on with the running episode, that
    episode's weight is given back instead and nothing is drawn, so that chunked calls act and draw as one
    call does.

    :return: the function that puts MORL-baselines' ``random_weights`` back.
    """
    import morl_baselines.multi_policy.envelope.envelope as envelope

    draw = envelope.random_weights
    episode: list[Any] = []  # the running episode's weight

    def weights(*args: Any, **kwargs: Any) -> Any:
        if not env.unweighted:
            return draw(*args, **kwargs)
        env.unweighted = False
        if not (env.went_on and episode):
            episode[:] = [draw(*args, **kwargs)]
        return episode[0]

    envelope.random_weights = weights
    return lambda: setattr(envelope, "random_weights", draw)


def train_defaults(agent: Any) -> dict[str, Any]:
    """The defaults of the learner's ``train`` (GPI's ``timesteps_per_iter``, its evaluation episodes)."""
    return {name: p.default for name, p in inspect.signature(agent.train).parameters.items()}


def train_in_chunks(
    agent: Any, env: Any, eval_env: Any, run: dict[str, Any], folder: Path, train_kwargs: dict[str, Any]
) -> Progress:
    """
    Train ``agent`` for ``run["timesteps"]`` env steps in chunks, going on from ``folder``'s checkpoint if it
    holds one, saving one after every chunk.

    :param env: the learner's training env (:class:`Continuing` for CAPQL and Envelope).
    :param eval_env: the counting env of the learner's own evaluations.
    :param run: :data:`RUN_KEYS` and ``stop_after`` (chunks of this process before :class:`Stopped`, or ``None``).
    :param train_kwargs: CAPQL's and Envelope's ``train`` arguments beyond the steps.
    :raises CheckpointError: the folder's checkpoint is not this run's.
    :raises LoopChanged: an iterated learner whose ``train`` is not the one :func:`gpi_iteration` follows.
    :raises Stopped: after ``run["stop_after"]`` chunks (the checkpoint saved).
    """
    from morl_baselines.multi_policy.linear_support.linear_support import LinearSupport

    if run["algo"] in ITERATED:
        check_loop_source(type(agent))
    progress = read_progress(folder, {k: run[k] for k in RUN_KEYS})
    support = None
    if progress is None:
        progress = Progress(run={k: run[k] for k in RUN_KEYS})
        if run["algo"] in ITERATED:
            support = LinearSupport(num_objectives=agent.reward_dim, epsilon=None)  # train's, for gpi-ls
    else:
        support = load(folder, agent, progress)
        eval_env.steps = progress.evaluations_in_training
        progress.resumes += 1
    restore = _keep_envelope_weight(env) if run["algo"] == "envelope" else None
    try:
        _chunks(agent, env, eval_env, run, folder, train_kwargs, support, progress)
    finally:
        if restore is not None:
            restore()
    return progress


def _chunks(
    agent: Any,
    env: Any,
    eval_env: Any,
    run: dict[str, Any],
    folder: Path,
    train_kwargs: dict[str, Any],
    support: Any,
    progress: Progress,
) -> None:
    """The chunks :func:`train_in_chunks` has left, each saved (``progress`` updated)."""
    defaults, chunk, done_here = train_defaults(agent), run["chunk_steps"], 0
    iterations = run["timesteps"] // chunk if run["algo"] in ITERATED else None
    started, wall = time.perf_counter(), progress.wall_time_train_s
    while not progress.ended and (
        progress.chunks < iterations if iterations is not None else agent.global_step < run["timesteps"]
    ):
        if iterations is not None:
            progress.ended = not gpi_iteration(agent, support, eval_env, chunk, defaults)
        else:
            if done_here:
                env.hold()  # the last chunk's episode goes on (a resumed process starts a new one)
            steps = min(chunk, run["timesteps"] - agent.global_step)
            agent.train(total_timesteps=steps, eval_env=eval_env, reset_num_timesteps=False, **train_kwargs)
        progress.chunks += 0 if progress.ended else 1
        progress.env_steps, progress.evaluations_in_training = int(agent.global_step), int(eval_env.steps)
        progress.wall_time_train_s = wall + time.perf_counter() - started
        save(folder, agent, support, progress)
        done_here += 1
        if run["stop_after"] is not None and done_here >= run["stop_after"]:
            raise Stopped(
                f"stopped after {done_here} chunks (--stop-after-chunks); the checkpoint is in {folder}"
            )


__all__ = [
    "CHECKPOINT_KIND",
    "ITERATED",
    "LOOP_SOURCES",
    "CheckpointError",
    "Continuing",
    "LoopChanged",
    "Progress",
    "Stopped",
    "check_loop_source",
    "gpi_iteration",
    "load",
    "read_progress",
    "save",
    "train_defaults",
    "train_in_chunks",
]
