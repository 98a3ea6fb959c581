"""
Files someone else made, built hostile inside the tests: they never run code, never write outside the
output folder, and never cost more than a few hundred MB (docs/ROBUSTNESS.md, "Limits").

Each test is one class of defect: traversal names, module-prefixed and foreign env ids, env kwargs,
oversized members and zip bombs, nesting and fan-out, deep JSON, bad selection settings. The memory-hungry
ones run in a subprocess under ``RLIMIT_AS`` (:func:`run_limited`), so that a regression fails with a
``MemoryError`` instead of swapping the machine.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest
from stable_baselines3 import DDPG

import sb3_hddpg  # noqa: F401  (registers the ids)
from sb3_hddpg.artifacts.limits import MAX_MEMBER_BYTES, MAX_MODELS, MAX_NESTING
from sb3_hddpg.hierarchy import WorkerSelectionWrapper
from sb3_hddpg.hierarchy.bundle import BundleError
from sb3_hddpg.hierarchy.hierarchy import Hierarchy, SelectionConfig
from sb3_hddpg.hierarchy.loading import load_policy

ROOT = Path(__file__).resolve().parents[1]
#: Address space a child that loads hostile files may map beyond what its imports map. The imports' own share
#: is measured, not assumed: PyTorch's CUDA build (what pip installs where its CPU index cannot be reached)
#: maps several GB more than the CPU build's ~0.7 GB before any file is read.
MEMORY_HEADROOM = 1300 << 20
SMALL = {
    "buffer_size": 100,
    "learning_starts": 10,
    "seed": 0,
    "device": "cpu",
    "policy_kwargs": {"net_arch": [8]},
}


def run_limited(
    code: str, cwd: Path, headroom: int = MEMORY_HEADROOM, timeout: float = 300
) -> dict[str, Any]:
    """
    Run ``code`` in a fresh interpreter whose address space may grow by ``headroom`` bytes past what the
    imports of the code under test map; it must print one JSON line. A ``MemoryError`` or a kill shows as a
    failed run, never as a swapping machine.
    """
    prologue = textwrap.dedent(
        f"""
        import json, resource, sys
        import torch, stable_baselines3, sb3_hddpg.hierarchy.hierarchy  # their mappings are not the files'
        with open("/proc/self/status") as status:
            mapped = next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmSize:"))
        resource.setrlimit(resource.RLIMIT_AS, (mapped + {headroom}, mapped + {headroom}))
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", prologue + textwrap.dedent(code)],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=cwd,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert done.returncode == 0, f"exit {done.returncode}\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
    return json.loads(done.stdout.strip().splitlines()[-1])


def _worker(env_id: str) -> DDPG:
    return DDPG("MlpPolicy", gym.make(env_id), **SMALL)


def _hierarchy(workers: dict[str, Any]) -> Hierarchy:
    # Nested workers ("subN") learn the goal term; plain ones their own name's.
    terms = {n: "goal" for n in workers if n.startswith("sub")}
    env = WorkerSelectionWrapper(gym.make("hddpg/SnakeReach-v0"), workers, reward_terms=terms)
    manager = DDPG("MlpPolicy", env, **SMALL)
    config = SelectionConfig(preferences={n: 1.0 for n in workers}, reward_terms=terms)
    return Hierarchy(manager, workers, config)


@pytest.fixture(scope="module")
def bundle() -> bytes:
    """A valid two-worker bundle with untrained tiny networks (the tests edit copies of it)."""
    return _hierarchy(
        {"goal": _worker("hddpg/SnakeGoal-v0"), "avoid": _worker("hddpg/SnakeAvoid-v0")}
    ).to_bytes()


def _members(data: bytes) -> tuple[dict[str, Any], dict[str, bytes]]:
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    return json.loads(members.pop("manifest.json")), members


def _write(
    path: Path,
    manifest: Any,
    members: dict[str, bytes],
    rehash: bool = True,
    raw_manifest: bytes | None = None,
    zeros: dict[str, int] | None = None,
) -> Path:
    """
    A bundle with this manifest and these members; ``rehash`` makes every listed sha256 match; ``zeros``
    adds members of that many zero bytes, streamed (a zip bomb without holding it in memory).
    """
    if rehash and isinstance(manifest, dict):
        for entry in [manifest["manager"], *manifest["workers"].values()]:
            if isinstance(entry, dict) and entry.get("file") in members:
                entry["sha256"] = hashlib.sha256(members[entry["file"]]).hexdigest()
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("manifest.json", raw_manifest if raw_manifest is not None else json.dumps(manifest))
        for name, data in members.items():
            archive.writestr(name, data)
        for name, size in (zeros or {}).items():
            with archive.open(name, "w", force_zip64=True) as handle:
                block = bytes(1 << 20)
                for _ in range(size >> 20):
                    handle.write(block)
    return path


def _zeros_zip_member(size: int) -> bytes:
    """A zip holding one member of ``size`` zero bytes as policy.pth: a zip bomb (~1000x)."""
    buffer = io.BytesIO()
    with (
        zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as archive,
        archive.open("policy.pth", "w", force_zip64=True) as handle,
    ):
        block = bytes(1 << 20)
        for _ in range(size >> 20):
            handle.write(block)
    return buffer.getvalue()


# ---------------------------------------------------------------------------------------------- names
@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        (lambda m: m["workers"]["goal"].update(file="../../evil.zip"), "names member"),
        (lambda m: m["workers"]["goal"].update(file="/tmp/evil.zip"), "names member"),
        (lambda m: m["manager"].update(file="workers/goal.zip"), "names member"),
        (
            lambda m: m.update(
                worker_names=["../x", "avoid"],
                workers={"../x": m["workers"]["goal"], "avoid": m["workers"]["avoid"]},
            ),
            "worker_names",
        ),
        (lambda m: m["workers"]["avoid"].update(file="workers/goal.zip"), "names member"),  # fan-out by reuse
        (lambda m: m["workers"]["goal"].update(kind="pickle"), "unknown kind"),
    ],
    ids=["dotdot", "absolute", "manager-aliases-worker", "worker-name", "two-entries-one-member", "kind"],
)
def test_names_from_a_bundle_are_checked_before_they_pick_a_member(bundle, tmp_path, edit, needle):
    manifest, members = _members(bundle)
    edit(manifest)
    path = _write(tmp_path / "b.zip", manifest, members)
    with pytest.raises(BundleError, match=needle):
        Hierarchy.load(path)


def test_package_writes_nothing_outside_its_folder(tmp_path):
    """A worker entry whose algo is a path, and a zip with a ``../`` member: nothing lands outside ``--out``."""
    from hddpg_zoo.packaging import _unpack_model
    from sb3_hddpg.artifacts.provenance import sha256_file

    folder = tmp_path / "shared" / "workers"
    folder.mkdir(parents=True)
    worker = _worker("hddpg/SnakeGoal-v0")
    worker.save(folder / "goal.zip")
    with zipfile.ZipFile(folder / "goal.zip", "a") as archive:
        archive.writestr("../../escaped.txt", "outside")
    from sb3_hddpg.artifacts.spec import model_spec

    for algo in ("../../y", "/tmp/x/y"):
        entry = {
            "name": "goal",
            "file": "goal.zip",
            "sha256": sha256_file(folder / "goal.zip"),
            "algo": algo,
            "env_id": "hddpg/SnakeGoal-v0",
            "spec": model_spec(worker),
        }
        (folder / "manifest.json").write_text(json.dumps({"schema_version": 1, "workers": {"goal": entry}}))
        with pytest.raises(ValueError, match="algo"):
            load_policy(folder / "goal.zip")
    # Unpacking copies only SB3's own members: the '../../escaped.txt' member is not written anywhere.
    target = tmp_path / "pkg" / "unpacked"
    target.parent.mkdir()
    _unpack_model(folder / "goal.zip", target)
    assert sorted(p.name for p in target.iterdir()) == sorted(
        {"data", "policy.pth", "pytorch_variables.pth", "_stable_baselines3_version", "system_info.txt"}
        | {p.name for p in target.iterdir() if p.name.endswith(".optimizer.pth")}
    )
    assert not list(tmp_path.rglob("escaped.txt"))


# ------------------------------------------------------------------------------------------- env ids
def test_a_module_prefixed_env_id_imports_nothing(bundle, tmp_path, monkeypatch):
    marker = tmp_path / "pwned"
    (tmp_path / "evilmod.py").write_text(f"open({str(marker)!r}, 'w').close()\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    manifest, members = _members(bundle)
    for env_id in ("evilmod:hddpg/SnakeReach-v0", "os:hddpg/SnakeReach-v0"):
        manifest["env_id"] = env_id
        path = _write(tmp_path / "b.zip", manifest, members)
        with pytest.raises(BundleError, match="env_id"):
            Hierarchy.load(path)
        with pytest.raises(BundleError, match="env_id"):
            Hierarchy.load(path, trusted=True)  # --trust widens the allow-list, never to module prefixes
    assert not marker.exists() and "evilmod" not in sys.modules


def test_only_registered_allowed_env_ids_are_used(bundle, tmp_path):
    manifest, members = _members(bundle)
    manifest["env_id"] = "hddpg/Nope-v0"
    with pytest.raises(BundleError, match="not registered"):
        Hierarchy.load(_write(tmp_path / "a.zip", manifest, members))
    # A registered env that is not ours: refused by default, named in the message, allowed on opt-in.
    manifest["env_id"] = "Pendulum-v1"
    path = _write(tmp_path / "b.zip", manifest, members)
    with pytest.raises(BundleError, match="allowed_env_ids"):
        Hierarchy.load(path)
    # Opted in, the id passes the gate and the env is built (then the spaces do not fit: a clear error).
    with pytest.raises(BundleError, match=r"invalid settings.*(state_layout|observations of shape)"):
        Hierarchy.load(path, allowed_env_ids=["Pendulum-v1"])


def test_worker_manifest_env_ids_and_ham_files_pass_the_same_gate(tmp_path):
    from sb3_hddpg.artifacts.provenance import sha256_file
    from sb3_hddpg.artifacts.spec import model_spec
    from sb3_hddpg.baselines.ham import load_ham

    folder = tmp_path / "workers"
    folder.mkdir()
    worker = _worker("hddpg/SnakeGoal-v0")
    worker.save(folder / "goal.zip")
    entry = {"name": "goal", "file": "goal.zip", "sha256": sha256_file(folder / "goal.zip")}
    entry |= {"algo": "ddpg", "spec": model_spec(worker)}

    def write(**fields: Any) -> Path:
        (folder / "manifest.json").write_text(json.dumps({"workers": {"goal": {**entry, **fields}}}))
        return folder / "goal.zip"

    with pytest.raises(ValueError, match="env_id"):
        load_policy(write(env_id="evilmod:hddpg/SnakeGoal-v0"))
    with pytest.raises(ValueError, match="allowed_env_ids"):
        load_policy(write(env_id="Pendulum-v1"))
    assert load_policy(write(env_id="Pendulum-v1"), allowed_env_ids=["Pendulum-v1"]).env_id == "Pendulum-v1"
    assert load_policy(write(env_id="hddpg/SnakeGoal-v0")).env_id == "hddpg/SnakeGoal-v0"

    ham = tmp_path / "ham.json"
    base = {
        "kind": "sb3-hddpg-ham",
        "schema_version": 1,
        "workers_manifest": "workers/manifest.json",
        "worker_names": {"goal": "goal", "avoid": "goal"},
        "threshold": 0.1,
    }
    for fields, needle in [
        ({"env_id": "evilmod:hddpg/SnakeReach-v0"}, "env_id"),
        ({"env_id": "hddpg/SnakeReach-v0", "env_kwargs": ["n_joints", 4]}, "env_kwargs"),
        ({"env_id": "hddpg/SnakeReach-v0", "workers_manifest": "/etc/passwd"}, "workers_manifest"),
        (
            {"env_id": "hddpg/SnakeReach-v0", "worker_names": {"goal": "../x", "avoid": "goal"}},
            "worker_names",
        ),
    ]:
        ham.write_text(json.dumps({**base, **fields}))
        with pytest.raises(ValueError, match=needle):
            load_ham(ham)
    ham.write_text(json.dumps({k: v for k, v in base.items() if k != "workers_manifest"}))
    with pytest.raises(ValueError, match="workers_manifest"):
        load_ham(ham)


# ---------------------------------------------------------------------------------------- env kwargs
@pytest.mark.parametrize(
    ("env_kwargs", "needle"),
    [
        (["n_joints", 4], "env_kwargs"),
        ({"n_obstacles": 10_000_000}, "n_obstacles"),
        ({"substeps": 10**9}, "substeps"),
        ({"max_episode_steps": 10**12}, "max_episode_steps"),
        ({"render_mode": "human"}, "render_mode"),
        ({"n_joints": [4] * 1000}, "n_joints"),
    ],
    ids=["list", "obstacles", "substeps", "gym-make-key", "render-mode", "nested-value"],
)
def test_env_kwargs_from_a_file_are_the_envs_own_and_in_its_limits(bundle, tmp_path, env_kwargs, needle):
    manifest, members = _members(bundle)
    manifest["env_kwargs"] = env_kwargs
    with pytest.raises(BundleError, match=needle):
        Hierarchy.load(_write(tmp_path / "b.zip", manifest, members))


# ---------------------------------------------------------------------------- selection and structure
@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        (lambda m: m["selection"].update(selection="evil"), "selection.selection"),
        (lambda m: m["selection"].update(option_steps=-3), "option_steps"),
        (lambda m: m["selection"].update(temperature="abc"), "temperature"),
        (lambda m: m["selection"].update(floor=0.9), "floor"),
        (lambda m: m["selection"].update(floor=0.5), r"selection\.floor: .*\[0(\.0)?, 0\.5\)"),
        (lambda m: m["selection"].update(preferences={"goal": -1.0}), "preferences"),
        (lambda m: m["selection"].update(surprise=1), "surprise"),
        (lambda m: m.update(worker_names=[], workers={}), "2 and"),
        (lambda m: m.pop("worker_names"), "worker_names"),
        (lambda m: m["manager"]["spec"]["observation_space"].update(shape=[0], low=[], high=[]), "shape"),
        (lambda m: m.update(schema_version=True), "schema version"),
    ],
    ids=[
        "selection",
        "option-steps",
        "temperature",
        "floor",
        "floor-at-its-limit",
        "preference",
        "unknown-key",
        "zero-workers",
        "missing-key",
        "obs-shape-0",
        "bool-version",
    ],
)
def test_bad_settings_in_a_bundle_are_refused_by_name(bundle, tmp_path, edit, needle):
    manifest, members = _members(bundle)
    edit(manifest)
    with pytest.raises(BundleError, match=needle):
        Hierarchy.load(_write(tmp_path / "b.zip", manifest, members))


def test_deep_and_huge_json_is_refused_without_recursion(bundle, tmp_path):
    manifest, members = _members(bundle)
    deep = _write(tmp_path / "deep.zip", manifest, members, raw_manifest=b"[" * 200_000 + b"]" * 200_000)
    with pytest.raises(BundleError, match="nested"):
        Hierarchy.load(deep)
    huge = json.dumps({**manifest, "padding": "x" * (2 << 20)}).encode()
    with pytest.raises(BundleError, match="limit"):
        Hierarchy.load(_write(tmp_path / "huge.zip", manifest, members, raw_manifest=huge))
    folder = tmp_path / "w"
    folder.mkdir()
    (folder / "manifest.json").write_text("[" * 200_000)
    from sb3_hddpg.artifacts.manifests import read_workers_manifest

    with pytest.raises(ValueError, match="nested"):
        read_workers_manifest(folder / "manifest.json")


# ----------------------------------------------------------------------------- sizes (memory-limited)
def test_unlisted_members_are_never_read(bundle, tmp_path):
    manifest, members = _members(bundle)
    path = _write(tmp_path / "b.zip", manifest, members)
    with zipfile.ZipFile(path, "a", compression=zipfile.ZIP_STORED) as archive:
        archive.writestr("junk.bin", b"A" * 4096)
    # Damage the unlisted member's bytes: reading it would fail its CRC check.
    path.write_bytes(path.read_bytes().replace(b"A" * 4096, b"B" * 4096))
    assert Hierarchy.load(path).names == ["goal", "avoid"]


def test_oversized_members_and_zip_bombs_cost_little_memory(bundle, tmp_path):
    manifest, members = _members(bundle)
    # A listed worker replaced by zeros over the member limit, sha256 updated: refused from its header.
    bomb = _write(
        tmp_path / "listed.zip",
        json.loads(json.dumps(manifest)),
        {name: data for name, data in members.items() if name != "workers/goal.zip"},  # one entry per name
        zeros={"workers/goal.zip": MAX_MEMBER_BYTES + (1 << 20)},
    )
    # A worker zip whose policy.pth inflates 1000x to 100 MiB (under the size limit, over the ratio).
    inner = _zeros_zip_member(100 << 20)
    _write(tmp_path / "inner.zip", json.loads(json.dumps(manifest)), {**members, "workers/goal.zip": inner})
    result = run_limited(
        f"""
        from sb3_hddpg.hierarchy.hierarchy import Hierarchy
        out = {{}}
        for name in ("listed", "inner"):
            try:
                Hierarchy.load({str(tmp_path)!r} + "/" + name + ".zip")
                out[name] = "loaded"
            except ValueError as error:
                out[name] = str(error)
        print(json.dumps(out))
        """,
        tmp_path,
    )
    assert "over the" in result["listed"] and "workers/goal.zip" in result["listed"], result
    assert "zip bomb" in result["inner"] and "policy.pth" in result["inner"], result
    assert bomb.stat().st_size < 2 << 20  # a small file, as in the issue


@pytest.mark.slow
def test_an_unlisted_gigabyte_costs_no_memory(bundle, tmp_path):
    """The issue's case: a small bundle whose unlisted member inflates to 1 GiB loads under a 2 GiB limit."""
    manifest, members = _members(bundle)
    path = _write(tmp_path / "unlisted.zip", manifest, members, zeros={"junk.bin": 1 << 30})
    assert path.stat().st_size < 4 << 20
    result = run_limited(
        f"""
        from sb3_hddpg.hierarchy.hierarchy import Hierarchy
        print(json.dumps(Hierarchy.load({str(path)!r}).names))
        """,
        tmp_path,
    )
    assert result == ["goal", "avoid"]


@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        (lambda s: s["policy_kwargs"].update(net_arch=[65536, 65536]), "parameters"),
        (
            lambda s: s["policy_kwargs"].update(net_arch={"pi": [8], "qf": [65536, 4096]}, n_critics=64),
            "parameters",
        ),
        (lambda s: s["hyperparameters"].update(buffer_size=10**13), "buffer_size"),
        (lambda s: s["observation_space"].update(shape=[1 << 16, 1 << 16]), "shape"),
    ],
    ids=["net-arch", "critics", "buffer", "space"],
)
def test_parameter_and_buffer_bombs_are_refused_before_allocation(bundle, tmp_path, edit, needle):
    manifest, members = _members(bundle)
    edit(manifest["workers"]["goal"]["spec"])
    path = _write(tmp_path / "b.zip", manifest, members)
    result = run_limited(
        f"""
        from sb3_hddpg.hierarchy.hierarchy import Hierarchy
        try:
            Hierarchy.load({str(path)!r})
            print(json.dumps("loaded"))
        except ValueError as error:
            print(json.dumps(str(error)))
        """,
        tmp_path,
    )
    assert needle in result and "goal.zip" in result, result


def _nested(depth: int, width: int = 1) -> Hierarchy:
    """A hierarchy ``depth`` levels above plain workers; each level has ``width`` nested copies + 1 worker."""
    level = _hierarchy({"goal": _worker("hddpg/SnakeGoal-v0"), "avoid": _worker("hddpg/SnakeAvoid-v0")})
    for _ in range(depth):
        workers: dict[str, Any] = {f"sub{i}": level for i in range(width)}
        workers["avoid"] = _worker("hddpg/SnakeAvoid-v0")
        level = _hierarchy(workers)
    return level


def test_nesting_depth_and_fan_out_are_bounded(tmp_path):
    (tmp_path / "ok.zip").write_bytes(_nested(MAX_NESTING).to_bytes())
    (tmp_path / "deep.zip").write_bytes(_nested(MAX_NESTING + 1).to_bytes())
    # Fan-out: three nested copies per level, three levels deep: 107 models, over MAX_MODELS (64).
    (tmp_path / "wide.zip").write_bytes(_nested(3, width=3).to_bytes())
    result = run_limited(
        f"""
        from sb3_hddpg.hierarchy.hierarchy import Hierarchy
        out = {{}}
        for name in ("ok", "deep", "wide"):
            try:
                Hierarchy.load({str(tmp_path)!r} + "/" + name + ".zip")
                out[name] = "loaded"
            except ValueError as error:
                out[name] = str(error)
        print(json.dumps(out))
        """,
        tmp_path,
    )
    assert result["ok"] == "loaded", result
    assert f"more than {MAX_NESTING} deep" in result["deep"], result
    assert f"more than {MAX_MODELS} models" in result["wide"], result
