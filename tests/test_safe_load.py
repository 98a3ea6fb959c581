"""Safe loading of shared SB3 zips: rebuild from a JSON spec, take only the tensors, never run pickled code."""

from __future__ import annotations

import base64
import copy
import io
import json
import pickle
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch as th
from sb3_contrib import TQC
from stable_baselines3 import A2C, DDPG, SAC, TD3

from sb3_hddpg.artifacts.safe_load import SafeLoadError, load_model, load_model_safely
from sb3_hddpg.artifacts.spec import model_spec
from sb3_hddpg.artifacts.weights import apply_weights

TINY = {"net_arch": [16, 16]}

# name -> (class, constructor kwargs). "SAC-variant" covers dict net_arch, a non-default activation, gSDE and a
# fixed entropy coefficient (stored as ent_coef_tensor instead of log_ent_coef).
CASES: dict[str, tuple[type, dict[str, Any]]] = {
    "DDPG": (DDPG, {"policy_kwargs": TINY}),
    "TD3": (TD3, {"policy_kwargs": TINY}),
    "SAC": (SAC, {"policy_kwargs": TINY}),
    "TQC": (TQC, {"policy_kwargs": {**TINY, "n_quantiles": 5}}),
    "SAC-variant": (
        SAC,
        {
            "policy_kwargs": {"net_arch": {"pi": [16], "qf": [16, 16]}, "activation_fn": th.nn.Tanh},
            "ent_coef": 0.1,
            "use_sde": True,
        },
    ),
}


class _TouchPayload:
    """Pickles to ``exec("open(marker, 'w').close()")``: unpickling it creates ``marker`` and yields None."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self) -> tuple[Any, ...]:
        return (exec, (f"open({self.marker!r}, 'w').close()",))


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Any, Path]]:
    """Each case trained a few hundred steps on Pendulum-v1 and saved; shared by the tests in this module."""
    folder = tmp_path_factory.mktemp("models")
    out = {}
    for name, (cls, kwargs) in CASES.items():
        model = cls(
            "MlpPolicy",
            "Pendulum-v1",
            learning_starts=100,
            buffer_size=1_000,
            batch_size=32,
            seed=0,
            **kwargs,
        )
        model.learn(total_timesteps=250)
        path = folder / f"{name}.zip"
        model.save(path)
        out[name] = (model, path)
    return out


def _observations(model: Any, n: int = 64) -> np.ndarray:
    model.observation_space.seed(123)
    return np.stack([model.observation_space.sample() for _ in range(n)])


def _same_actions(a: Any, b: Any) -> bool:
    obs = _observations(a)
    return np.array_equal(a.predict(obs, deterministic=True)[0], b.predict(obs, deterministic=True)[0])


def _rewrite_zip(src: Path, dst: Path, replace: dict[str, bytes | None]) -> None:
    """Copy ``src`` to ``dst``, replacing member contents (None drops the member)."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for info in zin.infolist():
            if info.filename in replace:
                if replace[info.filename] is not None:
                    zout.writestr(info.filename, replace[info.filename])
            else:
                zout.writestr(info, zin.read(info))


@pytest.mark.parametrize("name", list(CASES))
def test_round_trip_same_actions(trained: dict[str, tuple[Any, Path]], name: str) -> None:
    model, path = trained[name]
    spec = model_spec(model)
    # What a manifest holds: strict JSON, read back.
    spec = json.loads(json.dumps(spec, allow_nan=False))
    loaded = load_model_safely(path, spec)
    assert type(loaded) is type(model)
    assert _same_actions(model, loaded)
    for key, value in model.policy.state_dict().items():
        assert th.equal(value, loaded.policy.state_dict()[key]), key
    _, variables = model._get_torch_save_params()
    for var in variables:
        assert th.equal(getattr(model, var), getattr(loaded, var)), var
    # The default (untrusted) path of load_model is the same thing.
    assert _same_actions(model, load_model(path, spec))


def test_trusted_load_uses_sb3(trained: dict[str, tuple[Any, Path]]) -> None:
    model, path = trained["TD3"]
    assert _same_actions(model, load_model(path, trusted=True, algorithm="TD3"))
    assert _same_actions(model, load_model(path, model_spec(model), trusted=True))
    with pytest.raises(ValueError, match="spec"):
        load_model(path)


def test_trusted_load_of_a_zip_saved_by_sbx_uses_sbx(tmp_path: Path) -> None:
    # SBX (SB3's JAX sibling) writes SB3's zip layout with its own policy classes, which SB3's loader cannot
    # rebuild ("'TD3Policy' object has no attribute 'actor'"); with the user's trust, SBX's loader opens it.
    sbx = pytest.importorskip("sbx")
    import gymnasium as gym

    env = gym.make("hddpg/SnakeAvoid-v0")
    model = sbx.DDPG("MlpPolicy", env, policy_kwargs={"net_arch": [16, 16]}, seed=0)
    path = tmp_path / "sbx_ddpg.zip"
    model.save(path)
    loaded = load_model(path, trusted=True, algorithm="DDPG")
    assert type(loaded) is sbx.DDPG
    observation, _ = env.reset(seed=3)
    expected, _ = model.predict(observation, deterministic=True)
    actual, _ = loaded.predict(observation, deterministic=True)
    np.testing.assert_allclose(actual, expected, atol=1e-6)
    with io.BytesIO(path.read_bytes()) as in_memory:  # the same from memory
        assert type(load_model(in_memory, trusted=True, algorithm="DDPG")) is sbx.DDPG
    env.close()


def test_malicious_data_entry_is_not_executed(trained: dict[str, tuple[Any, Path]], tmp_path: Path) -> None:
    model, path = trained["DDPG"]
    marker = tmp_path / "pwned"
    with zipfile.ZipFile(path) as archive:
        data = json.loads(archive.read("data"))
    assert data["action_noise"] is None
    data["action_noise"] = {
        ":type:": "<class 'NoneType'>",
        ":serialized:": base64.b64encode(pickle.dumps(_TouchPayload(marker))).decode(),
    }
    evil = tmp_path / "evil.zip"
    _rewrite_zip(path, evil, {"data": json.dumps(data).encode()})

    # The payload is live: SB3's ordinary loader runs it.
    DDPG.load(evil, device="cpu")
    assert marker.exists()
    marker.unlink()

    loaded = load_model_safely(evil, model_spec(model))
    assert _same_actions(model, loaded)
    assert not marker.exists()
    load_model(evil, model_spec(model))
    assert not marker.exists()


def test_pickle_payload_in_policy_pth_is_refused(
    trained: dict[str, tuple[Any, Path]], tmp_path: Path
) -> None:
    model, path = trained["DDPG"]
    marker = tmp_path / "pwned"
    buffer = io.BytesIO()
    th.save({"actor.mu.0.weight": _TouchPayload(marker)}, buffer)
    evil = tmp_path / "evil_weights.zip"
    _rewrite_zip(path, evil, {"policy.pth": buffer.getvalue()})
    with pytest.raises(SafeLoadError, match=r"evil_weights\.zip.*policy\.pth"):
        load_model_safely(evil, model_spec(model))
    assert not marker.exists()


def test_not_a_zip(trained: dict[str, tuple[Any, Path]], tmp_path: Path) -> None:
    model, _ = trained["DDPG"]
    fake = tmp_path / "notes.zip"
    fake.write_text("these are not the weights you are looking for\n")
    with pytest.raises(ValueError, match=r"notes\.zip"):
        load_model_safely(fake, model_spec(model))


def test_truncated_zip(trained: dict[str, tuple[Any, Path]], tmp_path: Path) -> None:
    model, path = trained["DDPG"]
    raw = path.read_bytes()
    half = tmp_path / "half.zip"
    half.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ValueError, match=r"half\.zip"):
        load_model_safely(half, model_spec(model))


def test_missing_policy_member(trained: dict[str, tuple[Any, Path]], tmp_path: Path) -> None:
    model, path = trained["DDPG"]
    stripped = tmp_path / "no_policy.zip"
    _rewrite_zip(path, stripped, {"policy.pth": None})
    with pytest.raises(ValueError, match=r"no_policy\.zip.*policy\.pth"):
        load_model_safely(stripped, model_spec(model))


def test_net_arch_mismatch_names_key_and_shapes(trained: dict[str, tuple[Any, Path]]) -> None:
    model, path = trained["DDPG"]
    spec = model_spec(model)
    spec["policy_kwargs"]["net_arch"] = [32, 32]
    with pytest.raises(SafeLoadError) as excinfo:
        load_model_safely(path, spec)
    message = str(excinfo.value)
    assert "'actor.mu.0.weight'" in message
    assert "[16, 3]" in message and "[32, 3]" in message


def test_a_missing_or_extra_tensor_is_named_with_what_the_spec_builds() -> None:
    # A dict of its own: SB3 writes use_sde into the policy_kwargs an off-policy model is given (TINY's).
    model = DDPG("MlpPolicy", "Pendulum-v1", buffer_size=10, policy_kwargs={"net_arch": [16, 16]})
    state = model.policy.state_dict()
    missing = {key: value for key, value in state.items() if key != "actor.mu.0.weight"}
    with pytest.raises(
        SafeLoadError, match=r"'actor\.mu\.0\.weight': no such key in the file, shape \[16, 3\] in"
    ):
        apply_weights(model, missing, {}, "m.zip", "cpu")
    with pytest.raises(
        SafeLoadError, match=r"'evil': shape \[2\] in the file, no such key in the spec-built"
    ):
        apply_weights(model, {**state, "evil": th.zeros(2)}, {}, "m.zip", "cpu")


@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        (lambda s: s.update(algorithm="A2C"), "A2C"),
        (lambda s: s["policy_kwargs"].update(activation_fn="os.system"), "activation_fn"),
        (
            lambda s: s["policy_kwargs"].update(features_extractor_kwargs={"x": 1}),
            "features_extractor_kwargs",
        ),
        (lambda s: s["hyperparameters"].update(replay_buffer_class="x"), "replay_buffer_class"),
        (lambda s: s["observation_space"].update(type="Discrete"), "Discrete"),
        (lambda s: s["policy_kwargs"].update(net_arch=[10**9]), "net_arch"),
    ],
)
def test_hostile_spec_is_refused(trained: dict[str, tuple[Any, Path]], edit: Any, needle: str) -> None:
    model, path = trained["DDPG"]
    spec = copy.deepcopy(model_spec(model))
    edit(spec)
    with pytest.raises(SafeLoadError, match=needle):
        load_model_safely(path, spec)


def test_model_spec_refuses_what_it_cannot_describe() -> None:
    class Custom(th.nn.ReLU):
        pass

    model = DDPG("MlpPolicy", "Pendulum-v1", buffer_size=10, policy_kwargs={"activation_fn": Custom})
    with pytest.raises(ValueError, match="activation_fn"):
        model_spec(model)
    model = DDPG("MlpPolicy", "Pendulum-v1", buffer_size=10)
    model.policy_kwargs["optimizer_kwargs"] = {"eps": "tiny"}
    with pytest.raises(ValueError, match=r"optimizer_kwargs\.eps"):
        model_spec(model)
    with pytest.raises(ValueError, match="A2C"):
        model_spec(A2C("MlpPolicy", "Pendulum-v1", n_steps=8))


# ---- limits (sb3_hddpg/artifacts/limits.py): a spec or zip that would cost more than a few hundred MB is refused first


@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        (lambda s: s["policy_kwargs"].update(net_arch=[65536, 65536]), "parameters"),
        (lambda s: s["policy_kwargs"].update(net_arch=[4096] * 64), "parameters"),
        (lambda s: s["hyperparameters"].update(buffer_size=10**13), "buffer_size"),
        (lambda s: s["hyperparameters"].update(buffer_size=0), "buffer_size"),
        (lambda s: s["observation_space"].update(shape=[0], low=[], high=[]), "shape"),
        (lambda s: s["observation_space"].update(shape=[1 << 16, 1 << 16]), "shape"),
        (lambda s: s["observation_space"].update(shape=[1] * 9), "dimensions"),
    ],
    ids=["wide", "deep", "buffer", "zero-buffer", "empty-space", "huge-space", "many-dims"],
)
def test_spec_bombs_are_refused_before_anything_is_built(trained, edit, needle) -> None:
    model, path = trained["DDPG"]
    spec = copy.deepcopy(model_spec(model))
    edit(spec)
    with pytest.raises(SafeLoadError, match=needle):
        load_model_safely(path, spec)


def test_oversized_and_bomb_members_are_refused_from_their_header(trained, tmp_path: Path) -> None:
    from sb3_hddpg.artifacts.limits import MAX_MEMBER_BYTES

    model, path = trained["DDPG"]
    # 100 MiB of zeros in policy.pth: under the size limit but ~1000x compressed (a zip bomb).
    bomb = tmp_path / "bomb.zip"
    with zipfile.ZipFile(path) as zin, zipfile.ZipFile(bomb, "w", compression=zipfile.ZIP_DEFLATED) as zout:
        for info in zin.infolist():
            if info.filename != "policy.pth":
                zout.writestr(info, zin.read(info))
        with zout.open("policy.pth", "w", force_zip64=True) as handle:
            for _ in range(100):
                handle.write(bytes(1 << 20))
    with pytest.raises(SafeLoadError, match=r"bomb\.zip.*policy\.pth.*zip bomb"):
        load_model_safely(bomb, model_spec(model))
    # Incompressible but over the size limit: refused from the declared size, before reading.
    big = tmp_path / "big.zip"
    with zipfile.ZipFile(path) as zin, zipfile.ZipFile(big, "w", compression=zipfile.ZIP_STORED) as zout:
        for info in zin.infolist():
            if info.filename != "policy.pth":
                zout.writestr(info.filename, zin.read(info))
        with zout.open("policy.pth", "w", force_zip64=True) as handle:
            chunk = np.random.default_rng(0).bytes(1 << 20)
            for _ in range((MAX_MEMBER_BYTES >> 20) + 1):
                handle.write(chunk)
    with pytest.raises(SafeLoadError, match=r"policy\.pth.*over the"):
        load_model_safely(big, model_spec(model))
    big.unlink()


def test_messages_never_format_an_unbounded_value(trained) -> None:
    model, path = trained["DDPG"]
    spec = copy.deepcopy(model_spec(model))
    spec["policy_kwargs"]["activation_fn"] = "x" * 10_000_000
    with pytest.raises(SafeLoadError) as excinfo:
        load_model_safely(path, spec)
    assert "activation_fn" in str(excinfo.value) and len(str(excinfo.value)) < 2_000
    spec = copy.deepcopy(model_spec(model))
    nested: list[Any] = []
    for _ in range(30):  # a value shared 2^30 times over, as a YAML alias bomb builds it
        nested = [nested, nested]
    spec["hyperparameters"]["gamma"] = nested
    with pytest.raises(SafeLoadError) as excinfo:
        load_model_safely(path, spec)
    assert "gamma" in str(excinfo.value) and len(str(excinfo.value)) < 2_000
