"""Equal effort you can check: trial budgets as a share of the final budget, studies exported, the table generated."""

from __future__ import annotations

import json
from pathlib import Path

import optuna
import pytest
from optuna.distributions import FloatDistribution
from optuna.trial import TrialState, create_trial

from hddpg_zoo.benchmark.pages import render_page
from hddpg_zoo.study_export import export_study, read_exports, studies_table, study_effort
from hddpg_zoo.tuning import TuningTarget, check_budget_fraction
from tests.cli_batch import run_batch

ROOT = Path(__file__).resolve().parents[1]


def test_trial_budget_as_a_share_of_the_final_budget():
    target = TuningTarget(level="flat", algo="sac", budget_fraction=0.1, final_budget=340_000)
    assert target.budget() == 34_000
    described = target.describe()
    assert described["budget_fraction"] == 0.1 and described["final_budget"] == 340_000
    assert described["timesteps"] == 34_000 and described["episode_set"] == "tuning"
    # A study made before the fraction and the tuning episodes describes itself as it did.
    old = TuningTarget(level="flat", timesteps=40_000, episode_set="curve").describe()
    assert "budget_fraction" not in old and "episode_set" not in old
    for args, message in (
        ((1.5, 100, None), "budget_fraction in \\(0, 1\\]"),
        ((0.1, None, None), "final_budget >= 1"),
        ((0.1, 100, 50), "not both"),
    ):
        with pytest.raises(ValueError, match=message):
            check_budget_fraction(*args)
    with pytest.raises(ValueError, match="episode_set"):
        TuningTarget(level="flat", episode_set="final-test")


def make_study(url: str, name: str, target: TuningTarget, values: list[float | None]) -> None:
    study = optuna.create_study(storage=url, study_name=name, direction="maximize")
    study.set_user_attr("target", target.describe())
    for value in values:
        state = TrialState.COMPLETE if value is not None else TrialState.PRUNED
        study.add_trial(
            create_trial(
                state=state,
                value=value,
                params={"learning_rate": 1e-3},
                distributions={"learning_rate": FloatDistribution(1e-5, 1e-2, log=True)},
                user_attrs={"seed_peaks": [value or 0.0], "history": [{"timesteps": 1}] * 3},
            )
        )


def test_studies_are_exported_and_summarised(tmp_path):
    url = f"sqlite:///{tmp_path / 'studies.db'}"
    flat = TuningTarget(level="flat", algo="sac", budget_fraction=0.1, final_budget=340_000)
    manager = TuningTarget(level="flat", algo="ddpg", budget_fraction=0.1, final_budget=40_000, n_seeds=3)
    make_study(url, "flat-sac", flat, [300.0, None, 301.5])
    make_study(url, "flat-ddpg", manager, [290.0, 295.0, None])

    # Through the CLI: one JSON per study; the three command lines in one interpreter (tests/cli_batch.py),
    # each with its own exit code and output.
    out = tmp_path / "run" / "studies"
    *done, missing = run_batch(
        [
            ["export-study", "--storage", url, "--study-name", name, "--out", str(out)]
            for name in ("flat-sac", "flat-ddpg", "nope")
        ]
    )
    for result in done:
        assert result.returncode == 0, result.stdout + result.stderr
    assert missing.returncode == 2 and "no study 'nope'" in missing.stderr + missing.stdout
    assert "Traceback" not in missing.stderr

    exported = json.loads((out / "flat-sac.json").read_text())
    assert [t["state"] for t in exported["trials"]] == ["COMPLETE", "PRUNED", "COMPLETE"]
    assert "history" not in exported["trials"][0] and exported["trials"][0]["seed_peaks"] == [300.0]
    assert exported == export_study(url, "flat-sac")

    exports = read_exports(out)
    efforts = {e["study"]: e for e in map(study_effort, exports)}
    assert (
        efforts["flat-sac"]["env_steps_at_most"] == 3 * 34_000 and efforts["flat-sac"]["best_value"] == 301.5
    )
    assert efforts["flat-ddpg"]["env_steps_at_most"] == 3 * 3 * 4_000
    table = studies_table(exports)
    assert (
        "| `flat-sac` | flat | sac | 3 (2 + 1) | 34,000 x 1 | 10% of 340,000 | 102,000 | tuning episodes | 301.5 |"
        in table
    )

    page = "<!-- generated:run/studies -->\nold\n<!-- /generated:run/studies -->\n"
    text, written = render_page(page, "run", {}, {"studies": lambda: table})
    assert written == ["studies"] and table in text


def test_the_shipped_studies_table_regenerates_from_the_shipped_exports():
    from hddpg_zoo.benchmark.pages import update_tuning_page

    record = ROOT / "docs" / "results" / "record"
    outcome = update_tuning_page(record, ROOT / "docs" / "TUNING.md", check=True)
    assert outcome["written"] == ["studies"]
    assert outcome["changed"] == [], "run `hddpg-cli report docs/results/record` to regenerate"
    names = {path.stem for path in (record / "studies").glob("*.json")}
    assert {"goal", "avoid", "ddpg", "sac", "ddpg-her", "sac-her", "hddpg", "hddpg-front", "ham"} <= names


def test_report_on_study_exports_alone_writes_only_the_tuning_table(tmp_path):
    run = tmp_path / "studies-run"
    (run / "studies").mkdir(parents=True)
    shipped = ROOT / "docs" / "results" / "record" / "studies"
    for name in ("ddpg", "ham"):
        (run / "studies" / f"{name}.json").write_text((shipped / f"{name}.json").read_text())
    page = tmp_path / "tuning.md"
    page.write_text(
        "before\n<!-- generated:studies-run/studies -->\nstale\n<!-- /generated:studies-run/studies -->\n"
    )
    # Both command lines in one interpreter (tests/cli_batch.py), each with its own exit code and output;
    # the second: a folder that is neither a benchmark folder nor holds study exports, one line, exit 2.
    done, refused = run_batch(
        [["report", str(run), "--tuning-page", str(page)], ["report", str(tmp_path / "empty")]]
    )
    assert done.returncode == 0, done.stderr
    text = page.read_text()
    assert text.startswith("before\n") and "stale" not in text and "| `ddpg` | flat | ddpg |" in text
    assert refused.returncode == 2 and "Traceback" not in refused.stderr
