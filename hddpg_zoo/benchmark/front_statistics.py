"""
The front scenario's statistics over seeds (:func:`front_results`): per member and plane the hypervolumes and
their summaries, the conditioned manager's paired comparisons by the one decision rule, and the
episode-outcome plane of an env whose collision term marks crashes (:func:`crash_plane`). :mod:`~.front`
runs the scenario and writes the records read here.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, cast

import numpy as np

from hddpg_zoo.benchmark.episodes import CRASH_TERM
from hddpg_zoo.benchmark.front_points import (
    PLANES,
    SAFE_CONTACTS,
    hypervolume,
    safe_best_reach,
    safe_touch,
)
from hddpg_zoo.benchmark.morl import morl_results
from hddpg_zoo.records.results_leaves import (
    FrontComparison,
    FrontManager,
    FrontResults,
)
from hddpg_zoo.stats import (
    EQUIVALENCE_MARGIN,
    FAMILY_ALPHA,
    holm_adjust,
    holm_confidences,
    paired_t_interval,
    probability_of_improvement,
    summarise,
    t_interval,
)
from sb3_hddpg.artifacts.records import JsonObject


def _record_planes(record: Mapping[str, Any]) -> dict[str, list[list[object]]]:
    """A front record's planes (a snake record written before they were stated: the snake's)."""
    return record.get("planes") or {
        plane: [list(o) for o in objectives] for plane, objectives in PLANES.items()
    }


#: The episode-outcome plane of an env whose collision term marks crashes (MO-Gymnasium's highway envs).
CRASH_PLANE = "crashes"
#: A point's crash rate, in its plane: the share of its episodes that ended in a crash.
CRASH_RATE = "crash_rate"


def crash_plane(record: Mapping[str, Any]) -> tuple[list[tuple[str, bool]], tuple[float, float]] | None:
    """
    The episode-outcome plane of a front record whose points hold the crash term's return
    (:data:`~.episodes.CRASH_TERM`, -1 per crashed episode, 0 otherwise): the env's first other term's return
    (on highway its speed), to maximise, against the crash rate, to minimise; reference (0 return, every
    episode crashed). ``None`` for an env without that term.
    """
    terms = [str(key)[: -len("_term")] for key, _ in _record_planes(record).get("terms", [])]
    crash_key = f"{CRASH_TERM}_return"
    points = [p for member in record.get("front", {}).values() for p in member.get("points", [])]
    if CRASH_TERM not in terms or not points or not all(crash_key in p for p in points):
        return None
    first = next(term for term in terms if term != CRASH_TERM)
    return [(f"{first}_return", True), (CRASH_RATE, False)], (0.0, 1.0)


def with_crash_rate(point: Mapping[str, Any]) -> dict[str, Any]:
    """A front point with its crash rate: minus its crash term's mean return per episode (one crash at most)."""
    return {**point, CRASH_RATE: -float(point[f"{CRASH_TERM}_return"])}


def front_results(
    runs: Mapping[int, JsonObject],
    workers: Mapping[int, JsonObject] | None = None,
    flat: Mapping[str, Mapping[int, JsonObject]] | None = None,
) -> FrontResults:
    """
    The front scenario's statistics over seeds: per member and plane the per-seed hypervolumes and their
    summary (mean, 95 % bootstrap CI, IQM), the conditioned manager's paired differences with every other
    member (Student t interval over seeds, probability of improvement) and per seed the decides-by-state
    ratios.

    :param runs: seed -> the ``hddpg-front`` record.
    :param workers: seed -> the workers' task record (for the hierarchy's wall-clock beside a MORL learner's).
    :param flat: flat method -> seed -> its record, scored on the front's test episodes (beside the front's
        equal-weighting point: each seed's reach reward and training env steps).
    """
    seeds = sorted(runs)
    first: Mapping[str, Any] = runs[seeds[0]] if seeds else {}
    planes = _record_planes(first)
    references = dict(first.get("references", {}))
    members = [m for m in first.get("front", {}) if all(m in runs[s]["front"] for s in seeds)]
    per_seed = {
        member: {
            plane: {str(s): runs[s]["front"][member]["hypervolume"][plane] for s in seeds} for plane in planes
        }
        for member in members
    }
    points = {str(s): {m: runs[s]["front"][m]["points"] for m in per_seed} for s in seeds}
    crash = crash_plane(first)
    if crash is not None:
        # Per-step terms hide how often an episode ends in a crash: the episode-outcome plane shows it.
        objectives, reference = crash
        planes = {**planes, CRASH_PLANE: [list(o) for o in objectives]}
        references[CRASH_PLANE] = list(reference)
        for seed in points:
            for member in per_seed:
                points[seed][member] = [with_crash_rate(p) for p in points[seed][member]]
                per_seed[member][CRASH_PLANE] = {
                    **per_seed[member].get(CRASH_PLANE, {}),
                    seed: hypervolume(points[seed][member], objectives, reference),
                }
    summaries = {
        member: {plane: summarise(list(values.values())) for plane, values in by_plane.items()}
        for member, by_plane in per_seed.items()
    }
    comparisons = _front_comparisons(per_seed, members, seeds, planes)
    results: FrontResults = {
        "members": members,
        "references": references,
        "planes": planes,
        "hypervolume_per_seed": per_seed,
        "hypervolume": summaries,
        "comparisons": comparisons,
        "decides_by_state": {str(s): runs[s].get("decides_by_state", {}) for s in seeds},
        "points": points,
    }
    if "manager" in first:
        results["manager"] = cast(FrontManager, first["manager"])
    morl = morl_results(runs, workers or {})
    if morl is not None:
        results["morl"] = morl
    flat_runs = {
        method: {str(s): _flat_point(by_seed[s]) for s in seeds if s in by_seed}
        for method, by_seed in (flat or {}).items()
    }
    if any(flat_runs.values()):
        results["flat"] = {method: points for method, points in flat_runs.items() if points}
    if "outcomes" in planes:
        results["safe_touch"] = {
            "contacts": SAFE_CONTACTS,
            "per_seed": {
                m: {str(s): safe_touch(runs[s]["front"][m]["points"]) for s in seeds} for m in per_seed
            },
            "best_reach": {
                m: {str(s): safe_best_reach(runs[s]["front"][m]["points"]) for s in seeds} for m in per_seed
            },
        }
    return results


def _flat_point(record: Mapping[str, Any]) -> dict[str, float]:
    """A flat run's reach reward on its test episodes (their mean: a copied record holds them) and its env steps."""
    reach = float(np.mean([float(e["reach_reward"]) for e in record["episodes"]]))
    return {"mean_reach_reward": reach, "env_steps": float(record["history"][-1]["total_timesteps"])}


def _front_comparisons(
    per_seed: Mapping[str, Mapping[str, Mapping[str, float]]],
    members: list[str],
    seeds: list[int],
    planes: Mapping[str, object],
) -> dict[str, FrontComparison]:
    """
    The conditioned manager's paired differences with every other member, and GPI's (where the front has it)
    with every member but the conditioned manager, per plane, adjusted by the one decision rule
    (:func:`_adjust_front_comparisons`); none with fewer than two seeds.

    :param per_seed: member -> plane -> seed -> hypervolume.
    :param members: the members every seed has.
    :param seeds: the seeds.
    :param planes: the planes measured.
    :return: ``"CHALLENGER vs OTHER"`` -> its comparison.
    """
    comparisons: dict[str, FrontComparison] = {}
    # The conditioned manager against every other member; GPI, where the front has it, against the rest.
    challengers = [c for c in ("conditioned", "gpi") if c in per_seed]
    for challenger in challengers if len(seeds) >= 2 else ():  # one seed makes no paired interval
        for other in members:
            if other in challengers[: challengers.index(challenger) + 1]:
                continue
            entry: FrontComparison = {"seeds": seeds, "planes": {}}
            for plane in planes:
                xa = np.array([per_seed[challenger][plane][str(s)] for s in seeds])
                xb = np.array([per_seed[other][plane][str(s)] for s in seeds])
                interval = paired_t_interval(xa, xb)
                entry["planes"][plane] = {
                    "difference": interval["difference"],
                    "ci_low": interval["ci_low"],
                    "ci_high": interval["ci_high"],
                    "p_value": interval["p_value"],
                    "wins": int(np.sum(xa > xb)),
                    "probability_of_improvement": probability_of_improvement(xa, xb),
                    "standard_error": interval["standard_error"],
                    "equivalence_margin": float(EQUIVALENCE_MARGIN * abs(xb.mean())),
                }
            comparisons[f"{challenger} vs {other}"] = entry
    _adjust_front_comparisons(comparisons)
    return comparisons


def _adjust_front_comparisons(comparisons: Mapping[str, FrontComparison]) -> None:
    """
    The benchmark's one decision rule on the front's table, in place: per plane the front's comparisons are
    one family, Holm-adjusted, each with the t interval at its Holm-consistent level
    (:func:`~hddpg_zoo.stats.holm_confidences`).
    """
    planes = {plane for entry in comparisons.values() for plane in entry["planes"]}
    for plane in sorted(planes):
        members = [entry["planes"][plane] for entry in comparisons.values() if plane in entry["planes"]]
        p_values = [c["p_value"] for c in members]
        for c, p_holm, confidence, n in zip(
            members,
            holm_adjust(p_values),
            holm_confidences(p_values, FAMILY_ALPHA),
            [len(entry["seeds"]) for entry in comparisons.values() if plane in entry["planes"]],
            strict=True,
        ):
            c["p_holm"] = p_holm
            c["confidence_adjusted"] = confidence
            c["ci_low_adjusted"], c["ci_high_adjusted"] = t_interval(
                c["difference"], c["standard_error"], n, confidence
            )
