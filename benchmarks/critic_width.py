"""
Training speed of the half-cheetah workers' learner by critic width, side by side in one process: CrossQ
(the bundled ``zoo_configs/crossq.yml`` block of ``mo-halfcheetah-v5``) with the critics of sb3-contrib's
and SBX's default, ``[1024, 1024]``, against ``[256, 256]``, and SAC with ``[256, 256]`` for reference.

Every case trains the ``speed`` worker's view of MO-Gymnasium's half-cheetah (200-step episodes) on the
backend asked for; after a warm-up past ``learning_starts`` (which also compiles SBX's update), rounds of
``learn(--steps)`` alternate between the cases, and each measurement records env steps per second of wall
time and of this process's CPU time. Ratios are against the first case. Run it with nothing else on the
machine: the update is arithmetic-bound, so other processes slow it directly.

    MUJOCO_GL=egl python benchmarks/critic_width.py [--steps 500] [--rounds 3] [--backend sbx]

Needs the ``mo`` and ``mujoco`` extras (and ``fast`` for SBX).
"""

from __future__ import annotations

import argparse
import os
import statistics
from typing import Any

from sb3_hddpg.training.backends import configure_jax_threads

configure_jax_threads(1)  # before jax's first import, as train_agent does

import torch  # noqa: E402
from backend_speed import measure  # noqa: E402  (this folder is on sys.path when a script here runs)
from stable_baselines3.common.env_util import make_vec_env  # noqa: E402

from sb3_hddpg.algorithms import algorithm  # noqa: E402
from sb3_hddpg.envs.terms_env import make_term_view, terms_env  # noqa: E402
from sb3_hddpg.training.config import default_config, load_hyperparams  # noqa: E402
from sb3_hddpg.training.models import make_model  # noqa: E402

#: case -> (algorithm, critic layers)
CASES = {"crossq-1024": ("crossq", 1024), "crossq-256": ("crossq", 256), "sac-256": ("sac", 256)}


def build(case: str, backend: str) -> Any:
    """The case's model on the speed worker's view, warmed up past ``learning_starts``."""
    algo, width = CASES[case]
    env = terms_env(
        "mo-halfcheetah-v5",
        terms=["speed", "energy"],
        term_bounds={"speed": (-3.0, 12.0), "energy": (-6.0, 0.0)},
        episode_steps=200,
    )
    env_id, view_kwargs = env.term_view("speed")
    params = load_hyperparams(env.worker_config_keys("speed"), algorithm(algo).cls, default_config(algo))

    def factory() -> Any:
        return make_term_view(env_id, view_kwargs, "speed")

    kwargs = params.model_kwargs(factory())
    # The same actor for every case; only the critics' width differs (SAC's own block names the network).
    kwargs["policy_kwargs"] = {"net_arch": {"pi": [256, 256], "qf": [width, width]}}
    kwargs["buffer_size"] = 100_000
    kwargs["learning_starts"] = 1_000
    model = make_model(algo, backend, make_vec_env(factory, n_envs=1, seed=0), kwargs, seed=0)
    model.learn(1_200)
    return model


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--steps", type=int, default=500, help="env steps (and updates) per measurement")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds (medians are reported)")
    parser.add_argument("--backend", choices=("sb3", "sbx"), default="sbx")
    parser.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, among {list(CASES)}")
    args = parser.parse_args()
    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    unknown = [c for c in cases if c not in CASES]
    if unknown:
        parser.error(f"unknown cases {unknown}; choose from {list(CASES)}")
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    models = {case: build(case, args.backend) for case in cases}
    rates: dict[str, list[tuple[float, float]]] = {case: [] for case in cases}
    for _ in range(args.rounds):
        for case, model in models.items():
            rates[case].append(measure(model, args.steps))
    load_after = os.getloadavg()
    wall = {case: statistics.median(r[0] for r in rates[case]) for case in cases}
    cpu = {case: statistics.median(r[1] for r in rates[case]) for case in cases}
    print(
        f"load average before {load_before[0]:.2f} after {load_after[0]:.2f} (1 min); {os.cpu_count()} CPUs; "
        f"backend {args.backend}"
    )
    print(f"{'case':12s} {'steps/s wall':>13s} {'steps/s CPU':>12s} {'vs ' + cases[0]:>18s}")
    for case in cases:
        print(
            f"{case:12s} {wall[case]:13.1f} {cpu[case]:12.1f} "
            f"{wall[case] / wall[cases[0]]:8.2f}x wall {cpu[case] / cpu[cases[0]]:5.2f}x CPU"
        )
    print(f"(medians of {args.rounds} rounds of {args.steps} steps, one update per step)")


if __name__ == "__main__":
    main()
