"""
The SBX (JAX) training backend: exported models are plain SB3 with the JAX policy's actions, every training
command and API takes ``--backend``/``backend=``, XLA keeps to its thread budget, and nothing recompiles
per model or per ``learn`` call. Tiny budgets; skipped where SBX is not installed (``pip install
"sb3-hddpg[fast]"``), except the checks of the errors a user without it sees.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import sb3_hddpg  # noqa: F401  (registers the env ids)
from sb3_hddpg.training.backends import BACKENDS, BackendError, check_backend, sbx_installed
from tests.cli_batch import ROOT, run_batch
from tests.helpers import TINY_CONFIG

needs_sbx = pytest.mark.skipif(
    not sbx_installed(), reason='needs the SBX backend: pip install "sb3-hddpg[fast]"'
)

#: The same block asking for SBX through the config key instead of ``--backend``.
SBX_CONFIG = TINY_CONFIG.replace("  n_timesteps: 150\n", "  n_timesteps: 150\n  backend: sbx\n")
FAST = ("--no-progress", "--eval-freq", "100", "--eval-episodes", "1")


def one_error_line(result: subprocess.CompletedProcess) -> str:
    shown = f"exit {result.returncode}\nstdout: {result.stdout[-1500:]}\nstderr: {result.stderr[-3000:]}"
    assert "Traceback" not in result.stderr, shown
    assert result.returncode == 2, shown
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), shown
    return lines[0]


def test_backend_names():
    assert BACKENDS == ("sb3", "sbx")
    assert check_backend(" SB3 ") == "sb3"
    with pytest.raises(BackendError, match=r"Unknown backend 'torch'; choose from \['sb3', 'sbx'\]"):
        check_backend("torch")


#: One command line per training command, with a backend value to fill in.
def _commands(tmp: Path, backend: str) -> list[list[str]]:
    config = tmp / "tiny.yml"
    config.write_text(TINY_CONFIG)
    return [
        ["train-workers", "--backend", backend, "--config", str(config), "--out", str(tmp / "w")],
        ["train-manager", "--backend", backend, "--workers", str(tmp), "--out", str(tmp / "m")],
        ["train-flat", "--backend", backend, "--config", str(config), "--out", str(tmp / "f")],
        ["benchmark", "--backend", backend, "--out", str(tmp / "b")],
        ["tune", "--level", "flat", "--backend", backend, "--out", str(tmp / "t")],
        ["quickstart", "--backend", backend, "--budget", "tiny", "--out", str(tmp / "q")],
    ]


def test_unknown_backend_is_a_usage_error(tmp_path):
    for result in run_batch(_commands(tmp_path, "jax")):
        line = one_error_line(result)
        assert "'jax'" in line and "sbx" in line and "--backend" in line
    assert not any(tmp_path.glob("[wmfbtq]")), "nothing may be created on bad input"


def test_missing_sbx_is_one_line_naming_the_extra(tmp_path):
    """Where SBX is not installed, asking for it says how to install it (sys.modules[name] = None is how
    Python itself marks a module as not importable)."""
    commands = [*_commands(tmp_path, "sbx"), ["train-flat", "--config", str(tmp_path / "sbx.yml")]]
    (tmp_path / "sbx.yml").write_text(SBX_CONFIG)
    script = textwrap.dedent(
        f"""
        import json, sys
        sys.modules["sbx"] = None
        from tests.cli_batch import run_one
        print(json.dumps([run_one(argv) for argv in {json.dumps(commands)}]))
        """
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "200"}
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=env, cwd=ROOT, timeout=600
    )
    assert done.returncode == 0, done.stderr[-3000:]
    for argv, r in zip(commands, json.loads(done.stdout.splitlines()[-1])):
        line = one_error_line(subprocess.CompletedProcess(argv, r["code"], r["stdout"], r["stderr"]))
        assert 'pip install "sb3-hddpg[fast]"' in line, line


def test_every_training_command_documents_backend(tmp_path):
    for result in run_batch([[argv[0], "--help"] for argv in _commands(tmp_path, "sbx")]):
        assert result.returncode == 0, result.stderr
        assert "--backend" in result.stdout and "sb3-hddpg[fast]" in result.stdout, result.stdout


# ------------------------------------------------------------------------------------------ with SBX
def _observations(n: int = 256) -> np.ndarray:
    """Real observations of the goal worker's env, from random play."""
    env = gym.make("hddpg/SnakeGoal-v0")
    obs, _ = env.reset(seed=5)
    out = []
    rng = np.random.default_rng(0)
    for _ in range(n):
        out.append(obs)
        obs, _, terminated, truncated, _ = env.step(rng.uniform(-1, 1, env.action_space.shape))
        if terminated or truncated:
            obs, _ = env.reset()
    env.close()
    return np.asarray(out, dtype=np.float32)


def _perturbed(model, scale: float = 0.3):
    """``model`` with every weight moved by random noise, targets separately: exporting must map each tree
    (actor, target actor, critics, target critics) to its own SB3 module. Cheaper than training, which
    would compile the update of every algorithm (minutes on a loaded CI machine; the CLI tests train)."""
    import jax

    rng = np.random.default_rng(3)

    def moved(tree):
        return jax.tree_util.tree_map(
            lambda x: x + scale * rng.standard_normal(np.shape(x)).astype(np.float32), tree
        )

    policy = model.policy
    policy.actor_state = policy.actor_state.replace(params=moved(policy.actor_state.params))
    if hasattr(policy.actor_state, "target_params"):
        policy.actor_state = policy.actor_state.replace(target_params=moved(policy.actor_state.target_params))
    policy.qf_state = policy.qf_state.replace(
        params=moved(policy.qf_state.params), target_params=moved(policy.qf_state.target_params)
    )
    if hasattr(model, "ent_coef_state"):
        model.ent_coef_state = model.ent_coef_state.replace(params=moved(model.ent_coef_state.params))
    model.num_timesteps = 150
    return model


@pytest.fixture(scope="module")
def trained():
    """One SBX model per algorithm on the goal worker's env, weights moved off their initial values, with
    its SB3 export."""
    if not sbx_installed():
        pytest.skip("needs SBX")
    from stable_baselines3.common.env_util import make_vec_env

    from sb3_hddpg.training.backends import configure_jax_threads
    from sb3_hddpg.training.models import make_model, to_sb3

    configure_jax_threads(1)
    models = {}
    for algo in ("ddpg", "td3", "sac"):
        env = make_vec_env("hddpg/SnakeGoal-v0", n_envs=1, seed=0)
        kwargs = dict(
            learning_starts=50, batch_size=16, buffer_size=1000, policy_kwargs=dict(net_arch=[16, 16])
        )
        model = _perturbed(make_model(algo, "sbx", env, kwargs, seed=1))
        models[algo] = (model, to_sb3(model), kwargs)
    return models


@needs_sbx
@pytest.mark.parametrize("algo", ["ddpg", "td3"])
def test_a_model_under_the_action_penalty_exports_as_its_algorithm(trained, algo):
    # A tuning trial exports the model it trained as is, still under the penalty's subclass (a trial once
    # failed on it: "Cannot export DDPG to SB3").
    import sbx
    from stable_baselines3 import DDPG, TD3

    from sb3_hddpg.callbacks import apply_action_l2
    from sb3_hddpg.training.models import to_sb3

    model, exported, _ = trained[algo]
    apply_action_l2(model, 0.5)
    try:
        assert type(model) is not getattr(sbx, algo.upper())  # the penalty's subclass, named as its base
        penalised = to_sb3(model)
    finally:
        apply_action_l2(model, 0.0)
    assert type(penalised) is {"ddpg": DDPG, "td3": TD3}[algo]
    obs = _observations()
    expected = exported.predict(obs, deterministic=True)[0]
    assert np.abs(penalised.predict(obs, deterministic=True)[0] - expected).max() <= 1e-6


@needs_sbx
@pytest.mark.parametrize("algo", ["ddpg", "td3", "sac"])
def test_a_learning_rate_schedule_reaches_the_jax_optimisers(algo, tmp_path):
    # SBX's own TD3 and DDPG build their optimisers at the schedule's first value and keep it there; on
    # our backend actor and critic follow it as on SB3, and the export carries the schedule.
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.env_util import make_vec_env

    from sb3_hddpg.training.config_values import parse_schedule
    from sb3_hddpg.training.models import load_native, make_model, to_sb3

    class RecordRates(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.rates: list[tuple[float, float, float]] = []

        def _on_rollout_start(self) -> None:
            policy = self.model.policy
            actor, critic = (
                state.opt_state.hyperparams["learning_rate"]
                for state in (policy.actor_state, policy.qf_state)
            )
            self.rates.append((self.model._current_progress_remaining, float(actor), float(critic)))

        def _on_step(self) -> bool:
            return True

    env = make_vec_env("hddpg/SnakeGoal-v0", n_envs=1, seed=0)
    kwargs = dict(
        learning_rate=parse_schedule("lin_1e-3", "learning_rate"),
        learning_starts=50,
        batch_size=16,
        buffer_size=1000,
        train_freq=10,
        gradient_steps=10,
        policy_kwargs=dict(net_arch=[16, 16]),
    )
    model = make_model(algo, "sbx", env, kwargs, seed=1)
    recorder = RecordRates()
    model.learn(200, callback=recorder)
    trained = [(progress, actor, critic) for progress, actor, critic in recorder.rates if progress < 0.7]
    assert len(trained) >= 10
    for progress, actor, critic in trained:
        assert actor == pytest.approx(1e-3 * progress, abs=1e-9) and critic == pytest.approx(actor)
    assert to_sb3(model).lr_schedule(0.5) == pytest.approx(5e-4)
    # A checkpoint or best model reloaded from SBX's own file (as every training command exports) too.
    model.save(tmp_path / "model.zip")
    reloaded = load_native(algo, "sbx", tmp_path / "model.zip")
    # A resumed run keeps an optimiser whose rate the schedule can still set.
    assert hasattr(reloaded.policy.actor_state.opt_state, "hyperparams")
    assert to_sb3(reloaded).lr_schedule(0.5) == pytest.approx(5e-4)


@needs_sbx
@pytest.mark.parametrize("algo", ["ddpg", "td3", "sac"])
def test_export_acts_like_the_jax_policy(trained, algo, tmp_path):
    from stable_baselines3 import DDPG, SAC, TD3

    from sb3_hddpg.artifacts.safe_load import load_model
    from sb3_hddpg.artifacts.spec import model_spec

    model, exported, _ = trained[algo]
    sb3_class = {"ddpg": DDPG, "td3": TD3, "sac": SAC}[algo]
    assert type(exported) is sb3_class
    obs = _observations()
    jax_actions = model.predict(obs, deterministic=True)[0]
    assert np.abs(jax_actions).max() > 0.01  # the policy acts, so the comparison means something
    assert np.abs(exported.predict(obs, deterministic=True)[0] - jax_actions).max() <= 1e-5
    # The critics were copied too (the twin critics of TD3 and SAC in their order).
    import torch

    actions = (
        np.random.default_rng(2).uniform(-1, 1, (len(obs), *model.action_space.shape)).astype(np.float32)
    )
    q_jax = np.asarray(model.policy.qf_state.apply_fn(model.policy.qf_state.params, obs, actions))
    with torch.no_grad():
        q_torch = np.stack(
            [q.numpy() for q in exported.critic(torch.as_tensor(obs), torch.as_tensor(actions))]
        )
    assert q_jax.shape == q_torch.shape and np.abs(q_jax - q_torch).max() <= 1e-4
    # Saved, it opens with plain SB3 and with the project's safe loader, acting the same.
    path = tmp_path / f"{algo}.zip"
    exported.save(path)
    for loaded in (sb3_class.load(path, device="cpu"), load_model(path, spec=model_spec(exported))):
        assert np.abs(loaded.predict(obs, deterministic=True)[0] - jax_actions).max() <= 1e-5
    assert exported.num_timesteps == model.num_timesteps == 150
    if algo != "sac":  # the target actor went to actor_target, not to actor
        target = np.asarray(model.policy.actor_state.apply_fn(model.policy.actor_state.target_params, obs))
        with torch.no_grad():
            exported_target = exported.actor_target(torch.as_tensor(obs)).numpy()
        assert np.abs(target - exported_target).max() <= 1e-5
        assert np.abs(target - exported.actor(torch.as_tensor(obs)).detach().numpy()).max() > 1e-2
    with torch.no_grad():
        q_target = np.stack(
            [q.numpy() for q in exported.critic_target(torch.as_tensor(obs), torch.as_tensor(actions))]
        )
    q_target_jax = np.asarray(
        model.policy.qf_state.apply_fn(model.policy.qf_state.target_params, obs, actions)
    )
    assert np.abs(q_target - q_target_jax).max() <= 1e-4
    if algo == "sac":
        log_ent_coef = float(np.asarray(model.ent_coef_state.params["log_ent_coef"]))
        assert abs(exported.log_ent_coef.item() - log_ent_coef) <= 1e-6 and log_ent_coef != 0.0


@needs_sbx
@pytest.mark.parametrize("algo", ["ddpg", "td3", "sac"])
def test_sbx_starts_from_sb3s_initial_weights(trained, algo):
    """Same seed, same initial networks on both backends (flax's own initialisation would differ)."""
    from stable_baselines3.common.env_util import make_vec_env

    from sb3_hddpg.training.models import make_model

    _, _, kwargs = trained[algo]
    obs = _observations(64)
    actions = []
    for backend in ("sb3", "sbx"):
        env = make_vec_env("hddpg/SnakeGoal-v0", n_envs=1, seed=0)
        actions.append(make_model(algo, backend, env, kwargs, seed=7).predict(obs, deterministic=True)[0])
    assert np.abs(actions[0] - actions[1]).max() <= 1e-5


@needs_sbx
@pytest.mark.slow
def test_no_recompile_per_model_or_learn_call():
    """A second model of the same architecture, and a second learn call, compile nothing."""
    import jax
    from stable_baselines3.common.env_util import make_vec_env

    from sb3_hddpg.training.models import make_model

    compiled: list[str] = []

    class Counter(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if record.getMessage().startswith("Finished XLA compilation"):
                compiled.append(record.getMessage())

    handler, jax_logger = Counter(), logging.getLogger("jax")
    previous_level = jax_logger.level
    jax_logger.addHandler(handler)
    jax_logger.setLevel(logging.DEBUG)
    jax.config.update("jax_log_compiles", True)
    try:
        counts = []
        for seed in (0, 1):
            env = make_vec_env("hddpg/SnakeGoal-v0", n_envs=1, seed=seed)
            kwargs = dict(learning_starts=20, batch_size=8, buffer_size=500, policy_kwargs=dict(net_arch=[8]))
            model = make_model("ddpg", "sbx", env, kwargs, seed=seed)
            for _ in range(2):
                before = len(compiled)
                model.learn(40, reset_num_timesteps=False)
                counts.append(len(compiled) - before)
    finally:
        jax.config.update("jax_log_compiles", False)
        jax_logger.removeHandler(handler)
        jax_logger.setLevel(previous_level)
    assert counts[0] >= 1  # the first learn call compiled the update (the counter works)
    assert counts[1:] == [0, 0, 0], counts


@needs_sbx
def test_jax_keeps_to_one_thread():
    """With the default of one thread, a jitted matrix product keeps one thread busy, not XLA's whole pool."""
    script = textwrap.dedent(
        """
        import os
        from sb3_hddpg.training.backends import configure_jax_threads
        configure_jax_threads(1)
        import jax, jax.numpy as jnp

        def ticks():
            out = {}
            for tid in os.listdir("/proc/self/task"):
                fields = open(f"/proc/self/task/{tid}/stat").read().rsplit(")", 1)[1].split()
                out[tid] = int(fields[11]) + int(fields[12])
            return out

        x = jnp.ones((1200, 1200))
        f = jax.jit(lambda a: jnp.tanh(a @ a) @ a)
        f(x).block_until_ready()
        start = ticks()
        for _ in range(8):
            f(x).block_until_ready()
        end = ticks()
        busy = sorted((end[t] - start.get(t, 0) for t in end), reverse=True)
        print(busy[0], busy[1])
        """
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for name in ("PJRT_NPROC", "NPROC", "XLA_FLAGS"):
        env.pop(name, None)
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    first, second = map(int, done.stdout.split())
    assert first >= 20 and second <= max(2, first // 20), done.stdout  # (XLA's default spreads it evenly)


@needs_sbx
@pytest.mark.parametrize(
    "timesteps",
    [
        # Fewer steps than learning_starts: every part of the SBX path runs but the update is never
        # compiled, which alone takes minutes on a loaded machine.
        50,
        pytest.param(300, marks=pytest.mark.slow),
    ],
)
def test_every_training_command_trains_on_sbx_and_ships_sb3(tmp_path, timesteps):
    """train-workers, train-manager, train-flat (by option and by config key): SB3 files, SBX recorded."""
    from stable_baselines3 import DDPG, TD3

    from sb3_hddpg.hierarchy.hierarchy import Hierarchy
    from sb3_hddpg.hierarchy.loading import load_policy

    tiny, sbx_config = tmp_path / "tiny.yml", tmp_path / "sbx.yml"
    tiny.write_text(TINY_CONFIG)
    sbx_config.write_text(SBX_CONFIG)
    fast = (*FAST, "--timesteps", str(timesteps))
    results = run_batch(
        [
            ["train-workers", *fast, "--backend", "sbx", "--config", str(tiny), "--out", str(tmp_path / "w")],
            ["train-manager", *fast, "--backend", "sbx", "--config", str(tiny), "--workers", str(tmp_path / "w"),
             "--out", str(tmp_path / "m")],
            ["train-flat", *fast, "--config", str(sbx_config), "--out", str(tmp_path / "k")],
            # TD3 builds and compiles networks of its own: only in the slow (real training) variant.
            *([["train-flat", *fast, "--algo", "td3", "--backend", "sbx", "--config", str(tiny),
                "--out", str(tmp_path / "f")]] if timesteps > 100 else []),
        ]
    )  # fmt: skip
    for result in results:
        assert result.returncode == 0, result.stderr[-3000:]
    workers = json.loads((tmp_path / "w" / "workers" / "manifest.json").read_text())["workers"]
    assert {entry["backend"] for entry in workers.values()} == {"sbx"}
    for name, cls in (("goal", DDPG), ("avoid", DDPG)):  # the snake arm's default learner
        assert type(cls.load(tmp_path / "w" / "workers" / f"{name}.zip", device="cpu")) is cls
    # A bundle with an SBX-trained manager over SBX-trained workers: verified and loaded like any other.
    hierarchy = Hierarchy.load(tmp_path / "m" / "hierarchy.zip")
    assert type(hierarchy.manager) is DDPG and hierarchy.metadata["backend"] == "sbx"
    assert {name: type(worker) for name, worker in hierarchy.workers.items()} == {"goal": DDPG, "avoid": DDPG}
    env = gym.make("hddpg/SnakeReach-v0")
    obs, _ = env.reset(seed=0)
    assert env.action_space.contains(hierarchy.predict(obs, deterministic=True)[0].astype(np.float32))
    if timesteps > 100:
        flat = json.loads((tmp_path / "f" / "flat" / "manifest.json").read_text())["models"]["td3"]
        assert flat["backend"] == "sbx" and flat["spec"]["algorithm"] == "TD3"
        assert type(load_policy(tmp_path / "f" / "flat" / "td3.zip").policy) is TD3
    by_key = json.loads((tmp_path / "k" / "flat" / "manifest.json").read_text())["models"]["ddpg"]
    assert by_key["backend"] == "sbx"


@needs_sbx
def test_api_backend_selection(tmp_path):
    """The library functions take ``backend=`` (or the config key) too; resuming with the other backend is
    refused."""
    from hddpg_zoo.benchmark import BenchmarkSettings
    from hddpg_zoo.tuning import TuningTarget
    from sb3_hddpg.training.flat import train_flat

    config = tmp_path / "tiny.yml"
    config.write_text(TINY_CONFIG)
    # Fewer steps than learning_starts: the SBX path end to end, without compiling the update.
    result = train_flat(tmp_path, config=config, timesteps=60, eval_freq=0, eval_episodes=1, backend="sbx")
    manifest, outcome = result.manifest, result.outcome
    assert outcome is not None and outcome.backend == "sbx"
    assert manifest["models"]["ddpg"]["backend"] == "sbx"
    assert type(outcome.model).__module__.startswith("stable_baselines3")
    by_key = tmp_path / "sbx.yml"
    by_key.write_text(SBX_CONFIG)
    manifest = train_flat(tmp_path / "k", config=by_key, timesteps=60, eval_freq=0, eval_episodes=1).manifest
    assert manifest["models"]["ddpg"]["backend"] == "sbx"
    with pytest.raises(ValueError, match="trained with backend 'sbx'; resume it with --backend sbx"):
        train_flat(tmp_path, config=config, timesteps=90, eval_freq=0, resume=True, backend="sb3")
    with pytest.raises(BackendError, match="not 'ppo'"):
        BenchmarkSettings(methods=["ppo"], backend="sbx")
    assert BenchmarkSettings(methods=["ddpg"], backend="SBX").backend == "sbx"
    assert TuningTarget(level="flat", backend="sbx").describe()["backend"] == "sbx"
    assert "backend" not in TuningTarget(level="flat").describe()  # older studies stay resumable


@needs_sbx
@pytest.mark.slow
def test_benchmark_tune_quickstart_on_sbx(tmp_path):
    """The three composite commands, end to end on SBX at tiny budgets (a few minutes: slow)."""
    results = run_batch(
        [
            ["benchmark", "--backend", "sbx", "--methods", "ddpg", "--seeds", "1", "--timesteps", "150",
             "--worker-timesteps", "150", "--flat-timesteps", "150", "--eval-episodes", "1", "--test-episodes", "1",
             "--out", str(tmp_path / "b")],
            ["tune", "--level", "flat", "--backend", "sbx", "--n-trials", "1", "--timesteps", "150",
             "--n-evaluations", "1", "--eval-episodes", "1", "--out", str(tmp_path / "t")],
            ["quickstart", "--backend", "sbx", "--budget", "tiny", "--processes", "1", "--out", str(tmp_path / "q")],
        ]
    )  # fmt: skip
    for result in results:
        assert result.returncode == 0, result.stderr[-3000:]
    settings = json.loads((tmp_path / "b" / "benchmark.json").read_text())["settings"]
    assert settings["backend"] == "sbx"
    flat = json.loads((tmp_path / "q" / "flat" / "manifest.json").read_text())["models"]
    assert {entry["backend"] for entry in flat.values()} == {"sbx"}
