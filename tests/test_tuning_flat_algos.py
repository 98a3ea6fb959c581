"""``tune --level flat --algo td3|sac``: the same tuning effort for every flat baseline."""

from __future__ import annotations

import math
from pathlib import Path

import optuna
import pytest
import yaml
from stable_baselines3 import DDPG, SAC, TD3

from hddpg_zoo import tuning
from hddpg_zoo.hyperparams_opt import (
    base_params,
    check_fixed_params,
    sample_sac_params,
    sampler_for,
    search_space,
)
from hddpg_zoo.study_storage import default_storage_url
from hddpg_zoo.tuning import StudySettings, TuningTarget
from sb3_hddpg.training.config import (
    default_config,
    load_config_file,
    load_hyperparams,
    parse_block,
    select_block,
)
from sb3_hddpg.training.sbx_models import sbx_kwargs
from tests.cli_batch import run_batch

REPO = Path(__file__).resolve().parent.parent
FIXED = {"net_arch": "small", "buffer_size": 10_000, "batch_size": 32}
SHARED = ("gamma", "learning_rate", "batch_size", "buffer_size", "tau", "train_freq", "net_arch")


def test_every_flat_algorithm_searches_the_shared_parameters_alike():
    ddpg, td3, sac = (search_space("flat", algo) for algo in ("ddpg", "td3", "sac"))
    assert td3 == ddpg  # TD3 gets DDPG's space (rl_zoo3 does the same)
    for name in SHARED:
        assert sac[name] == ddpg[name], name
    assert "ent_coef_init" in sac and "noise_type" not in sac  # SAC explores by its own entropy
    assert "log_std_init" not in sac  # read only with gSDE: a dimension that would change nothing
    with pytest.raises(ValueError, match="Unknown parameter 'noise_std' for level 'flat' \\(sac\\)"):
        check_fixed_params("flat", {"noise_std": 0.2}, "sac")
    with pytest.raises(ValueError, match="trains nothing"):
        sampler_for("ham", "sac")
    assert sampler_for("worker", "sac") is sampler_for("flat", "sac")  # a worker takes its record's sampler
    # A manager of another algorithm: that algorithm's space plus the same selection parameters.
    manager_sac, manager_ddpg = search_space("manager", "sac"), search_space("manager", "ddpg")
    wrapper = {"temperature", "floor", "selection", "option_steps"}
    assert set(manager_sac) == set(sac) | wrapper and set(manager_ddpg) == set(ddpg) | wrapper
    with pytest.raises(ValueError, match=r"Expected an algorithm among .*, got 'a2c'"):
        TuningTarget(level="flat", algo="a2c")


#: Every block a study tunes: (level, algorithm, bundled config block).
TUNED_BLOCKS = [
    ("worker", "ddpg", "hddpg/SnakeGoal-v0"),
    ("worker", "ddpg", "hddpg/SnakeAvoid-v0"),
    ("manager", "ddpg", "manager"),
    ("manager", "sac", "manager"),
    ("manager", "td3", "manager"),
    ("flat", "ddpg", "hddpg/SnakeReach-v0"),
    ("flat", "td3", "hddpg/SnakeReach-v0"),
    ("flat", "sac", "hddpg/SnakeReach-v0"),
]


@pytest.mark.parametrize(("level", "algo", "key"), TUNED_BLOCKS)
def test_every_bundled_block_is_a_point_of_its_search_space(level, algo, key):
    # Equal effort: each study's first trial is its method's bundled config, which the space must hold
    # whole, or that method would start its search from somewhere else than the others.
    block = select_block(load_config_file(default_config(algo)), key)
    params, outside = base_params(level, block, algo)
    assert outside == []
    replayed = sampler_for(level, algo)(optuna.trial.FixedTrial(params))
    cls = {"ddpg": DDPG, "td3": TD3, "sac": SAC}[algo]
    original = parse_block(dict(block), cls, source=key, manager=level == "manager")
    rebuilt = parse_block(tuning.merge_block(block, replayed), cls, source=key, manager=level == "manager")
    assert rebuilt.algo_kwargs == original.algo_kwargs
    assert (rebuilt.noise_type, rebuilt.noise_std) == (original.noise_type, original.noise_std)
    assert rebuilt.wrapper_kwargs == original.wrapper_kwargs


def test_base_params_leave_out_what_the_space_cannot_express():
    block = {"gamma": 0.5, "train_freq": 4, "gradient_steps": 1, "noise_type": None, "noise_std": 0.2}
    params, outside = base_params("worker", block)
    assert params == {"train_freq": 4, "noise_type": "none"}  # no noise: no noise_std to sample
    assert {"gamma", "gradient_steps", "learning_rate", "net_arch"} <= set(outside)
    assert "noise_std" not in outside
    assert base_params("ham", {}, ham_threshold=5.5) == ({"threshold": 5.5}, [])


def test_a_replayed_sac_trial_is_a_block_sac_accepts():
    params = {
        **FIXED,
        "gamma": 0.98,
        "learning_rate": 3e-4,
        "tau": 0.02,
        "train_freq": 4,
        "ent_coef_init": 0.1,
    }
    changes = sample_sac_params(optuna.trial.FixedTrial(params))
    block = dict(yaml.safe_load((REPO / "zoo_configs" / "sac.yml").read_text())["default"], **changes)
    parsed = parse_block(block, SAC, source="replayed")
    assert parsed.algo_kwargs["policy_kwargs"] == {"net_arch": [64, 64]}
    assert parsed.algo_kwargs["gradient_steps"] == 4 and parsed.algo_kwargs["ent_coef"] == "auto_0.1"
    # SB3 and SBX both build it: the entropy coefficient starts at 0.1, as the trial said.
    model = SAC("MlpPolicy", "Pendulum-v1", **{**parsed.algo_kwargs, "buffer_size": 1_000})
    assert float(model.log_ent_coef.exp().item()) == pytest.approx(0.1)
    sbx = pytest.importorskip("sbx")
    jax_model = sbx.SAC(
        "MlpPolicy", "Pendulum-v1", **sbx_kwargs("sac", {**parsed.algo_kwargs, "buffer_size": 1_000})
    )
    assert float(jax_model.ent_coef.apply({"params": jax_model.ent_coef_state.params})) == pytest.approx(0.1)


@pytest.mark.slow  # two trainings per algorithm: 40-120 s each on a shared 2-core machine
@pytest.mark.parametrize(
    ("algo", "cls", "backend"), [("td3", TD3, "sb3"), ("sac", SAC, "sb3"), ("sac", SAC, "sbx")]
)
def test_two_tiny_trials_and_a_saved_config(algo, cls, backend, tmp_path):
    if backend == "sbx":
        pytest.importorskip("sbx")
    config = yaml.safe_load((REPO / "zoo_configs" / f"{algo}.yml").read_text())
    for block in config.values():
        block.update(learning_starts=50, n_timesteps=200, policy_kwargs="dict(net_arch=[16])")
    base = tmp_path / f"{algo}.yml"
    base.write_text(yaml.safe_dump(config, sort_keys=False))
    target = TuningTarget(
        level="flat",
        algo=algo,
        config=str(base),
        timesteps=200,
        n_evaluations=2,
        eval_episodes=1,
        backend=backend,
    )
    assert target.name == f"flat-{algo}" and target.describe()["algo"] == algo
    settings = StudySettings(
        storage=default_storage_url(tmp_path), study_name=target.name, n_trials=2, pruner="none", seed=0,
        fixed_params={**FIXED, "train_freq": 4},  # 200 steps in whole updates: exactly two evaluations
    )  # fmt: skip
    study = tuning.tune(target, settings, tmp_path)
    assert [t.state for t in study.trials] == [optuna.trial.TrialState.COMPLETE] * 2
    assert all(math.isfinite(t.value) and len(t.intermediate_values) == 2 for t in study.trials)
    assert tuning.best_block(study, target) == study.best_trial.user_attrs["config_block"]
    saved = tuning.save_best_config(study, target, tmp_path / "best.yml")
    hyperparams = load_hyperparams("hddpg/SnakeReach-v0", cls, saved)
    assert hyperparams.algo_kwargs["learning_rate"] == study.best_params["learning_rate"]


def test_algo_usage_errors_through_the_cli(tmp_path):
    wrong_level, unknown = run_batch(
        [
            [
                "tune",
                "--level",
                "ham",
                "--workers",
                str(tmp_path),
                "--algo",
                "sac",
                "--out",
                str(tmp_path / "a"),
            ],
            ["tune", "--level", "flat", "--algo", "a2c", "--out", str(tmp_path / "b")],
        ]
    )
    assert wrong_level.returncode == 2 and "levels worker, flat, manager" in wrong_level.stderr
    assert unknown.returncode == 2 and "'a2c'" in unknown.stderr
    assert "Traceback" not in wrong_level.stderr + unknown.stderr


def test_a_sac_manager_study_trains_sac_managers_and_saves_their_block(tmp_path):
    from sb3_hddpg.training.workers import train_workers

    config = yaml.safe_load((REPO / "sb3_hddpg" / "zoo_configs" / "sac.yml").read_text())
    for block in config.values():
        block.update(learning_starts=50, n_timesteps=200)
    path = tmp_path / "sac.yml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    workers = tmp_path / "workers"
    train_workers(workers, timesteps=150, eval_freq=0, eval_episodes=1)
    target = TuningTarget(
        level="manager",
        algo="sac",
        workers_dir=str(workers),
        config=str(path),
        timesteps=200,
        n_evaluations=2,
        eval_episodes=1,
    )
    assert target.name == "manager-sac" and target.describe()["algo"] == "sac"
    settings = StudySettings(
        storage=default_storage_url(tmp_path), study_name=target.name, n_trials=1, pruner="none", seed=0
    )
    study = tuning.tune(target, settings, tmp_path)
    trial = study.trials[0]
    assert trial.user_attrs["base_config"] is True and math.isfinite(trial.value)
    base = config["manager"]
    # As many decisions as the SAC manager block's options make 200 env steps.
    assert trial.user_attrs["decisions"] == 200 // base["wrapper_kwargs"]["option_steps"]
    assert "ent_coef" in trial.user_attrs["config_block"] and "noise_type" not in trial.params
    saved = tmp_path / "best.yml"
    tuning.save_best_config(study, target, saved)
    manager = load_hyperparams("manager", SAC, saved, manager=True)
    assert (
        manager.wrapper_kwargs == base["wrapper_kwargs"]
        and manager.algo_kwargs["ent_coef"] == base["ent_coef"]
    )
