"""
Per-episode records of the benchmark's test evaluations, ``episodes.csv``, and the one function that derives a
seed's test metrics from them (:func:`seed_metrics`), so that ``results.json`` follows from the episodes.

A row holds the run (method, seed), the episode set and the episode's seed, and every metric the evaluation
measures, generic over the env's reward terms: the raw episode sum of each term (``raw:<term>``) and of each
normalised term (``norm:<term>``), their normalised total, and the snake's touch, collision and clearance
metrics where the env reports them.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import cast

import numpy as np

from sb3_hddpg.artifacts.io import atomic_write
from sb3_hddpg.artifacts.limits import MAX_CSV_BYTES, MAX_CSV_CELLS, LimitError, read_file_bytes
from sb3_hddpg.artifacts.records import JsonObject
from sb3_hddpg.envs.contract import TermNormaliser
from sb3_hddpg.evaluation import EvaluationResult

#: Columns of ``episodes.csv`` before the metrics.
EPISODE_KEYS = ("method", "seed", "episode_set", "episode_seed")
#: An episode's metric -> the per-seed metric (the mean over the seed's episodes) it makes.
SEED_METRIC_OF = {
    "reward": "mean_reward",
    "reach_reward": "mean_reach_reward",
    "length": "mean_length",
    "goal_touch_rate": "goal_touch_rate",
    "goal_touched": "goal_reached_rate",
    "collisions": "collisions_per_episode",
    "success": "success_rate",
    "min_clearance": "min_clearance",
    "action_saturation": "action_saturation",
}
#: One row of ``episodes.csv``: the run's columns (text, whole numbers) and the episode's numbers.
EpisodeRow = dict[str, str | int | float]

#: The term that is negative only in an episode that ends in a crash (MO-Gymnasium's highway envs pay it -1 on
#: a crash, which ends the episode, and 0 otherwise): its episodes with a negative raw sum make ``crash_rate``.
CRASH_TERM = "collision"

#: Prefixes of the per-term columns: a term's raw episode sum, and its normalised episode sum.
RAW_PREFIX, NORMALISED_PREFIX = "raw:", "norm:"


def episode_rows(result: EvaluationResult, bounds: Mapping[str, Sequence[float]]) -> list[dict[str, float]]:
    """
    Every episode of an evaluation as a flat row of numbers (booleans as 0/1; metrics the env does not
    report left out).

    :param result: an evaluation (:func:`sb3_hddpg.evaluation.evaluate`).
    :param bounds: the env's per-step reward bounds (its contract's ``reward_bounds``), to normalise terms.
    """
    normaliser = TermNormaliser(bounds)
    rows = []
    for episode in result.episodes:
        row: dict[str, float] = {"episode_seed": episode.seed}
        for key in SEED_METRIC_OF:
            value = getattr(episode, key)
            if value is not None:
                row[key] = float(value)
        for term, raw in episode.term_rewards.items():
            row[f"{RAW_PREFIX}{term}"] = float(raw)
            row[f"{NORMALISED_PREFIX}{term}"] = normaliser.episode_sum(term, raw, episode.length)
        rows.append(row)
    return rows


def term_sum_keys(values: Iterable[str]) -> list[str]:
    """
    The keys among ``values`` of each reward term's normalised episode sum (``<term>_reach_reward``, as
    :func:`seed_metrics` names them): on another env they add up to its normalised return.
    """
    return sorted(k for k in values if k.endswith("_reach_reward") and k != "mean_reach_reward")


def seed_metrics(rows: Iterable[Mapping[str, str | int | float]]) -> dict[str, float]:
    """
    A seed's test metrics from its episode rows: the mean of each metric over the episodes, under the names of
    an evaluation summary (``mean_reach_reward``, ``collisions_per_episode``, ``mean_<term>_reward``,
    ``<term>_reach_reward``...). The one derivation of per-seed test metrics from episodes.

    :param rows: the seed's rows (of one run, one episode set).
    :raises ValueError: no rows.
    """
    rows = list(rows)
    if not rows:
        raise ValueError("Expected the episode rows of a run, actually: none")
    out: dict[str, float] = {"episodes": float(len(rows))}
    for key in sorted({k for row in rows for k in row} - {*EPISODE_KEYS}):
        values = [float(row[key]) for row in rows if row.get(key) not in (None, "")]
        if len(values) != len(rows):
            continue  # a metric some episodes lack is not averaged over the others
        if key.startswith(RAW_PREFIX):
            name = f"mean_{key[len(RAW_PREFIX) :]}_reward"
        elif key.startswith(NORMALISED_PREFIX):
            name = f"{key[len(NORMALISED_PREFIX) :]}_reach_reward"
        elif key in SEED_METRIC_OF:
            name = SEED_METRIC_OF[key]
        else:
            continue
        out[name] = float(np.mean(values))
    crash = f"{RAW_PREFIX}{CRASH_TERM}"
    if all(row.get(crash) not in (None, "") for row in rows):
        out["crash_rate"] = float(np.mean([float(row[crash]) < 0 for row in rows]))
    return out


def records_episode_rows(records: Iterable[JsonObject]) -> list[EpisodeRow]:
    """The rows of ``episodes.csv`` from the records that hold test episodes (older records hold none)."""
    rows: list[EpisodeRow] = []
    for record in records:
        episodes = record.get("episodes")
        if not episodes:
            continue
        base: EpisodeRow = {
            "method": record["method"],
            "seed": record["seed"],
            "episode_set": record.get("test_episode_set", {}).get("name", ""),
        }
        rows.extend({**base, **row} for row in episodes)
    return rows


def write_episodes_csv(path: Path, rows: Sequence[Mapping[str, str | int | float]]) -> Path:
    """Write ``episodes.csv`` atomically: the run columns, then every metric column any row has, sorted."""
    metric_keys = sorted({k for row in rows for k in row} - set(EPISODE_KEYS))

    def write(tmp: Path) -> None:
        with open(tmp, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=[*EPISODE_KEYS, *metric_keys], restval="")
            writer.writeheader()
            writer.writerows({k: _cell(v) for k, v in row.items()} for row in rows)

    return atomic_write(path, write)


def _cell(value: str | int | float) -> str | int:
    """Floats written with ``repr`` precision, so that a read-back row gives the same means."""
    return repr(value) if isinstance(value, float) else value


def read_episodes_csv(path: Path) -> list[EpisodeRow]:
    """
    Read ``episodes.csv``: ``seed`` and ``episode_seed`` as integers, every metric as a finite float (an empty
    cell: the metric is not reported there, left out of the row).

    :raises ValueError: a file over :data:`~sb3_hddpg.artifacts.limits.MAX_CSV_BYTES`, a missing run column,
        or a cell that is not a finite number, naming the file and the line.
    """
    try:
        # A regular file within the limit, read once (a FIFO would block the reader forever).
        text = read_file_bytes(path, MAX_CSV_BYTES).decode("utf-8")
    except LimitError as error:
        raise ValueError(f"{error}: not an episodes.csv of ours") from None
    except UnicodeDecodeError:
        raise ValueError(f"{str(path)!r} is not UTF-8 text: not an episodes.csv of ours") from None
    rows: list[EpisodeRow] = []
    cells = 0
    with io.StringIO(text, newline="") as handle:
        reader = csv.DictReader(handle)
        try:
            missing = [k for k in EPISODE_KEYS if k not in (reader.fieldnames or [])]
            if missing:
                raise ValueError(
                    f"{str(path)!r}: expected the columns {list(EPISODE_KEYS)}, missing {missing}"
                )
            for raw in reader:
                rows.append(_parse_row(raw, f"{path}:{reader.line_num}"))
                cells += len(rows[-1])
                if cells > MAX_CSV_CELLS:
                    raise ValueError(
                        f"{str(path)!r}: more than {MAX_CSV_CELLS} cells by line {reader.line_num}: not an "
                        "episodes.csv of ours"
                    )
        except (csv.Error, UnicodeDecodeError) as error:  # a NUL byte, a field over csv's limit, not UTF-8
            raise ValueError(f"{path}:{reader.line_num}: not a CSV row ({error})") from None
    return rows


def _parse_row(raw: Mapping[str | None, str | list[str] | None], where: str) -> EpisodeRow:
    # csv's key for the cells past the header's, and its value for the missing ones.
    if None in raw or None in raw.values():
        raise ValueError(f"{where}: expected as many cells as the header has columns")
    cells = cast(Mapping[str, str], raw)
    row: EpisodeRow = {"method": cells["method"], "episode_set": cells["episode_set"]}
    for key, text in cells.items():
        if key in ("method", "episode_set") or text == "":
            continue
        try:
            value = float(text)
        except ValueError:
            raise ValueError(
                f"{where}: expected a number in column {key!r}, actually: {text[:40]!r}"
            ) from None
        whole = key in ("seed", "episode_seed")
        if not math.isfinite(value) or (whole and not value.is_integer()):
            kind = "a whole number" if whole else "a finite number"
            raise ValueError(f"{where}: expected {kind} in column {key!r}, actually: {text[:40]!r}")
        row[key] = int(value) if whole else value
    return row


def group_rows(rows: Iterable[EpisodeRow]) -> dict[str, dict[int, list[EpisodeRow]]]:
    """Rows by method, then seed."""
    grouped: dict[str, dict[int, list[EpisodeRow]]] = {}
    for row in rows:
        grouped.setdefault(str(row["method"]), {}).setdefault(int(row["seed"]), []).append(row)
    return grouped
