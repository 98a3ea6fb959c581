"""``python -m build`` makes an sdist and a wheel that install cleanly in a fresh virtual environment."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from sb3_hddpg.algorithms import REGISTRY

REPO = Path(__file__).resolve().parents[1]
# Not shipped, or rebuilt: what a fresh clone does not have either.
LOCAL = (".git", ".venv", "runs", "build", "dist", "*.egg-info", "__pycache__", ".*_cache", ".hypothesis")

pytestmark = pytest.mark.slow  # a fresh environment installs torch and every dependency: minutes


def _run(*args: object, cwd: Path | None = None, env: dict[str, str] | None = None) -> str:
    # Without PYTHONPATH: a checkout on the path would hide what the installed package lacks.
    env = env or {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    result = subprocess.run(
        [str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True, timeout=1800
    )
    assert result.returncode == 0, f"{args}:\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
    return result.stdout


def test_sdist_and_wheel_install_in_a_fresh_venv(tmp_path):
    pytest.importorskip("build")
    if shutil.which("make") is None:
        pytest.skip("needs make (the venv is made by the Makefile's torch target)")
    source = tmp_path / "src"
    shutil.copytree(REPO, source, symlinks=True, ignore=shutil.ignore_patterns(*LOCAL))
    # The sdist first, then the wheel built from it: a file missing from the sdist breaks the wheel.
    _run(sys.executable, "-m", "build", "--outdir", tmp_path / "dist", source)
    wheels = list((tmp_path / "dist").glob("sb3_hddpg-*-py3-none-any.whl"))
    sdists = list((tmp_path / "dist").glob("sb3_hddpg-*.tar.gz"))
    assert len(wheels) == 1 and len(sdists) == 1
    with zipfile.ZipFile(wheels[0]) as archive:
        names = set(archive.namelist())
    # Package data (the zoo_configs link at the root is a checkout convenience; the files live in the package).
    for data in ("version.txt", "py.typed", *(f"zoo_configs/{a}.yml" for a in REGISTRY)):
        assert f"sb3_hddpg/{data}" in names, data
    assert not any(name.startswith("tests/") for name in names)
    # One install, two packages: the harness beside the library.
    assert {"hddpg_zoo/__init__.py", "hddpg_zoo/py.typed", "hddpg_zoo/cli/benchmark.py"} <= names

    # A fresh venv made the Makefile's way (CPU torch first), then the wheel with its dependencies.
    venv = tmp_path / "venv"
    _run("make", "-C", REPO, f"VENV={venv}", f"PYTHON={sys.executable}", "torch")
    python = venv / "bin" / "python"
    _run(python, "-m", "pip", "install", "--quiet", wheels[0])
    _run(python, "-m", "pip", "check")
    outside = tmp_path / "elsewhere"  # not the checkout: the installed package must be complete on its own
    outside.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env.update(SDL_VIDEODRIVER="dummy", SDL_AUDIODRIVER="dummy", MPLBACKEND="Agg")
    probe = (
        "import sb3_hddpg, gymnasium as gym\n"
        "from sb3_hddpg.training.config import agent_kwargs, default_config\n"
        "assert '/site-packages/' in sb3_hddpg.__file__, sb3_hddpg.__file__\n"
        "assert all(default_config(a).is_file() for a in ('ddpg', 'td3', 'sac', 'tqc'))\n"
        "kwargs = agent_kwargs('hddpg/SnakeGoal-v0', gym.make('hddpg/SnakeGoal-v0'))\n"
        "print(sb3_hddpg.__version__, kwargs['policy_kwargs'])\n"
    )
    version = (REPO / "sb3_hddpg" / "version.txt").read_text().strip()
    assert _run(python, "-c", probe, cwd=outside, env=env).split()[0] == version
    assert (
        _run(venv / "bin" / "hddpg-cli", "--version", cwd=outside, env=env).strip() == f"sb3-hddpg {version}"
    )
    printed = _run(
        venv / "bin" / "hddpg-cli", "evaluate", "scripted", "--episodes", "1", cwd=outside, env=env
    )
    assert "touching the goal" in printed
    # The wheel's own dependencies hold no harness package: a harness command names the extra in one line.
    harness = subprocess.run(
        [venv / "bin" / "hddpg-cli", "benchmark", "--help"],
        cwd=outside,
        env=env,
        capture_output=True,
        text=True,
    )
    assert harness.returncode == 2 and 'pip install "sb3-hddpg[bench]"' in harness.stderr, harness.stderr

    # The sdist installs too (built into a wheel by pip), with the same package data.
    _run(python, "-m", "pip", "install", "--quiet", "--force-reinstall", "--no-deps", sdists[0])
    _run(python, "-c", probe, cwd=outside, env=env)
