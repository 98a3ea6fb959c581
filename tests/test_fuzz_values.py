"""
Values from files and the command line under abuse (hypothesis): hostile config blocks, hyperparameters,
env kwargs, term specs and term bounds are either accepted, and then within the schema's bounds, or refused
with one short line (a ``ValueError``). A few command lines per class go through the CLI: exit 2, one line.

Short budgets by default; the ``slow`` variant runs each property many more times.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from stable_baselines3 import DDPG, SAC

from sb3_hddpg.artifacts.io import NotFiniteError, atomic_write_json
from sb3_hddpg.artifacts.limits import (
    MAX_ENV_FLOAT,
    MAX_ENV_INTEGER,
    MAX_EPISODE_LENGTH,
    MAX_SHOWN,
)
from sb3_hddpg.artifacts.manifests import ResumeMismatch, check_resumed_env
from sb3_hddpg.artifacts.values import (
    FLAGS,
    HYPERPARAMETERS,
    PLAIN_STRING,
    RUN_SETTINGS,
    WRAPPER_SETTINGS,
    check_env_kwargs,
    check_make_kwargs,
)
from sb3_hddpg.envs.contract import TermNormaliser, check_bounds
from sb3_hddpg.envs.terms_env import parse_term_bounds
from sb3_hddpg.training.config import load_hyperparams, parse_block
from sb3_hddpg.training.config_values import ConfigError
from tests.helpers import TINY_CONFIG

#: The longest message a refusal may print (a value shown is cut to MAX_SHOWN; the rest is words).
LONGEST_MESSAGE = 3 * MAX_SHOWN + 400
SHORT = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
LONG = settings(max_examples=800, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

# ------------------------------------------------------------------------ hostile values
NUMBERS = st.one_of(
    st.integers(min_value=-(10**15), max_value=10**15),
    st.sampled_from([0, 1, -1, 2**31, 2**63, 10**12, 2_000_000_000]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([math.nan, math.inf, -math.inf, 5e-324, 1e308, -0.0, 1e9, 1e-9]),
)
SCALARS = st.one_of(
    NUMBERS,
    st.booleans(),
    st.none(),
    st.text(max_size=20),
    st.sampled_from(
        ["/dev/zero", "/etc/passwd", "../x", "~/.ssh/id_rsa", "os:Evil-v0", "human", "auto", "1e7"]
    ),
)
VALUES = st.one_of(
    SCALARS, st.lists(SCALARS, max_size=4), st.dictionaries(st.text(max_size=8), SCALARS, max_size=3)
)


def assert_one_line(error: BaseException) -> None:
    """A refusal a user can read: one line, not too long, and not empty."""
    message = str(error)
    assert message and "\n" not in message and len(message) <= LONGEST_MESSAGE, message


# ------------------------------------------------------------------------ hyperparameters
HYPER_KEYS = st.sampled_from(
    [*HYPERPARAMETERS, *FLAGS, "train_freq", "buffer_size", "ent_coef", "noise_type"]
)


@st.composite
def blocks(draw: Any) -> dict[str, Any]:
    block: dict[str, Any] = {"n_timesteps": draw(st.one_of(st.just(100), NUMBERS))}
    for key in draw(st.lists(HYPER_KEYS, max_size=6, unique=True)):
        block[key] = draw(VALUES)
    if draw(st.booleans()):
        block["replay_buffer_class"] = "GoalRelabelingReplayBuffer"
        block["replay_buffer_kwargs"] = {"relabel_fraction": draw(NUMBERS)}
    if draw(st.booleans()):
        block["env_kwargs"] = draw(
            st.dictionaries(
                st.sampled_from(["n_obstacles", "config", "max_episode_steps", "render_mode", "dt"]),
                VALUES,
                max_size=3,
            )
        )
    if draw(st.booleans()):
        block["wrapper_kwargs"] = draw(
            st.dictionaries(st.sampled_from(sorted(WRAPPER_SETTINGS)), NUMBERS, max_size=2)
        )
    return block


def check_block(block: dict[str, Any], algo: type) -> None:
    """The invariant: refused in one line, or every bounded value inside its bound."""
    try:
        parsed = parse_block(dict(block), algo, source="fuzz", manager=True)
    except ValueError as error:
        assert_one_line(error)
        return
    kwargs = {**parsed.algo_kwargs, "n_timesteps": parsed.n_timesteps, "n_envs": parsed.n_envs}
    for key, value in kwargs.items():
        if key in HYPERPARAMETERS and isinstance(value, (int, float)):
            assert HYPERPARAMETERS[key].check(value, key) == value
    for key, value in parsed.wrapper_kwargs.items():
        if key in WRAPPER_SETTINGS:
            WRAPPER_SETTINGS[key].check(value, key)
    relabel = (parsed.algo_kwargs.get("replay_buffer_kwargs") or {}).get("relabel_fraction")
    assert relabel is None or 0.0 <= relabel <= 1.0
    assert 0.0 <= parsed.noise_std <= 1e6
    for key, value in parsed.env_kwargs.items():
        assert key not in ("config",), key
        if key == "max_episode_steps":
            assert value is None or 1 <= value <= MAX_EPISODE_LENGTH
        if key == "render_mode":
            assert value in (None, "rgb_array")
        if isinstance(value, str):
            assert PLAIN_STRING.match(value)


@SHORT
@given(blocks())
def test_hostile_config_blocks_are_bounded_or_refused_in_one_line(block):
    check_block(block, DDPG)


@pytest.mark.slow
@LONG
@given(blocks(), st.sampled_from([DDPG, SAC]))
def test_hostile_config_blocks_many(block, algo):
    check_block(block, algo)


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("batch_size", 2_000_000_000),
        ("gradient_steps", 1e9),
        ("n_envs", 100_000),
        ("gamma", math.inf),
        ("gamma", 1.0),
        ("tau", -1),
        ("tau", 0),
        ("learning_rate", 0),
        ("learning_rate", 2.0),
        ("learning_starts", -5),
        ("learning_starts", 10**12),
        ("train_freq", 10**9),
        ("train_freq", [4, "fortnight"]),
        ("noise_std", math.nan),
        ("target_policy_noise", math.inf),
        ("n_timesteps", 10**13),
        ("use_sde", "yes"),
    ],
)
def test_each_hyperparameter_of_the_issue_is_refused_naming_it(key, value):
    block = {"n_timesteps": 100, key: value}
    with pytest.raises(ConfigError, match=key) as caught:
        parse_block(block, SAC, source="fuzz")
    assert_one_line(caught.value)


def test_relabel_fraction_nan_and_wrapper_settings_are_refused():
    nan = {"n_timesteps": 10, "replay_buffer_class": "GoalRelabelingReplayBuffer"}
    with pytest.raises(ConfigError, match="relabel_fraction"):
        parse_block({**nan, "replay_buffer_kwargs": {"relabel_fraction": math.nan}}, DDPG, source="f")
    for key, value in (("option_steps", 10**9), ("temperature", 0), ("option_gamma", math.inf)):
        with pytest.raises(ConfigError, match=key):
            parse_block({"n_timesteps": 10, "wrapper_kwargs": {key: value}}, DDPG, source="f", manager=True)


def test_the_bundled_configs_pass_the_schema():
    import sb3_hddpg.training.config as config

    for path in sorted(Path(config.DEFAULT_CONFIG).parent.glob("*.yml")):
        algo = {"ddpg": DDPG, "sac": SAC}.get(path.stem)
        if algo is None:
            continue
        for key in yaml.safe_load(path.read_text()):
            load_hyperparams(key, algo, path, manager=key == "manager")


@SHORT
@given(st.dictionaries(st.text(max_size=10), VALUES, max_size=4))
def test_hostile_yaml_files_are_bounded_or_refused(tmp_path, block):
    path = tmp_path / "c.yml"
    try:
        path.write_text(yaml.safe_dump({"default": {"n_timesteps": 100, **block}}))
    except (yaml.YAMLError, UnicodeEncodeError):
        return
    try:
        load_hyperparams("hddpg/SnakeGoal-v0", DDPG, path)
    except ValueError as error:
        assert_one_line(error)


# ------------------------------------------------------------------------ env kwargs
ENV_KEYS = {
    "hddpg/SnakeReach-v0": ["n_obstacles", "n_joints", "dt", "observe", "render_mode", "reward", "substeps"],
    "mo-mountaincarcontinuous-v0": ["goal_velocity", "render_mode", "episode_steps", "bogus"],
    "breakable-bottles-v0": ["size", "prob_drop", "unbreakable_bottles", "render_mode"],
    "minecart-v0": ["config", "frame_skip", "image_observation", "render_mode"],
}


@st.composite
def env_settings(draw: Any) -> tuple[str, dict[str, Any]]:
    inner = draw(st.sampled_from(sorted(ENV_KEYS)))
    kwargs = {
        k: draw(VALUES) for k in draw(st.lists(st.sampled_from(ENV_KEYS[inner]), max_size=3, unique=True))
    }
    if inner.startswith("hddpg/"):
        return inner, kwargs
    adapter = {"env_id": draw(st.sampled_from([inner, inner, "os:Evil-v0", "../x", 7]))}
    if draw(st.booleans()):
        adapter["term_bounds"] = draw(
            st.dictionaries(
                st.sampled_from(["obj0", "fuel", "../p"]), st.lists(NUMBERS, max_size=3), max_size=2
            )
        )
    if draw(st.booleans()):
        adapter["episode_steps"] = draw(NUMBERS)
    return "hddpg/MultiObjective-v0", {**adapter, **kwargs}


def check_settings(env_id: str, kwargs: dict[str, Any]) -> None:
    try:
        checked = check_env_kwargs(env_id, kwargs, "fuzz")
    except ValueError as error:
        assert_one_line(error)
        return
    for key, value in checked.items():
        assert "config" not in key and "file" not in key
        if key in ("episode_steps", "max_episode_steps") and value is not None:
            assert 1 <= value <= MAX_EPISODE_LENGTH
        elif key == "render_mode":
            assert value in (None, "rgb_array")
        elif key == "term_bounds":
            TermNormaliser(value)  # normalisable: the same check as the env's own
        elif isinstance(value, bool) or value is None:
            pass
        elif isinstance(value, int):
            assert abs(value) <= MAX_ENV_INTEGER
        elif isinstance(value, float):
            assert math.isfinite(value) and abs(value) <= MAX_ENV_FLOAT
        elif isinstance(value, str):
            assert PLAIN_STRING.match(value) or key == "env_id"


@SHORT
@given(env_settings())
def test_hostile_env_kwargs_are_bounded_or_refused_in_one_line(setting):
    check_settings(*setting)


@pytest.mark.slow
@LONG
@given(env_settings())
def test_hostile_env_kwargs_many(setting):
    check_settings(*setting)


@pytest.mark.parametrize(
    ("env_id", "kwargs", "named"),
    [
        ("hddpg/MultiObjective-v0", {"env_id": "minecart-v0", "config": "/dev/zero"}, "config"),
        ("hddpg/MultiObjective-v0", {"env_id": "minecart-v0", "config": "mine.json"}, "config"),
        ("hddpg/MultiObjective-v0", {"env_id": "breakable-bottles-v0", "size": 1e10}, "size"),
        ("hddpg/MultiObjective-v0", {"env_id": "breakable-bottles-v0", "size": "5"}, "size"),
        (
            "hddpg/MultiObjective-v0",
            {"env_id": "mo-mountaincarcontinuous-v0", "episode_steps": 10**12},
            "episode_steps",
        ),
        ("hddpg/MultiObjective-v0", {"env_id": "mo-mountaincarcontinuous-v0", "bogus": 1}, "goal_velocity"),
        ("hddpg/MultiObjective-v0", {"env_id": "os:Evil-v0"}, "env_id"),
        ("hddpg/MultiObjective-v0", {"size": 3}, "env_id"),
        ("hddpg/SnakeReach-v0", {"n_obstacles": 1e7}, "n_obstacles"),
        ("hddpg/SnakeReach-v0", {"render_mode": "human"}, "render_mode"),
        ("hddpg/SnakeReach-v0", {"observe": ["/etc/passwd"]}, "observe"),
        (
            "hddpg/MultiObjective-v0",
            {"env_id": "mo-mountaincarcontinuous-v0", "term_bounds": {"fuel": [5e-324, 1e-323]}},
            "term_bounds",
        ),
    ],
)
def test_each_env_setting_of_the_issue_is_refused_naming_it(env_id, kwargs, named):
    with pytest.raises(ValueError, match=named) as caught:
        check_env_kwargs(env_id, kwargs, "file")
    assert_one_line(caught.value)


def test_a_config_blocks_env_kwargs_are_checked_against_the_env():
    assert check_make_kwargs("hddpg/SnakeGoal-v0", {"n_obstacles": 4, "max_episode_steps": 50}, "b") == {
        "n_obstacles": 4,
        "max_episode_steps": 50,
    }
    with pytest.raises(ValueError, match="max_episode_steps"):
        check_make_kwargs("hddpg/SnakeGoal-v0", {"max_episode_steps": 1e12}, "b")
    with pytest.raises(ValueError, match="not a parameter"):
        check_make_kwargs("hddpg/SnakeGoal-v0", {"xml": 1}, "b")


def test_gymnasiums_own_ids_are_adaptable_by_default():
    ok = check_env_kwargs("hddpg/InfoTerms-v0", {"env_id": "Pendulum-v1", "g": 9.8, "terms": ["a"]}, "f")
    assert ok["env_id"] == "Pendulum-v1"
    with pytest.raises(ValueError, match="not a parameter"):
        check_env_kwargs("hddpg/InfoTerms-v0", {"env_id": "Pendulum-v1", "gravity": 9.8}, "f")


# ------------------------------------------------------------------------ term specs and bounds
TERM_TEXT = st.one_of(
    st.text(max_size=40),
    st.lists(
        st.tuples(st.sampled_from(["time", "fuel", "x", "é", ""]), NUMBERS, NUMBERS),
        min_size=1,
        max_size=4,
    ).map(lambda parts: ",".join(f"{n}={lo!r}:{hi!r}" for n, lo, hi in parts)),
)


def check_term_bounds(text: str) -> None:
    try:
        bounds = parse_term_bounds(text)
    except ValueError as error:
        assert_one_line(error)
        return
    normaliser = TermNormaliser(bounds)
    for term, (low, high) in bounds.items():
        assert math.isfinite(low) and math.isfinite(high) and low < high
        for value in (low, high, (low + high) / 2):
            normalised = normaliser({term: value})[term]
            assert math.isfinite(normalised) and -1e-9 <= normalised <= 1 + 1e-9


@SHORT
@given(TERM_TEXT)
def test_hostile_term_bounds_normalise_finitely_or_are_refused(text):
    check_term_bounds(text)


@pytest.mark.slow
@LONG
@given(TERM_TEXT)
def test_hostile_term_bounds_many(text):
    check_term_bounds(text)


@SHORT
@given(st.floats(allow_nan=True, allow_infinity=True), st.floats(allow_nan=True, allow_infinity=True))
def test_check_bounds_accepts_only_normalisable_pairs(low, high):
    try:
        (pair,) = check_bounds({"t": (low, high)}).values()
    except ValueError as error:
        assert_one_line(error)
        return
    scale = 1.0 / (pair[1] - pair[0])
    assert math.isfinite(scale) and scale > 0


def test_a_term_bounded_twice_is_refused():
    with pytest.raises(ValueError, match="'time' twice"):
        parse_term_bounds("time=-1:0,time=-3:3")


# ------------------------------------------------------------------------ JSON and resume
def test_nan_never_reaches_a_json_file(tmp_path):
    with pytest.raises(NotFiniteError, match=r"summary.mean_reward") as caught:
        atomic_write_json(tmp_path / "r.json", {"summary": {"mean_reward": math.nan}})
    assert_one_line(caught.value)
    assert not (tmp_path / "r.json").exists()
    with pytest.raises(NotFiniteError, match=r"episodes\[1\]"):
        atomic_write_json(tmp_path / "r.json", {"episodes": [1.0, -math.inf]})


@pytest.mark.parametrize(
    ("now", "named"),
    [
        ({"env_id": "x", "episode_steps": 500}, "episode_steps was 30 in the run, now 500"),
        ({"env_id": "x", "episode_steps": 30, "terms": ["b", "a"]}, "terms"),
        ({"env_id": "x", "episode_steps": 30, "term_bounds": {"a": [0, 1]}}, "term_bounds"),
        ({"env_id": "y", "episode_steps": 30}, "env_id"),
    ],
)
def test_resume_names_the_changed_setting(now, named):
    stored = {"env_id": "hddpg/MultiObjective-v0", "env_kwargs": {"env_id": "x", "episode_steps": 30}}
    check_resumed_env(stored, "hddpg/MultiObjective-v0", {"env_id": "x", "episode_steps": 30})
    with pytest.raises(ResumeMismatch, match=named) as caught:
        check_resumed_env(stored, "hddpg/MultiObjective-v0", now)
    assert_one_line(caught.value)
    with pytest.raises(ResumeMismatch, match="env was"):
        check_resumed_env(stored, "hddpg/SnakeReach-v0", {})


# ------------------------------------------------------------------------ through the CLI
HOSTILE_BLOCKS = {
    "gamma_inf": "gamma: .inf",
    "batch_huge": "batch_size: 2000000000",
    "gradient_steps": "gradient_steps: 1.0e9",
    "n_envs": "n_envs: 100000",
    "tau_negative": "tau: -1",
    "learning_starts": "learning_starts: -5",
    "relabel_nan": "replay_buffer_class: GoalRelabelingReplayBuffer\n  replay_buffer_kwargs: {relabel_fraction: .nan}",
    "config_path": "env_kwargs: {config: /dev/zero}",
    "n_obstacles": "env_kwargs: {n_obstacles: 1.0e7}",
    "episode_length": "env_kwargs: {max_episode_steps: 1.0e12}",
    "render_human": "env_kwargs: {render_mode: human}",
    "evil_id": "env_kwargs: {env_id: 'os:Evil-v0'}",
}


def test_hostile_values_through_the_cli_exit_2_with_one_line(tmp_path):
    from tests.cli_batch import run_batch

    commands, names = [], []
    for name, line in HOSTILE_BLOCKS.items():
        path = tmp_path / f"{name}.yml"
        path.write_text(TINY_CONFIG.replace("manager:", f"  {line}\nmanager:"))  # later keys win
        commands.append(
            ["train-workers", "--workers", "goal", "--config", str(path), "--out", str(tmp_path / name)]
        )
        names.append(name)
    env = ["evaluate", "random", "--episodes", "1", "--env", "mo-mountaincarcontinuous-v0"]
    for name, extra in (
        ("bounds_underflow", ["--terms", "time,fuel", "--term-bounds", "fuel=5e-324:1e-323"]),
        ("bounds_twice", ["--terms", "time,fuel", "--term-bounds", "time=-1:0,time=-3:3"]),
        ("bounds_overflow", ["--terms", "time,fuel", "--term-bounds", "fuel=-1e308:1e308"]),
        ("episode_steps", ["--episode-steps", "1000000000000"]),
    ):
        commands.append([*env, *extra])
        names.append(name)
    commands.append(["evaluate", "random", "--episodes", "1", "--env", "hddpg/MultiObjective-v0"])
    names.append("adapter_alone")
    for name, result in zip(names, run_batch(commands)):
        lines = [line for line in result.stderr.splitlines() if line.strip()]
        assert result.returncode == 2, (name, result.returncode, result.stderr[-2000:])
        assert len(lines) == 1 and "Traceback" not in result.stderr, (name, result.stderr[-2000:])
        assert not (tmp_path / name).exists() or not any((tmp_path / name).rglob("*.zip")), name


def test_evaluate_random_on_an_mo_env_writes_finite_json(tmp_path):
    from tests.cli_batch import run_batch

    out = tmp_path / "r.json"
    (done,) = run_batch(
        [
            [
                *("evaluate", "random", "--env", "mo-mountaincarcontinuous-v0", "--episodes", "1"),
                *("--episode-steps", "20", "--json", str(out)),
            ]
        ]
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "NaN" not in out.read_text() and "Infinity" not in out.read_text()


# ------------------------------------------------------------------------ run options
@SHORT
@given(st.dictionaries(st.sampled_from(sorted(RUN_SETTINGS)), NUMBERS, max_size=3))
def test_hostile_run_options_are_bounded_or_refused(changes):
    from sb3_hddpg.training import RunOptions

    try:
        run = RunOptions(**changes)
    except ValueError as error:
        assert_one_line(error)
        return
    for name, bound in RUN_SETTINGS.items():
        value = getattr(run, name)
        assert value is None or bound.check(value, name) == value


def test_resume_with_another_episode_length_through_the_cli(tmp_path):
    from tests.cli_batch import run_batch

    env = ["--env", "mo-mountaincarcontinuous-v0", "--terms", "time,fuel"]
    tiny = [
        "--config",
        str(tmp_path / "tiny.yml"),
        "--timesteps",
        "60",
        "--eval-freq",
        "0",
        "--out",
        str(tmp_path / "r"),
    ]
    (tmp_path / "tiny.yml").write_text(TINY_CONFIG)
    first, resumed = run_batch(
        [
            ["train-workers", *env, "--episode-steps", "30", "--workers", "time", *tiny],
            ["train-workers", *env, "--episode-steps", "500", "--resume", *tiny],
        ]
    )
    assert first.returncode == 0, first.stderr[-2000:]
    lines = [line for line in resumed.stderr.splitlines() if line.strip()]
    assert resumed.returncode != 0 and len(lines) == 1, resumed.stderr[-2000:]
    assert "--resume: episode_steps was 30 in the run, now 500" in lines[0]
    assert not (tmp_path / "r" / "workers" / "fuel.zip").exists()
