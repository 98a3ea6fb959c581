"""
Every ``hddpg-cli`` command answers bad input with one line on stderr that names the offending value, and
a non-zero exit (2 for usage errors), never a traceback.

One table, :data:`CASES`, lists every case. The tiny artifacts they need (workers for the default env,
workers for a 4-joint arm, a hierarchy bundle, damaged copies) are built once, in-process. Every case
then runs through the CLI's entry point in a separate interpreter: all of them in one batch subprocess
(:mod:`tests.cli_batch`; starting torch once instead of 60 times keeps the file fast), and the cases
marked ``alone`` also each in their own ``python -m sb3_hddpg`` process, so that real exit codes and stderr are
checked too.

Exit codes: 2 when the command line names something unusable (a bad option value, a missing path or one
of the wrong kind, a file whose content cannot be used for what it was named for, a refused output
folder); 1 for a failure while working; 130 for an interruption.
"""

from __future__ import annotations

import shutil
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pytest

from tests.cli_batch import run_batch
from tests.cli_runner import run_cli
from tests.helpers import TINY_CONFIG

# Workers for a 4-joint arm: the same config with env_kwargs, the way a user would train them.
FOUR_JOINT_CONFIG = TINY_CONFIG.replace("default: &tiny\n", "default: &tiny\n  env_kwargs: {n_joints: 4}\n")

TW = ("train-workers", "--no-progress")
TM = ("train-manager", "--no-progress", "--workers", "{w}", "--config", "{tiny}")


#: Cases also run in their own ``python -m sb3_hddpg`` process (at least one per command).
ALONE = {
    "tw-negative-timesteps",
    "tw-bad-term-bounds",
    "tw-config-unknown-key",
    "tm-nan-preference",
    "tm-workers-for-another-env",
    "ev-tampered-bundle",
    "ro-unknown-env",
    "tf-config-unknown-key",
    "bm-unknown-method",
    "tu-fix-unknown",
    "qs-unknown-budget",
    "rec-tampered-bundle",
    "ps-worker-zip",
    "pk-not-a-zip",
    "ev-module-prefixed-env",
    "tw-config-alias-bomb",
    "tu-in-memory-storage",
}


def case(case_id: str, args: tuple[str, ...], code: int, offending: str) -> Any:
    """One row of the table, as a pytest param."""
    return pytest.param(args, code, offending, id=case_id)


#: (arguments with {placeholders}, expected exit code, a string the error line must contain)
CASES = [
    # ---- train-workers: option values
    case("tw-unknown-worker", (*TW, "--workers", "nope", "--out", "{tmp}/o"), 2, "nope"),
    case(
        "tw-duplicate-worker", (*TW, "--workers", "goal", "--workers", "goal", "--out", "{tmp}/o"), 2, "goal"
    ),
    case("tw-negative-timesteps", (*TW, "--timesteps", "-5", "--out", "{tmp}/o"), 2, "-5"),
    case("tw-zero-timesteps", (*TW, "--timesteps", "0", "--out", "{tmp}/o"), 2, "got 0"),
    case("tw-text-timesteps", (*TW, "--timesteps", "ten", "--out", "{tmp}/o"), 2, "ten"),
    case("tw-negative-seed", (*TW, "--seed", "-1", "--out", "{tmp}/o"), 2, "-1"),
    case("tw-zero-n-envs", (*TW, "--n-envs", "0", "--out", "{tmp}/o"), 2, "got 0"),
    case("tw-negative-eval-freq", (*TW, "--eval-freq", "-3", "--out", "{tmp}/o"), 2, "-3"),
    case("tw-zero-eval-episodes", (*TW, "--eval-episodes", "0", "--out", "{tmp}/o"), 2, "--eval-episodes"),
    case("tw-negative-checkpoint-freq", (*TW, "--checkpoint-freq", "-7", "--out", "{tmp}/o"), 2, "-7"),
    case("tw-unknown-option", (*TW, "--timestep", "5", "--out", "{tmp}/o"), 2, "--timestep"),
    # ---- train-workers: another env with several objectives (docs/ENVIRONMENTS.md)
    case("tw-terms-without-env", (*TW, "--terms", "a,b", "--out", "{tmp}/o"), 2, "--terms needs --env"),
    case("tw-unregistered-env", (*TW, "--env", "nope-v0", "--out", "{tmp}/o"), 2, "nope-v0"),
    case("tw-module-prefixed-env", (*TW, "--env", "os:Evil-v0", "--out", "{tmp}/o"), 2, "os:Evil-v0"),
    case(
        "tw-bad-term-bounds",
        (*TW, "--env", "mo-mountaincarcontinuous-v0", "--term-bounds", "time=1", "--out", "{tmp}/o"),
        2,
        "time=1",
    ),
    case(
        "tw-terms-miscounted",
        (*TW, "--env", "mo-mountaincarcontinuous-v0", "--terms", "a,b,c", "--out", "{tmp}/o"),
        2,
        "Expected 2 `terms`",
    ),
    case(
        "tw-env-without-terms",
        (*TW, "--env", "Pendulum-v1", "--out", "{tmp}/o"),
        2,
        "declares no reward terms",
    ),
    # ---- train-workers: paths and files
    case("tw-config-missing", (*TW, "--config", "{tmp}/nope.yml", "--out", "{tmp}/o"), 2, "nope.yml"),
    case("tw-config-is-folder", (*TW, "--config", "{folder}", "--out", "{tmp}/o"), 2, "a-folder"),
    case("tw-config-invalid-yaml", (*TW, "--config", "{bad_yaml}", "--out", "{tmp}/o"), 2, "bad_yaml.yml"),
    case("tw-config-unknown-key", (*TW, "--config", "{unknown_key}", "--out", "{tmp}/o"), 2, "learning_rat"),
    case("tw-config-negative-timesteps", (*TW, "--config", "{negative_budget}", "--out", "{tmp}/o"), 2, "-5"),
    case("tw-out-holds-results", (*TW, "--config", "{tiny}", "--out", "{w}"), 2, "already holds results"),
    case("tw-out-is-a-file", (*TW, "--config", "{tiny}", "--out", "{text_file}"), 2, "notes.txt"),
    case("tw-out-under-a-file", (*TW, "--config", "{tiny}", "--out", "{text_file}/sub"), 2, "notes.txt"),
    case("tw-out-empty", (*TW, "--config", "{tiny}", "--out", ""), 2, "--out"),
    case("tw-seed-too-large", (*TW, "--seed", "99999999999", "--out", "{tmp}/o"), 2, "99999999999"),
    case("tw-config-alias-bomb", (*TW, "--config", "{alias_bomb}", "--out", "{tmp}/o"), 2, "aliases"),
    case("tw-config-deep-yaml", (*TW, "--config", "{deep_yaml}", "--out", "{tmp}/o"), 2, "deep_yaml.yml"),
    case("tw-config-buffer-bomb", (*TW, "--config", "{buffer_bomb}", "--out", "{tmp}/o"), 2, "buffer_size"),
    case("tw-config-net-arch-bomb", (*TW, "--config", "{net_arch_bomb}", "--out", "{tmp}/o"), 2, "net_arch"),
    case(
        "tw-config-controller-list",
        (*TW, "--config", "{controller_list}", "--out", "{tmp}/o"),
        2,
        "controller",
    ),
    # ---- train-manager: names, preferences and selection
    case("tm-duplicate-worker", (*TM, "--worker", "goal", "--worker", "goal", "--out", "{tmp}/o"), 2, "goal"),
    case("tm-unknown-worker", (*TM, "--worker", "goal", "--worker", "nope", "--out", "{tmp}/o"), 2, "nope"),
    case("tm-unknown-prefer", (*TM, "--prefer", "nope", "--out", "{tmp}/o"), 2, "nope"),
    case("tm-unknown-algo", (*TM, "--algo", "a2c", "--out", "{tmp}/o"), 2, "a2c"),
    case("tm-unknown-preference", (*TM, "--preference", "nope=1.2", "--out", "{tmp}/o"), 2, "nope"),
    case("tm-zero-preference", (*TM, "--preference", "goal=0", "--out", "{tmp}/o"), 2, "0"),
    case("tm-negative-preference", (*TM, "--preference", "goal=-1", "--out", "{tmp}/o"), 2, "-1"),
    case("tm-nan-preference", (*TM, "--preference", "goal=nan", "--out", "{tmp}/o"), 2, "nan"),
    case("tm-inf-preference", (*TM, "--preference", "goal=inf", "--out", "{tmp}/o"), 2, "inf"),
    case("tm-malformed-preference", (*TM, "--preference", "goal", "--out", "{tmp}/o"), 2, "goal"),
    case("tm-repeated-preference", (*TM, "--preference", "goal=1,goal=2", "--out", "{tmp}/o"), 2, "goal"),
    case("tm-zero-bias", (*TM, "--prefer", "goal", "--bias", "0", "--out", "{tmp}/o"), 2, "> 0, actually: 0"),
    case("tm-negative-bias", (*TM, "--prefer", "goal", "--bias", "-0.5", "--out", "{tmp}/o"), 2, "-0.5"),
    case("tm-nan-bias", (*TM, "--prefer", "goal", "--bias", "nan", "--out", "{tmp}/o"), 2, "nan"),
    case("tm-inf-bias", (*TM, "--prefer", "goal", "--bias", "inf", "--out", "{tmp}/o"), 2, "inf"),
    case("tm-unknown-selection", (*TM, "--selection", "best", "--out", "{tmp}/o"), 2, "best"),
    case("tm-zero-option-steps", (*TM, "--option-steps", "0", "--out", "{tmp}/o"), 2, "got 0"),
    case("tm-negative-timesteps", (*TM, "--timesteps", "-1", "--out", "{tmp}/o"), 2, "-1"),
    case("tm-negative-seed", (*TM, "--seed", "-2", "--out", "{tmp}/o"), 2, "-2"),
    # ---- train-manager: workers folders and files
    case(
        "tm-workers-missing",
        ("train-manager", "--workers", "{tmp}/nowhere", "--out", "{tmp}/o"),
        2,
        "nowhere",
    ),
    case(
        "tm-workers-is-a-file",
        ("train-manager", "--workers", "{text_file}", "--out", "{tmp}/o"),
        2,
        "notes.txt",
    ),
    case(
        "tm-workers-no-manifest",
        ("train-manager", "--workers", "{folder}", "--out", "{tmp}/o"),
        2,
        "a-folder",
    ),
    case(
        "tm-manifest-invalid",
        ("train-manager", "--workers", "{bad_manifest}", "--out", "{tmp}/o"),
        2,
        "manifest.json",
    ),
    case(
        "tm-worker-hash-mismatch",
        ("train-manager", "--workers", "{tampered_workers}", "--out", "{tmp}/o"),
        2,
        "goal.zip",
    ),
    case(
        "tm-worker-truncated",
        ("train-manager", "--workers", "{truncated_workers}", "--out", "{tmp}/o"),
        2,
        "goal.zip",
    ),
    case(
        "tm-worker-file-missing",
        ("train-manager", "--workers", "{missing_worker}", "--out", "{tmp}/o"),
        2,
        "avoid.zip",
    ),
    case(
        "tm-workers-for-another-env",
        ("train-manager", "--workers", "{w4}", "--config", "{tiny}", "--out", "{tmp}/o"),
        2,
        "(27,)",
    ),
    case(
        "tm-config-unknown-key",
        ("train-manager", "--workers", "{w}", "--config", "{unknown_key}", "--out", "{tmp}/o"),
        2,
        "learning_rat",
    ),
    case(
        "tm-config-motion-text",
        (*TM[:-1], "{motion_text}", "--out", "{tmp}/o"),
        2,
        "manager_motion: expected",
    ),
    case(
        "tm-config-states-nested", (*TM[:-1], "{nested_states}", "--out", "{tmp}/o"), 2, "worker_states.goal"
    ),
    case("tm-out-holds-results", (*TM, "--out", "{m}"), 2, "already holds results"),
    # ---- evaluate
    case("ev-missing", ("evaluate", "{tmp}/nope.zip"), 2, "nope.zip"),
    case("ev-folder-without-model", ("evaluate", "{folder}"), 2, "a-folder"),
    case("ev-not-a-zip", ("evaluate", "{text_zip}"), 2, "text.zip"),
    case("ev-truncated-bundle", ("evaluate", "{truncated_bundle}"), 2, "truncated.zip"),
    case("ev-tampered-bundle", ("evaluate", "{tampered_bundle}"), 2, "manager.zip"),
    case("ev-worker-hash-mismatch", ("evaluate", "{tampered_workers}/workers/goal.zip"), 2, "goal.zip"),
    case("ev-zip-without-manifest", ("evaluate", "{lonely_zip}"), 2, "--trust"),
    case(
        "ev-worker-for-another-env",
        ("evaluate", "{w4}/workers/goal.zip", "--env", "hddpg/SnakeGoal-v0"),
        0,
        "",
    ),
    case("ev-unknown-env", ("evaluate", "random", "--env", "hddpg/Nope-v0"), 2, "Nope"),
    case("ev-zero-episodes", ("evaluate", "random", "--episodes", "0"), 2, "got 0"),
    case("ev-negative-episodes", ("evaluate", "random", "--episodes", "-3"), 2, "-3"),
    case("ev-negative-seed", ("evaluate", "random", "--seed", "-1"), 2, "-1"),
    case("ev-json-is-a-folder", ("evaluate", "random", "--json", "{folder}"), 2, "a-folder"),
    case("ev-unknown-algo", ("evaluate", "{lonely_zip}", "--trust", "--algo", "a2c"), 2, "A2C"),
    # ---- evaluate: hostile bundles and files (a file someone else made; docs/ROBUSTNESS.md "Limits")
    case("ev-module-prefixed-env", ("evaluate", "{hostile_env_id}"), 2, "env_id"),
    case("ev-env-kwargs-list", ("evaluate", "{hostile_env_kwargs_list}"), 2, "env_kwargs"),
    case("ev-env-kwargs-huge", ("evaluate", "{hostile_n_obstacles}"), 2, "n_obstacles"),
    case("ev-temperature-text", ("evaluate", "{hostile_temperature}"), 2, "temperature"),
    case("ev-selection-unknown", ("evaluate", "{hostile_selection}"), 2, "selection.selection"),
    case("ev-option-steps-negative", ("evaluate", "{hostile_option_steps}"), 2, "option_steps"),
    case("ev-zero-workers", ("evaluate", "{hostile_zero_workers}"), 2, "0 workers"),
    case("ev-observation-shape-0", ("evaluate", "{hostile_shape}"), 2, "shape"),
    case("ev-deep-json", ("evaluate", "{hostile_deep_json}"), 2, "nested"),
    case("ev-traversal-member", ("evaluate", "{hostile_traversal}"), 2, "names member"),
    case("ev-parameter-bomb", ("evaluate", "{hostile_net_arch}"), 2, "parameters"),
    case("ev-ham-missing-keys", ("evaluate", "{ham_missing_keys}"), 2, "workers_manifest"),
    # ---- rollout
    case("ro-zero-episodes", ("rollout", "--episodes", "0"), 2, "0"),
    case("ro-negative-seed", ("rollout", "--seed", "-4"), 2, "-4"),
    case("ro-unknown-env", ("rollout", "--env", "hddpg/Nope-v0"), 2, "Nope"),
    case("ro-png-is-a-folder", ("rollout", "--png", "{folder}"), 2, "a-folder"),
    # ---- train-flat
    case("tf-unknown-algo", ("train-flat", "--algo", "a2c", "--out", "{tmp}/o"), 2, "a2c"),
    case("tf-negative-timesteps", ("train-flat", "--timesteps", "-3", "--out", "{tmp}/o"), 2, "-3"),
    case("tf-zero-n-envs", ("train-flat", "--n-envs", "0", "--out", "{tmp}/o"), 2, "got 0"),
    case(
        "tf-config-unknown-key",
        ("train-flat", "--config", "{unknown_key}", "--out", "{tmp}/o"),
        2,
        "learning_rat",
    ),
    case(
        "tf-out-holds-results",
        ("train-flat", "--config", "{tiny}", "--out", "{w}"),
        2,
        "already holds results",
    ),
    # ---- benchmark
    case("bm-unknown-method", ("benchmark", "--methods", "hddpg,nope", "--out", "{tmp}/o"), 2, "nope"),
    case("bm-zero-seeds", ("benchmark", "--seeds", "0", "--out", "{tmp}/o"), 2, "got 0"),
    case("bm-negative-timesteps", ("benchmark", "--timesteps", "-10", "--out", "{tmp}/o"), 2, "-10"),
    case("bm-negative-bias", ("benchmark", "--bias", "-2", "--out", "{tmp}/o"), 2, "-2"),
    case("bm-zero-n-jobs", ("benchmark", "--n-jobs", "0", "--out", "{tmp}/o"), 2, "got 0"),
    case("bm-negative-hysteresis", ("benchmark", "--ham-hysteresis", "-1", "--out", "{tmp}/o"), 2, "-1"),
    case("bm-out-is-a-file", ("benchmark", "--out", "{text_file}"), 2, "notes.txt"),
    case("bm-unknown-executor", ("benchmark", "--executor", "slurm", "--out", "{tmp}/o"), 2, "slurm"),
    case(
        "bm-ray-address-alone",
        ("benchmark", "--ray-address", "10.0.0.1:6379", "--out", "{tmp}/o"),
        2,
        "--executor ray",
    ),
    case(
        "bm-ray-address-malformed",
        ("benchmark", "--executor", "ray", "--ray-address", "headnode", "--out", "{tmp}/o"),
        2,
        "'headnode'",
    ),
    case(
        "bm-transfer-bad-preference",
        ("benchmark", "--scenario", "transfer", "--preference", "goal=-1", "--out", "{tmp}/o"),
        2,
        "goal",
    ),
    case(
        "bm-transfer-with-ham",
        ("benchmark", "--scenario", "transfer", "--methods", "hddpg,ham", "--out", "{tmp}/o"),
        2,
        "ham",
    ),
    # ---- grow and morl-report
    case("gr-missing-workers", ("grow", "--workers", "{tmp}/nope"), 2, "nope"),
    case("gr-zero-support", ("grow", "--workers", "{tmp}/nope", "--support", "0"), 2, "--support"),
    case("fc-missing-workers", ("fit-critics", "--workers", "{tmp}/nope"), 2, "nope"),
    case("fc-not-workers", ("fit-critics", "--workers", "{folder}"), 2, "a-folder"),
    case("mr-missing-run", ("morl-report", "{tmp}/nope"), 2, "nope"),
    # ---- export-models
    case("ex-missing-run", ("export-models", "{tmp}/nope", "{tmp}/models"), 2, "nope"),
    case(
        "ex-unknown-method",
        ("export-models", "docs/results/bench-e20", "{tmp}/models", "--method", "hddpg-nope"),
        2,
        "hddpg-nope",
    ),
    # ---- report and export-study: the docs' tables and the shipped studies
    case("rp-missing-run", ("report", "{tmp}/nope"), 2, "nope"),
    case("rp-not-a-benchmark", ("report", "{folder}"), 2, "a-folder"),
    case(
        "rp-missing-page",
        ("report", "docs/results/bench-e20", "--page", "{tmp}/nope.md", "--check"),
        2,
        "nope.md",
    ),
    case(
        "es-bad-storage",
        ("export-study", "--storage", "nope://x", "--study-name", "s", "--out", "{tmp}/s"),
        2,
        "nope",
    ),
    case(
        "es-missing-study",
        ("export-study", "--storage", "sqlite:///{tmp}/s.db", "--study-name", "absent", "--out", "{tmp}/s"),
        2,
        "s.db' does not exist",
    ),
    case("ex-not-a-benchmark", ("export-models", "{folder}", "{tmp}/models"), 2, "a-folder"),
    # ---- snapshot, and the benchmark's --snapshot
    case("sn-missing-run", ("snapshot", "{tmp}/nope", "{tmp}/snap"), 2, "nope"),
    case("sn-not-a-benchmark", ("snapshot", "{folder}", "{tmp}/snap"), 2, "a-folder"),
    case("sn-dest-current-folder", ("snapshot", "docs/results/record", "."), 2, "the current folder"),
    case(
        "bm-snapshot-current-folder",
        ("benchmark", "--seeds", "1", "--methods", "ham", "--out", "{tmp}/o", "--snapshot", "."),
        2,
        "the current folder",
    ),
    # ---- tune
    case("tu-unknown-level", ("tune", "--level", "everything", "--out", "{tmp}/o"), 2, "everything"),
    case("tu-unknown-block", ("tune", "--level", "flat", "--block", "nope", "--out", "{tmp}/o"), 2, "nope"),
    case(
        "tu-budget-fraction",
        ("tune", "--level", "flat", "--budget-fraction", "2", "--final-budget", "100", "--out", "{tmp}/o"),
        2,
        "budget_fraction",
    ),
    case("tu-worker-missing", ("tune", "--level", "worker", "--out", "{tmp}/o"), 2, "--worker"),
    case(
        "tu-unknown-worker", ("tune", "--level", "worker", "--worker", "nope", "--out", "{tmp}/o"), 2, "nope"
    ),
    case("tu-zero-trials", ("tune", "--level", "flat", "--n-trials", "0", "--out", "{tmp}/o"), 2, "got 0"),
    case(
        "tu-unknown-sampler", ("tune", "--level", "flat", "--sampler", "nope", "--out", "{tmp}/o"), 2, "nope"
    ),
    case(
        "tu-unknown-storage",
        ("tune", "--level", "flat", "--storage", "nosuchdb://x", "--out", "{tmp}/o"),
        2,
        "nosuchdb",
    ),
    case(
        "tu-in-memory-storage",
        ("tune", "--level", "flat", "--storage", "sqlite://", "--out", "{tmp}/o"),
        2,
        "In-memory",
    ),
    case("tu-fix-unknown", ("tune", "--level", "flat", "--fix", "nope=1", "--out", "{tmp}/o"), 2, "nope"),
    case(
        "tu-zero-seeds", ("tune", "--level", "flat", "--seeds-per-trial", "0", "--out", "{tmp}/o"), 2, "got 0"
    ),
    case(
        "tu-ham-seeds",
        ("tune", "--level", "ham", "--seeds-per-trial", "2", "--out", "{tmp}/o"),
        2,
        "--seeds-per-trial",
    ),
    case(
        "tu-ray-address-alone",
        ("tune", "--level", "flat", "--ray-address", "auto", "--out", "{tmp}/o"),
        2,
        "--executor ray",
    ),
    case("tu-algo-unknown", ("tune", "--level", "flat", "--algo", "a2c", "--out", "{tmp}/o"), 2, "a2c"),
    case(
        "tu-algo-not-flat",
        ("tune", "--level", "ham", "--algo", "sac", "--out", "{tmp}/o"),
        2,
        "levels worker, flat, manager",
    ),
    case(
        "tu-sac-fix-noise",
        ("tune", "--level", "flat", "--algo", "sac", "--fix", "noise_std=0.1", "--out", "{tmp}/o"),
        2,
        "noise_std",
    ),
    case(
        "tu-fix-out-of-range",
        ("tune", "--level", "flat", "--fix", "learning_rate=5", "--out", "{tmp}/o"),
        2,
        "learning_rate",
    ),
    case(
        "tu-config-unknown-key",
        ("tune", "--level", "flat", "--config", "{unknown_key}", "--out", "{tmp}/o"),
        2,
        "learning_rat",
    ),
    case(
        "tu-workers-missing",
        ("tune", "--level", "manager", "--workers", "{tmp}/nowhere", "--out", "{tmp}/o"),
        2,
        "nowhere",
    ),
    case(
        "tu-workers-for-another-env",
        ("tune", "--level", "manager", "--workers", "{w4}", "--out", "{tmp}/o"),
        2,
        "sees 27 values but the env gives 39",
    ),
    case(
        "tu-tampered-workers",
        ("tune", "--level", "ham", "--workers", "{tampered_workers}", "--out", "{tmp}/o"),
        2,
        "goal.zip",
    ),
    # ---- quickstart
    case("qs-unknown-budget", ("quickstart", "--budget", "huge", "--out", "{tmp}/o"), 2, "huge"),
    case("qs-zero-processes", ("quickstart", "--processes", "0", "--out", "{tmp}/o"), 2, "got 0"),
    case("qs-out-holds-results", ("quickstart", "--out", "{w}"), 2, "already holds results"),
    # Port 9 (discard): nothing listens there on a test machine.
    case(
        "qs-ray-unreachable",
        ("quickstart", "--executor", "ray", "--ray-address", "127.0.0.1:9", "--out", "{tmp}/o"),
        2,
        "127.0.0.1:9",
    ),
    # ---- record
    case("rec-missing", ("record", "{tmp}/nope.zip", "--out", "{tmp}/x.gif"), 2, "nope.zip"),
    case("rec-bad-extension", ("record", "{m}/hierarchy.zip", "--out", "{tmp}/x.avi"), 2, "x.avi"),
    case(
        "rec-zero-episodes",
        ("record", "{m}/hierarchy.zip", "--out", "{tmp}/x.gif", "--episodes", "0"),
        2,
        "got 0",
    ),
    case("rec-zero-fps", ("record", "{m}/hierarchy.zip", "--out", "{tmp}/x.gif", "--fps", "0"), 2, "got 0"),
    case("rec-tampered-bundle", ("record", "{tampered_bundle}", "--out", "{tmp}/x.gif"), 2, "manager.zip"),
    # ---- plot-selection
    case("ps-worker-zip", ("plot-selection", "{w}/workers/goal.zip", "--out", "{tmp}/p.png"), 2, "goal.zip"),
    case(
        "ps-zero-episodes",
        ("plot-selection", "{m}/hierarchy.zip", "--episodes", "0", "--out", "{tmp}/p.png"),
        2,
        "got 0",
    ),
    case("ps-out-not-png", ("plot-selection", "{m}/hierarchy.zip", "--out", "{folder}"), 2, "a-folder"),
    case(
        "ps-truncated-bundle",
        ("plot-selection", "{truncated_bundle}", "--out", "{tmp}/p.png"),
        2,
        "truncated.zip",
    ),
    # ---- package
    case("pk-missing", ("package", "{tmp}/nope.zip", "--out", "{tmp}/pk"), 2, "nope.zip"),
    case("pk-not-a-zip", ("package", "{text_zip}", "--out", "{tmp}/pk"), 2, "text.zip"),
    case(
        "pk-traversal-algo", ("package", "{traversal_algo}/workers/goal.zip", "--out", "{tmp}/pk"), 2, "algo"
    ),
    case("pk-out-not-empty", ("package", "{m}/hierarchy.zip", "--out", "{w}"), 2, "not empty"),
    case(
        "pk-zero-episodes",
        ("package", "{m}/hierarchy.zip", "--out", "{tmp}/pk", "--episodes", "0"),
        2,
        "got 0",
    ),
    # ---- no command
    case("unknown-command", ("train-everything",), 2, "train-everything"),
]


@pytest.fixture(scope="module")
def artifacts(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """Tiny trained artifacts and damaged copies of them, built once, in-process (no CLI start-up cost)."""
    from sb3_hddpg.training.manager import train_manager
    from sb3_hddpg.training.workers import train_workers

    root = tmp_path_factory.mktemp("bad-input")
    tiny = root / "tiny.yml"
    tiny.write_text(TINY_CONFIG)
    four = root / "four.yml"
    four.write_text(FOUR_JOINT_CONFIG)
    quick = {"eval_freq": 0, "eval_episodes": 1}
    train_workers(root / "w", config=tiny, **quick)
    train_workers(root / "w4", config=four, **quick)
    train_manager(root / "w", root / "m", config=tiny, timesteps=120, **quick)

    def copy_workers(name: str) -> Path:
        target = root / name
        shutil.copytree(root / "w" / "workers", target / "workers")
        return target

    tampered = copy_workers("tampered_workers")
    with open(tampered / "workers" / "goal.zip", "ab") as handle:
        handle.write(b"\0")
    truncated = copy_workers("truncated_workers")
    data = (truncated / "workers" / "goal.zip").read_bytes()
    (truncated / "workers" / "goal.zip").write_bytes(data[: len(data) // 2])
    missing = copy_workers("missing_worker")
    (missing / "workers" / "avoid.zip").unlink()
    bad_manifest = copy_workers("bad_manifest")
    (bad_manifest / "workers" / "manifest.json").write_text('{"workers": ')
    lonely = root / "lonely"
    lonely.mkdir()
    shutil.copy(root / "w" / "workers" / "goal.zip", lonely / "goal.zip")

    bundle = (root / "m" / "hierarchy.zip").read_bytes()
    (root / "truncated.zip").write_bytes(bundle[: len(bundle) * 2 // 3])
    with zipfile.ZipFile(root / "m" / "hierarchy.zip") as source:
        members = {name: source.read(name) for name in source.namelist()}
    swapped = dict(members)
    swapped["manager.zip"] = members["workers/goal.zip"]  # a swapped member, manifest unchanged
    with zipfile.ZipFile(root / "tampered.zip", "w") as target:
        for name, content in swapped.items():
            target.writestr(name, content)

    _hostile_files(root, members)

    (root / "a-folder").mkdir()
    (root / "notes.txt").write_text("not a folder\n")
    (root / "text.zip").write_text("this is not a zip file\n")
    (root / "bad_yaml.yml").write_text("default: [unclosed\n")
    (root / "unknown_key.yml").write_text(TINY_CONFIG.replace("batch_size", "learning_rat"))
    (root / "negative_budget.yml").write_text(TINY_CONFIG.replace("n_timesteps: 150", "n_timesteps: -5"))
    paths = {
        "w": root / "w",
        "w4": root / "w4",
        "m": root / "m",
        "tiny": tiny,
        "tampered_workers": tampered,
        "truncated_workers": truncated,
        "missing_worker": missing,
        "bad_manifest": bad_manifest,
        "lonely_zip": lonely / "goal.zip",
        "truncated_bundle": root / "truncated.zip",
        "tampered_bundle": root / "tampered.zip",
        "folder": root / "a-folder",
        "text_file": root / "notes.txt",
        "text_zip": root / "text.zip",
        "bad_yaml": root / "bad_yaml.yml",
        "unknown_key": root / "unknown_key.yml",
        "negative_budget": root / "negative_budget.yml",
        "alias_bomb": root / "alias_bomb.yml",
        "deep_yaml": root / "deep_yaml.yml",
        "buffer_bomb": root / "buffer_bomb.yml",
        "net_arch_bomb": root / "net_arch_bomb.yml",
        "controller_list": root / "controller_list.yml",
        "motion_text": root / "motion_text.yml",
        "nested_states": root / "nested_states.yml",
        "ham_missing_keys": root / "ham.json",
        "traversal_algo": root / "traversal_algo",
        **{f"hostile_{key}": root / f"hostile_{key}.zip" for key in HOSTILE_BUNDLES},
    }
    return {key: str(value) for key, value in paths.items()} | {"root": str(root)}


#: Bundles edited as someone might send them: (what is changed in the manifest), each refused by name.
HOSTILE_BUNDLES: dict[str, Any] = {
    "env_id": lambda m: m.update(env_id="os:hddpg/SnakeReach-v0"),
    "env_kwargs_list": lambda m: m.update(env_kwargs=["n_joints", 4]),
    "n_obstacles": lambda m: m.update(env_kwargs={"n_obstacles": 10_000_000}),
    "temperature": lambda m: m["selection"].update(temperature="abc"),
    "selection": lambda m: m["selection"].update(selection="evil"),
    "option_steps": lambda m: m["selection"].update(option_steps=-3),
    "zero_workers": lambda m: m.update(worker_names=[], workers={}),
    "shape": lambda m: m["manager"]["spec"]["observation_space"].update(shape=[0], low=[], high=[]),
    "deep_json": None,  # the manifest is 200,000 nested lists
    "traversal": lambda m: m["workers"]["goal"].update(file="../../goal.zip"),
    "net_arch": lambda m: m["workers"]["goal"]["spec"]["policy_kwargs"].update(net_arch=[65536, 65536]),
}


def _hostile_files(root: Path, members: dict[str, bytes]) -> None:
    """The hostile inputs of the table, generated from the tiny trained artifacts."""
    import json

    base = json.loads(members["manifest.json"])
    for key, edit in HOSTILE_BUNDLES.items():
        manifest = json.loads(json.dumps(base))
        if edit is not None:
            edit(manifest)
        raw = json.dumps(manifest).encode() if edit is not None else b"[" * 200_000 + b"]" * 200_000
        with zipfile.ZipFile(root / f"hostile_{key}.zip", "w") as target:
            target.writestr("manifest.json", raw)
            for name, content in members.items():
                if name != "manifest.json":
                    target.writestr(name, content)
    # Ten nested aliases, each listing the previous ten times: 10^10 values when expanded.
    lines = ["a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, 10)]
    lines += ["default:", "  n_timesteps: *a9", "  policy: 'MlpPolicy'"]
    (root / "alias_bomb.yml").write_text("\n".join(lines) + "\n")
    (root / "buffer_bomb.yml").write_text(TINY_CONFIG.replace("buffer_size: 1000", "buffer_size: 1e13"))
    (root / "net_arch_bomb.yml").write_text(TINY_CONFIG.replace("net_arch=[16]", "net_arch=[65536, 65536]"))
    (root / "controller_list.yml").write_text(
        "default:\n  n_timesteps: 10\n  callback:\n    - sb3_hddpg.callbacks.ControllerPrior: {controller: [1]}\n"
    )
    (root / "motion_text.yml").write_text(TINY_CONFIG + "  wrapper_kwargs: {manager_motion: x}\n")
    (root / "nested_states.yml").write_text(
        TINY_CONFIG + "  wrapper_kwargs: {worker_states: {goal: [[1]]}}\n"
    )
    (root / "deep_yaml.yml").write_text("default: " + "[" * 100_000 + "]" * 100_000 + "\n")
    (root / "ham.json").write_text(json.dumps({"kind": "sb3-hddpg-ham", "schema_version": 1, "env_id": "x"}))
    # A worker whose manifest entry names its algorithm with a path (package used to write there).
    target = root / "traversal_algo"
    shutil.copytree(root / "w" / "workers", target / "workers")
    manifest = json.loads((target / "workers" / "manifest.json").read_text())
    manifest["workers"]["goal"]["algo"] = "../../y"
    (target / "workers" / "manifest.json").write_text(json.dumps(manifest))


@pytest.fixture(scope="module")
def outcomes(artifacts: dict[str, str]) -> dict[tuple[str, ...], list[Any]]:
    """Every case's command line run in the batch, and the ``ALONE`` ones also in their own process."""
    commands = {}
    for index, param in enumerate(CASES):
        args = param.values[0]
        scratch = Path(artifacts["root"]) / f"case-{index}"
        scratch.mkdir()
        commands[args] = [arg.format(tmp=scratch, **artifacts) for arg in args]
    alone = {param.values[0] for param in CASES if param.id in ALONE}
    with ThreadPoolExecutor(max_workers=2) as pool:
        own = {args: pool.submit(run_cli, *commands[args], timeout=600) for args in alone}
        batch = run_batch(list(commands.values()))
        results = {args: [result] for args, result in zip(commands, batch)}
        for args, future in own.items():
            results[args].append(future.result())
    return results


@pytest.mark.parametrize(("args", "code", "offending"), CASES)
def test_bad_input_is_one_clear_line(outcomes, args, code, offending):
    for result in outcomes[args]:
        shown = f"exit {result.returncode}\nstdout: {result.stdout[-1500:]}\nstderr: {result.stderr[-3000:]}"
        assert "Traceback" not in result.stderr, shown
        if code == 0:  # a control case: the same input, used correctly, works
            assert result.returncode == 0, shown
            continue
        assert result.returncode == code, shown
        lines = [line for line in result.stderr.splitlines() if line.strip()]
        assert len(lines) == 1, shown
        assert lines[0].startswith("error: "), shown
        assert offending in lines[0], shown


def test_table_covers_every_command():
    """Every registered command has rows in the table (a new command must bring its own)."""
    import typer

    from sb3_hddpg.cli import app

    group = typer.main.get_command(app)
    registered = set(group.list_commands(None))  # every command, whether its module is imported yet or not
    in_table = {param.values[0][0] for param in CASES}
    assert registered - in_table == set()
    assert {"ALONE": ALONE - {param.id for param in CASES}} == {"ALONE": set()}


@pytest.mark.parametrize("how", ["--debug", "HDDPG_DEBUG=1"])
def test_debug_shows_the_traceback(artifacts, how, monkeypatch):
    if how == "--debug":
        result = run_cli("evaluate", artifacts["text_zip"], "--debug")
    else:
        monkeypatch.setenv("HDDPG_DEBUG", "1")
        result = run_cli("evaluate", artifacts["text_zip"])
    assert result.returncode != 0
    assert "Traceback" in result.stderr and "text.zip" in result.stderr
