"""The benchmark command's options of the front scenario (``--front-*``, ``--morl-python``)."""

from __future__ import annotations

from typing import Annotated

import typer

FrontManagerOpt = Annotated[
    str,
    typer.Option(
        "--front-manager",
        help="The algorithm of the front's managers (method hddpg-front): ddpg on the simplex as in the paper, "
        "or e.g. dqn choosing a worker by index.",
    ),
]
FrontTimestepsOpt = Annotated[
    int | None,
    typer.Option(
        "--front-timesteps",
        help="Each of the front's managers' budget in env steps (default: the manager's, --timesteps).",
    ),
]

FrontSweepOpt = Annotated[
    str,
    typer.Option(
        "--front-sweep",
        help="The preferences the front's managers are trained over and measured at: ratio-sweep (each worker "
        "weighted 1-4 times the others, 7 preferences) or ratio-sweep:MAX (ratios doubling up to MAX, a power "
        "of two; ratio-sweep:16 reaches 16:1 and 1:16 with 9 preferences); with --front-support, also the "
        "support's preferences over its workers (goal=1.5,avoid=0.6,mix-goal50-avoid50=0.9;...).",
    ),
]
FrontMotionOpt = Annotated[
    float,
    typer.Option(
        "--front-motion",
        help="The front's managers also see how their state moved over the last env step, scaled by this "
        "factor (train-manager --manager-motion); 0: the state only.",
    ),
]
FrontOptionStepsOpt = Annotated[
    int | None,
    typer.Option(
        "--front-option-steps",
        help="Env steps per decision of the front's managers (default: their manager block's option_steps; "
        "1 decides every env step, as a rule reading the state each step does). Their budget and their "
        "horizon stay in env steps: the block's discount becomes gamma ** (N / its option_steps).",
    ),
]
FrontPerPreferenceOpt = Annotated[
    bool,
    typer.Option(
        "--front-per-preference/--no-front-per-preference",
        help="The front also trains one manager per sweep preference, the conditioned manager's reference; "
        "--no-front-per-preference trains the conditioned manager alone (what one policy for every "
        "preference costs).",
    ),
]
MorlPythonOpt = Annotated[
    str | None,
    typer.Option(
        "--morl-python",
        help="The python of a virtual environment with MORL-baselines (it pins its own torch): the front "
        "scenario on an MO-Gymnasium env then adds its CAPQL, trained for the env steps of the workers and the "
        "conditioned manager, scored beside the hierarchy with MORL-baselines' indicators.",
    ),
]
FrontSupportOpt = Annotated[
    str | None,
    typer.Option(
        "--front-support",
        help="Method hddpg-support: weightings of the terms, one worker each beside the per-term ones "
        "(goal=0.5,avoid=0.5; several separated by ';'), trained from their <env>/mix config block.",
    ),
]
FrontStartOpt = Annotated[
    str | None,
    typer.Option(
        "--front-start",
        help="Method hddpg-support: 'gpi' starts its conditioned manager from GPI over the workers' "
        "critics (train-manager --init-from-gpi; the manager then trains on SB3).",
    ),
]
FrontGpiOpt = Annotated[
    str,
    typer.Option(
        "--front-gpi",
        help="The front's GPI member over discrete workers: 'actions' (argmax over actions of the best "
        "worker's value) or 'policies' (the action of the worker whose critic values its own action most).",
    ),
]
FrontCriticStepsOpt = Annotated[
    int,
    typer.Option(
        "--front-critic-steps",
        help="Method hddpg-support: each worker gets a critic fitted on this many env steps of its rollouts "
        "(fit-critics: a state value, or a discrete worker's Q over its actions; counted in its env steps). "
        "0: the critics the workers have.",
    ),
]
