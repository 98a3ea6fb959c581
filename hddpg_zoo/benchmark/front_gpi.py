"""
The front's GPI member (``gpi``): generalized policy improvement over a seed's workers with their per-term
critics (:mod:`sb3_hddpg.hierarchy.gpi`), at every preference of the front's sweep. It trains nothing: its
env steps are the workers' (counted once, as every member over them), and a preference costs none.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from hddpg_zoo.benchmark.front_points import FrontPoint, FrontSpec, sweep_labels
from sb3_hddpg.artifacts.manifests import load_workers
from sb3_hddpg.artifacts.workers import reward_specs_of
from sb3_hddpg.envs.contract import mix_terms
from sb3_hddpg.hierarchy.conditioning import PreferenceSpace
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.policy import Policy

#: The member's name in a front record.
GPI_MEMBER = "gpi"


def gpi_points(
    folder: Path,
    spec: FrontSpec,
    point: Callable[[str, Policy], FrontPoint],
    bundle: Path | None = None,
    sweep: PreferenceSpace | None = None,
    over_actions: bool = True,
) -> list[FrontPoint] | None:
    """
    GPI's points over the seed's workers, one per preference of the sweep, or ``None`` when a worker has no
    per-term critic (workers trained with ``--no-term-critic``, or on-policy ones). A preference over the
    workers weighs the terms as the managers' reward does: each worker's reward (its term, or its weighting
    of the terms) by its factor.

    :param folder: the seed's folder (its ``workers/``).
    :param spec: what the front measures.
    :param point: a policy's test point under a label (the front's own measure).
    :param bundle: where to save the GPI bundle (the one model that re-evaluates this member), if anywhere.
    :param sweep: the preferences, over workers of ``folder`` (default: ``spec``'s, over the terms).
    :param over_actions: discrete workers' GPI over actions, else over the workers' own actions
        (``Hierarchy.gpi``).
    """
    sweep = sweep or spec.sweep
    workers = load_workers(folder)
    if set(workers.critics) != set(workers) or not set(sweep.names) <= set(workers):
        return None
    specs = {name: reward_specs_of(workers).get(name, name) for name in sweep.names}
    gpi = Hierarchy.gpi(workers, over_actions=over_actions)
    if bundle is not None:
        bundle.parent.mkdir(parents=True, exist_ok=True)
        gpi.save(bundle)
    points = []
    for label, preference in zip(sweep_labels(sweep), sweep.points):
        gpi.set_preference(mix_terms(specs, dict(zip(sweep.names, preference))))
        points.append(point(label, gpi))
    return points
