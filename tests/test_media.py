"""Recordings, overlays, timelines and packages: every output exists, decodes and has the expected shape."""

import dataclasses
import json
import os

import gymnasium as gym
import imageio.v2 as imageio_v2
import imageio.v3 as iio
import numpy as np
import pytest
import yaml
from PIL import Image
from stable_baselines3 import DDPG

import sb3_hddpg  # noqa: F401  (registers the env ids)
from hddpg_zoo.media import record_video
from hddpg_zoo.media.figures import (
    plot_comparison,
    plot_learning_curves,
    plot_selection_timeline,
    step_axis_label,
)
from hddpg_zoo.media.overlay import PANEL_HEIGHT, WORKER_COLOURS
from hddpg_zoo.packaging import RESULTS_KEYS, package_policy, write_zoo_layout
from sb3_hddpg.artifacts.run_folder import RUN_MARKER
from sb3_hddpg.hierarchy import WorkerSelectionWrapper
from sb3_hddpg.hierarchy.hierarchy import Hierarchy, SelectionConfig
from sb3_hddpg.hierarchy.loading import load_policy
from sb3_hddpg.media import StepRecorder
from sb3_hddpg.media.trace import trace_episodes
from tests.cli_batch import run_batch

STEPS = 15  # per episode: short episodes keep the videos small


def _ddpg(env: gym.Env, seed: int) -> DDPG:
    return DDPG("MlpPolicy", env, policy_kwargs={"net_arch": [16]}, seed=seed, device="cpu")


@pytest.fixture(scope="module")
def bundle(tmp_path_factory):
    """An untrained but complete hierarchy bundle: enough to see that everything is drawn and written."""
    env = gym.make("hddpg/SnakeReach-v0")
    workers = {"goal": _ddpg(env, 1), "avoid": _ddpg(env, 2)}
    config = SelectionConfig(preferences={"goal": 1.0, "avoid": 1.0}, selection="sample")
    manager = _ddpg(WorkerSelectionWrapper(env, workers, **config.wrapper_kwargs()), 3)
    path = tmp_path_factory.mktemp("bundle") / "hierarchy.zip"
    Hierarchy(manager, workers, config).save(path)
    return path


def test_gif_has_one_frame_per_step_with_the_panel(tmp_path):
    loaded = load_policy("scripted")
    env = loaded.make_env(render_mode="rgb_array", max_episode_steps=STEPS)
    result = record_video(loaded.policy, env, tmp_path / "s.gif", episodes=2, fps=10)
    frames = iio.imread(tmp_path / "s.gif", index=None)
    assert result.frames == 2 * STEPS and frames.shape == (2 * STEPS, 400 + PANEL_HEIGHT, 400, 3)
    assert [r.episode for r in result.records] == [0] * STEPS + [1] * STEPS
    assert result.evaluation.summary()["episodes"] == 2


def test_mp4_streams_every_frame(tmp_path):
    loaded = load_policy("random")
    env = loaded.make_env(render_mode="rgb_array", max_episode_steps=STEPS)
    result = record_video(loaded.policy, env, tmp_path / "r.mp4", episodes=1, fps=5)
    reader = imageio_v2.get_reader(tmp_path / "r.mp4")
    assert reader.count_frames() == STEPS == result.frames
    assert reader.get_meta_data()["fps"] == 5
    assert reader.get_meta_data()["size"] == (400, 400 + PANEL_HEIGHT)


def test_video_suffix_and_arguments_are_checked(tmp_path):
    loaded = load_policy("random")
    env = loaded.make_env(render_mode="rgb_array", max_episode_steps=STEPS)
    with pytest.raises(ValueError, match=r"\.gif or \.mp4.*x\.avi"):
        record_video(loaded.policy, env, tmp_path / "x.avi")
    with pytest.raises(ValueError, match="rgb_array"):
        record_video(loaded.policy, loaded.make_env(), tmp_path / "x.gif")
    assert not list(tmp_path.iterdir())  # nothing half-written


def test_hierarchy_frames_show_the_acting_worker(bundle, tmp_path):
    loaded = load_policy(bundle)
    env = loaded.make_env(render_mode="rgb_array", max_episode_steps=STEPS)
    result = record_video(loaded.policy, env, tmp_path / "h.gif", episodes=1)
    frames = iio.imread(tmp_path / "h.gif", index=None)
    for record, frame in zip(result.records, frames):
        assert record.selected in ("goal", "avoid")
        assert sum(record.probabilities.values()) == pytest.approx(1.0, abs=1e-5)
        # The frame's border takes the acting worker's colour (GIF palettes shift colours a little).
        assert np.abs(frame[200, 1].astype(int) - WORKER_COLOURS[record.selected]).max() < 24


def test_step_recorder_reads_the_wrapper_info():
    env = gym.make("hddpg/SnakeReach-v0", max_episode_steps=STEPS)
    workers = {"goal": load_policy("scripted").policy, "avoid": load_policy("random").policy}
    wrapped = StepRecorder(WorkerSelectionWrapper(env, workers, selection="argmax"))
    wrapped.reset(seed=0)
    for _ in range(3):
        wrapped.step(np.array([2.0, -2.0], dtype=np.float32))
    assert [r.selected for r in wrapped.records] == ["goal"] * 3
    assert wrapped.records[0].probabilities["goal"] > 0.9
    assert all(np.isfinite(r.min_clearance) and np.isfinite(r.distance_to_goal) for r in wrapped.records)


def test_figures_decode(bundle, tmp_path):
    loaded = load_policy(bundle)
    records, result = trace_episodes(loaded.policy, loaded.make_env(max_episode_steps=STEPS), n_episodes=2)
    paths = [
        plot_selection_timeline(records, tmp_path / "sel.png", names=loaded.policy.names, sensor_range=0.3),
        plot_learning_curves(
            {
                "goal": [
                    {"timesteps": 1, "mean_reach_reward": 1.0},
                    {"timesteps": 2, "mean_reach_reward": 2.0},
                ]
            },
            tmp_path / "curves.png",
            references={"random": 1.5},
            note="Each point: 5 evaluation episodes. The table: 20 episodes.",
        ),
        plot_comparison({"HDDPG": {**result.summary(), "std_reach_reward": 1.0}}, tmp_path / "cmp.png"),
        # A switch without probabilities (HAM) still gets its timeline.
        plot_selection_timeline(
            [dataclasses.replace(r, probabilities={}) for r in records],
            tmp_path / "switch.png",
            ["goal", "avoid"],
        ),
    ]
    for path in paths:
        with Image.open(path) as image:
            image.verify()
            assert image.format == "PNG" and image.size[0] > 300
    # The black separators are mentioned only where a figure has them (two episodes or more).
    assert "2 episodes" in step_axis_label(records) and "black lines" in step_axis_label(records)
    first = [r for r in records if r.episode == records[0].episode]
    assert step_axis_label(first) == "step of the episode"


def test_cli_record_and_plot_selection(bundle, tmp_path):
    args = ("--episodes", "2", "--max-steps", str(STEPS))
    # The three command lines in one interpreter (tests/cli_batch.py), each with its own exit code and output.
    recorded, result, refused = run_batch(
        [
            ["record", str(bundle), "--out", str(tmp_path / "h.mp4"), "--fps", "20", *args],
            ["plot-selection", str(bundle), "--out", str(tmp_path / "sel.png"), *args],
            ["plot-selection", "scripted", "--out", str(tmp_path / "x.png")],
        ]
    )
    assert recorded.returncode == 0, recorded.stdout + recorded.stderr
    assert imageio_v2.get_reader(tmp_path / "h.mp4").count_frames() == 2 * STEPS
    assert result.returncode == 0, result.stdout + result.stderr
    assert "acted" in result.stdout
    assert Image.open(tmp_path / "sel.png").size[1] > 300
    assert refused.returncode == 2 and "selects no worker" in refused.stderr


def _front_matter(card: str) -> dict:
    assert card.startswith("---\n")
    return yaml.safe_load(card.split("---\n")[1])


def test_cli_package_bundle_like_huggingface_sb3(bundle, tmp_path):
    out = tmp_path / "pkg"
    # Both command lines in one interpreter (tests/cli_batch.py); the second, refused, writes nothing, so the
    # folder read below is the first one's.
    packaged, again = run_batch(
        [
            ["package", str(bundle), "--out", str(out), "--episodes", "2", "--video-steps", str(STEPS)],
            ["package", str(bundle), "--out", str(out)],
        ]
    )
    assert packaged.returncode == 0, packaged.stdout + packaged.stderr
    assert (out / RUN_MARKER).is_file()  # hidden: it lets a later --force replace what the tool wrote
    assert sorted(p.name for p in out.iterdir() if p.name != RUN_MARKER) == [
        "README.md",
        "config.json",
        "hierarchy.zip",
        "manifest.json",
        "replay.mp4",
        "results.json",
    ]
    results = json.loads((out / "results.json").read_text())
    assert tuple(results) == RESULTS_KEYS
    assert results["n_eval_episodes"] == 2 and results["is_deterministic"] is True
    assert isinstance(results["mean_reward"], float) and isinstance(results["std_reward"], float)
    meta = _front_matter((out / "README.md").read_text())
    assert meta["library_name"] == "stable-baselines3" and "hddpg/SnakeReach-v0" in meta["tags"]
    metric = meta["model-index"][0]["results"][0]["metrics"][0]
    assert metric["type"] == "mean_reward" and metric["value"].startswith(f"{results['mean_reward']:.2f}")
    config = json.loads((out / "config.json").read_text())
    assert config["worker_names"] == ["goal", "avoid"] and "policy_class" in config["manager"]
    assert json.loads((out / "manifest.json").read_text())["kind"] == "sb3-hddpg-hierarchy"
    assert imageio_v2.get_reader(out / "replay.mp4").count_frames() == STEPS
    assert isinstance(load_policy(out / "hierarchy.zip").policy, Hierarchy)
    assert again.returncode == 2 and "--force" in again.stderr


def test_package_sb3_zip(tmp_path):
    model = _ddpg(gym.make("hddpg/SnakeGoal-v0"), 0)
    model.save(tmp_path / "m.zip")
    out = tmp_path / "pkg"
    loaded = load_policy(tmp_path / "m.zip", trusted=True)
    package_policy(loaded, tmp_path / "m.zip", out, n_eval_episodes=1, video_steps=5)
    name = "ddpg-hddpg-SnakeReach-v0"  # an untracked zip acts in SnakeReach by default
    assert (out / f"{name}.zip").is_file() and (out / name / "data").is_file()
    assert json.loads((out / "config.json").read_text()) == json.loads((out / name / "data").read_text())
    assert _front_matter((out / "README.md").read_text())["model-index"][0]["name"] == "DDPG"
    # The card installs from a checkout or a wheel: sb3-hddpg is not on the package index.
    card = (out / "README.md").read_text()
    assert "pip install sb3-hddpg\n" not in card and "py3-none-any.whl" in card
    # A package is for sharing: the folder gets the umask's permissions like any new folder, not 0700.
    umask = os.umask(0)
    os.umask(umask)
    assert out.stat().st_mode & 0o777 == 0o777 & ~umask


def test_zoo_layout_names(tmp_path):
    model = _ddpg(gym.make("hddpg/SnakeGoal-v0"), 0)
    model.save(tmp_path / "goal.zip")
    write_zoo_layout({"hddpg/SnakeGoal-v0": tmp_path / "goal.zip"}, tmp_path / "zoo")
    assert DDPG.load(tmp_path / "zoo" / "ddpg" / "hddpg-SnakeGoal-v0_1" / "hddpg-SnakeGoal-v0.zip")
