"""The typed records beside trained models: one builder and one reader each, the same JSON on disk."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hddpg_zoo.records import (
    BenchmarkRecord,
    BenchmarkResults,
    Comparison,
    MethodResults,
    benchmark_record,
    benchmark_results,
    read_benchmark_record,
    read_benchmark_results,
)
from sb3_hddpg.artifacts.io import atomic_write_json, json_text
from sb3_hddpg.artifacts.limits import (
    MAX_CRITICS,
    MAX_QUANTILES,
    LimitError,
)
from sb3_hddpg.artifacts.network_limits import check_network_size
from sb3_hddpg.artifacts.records import (
    BENCHMARK_RECORD_VERSION,
    BENCHMARK_RESULTS_VERSION,
    WORKERS_MANIFEST_VERSION,
    BundleManifest,
    ModelsManifest,
    bundle_manifest,
    models_manifest,
    read_models_manifest,
    read_workers_manifest,
)
from sb3_hddpg.artifacts.records.ham import ham_file, read_ham_file
from sb3_hddpg.artifacts.run_folder import RUN_MARKER, _names, _read_marker

SHA = "0" * 64
SHIPPED_RESULTS = sorted((Path(__file__).parents[1] / "docs" / "results").glob("**/results.json"))


def _entry(name: str) -> dict[str, object]:
    return {
        "name": name,
        "file": f"{name}.zip",
        "sha256": SHA,
        "algo": "ddpg",
        "env_kwargs": {"observe": ["x"]},
    }


def test_models_manifest_round_trips_and_reads_as_its_json(tmp_path: Path) -> None:
    manifest = models_manifest("workers", {"goal": _entry("goal")}).with_shared_env("hddpg/SnakeReach-v0", {})
    manifest = manifest.with_entry("avoid", _entry("avoid"))
    path = atomic_write_json(tmp_path / "manifest.json", manifest)  # a record is written as its JSON
    on_disk = json.loads(path.read_text())
    assert on_disk == {
        "schema_version": WORKERS_MANIFEST_VERSION,
        "workers": {"goal": _entry("goal"), "avoid": _entry("avoid")},
        "shared_env": {"env_id": "hddpg/SnakeReach-v0", "env_kwargs": {}},
    }
    read = read_workers_manifest(path)
    assert isinstance(read, ModelsManifest) and read.names == ["goal", "avoid"]
    assert read.shared_env == {"env_id": "hddpg/SnakeReach-v0", "env_kwargs": {}}
    # Code that reads a manifest as the JSON object it was keeps working.
    assert read["workers"]["goal"]["file"] == "goal.zip" and dict(read) == on_disk


def test_a_manifest_without_a_schema_version_still_reads(tmp_path: Path) -> None:
    path = tmp_path / "manifest.json"
    path.write_text(json.dumps({"models": {"ddpg": _entry("ddpg")}}))
    assert read_models_manifest(path, "models").schema_version == 1


@pytest.mark.parametrize(
    "change, needle",
    [
        (lambda m: m.update(schema_version=WORKERS_MANIFEST_VERSION + 1), "unsupported schema version"),
        (lambda m: m.update(schema_version="1"), "unsupported schema version"),
        (lambda m: m["workers"].update({"../x": _entry("x")}), "expected a name"),
        (lambda m: m["workers"]["goal"].update(file="../goal.zip"), "file"),
        (lambda m: m.update(shared_env=["hddpg/SnakeReach-v0"]), "shared_env"),
        (lambda m: m.pop("workers"), "Not a valid workers manifest"),
    ],
)
def test_the_models_manifest_reader_refuses_what_it_cannot_use(tmp_path: Path, change, needle) -> None:
    manifest = {"schema_version": 1, "workers": {"goal": _entry("goal")}}
    change(manifest)
    path = tmp_path / "manifest.json"
    path.write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match=needle):
        read_workers_manifest(path)


def test_the_models_manifest_reader_goes_through_the_json_limits(tmp_path: Path) -> None:
    path = tmp_path / "manifest.json"
    path.write_text("[" * 10_000 + "]" * 10_000)
    with pytest.raises(LimitError):
        read_workers_manifest(path)


def _bundle_json() -> dict[str, object]:
    entry = {"file": "manager.zip", "sha256": SHA}
    workers = {n: {"file": f"workers/{n}.zip", "sha256": SHA, "kind": "sb3"} for n in ("goal", "avoid")}
    manifest = bundle_manifest(
        "hddpg/SnakeReach-v0", {}, ["goal", "avoid"], {}, entry, workers, {"python": "3"}
    )
    return manifest.to_json()


def test_bundle_manifest_round_trips() -> None:
    value = _bundle_json()
    assert value["kind"] == "sb3-hddpg-hierarchy" and value["schema_version"] == 1
    read = BundleManifest.from_json(json.loads(json_text(value, "manifest.json")), "b.zip")
    assert read.worker_names == ["goal", "avoid"] and read.to_json() == value
    assert [label for label, _ in read.member_entries()] == ["manager", "goal", "avoid"]


@pytest.mark.parametrize(
    "change, needle",
    [
        (lambda m: m.update(schema_version=2), "unsupported bundle schema version"),
        (lambda m: m.update(kind="other"), "not an sb3-hddpg hierarchy manifest"),
        (lambda m: m["workers"]["goal"].update(file="manager.zip"), "a bundle names it"),
        (lambda m: m.update(worker_names=["avoid", "goal"]), "do not match"),
        (lambda m: m["manager"].update(sha256="x"), "sha256"),
    ],
)
def test_the_bundle_manifest_reader_refuses_what_it_cannot_use(change, needle) -> None:
    value = _bundle_json()
    change(value)
    with pytest.raises(ValueError, match=needle):
        BundleManifest.from_json(value, "b.zip")


def test_ham_file_round_trips_with_its_metadata(tmp_path: Path) -> None:
    record = ham_file(
        2.5, 0.1, ["goal", "avoid"], "../w/manifest.json", "hddpg/SnakeReach-v0", {}, {"seed": 4}
    )
    path = atomic_write_json(tmp_path / "ham.json", record)
    on_disk = json.loads(path.read_text())
    assert on_disk["kind"] == "sb3-hddpg-ham" and on_disk["seed"] == 4
    assert on_disk["worker_names"] == {"goal": "goal", "avoid": "avoid"}
    read = read_ham_file(path)
    assert (read.threshold, read.hysteresis, read.names, read.metadata) == (
        2.5,
        0.1,
        ("goal", "avoid"),
        {"seed": 4},
    )
    assert read.to_json() == on_disk


@pytest.mark.parametrize(
    "change, needle",
    [
        (lambda m: m.update(schema_version=2), "reads up to 1"),
        (lambda m: m.update(threshold=float("inf")), "finite"),
        (lambda m: m.update(workers_manifest="/etc/passwd"), "manifest.json"),
        (lambda m: m.update(env_id="os:system"), "env_id"),
    ],
)
def test_the_ham_reader_refuses_what_it_cannot_use(tmp_path: Path, change, needle) -> None:
    value = ham_file(1.0, 0.0, ["goal", "avoid"], "w/manifest.json", "hddpg/SnakeReach-v0").to_json()
    change(value)
    path = tmp_path / "ham.json"
    path.write_text(json.dumps(value))
    with pytest.raises(ValueError, match=needle):
        read_ham_file(path)


def test_benchmark_record_round_trips_and_refuses_newer_versions(tmp_path: Path) -> None:
    record = benchmark_record("hddpg", 3, {"config_blocks": {}, "test": {"success_rate": 0.5}})
    value = record.to_json()
    assert list(value)[:5] == ["record_version", "method", "seed", "status", "config_blocks"]
    path = atomic_write_json(tmp_path / "seed-3.json", value)
    read = read_benchmark_record(path)
    assert isinstance(read, BenchmarkRecord) and read.results["test"] == {"success_rate": 0.5}
    path.write_text(json.dumps({**value, "record_version": BENCHMARK_RECORD_VERSION + 1}))
    with pytest.raises(ValueError, match="unsupported schema version"):
        read_benchmark_record(path)
    path.write_text(json.dumps({**value, "seed": -1}))
    with pytest.raises(ValueError, match="expected a benchmark record"):
        read_benchmark_record(path)


def test_one_network_check_for_configs_and_specs() -> None:
    # The critics bound is the same wherever a network comes from (a config used to allow 4096).
    with pytest.raises(LimitError, match="n_critics"):
        check_network_size("sac", {"net_arch": [16], "n_critics": MAX_CRITICS + 1})
    with pytest.raises(LimitError, match="n_quantiles"):
        check_network_size("tqc", {"net_arch": [16], "n_quantiles": MAX_QUANTILES + 1})
    # Without net_arch the algorithm's default layers are sized, so many critics are still counted.
    with pytest.raises(LimitError, match="parameters"):
        check_network_size("sac", {"n_critics": MAX_CRITICS}, obs_dim=4096, act_dim=8)
    assert check_network_size("ddpg", {"net_arch": [16]}, obs_dim=3, act_dim=1) > 0
    assert check_network_size("ddpg", None) == 0


def test_a_deep_run_marker_is_read_within_the_json_limits(tmp_path: Path) -> None:
    (tmp_path / RUN_MARKER).write_text("[" * 50_000 + "]" * 50_000)
    assert _read_marker(tmp_path) == {}
    (tmp_path / RUN_MARKER).write_text(json.dumps({"entries": ["report", "../x"]}))
    assert _names(_read_marker(tmp_path).get("entries")) == frozenset({"report"})


@pytest.mark.parametrize("path", SHIPPED_RESULTS, ids=lambda p: p.parent.name)
def test_every_shipped_results_file_reads_and_writes_back_the_same_json(path: Path) -> None:
    # Files from before aggregates, episode sets or a version existed read, with those parts empty.
    results = read_benchmark_results(path)
    assert isinstance(results, BenchmarkResults) and results.methods
    assert all(isinstance(entry, MethodResults) for entry in results.methods.values())
    assert all(isinstance(c, Comparison) for c in results.comparisons.values())
    written = results.to_json()
    assert written.pop("results_version") == 1
    original = json.loads(path.read_text())
    assert original.pop("results_version", 1) == 1  # files from before the version was written lack it
    assert written == original and list(written) == list(original)


def _small_results() -> BenchmarkResults:
    summary = {"mean": 1.0, "std": 0.0, "n": 2, "ci_low": 1.0, "ci_high": 1.0, "iqm": 1.0}
    return benchmark_results(
        settings={"seeds": [0, 1]},
        scenario="standard",
        metric="mean_reach_reward",
        methods={"hddpg": MethodResults((0, 1), {"0": {"slope": 1.0}}, {"slope": summary}, 10, 20)},
        comparisons={"hddpg vs ddpg": Comparison((0, 1), {"slope": {"difference": 0.5}}, 2.0)},
        comparison_families={"hddpg": {"comparisons": {"slope": 1}, "adjustment": "none"}},
        aggregates=None,
        workers={},
        colours={"hddpg": "tab:red"},
        test_seeds=(15_000, 15_019),
        test_episode_set={"name": "development", "first_seed": 15_000, "episodes": 20},
        curve_seeds=(10_000, 10_004),
        curve_window=2000,
        slope_unit_steps=1000,
    )


def test_benchmark_results_round_trip_with_the_run_and_its_curves(tmp_path: Path) -> None:
    results = _small_results().with_run(60.0, 120.0, 2, {"ddpg/seed-1": "diverged"}, {"nproc": 2})
    results = results.with_curves(
        {"own_steps": {"hddpg": {"x": [1.0], "mean": [2.0], "low": [1.0], "high": [3.0]}}}
    )
    path = atomic_write_json(tmp_path / "results.json", results.to_json())
    read = read_benchmark_results(path)
    assert read.to_json() == results.to_json()
    assert read.methods["hddpg"].stats["slope"]["mean"] == 1.0 and read.methods["hddpg"].own_timesteps == 20
    assert read.comparisons["hddpg vs ddpg"].slope_ratio == 2.0
    assert read.failures == {"ddpg/seed-1": "diverged"} and read["failures"] == {"ddpg/seed-1": "diverged"}
    assert read.run is not None and read.run.invocations == 2
    assert "aggregates" not in read  # none computed: left out, not written null


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        (lambda v: v.update(results_version=BENCHMARK_RESULTS_VERSION + 1), "unsupported schema version"),
        (lambda v: v.update(methods=[]), "methods: expected an object"),
        (lambda v: v["methods"]["hddpg"].update(seeds=["0"]), "'hddpg'.seeds: expected a list of seeds"),
        (lambda v: v["methods"]["hddpg"].update(stats={"slope": 3}), "stats.'slope': expected an object"),
        (lambda v: v["comparisons"]["hddpg vs ddpg"].update(slope_ratio="2"), "slope_ratio"),
        (lambda v: v.update(curve_window=True), "curve_window: expected a whole number"),
        (lambda v: v.update(wall_time_s_this_invocation="1 min"), "wall_time_s_this_invocation"),
    ],
)
def test_the_results_reader_refuses_what_it_cannot_use(tmp_path: Path, change, needle) -> None:
    value = _small_results().with_run(1.0).to_json()
    change(value)
    path = tmp_path / "results.json"
    path.write_text(json.dumps(value))
    with pytest.raises(ValueError, match=needle):
        read_benchmark_results(path)


def test_the_results_reader_goes_through_the_json_limits(tmp_path: Path) -> None:
    path = tmp_path / "results.json"
    path.write_text('{"methods": ' + "[" * 10_000 + "]" * 10_000 + "}")
    with pytest.raises(LimitError, match="nested"):
        read_benchmark_results(path)
    path.write_text("not json")
    with pytest.raises(ValueError, match="not readable benchmark results"):
        read_benchmark_results(path)
