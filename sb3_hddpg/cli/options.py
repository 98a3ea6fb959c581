"""Option validators shared by the commands: each names the option and the offending value."""

from __future__ import annotations

import contextlib
import functools
import inspect
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Annotated, Any, TypeVar

import gymnasium as gym
import typer

from sb3_hddpg.artifacts.io import FolderLockedError, locked_folder
from sb3_hddpg.artifacts.limits import count_bounds
from sb3_hddpg.artifacts.run_folder import (
    RunFolderError,
    check_clearable,
    check_out_folder,
    check_output_file,
    clear_run_folder,
    mark_run_folder,
    protected_reason,
    record_written,
)
from sb3_hddpg.artifacts.values import check_env_kwargs
from sb3_hddpg.cli.app import console_note
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
from sb3_hddpg.envs.terms_env import parse_term_bounds, parse_terms, terms_env
from sb3_hddpg.training.backends import BackendError, check_backend
from sb3_hddpg.training.run_options import MAX_SEED, RUN_OPTION_NAMES, RunOptions

F = TypeVar("F", bound=Callable[..., Any])

#: Files whose presence means a folder already holds results of ours.
RESULT_MARKERS = (
    "workers/manifest.json",
    "hierarchy.zip",
    "results.json",
    "benchmark.json",
    "flat",
    "checkpoints",
    "study.db",
)


def at_least(minimum: int) -> Callable[[int | None], int | None]:
    """A typer callback that accepts integers >= ``minimum`` (``None`` passes)."""

    def check(value: int | None) -> int | None:
        if value is not None and value < minimum:
            raise typer.BadParameter(f"must be >= {minimum}, got {value}")
        return value

    return check


def count(name: str) -> Callable[[int | None], int | None]:
    """A typer callback for a count of :data:`~sb3_hddpg.artifacts.limits.COUNTS` (``None`` passes)."""

    def check(value: int | None) -> int | None:
        low, high = count_bounds(name)
        if value is not None and not low <= value <= high:
            raise typer.BadParameter(f"must be in [{low}, {high}], got {value}")
        return value

    return check


def seed_range(value: int | None) -> int | None:
    """A typer callback for seeds: integers in ``[0, 2**32 - 1]`` (SB3's range; ``None`` passes)."""
    if value is not None and not 0 <= value <= MAX_SEED:
        raise typer.BadParameter(f"must be in [0, {MAX_SEED}], got {value}")
    return value


def discount(value: float | None) -> float | None:
    """A typer callback for a discount: a number in ``(0, 1]`` (``None`` passes)."""
    if value is not None and not 0 < value <= 1:
        raise typer.BadParameter(f"must be in (0, 1], got {value}")
    return value


def existing_file(value: Path | None) -> Path | None:
    """A typer callback for a file to read: it must exist and be a file (``None`` passes)."""
    return _existing(value, Path.is_file, "file")


def existing_dir(value: Path | None) -> Path | None:
    """A typer callback for a folder to read: it must exist and be a folder (``None`` passes)."""
    return _existing(value, Path.is_dir, "folder")


def _existing(value: Path | None, is_kind: Callable[[Path], bool], kind: str) -> Path | None:
    """``value`` if it exists and ``is_kind`` (a ``kind``); ``None`` passes. A refusal names what it found."""
    if value is None:
        return None
    if not value.exists():
        raise typer.BadParameter(f"no such {kind}: {str(value)!r}")
    if not is_kind(value):
        if value.is_dir() or value.is_file():
            found = "folder" if value.is_dir() else "file"
            raise typer.BadParameter(f"expected a {kind}, got a {found}: {str(value)!r}")
        wanted = "regular file" if kind == "file" else kind
        raise typer.BadParameter(f"expected a {wanted}, got a FIFO, socket or device: {str(value)!r}")
    return value


def writable_file(value: Path | None) -> Path | None:
    """A typer callback for a file to write: it must not be a folder (``None`` passes)."""
    if value is not None and value.is_dir():
        raise typer.BadParameter(f"expected a file to write, got a folder: {str(value)!r}")
    return value


def output_file(path: Path | None, force: bool, param_hint: str) -> Path | None:
    """The file a command writes, checked before any work: an existing one only with ``--force``."""
    if path is None:
        return None
    try:
        return check_output_file(path, force=force)
    except RunFolderError as error:
        raise typer.BadParameter(str(error), param_hint=param_hint) from None


@contextlib.contextmanager
def usage_errors(param_hint: str | None = None) -> Iterator[None]:
    """
    Report the library's input errors (``ValueError``, a missing or wrong-kind path) as a usage error (exit
    code 2): only around the checks before any work starts, so that a failure while working stays exit 1.

    :param param_hint: the option the problem comes from, e.g. ``"'--config'"`` (``None``: not named).
    """
    try:
        yield
    except (ValueError, FileNotFoundError, NotADirectoryError, IsADirectoryError, gym.error.Error) as error:
        message = str(error) or type(error).__name__
        raise typer.BadParameter(message, param_hint=param_hint) from error


def refuse_protected_out(out: Path) -> Path:
    """Refuse, as a usage error, an output folder that may never hold a run (the current one, home, root...)."""
    reason = "the current folder" if str(out) in ("", ".") else protected_reason(out)
    if reason is not None:
        raise typer.BadParameter(
            f"expected a folder for this run's files, got {str(out)!r} ({reason})", param_hint="'--out'"
        )
    return out


def prepare_out_dir(context: typer.Context, out: Path, resume: bool, force: bool) -> Path:
    """
    Take the run folder for this command: refuse a protected folder, a path through a file, a link, a
    folder of the user's, and one that already holds results unless ``--resume`` or ``--force`` (which
    clears only what the tool wrote); then lock it until the command ends.

    :param context: the command's context, whose closing releases the lock (typer's own copy of click
        hides it from ``click.get_current_context``).
    """
    refuse_protected_out(out)
    try:
        check_out_folder(out)
    except RunFolderError as error:
        raise typer.BadParameter(str(error), param_hint="'--out'") from None
    if out.exists() and not out.is_dir():
        raise typer.BadParameter(f"is a file, not a folder: {str(out)!r}", param_hint="'--out'")
    blocking = next((p for p in out.parents if p.exists() and not p.is_dir()), None)
    if blocking is not None:
        raise typer.BadParameter(
            f"{str(blocking)!r} is a file, so {str(out)!r} cannot be a folder", param_hint="'--out'"
        )
    held = [m for m in RESULT_MARKERS if (out / m).exists()]
    if held and not (resume or force):
        raise typer.BadParameter(
            f"{str(out)!r} already holds results ({held[0]}); pass --resume to continue or --force to overwrite",
            param_hint="'--out'",
        )
    clear = bool(held) and force and not resume
    try:
        if clear:  # before the lock: taking it writes the lock file that marks older run folders
            check_clearable(out)
        lock = locked_folder(out)
        lock.__enter__()
    except (FolderLockedError, RunFolderError) as error:
        raise typer.BadParameter(str(error), param_hint="'--out'") from None
    except OSError as error:
        raise typer.BadParameter(
            f"cannot create {str(out)!r}: {error.strerror or error}", param_hint="'--out'"
        ) from None
    # Released when the command returns or fails (its context closes then), not only when the process ends.
    context.call_on_close(lambda: lock.__exit__(None, None, None))
    if clear:
        with usage_errors("'--out'"):
            kept = clear_run_folder(out)
        if kept:
            console_note(
                f"--force kept {len(kept)} entries the tool did not write in {str(out)!r}: {kept[:5]}"
            )
    mark_run_folder(out, context.info_name or "hddpg-cli", reopen=True)
    # Registered after the lock's release, so run before it (click closes in reverse order).
    context.call_on_close(lambda: record_written(out))
    return out


#: Help of every training command's ``--backend``.
BACKEND_HELP = (
    'Training backend: sb3 (PyTorch) or sbx (JAX, faster; pip install "sb3-hddpg[fast]"). Saved models are '
    "plain SB3 zips either way. Default: the config block's 'backend' key, else sb3."
)


def backend_name(value: str | None) -> str | None:
    """A typer callback for ``--backend``: ``sb3`` or ``sbx``, and installed (``None`` passes)."""
    if value is None:
        return None
    try:
        return check_backend(value)
    except BackendError as error:
        raise typer.BadParameter(str(error)) from None


CHECKPOINT_HELP = (
    "Steps between resumable checkpoints (0: only on Ctrl-C/SIGTERM and at the end); "
    "a SIGKILL loses at most this many steps."
)
KEEP_CHECKPOINTS_HELP = (
    "After a successful run, keep the replay buffer in OUT/checkpoints/ (about 70 MB per agent at the "
    "bundled buffer_size) so that --resume with a larger --timesteps continues exactly; by default only "
    "the model checkpoint stays (resuming it refills the buffer first)."
)

# The options the commands share, spelled once.
ForceOpt = Annotated[bool, typer.Option("--force", help="Overwrite a folder that already holds results.")]
ReplaceFileOpt = Annotated[bool, typer.Option("--force", help="Replace the output file if it exists.")]
ResumeOpt = Annotated[bool, typer.Option("--resume", help="Continue an interrupted run from its checkpoint.")]
EvalEpisodesOpt = Annotated[
    int, typer.Option("--eval-episodes", callback=count("episodes"), help="Episodes per evaluation.")
]
BackendOpt = Annotated[str | None, typer.Option("--backend", callback=backend_name, help=BACKEND_HELP)]


#: What ``--env`` accepts; each command adds its one default.
ENV_HELP = (
    "Env id with several objectives: one of ours, an MO-Gymnasium id (the mo extra, which make installs), or "
    "a registered env with per-term rewards in info (docs/ENVIRONMENTS.md)."
)
#: The default of ``--env`` where it is the snake arm.
SNAKE_DEFAULT = f" Default: the snake arm ({SNAKE_REACH_ENV_ID})."
TERMS_HELP = (
    "Comma-separated reward term names, e.g. speed,energy: an MO-Gymnasium env's objectives in order "
    "(default obj0..objN), or the info keys of an env's per-term rewards (required there)."
)
TERM_BOUNDS_HELP = (
    "Per-step bounds TERM=LOW:HIGH[,...] for terms the env does not bound (needed for info terms; for an "
    "unbounded MO-Gymnasium reward_space they are otherwise estimated, with a warning)."
)
INFO_KEY_HELP = (
    "The info entry holding the per-term rewards, e.g. rewards (highway-env); default: info itself."
)
EPISODE_STEPS_HELP = "Time limit of an adapted env (default: its registered max_episode_steps)."

TermsOpt = Annotated[str | None, typer.Option("--terms", help=TERMS_HELP)]
TermBoundsOpt = Annotated[str | None, typer.Option("--term-bounds", help=TERM_BOUNDS_HELP)]
InfoKeyOpt = Annotated[str | None, typer.Option("--info-key", help=INFO_KEY_HELP)]
EpisodeStepsOpt = Annotated[
    int | None, typer.Option("--episode-steps", callback=count("episode_steps"), help=EPISODE_STEPS_HELP)
]


#: The options a command may take without using them itself (it reads them from its context with
#: :func:`run_options_of` or :func:`terms_env_of`): parameter name -> its annotation and default, the run
#: options named as the :class:`~sb3_hddpg.training.run_options.RunOptions` fields.
SHARED_OPTIONS: dict[str, tuple[object, object]] = {
    "seed": (int, typer.Option(0, "--seed", callback=seed_range, help="Training seed.")),
    "n_envs": (
        int | None,
        typer.Option(None, "--n-envs", callback=at_least(1), help="Training envs, in subprocesses when > 1."),
    ),
    "stop_on_plateau": (
        bool,
        typer.Option(False, "--stop-on-plateau", help="Stop after 3 evaluations without a new best."),
    ),
    "eval_freq": (
        int,
        typer.Option(5000, "--eval-freq", callback=at_least(0), help="Steps between evaluations."),
    ),
    "eval_episodes": (EvalEpisodesOpt, 5),
    "checkpoint_freq": (
        int,
        typer.Option(10_000, "--checkpoint-freq", callback=at_least(0), help=CHECKPOINT_HELP),
    ),
    "threads": (
        int,
        typer.Option(1, "--threads", callback=at_least(1), help="Torch threads (1 is fastest here)."),
    ),
    "progress_bar": (bool, typer.Option(True, "--progress/--no-progress", help="Show a progress bar.")),
    "keep_checkpoints": (bool, typer.Option(False, "--keep-checkpoints", help=KEEP_CHECKPOINTS_HELP)),
    "terms": (TermsOpt, None),
    "term_bounds": (TermBoundsOpt, None),
    "info_key": (InfoKeyOpt, None),
    "episode_steps": (EpisodeStepsOpt, None),
}
#: The options that name another env's terms, beside ``--env`` (:func:`terms_env_of`).
ENV_OPTIONS = ("terms", "term_bounds", "info_key", "episode_steps")
#: The options that are :class:`~sb3_hddpg.training.run_options.RunOptions` fields.
RUN_OPTIONS = tuple(name for name in SHARED_OPTIONS if name not in ENV_OPTIONS)


def takes_options(*names: str) -> Callable[[F], F]:
    """
    Give a typer command the options ``names`` (:data:`SHARED_OPTIONS`) as parameters, the env options
    after its ``--env`` and the others before its ``--resume`` (else last); the command is called without
    them and reads them from its context.

    :param names: keys of :data:`SHARED_OPTIONS`.
    """

    def decorate(command: F) -> F:
        # Evaluated annotations: typer reads this signature, not a postponed annotation's string.
        params = list(inspect.signature(command, eval_str=True).parameters.values())
        for name in names:
            annotation, default = SHARED_OPTIONS[name]
            anchors = ("env", "env_id", *ENV_OPTIONS) if name in ENV_OPTIONS else ()
            after = [i + 1 for i, p in enumerate(params) if p.name in anchors]
            at = max(
                after, default=next((i for i, p in enumerate(params) if p.name == "resume"), len(params))
            )
            kind = inspect.Parameter.POSITIONAL_OR_KEYWORD
            params.insert(at, inspect.Parameter(name, kind, annotation=annotation, default=default))

        @functools.wraps(command)
        def wrapper(**kwargs: object) -> Any:
            return command(**{key: value for key, value in kwargs.items() if key not in names})

        wrapper.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
        return wrapper  # type: ignore[return-value]

    return decorate


def run_options_of(context: typer.Context) -> RunOptions:
    """
    The :class:`~sb3_hddpg.training.run_options.RunOptions` of a running command, from its parameters named
    as the fields (fields it has no option for keep their defaults).

    :param context: the command's context (a ``typer.Context`` parameter of the command).
    """
    with usage_errors():
        return RunOptions(**{k: v for k, v in context.params.items() if k in RUN_OPTION_NAMES})


def terms_env_of(context: typer.Context, env: str | None) -> Any:
    """
    :func:`terms_env_option` of ``env`` and the :data:`ENV_OPTIONS` a command took with :func:`takes_options`.

    :param context: the command's context (a ``typer.Context`` parameter of the command).
    :param env: the command's ``--env``.
    """
    return terms_env_option(env, *(context.params[name] for name in ENV_OPTIONS))


def terms_env_option(
    env: str | None,
    terms: str | None,
    term_bounds: str | None,
    info_key: str | None = None,
    episode_steps: int | None = None,
) -> Any:
    """
    The :class:`~sb3_hddpg.envs.terms_env.TermsEnv` the env options name (``None`` without ``--env``); the
    library's errors become usage errors naming the option.
    """
    if env is None:
        options = ("--terms", terms), ("--term-bounds", term_bounds), ("--info-key", info_key)
        for name, value in (*options, ("--episode-steps", episode_steps)):
            if value is not None:
                message = f"{name} needs --env (the env whose terms it names)"
                raise typer.BadParameter(message, param_hint="'--env'")
        return None
    with usage_errors("'--terms'"):
        names = parse_terms(terms) if terms is not None else None
    with usage_errors("'--term-bounds'"):
        bounds = parse_term_bounds(term_bounds) if term_bounds is not None else None
    with usage_errors("'--env'"):
        shared = terms_env(env, names, bounds, info_key=info_key, episode_steps=episode_steps)
        # The same bounds as for env settings from a file (episode lengths, term bounds, values).
        check_env_kwargs(shared.env_id, shared.env_kwargs, "--env", trusted=True)
        return shared


RUN_PREFERENCE_HELP = (
    "For a preference-conditioned hierarchy (train-manager --preferences): the trade-off to act at, e.g. "
    "goal=0.4,avoid=1.6; one outside those it was trained over is refused."
)
RunPreferenceOpt = Annotated[str | None, typer.Option("--preference", help=RUN_PREFERENCE_HELP)]


def apply_run_preference(policy: object, text: str | None, kind: str) -> None:
    """
    Set ``--preference`` on a loaded policy: a usage error for a policy that takes none, a malformed text,
    or a preference outside those a conditioned manager was trained over.

    :param policy: the loaded policy.
    :param text: the option's value (``None``: not given).
    :param kind: the policy's kind, for the message.
    """
    if text is None:
        return
    from sb3_hddpg.hierarchy.selection import parse_preferences  # the library only when the option is used

    set_preference = getattr(policy, "set_preference", None)
    if set_preference is None:
        raise typer.BadParameter(f"applies to a hierarchy, not a {kind}", param_hint="'--preference'")
    with usage_errors("'--preference'"):
        set_preference(parse_preferences(text))
