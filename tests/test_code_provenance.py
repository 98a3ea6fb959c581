"""Every benchmark invocation records the code it ran; a resumed benchmark refuses to mix commits unless told."""

from __future__ import annotations

import subprocess
from dataclasses import asdict

import pytest
from cli_runner import REPO, run_cli

from hddpg_zoo.benchmark import BenchmarkSettings
from hddpg_zoo.benchmark.benchmark_file import (
    check_same_code,
    invocation_codes,
    read_benchmark_file,
)
from hddpg_zoo.provenance import CodeProvenance, code_provenance
from sb3_hddpg import __version__
from sb3_hddpg.artifacts.io import atomic_write_json

OTHER = "0" * 40


def test_the_code_of_this_checkout_is_its_version_and_commit():
    code = code_provenance()
    assert code.version == __version__
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True)
    if head.returncode != 0:
        pytest.skip("this copy of the package is not a git checkout")
    assert code.commit == head.stdout.strip() and isinstance(code.clean, bool)
    assert CodeProvenance.from_json(code.to_json(), "code") == code


def test_without_a_repository_or_git_the_commit_is_not_recorded(tmp_path, monkeypatch):
    # A folder outside any repository (as an installed wheel's): no commit, and no error.
    assert code_provenance(tmp_path) == CodeProvenance(__version__, None, None)
    monkeypatch.setenv("PATH", str(tmp_path))  # no git on the path
    assert code_provenance() == CodeProvenance(__version__, None, None)
    assert code_provenance().describe() == f"{__version__} (commit not recorded)"


@pytest.mark.parametrize(
    ("value", "match"),
    [
        ({"commit": OTHER}, "package version"),
        ({"version": "1", "commit": "abc"}, "commit: expected 40"),
        ({"version": "1", "commit": OTHER, "clean": "yes"}, "clean: expected"),
    ],
)
def test_a_bad_code_field_is_one_line_naming_it(value, match):
    with pytest.raises(ValueError, match=match):
        CodeProvenance.from_json(value, "benchmark.json: invocations[0].code")


def test_resuming_with_other_code_is_refused_unless_allowed():
    here = CodeProvenance("0.1.0", "a" * 40, True)
    assert check_same_code([here, CodeProvenance("0.1.0", "a" * 40, False)], here, False, "runs/b") is False
    with pytest.raises(ValueError, match=r"runs/b was run by 0\.1\.0 at 000000000000.*--allow-mixed-commits"):
        check_same_code([CodeProvenance("0.1.0", OTHER, True)], here, False, "runs/b")
    # Records from before the field: their code cannot be proven the same.
    with pytest.raises(ValueError, match="not recorded"):
        check_same_code([None], here, False, "runs/b")
    assert check_same_code([None, CodeProvenance("0.1.0", OTHER)], here, True, "runs/b") is True


def _folder(tmp_path, code: dict | None):
    settings = BenchmarkSettings(methods=["ham"], seeds=[0], timesteps=1000, worker_timesteps=100)
    invocation = {"started": "2026-01-01T00:00:00Z", "wall_time_s": 1.0, "interrupted": True}
    if code is not None:
        invocation["code"] = code
    out = tmp_path / "bench"
    atomic_write_json(out / "benchmark.json", {"settings": asdict(settings), "invocations": [invocation]})
    return out, settings


def test_a_folder_records_each_invocations_code(tmp_path):
    out, _ = _folder(tmp_path, {"version": "0.1.0", "commit": OTHER, "clean": False})
    header = read_benchmark_file(out / "benchmark.json")
    assert invocation_codes(header, "b") == [CodeProvenance("0.1.0", OTHER, False)]
    assert (
        check_same_code(invocation_codes(header, "b"), CodeProvenance("0.1.0", OTHER, True), False, "b")
        is False
    )
    bad, _ = _folder(tmp_path / "bad", {"version": 1})
    with pytest.raises(ValueError, match=r"invocations\[0\]\.code"):
        invocation_codes(read_benchmark_file(bad / "benchmark.json"), "benchmark.json")


def test_the_library_refuses_before_anything_runs(tmp_path):
    from hddpg_zoo.benchmark import run_benchmark

    out, settings = _folder(tmp_path, {"version": "0.0.1", "commit": OTHER, "clean": True})
    with pytest.raises(ValueError, match="allow-mixed-commits"):
        run_benchmark(settings, out, resume=True)
    assert not (out / "records").exists()


def test_the_cli_refuses_mixed_commits_with_one_line_and_exit_2(tmp_path):
    out, _ = _folder(tmp_path, {"version": "0.0.1", "commit": OTHER, "clean": True})
    before = (out / "benchmark.json").read_bytes()
    result = run_cli(
        "benchmark", "--methods", "ham", "--seeds", "1", "--timesteps", "1000", "--worker-timesteps", "100",
        "--resume", "--out", out, timeout=300,
    )  # fmt: skip
    assert result.returncode == 2, result.stderr
    assert "--allow-mixed-commits" in result.stderr and "0.0.1 at 000000000000" in result.stderr
    assert "Traceback" not in result.stderr
    assert (out / "benchmark.json").read_bytes() == before  # nothing of the folder touched


def test_a_resume_allowed_to_mix_commits_runs_and_says_so(tmp_path):
    import json

    from hddpg_zoo.benchmark import run_benchmark

    out, settings = _folder(tmp_path, {"version": "0.0.1", "commit": OTHER, "clean": True})
    settings = BenchmarkSettings(
        methods=["ham"], seeds=[0], timesteps=1000, worker_timesteps=100, test_episodes=2, eval_episodes=1
    )
    atomic_write_json(
        out / "benchmark.json",
        {**json.loads((out / "benchmark.json").read_text()), "settings": asdict(settings)},
    )
    run_benchmark(settings, out, resume=True, allow_mixed_commits=True)
    earlier, this = json.loads((out / "benchmark.json").read_text())["invocations"]
    assert earlier["code"]["commit"] == OTHER and "mixed_commits" not in earlier
    assert this["mixed_commits"] is True and this["code"] == code_provenance().to_json()
