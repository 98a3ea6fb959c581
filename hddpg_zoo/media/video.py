"""``record_video``: any policy acting in its env, rendered to a GIF or an MP4 with imageio."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import imageio.v3 as iio
import imageio_ffmpeg
import numpy as np
from PIL import Image

from hddpg_zoo.media.overlay import compose_frame
from sb3_hddpg.artifacts.io import atomic_write
from sb3_hddpg.artifacts.limits import check_count
from sb3_hddpg.envs.headless import rendering_errors
from sb3_hddpg.evaluation import EVAL_SEED_BASE, EvaluationResult, evaluate
from sb3_hddpg.media.trace import StepRecord, StepRecorder, selected_names
from sb3_hddpg.policy import Policy

#: The containers :func:`record_video` writes, by file suffix.
VIDEO_FORMATS = (".gif", ".mp4")


@dataclass
class RecordingResult:
    """
    What :func:`record_video` wrote.

    :param path: the video file.
    :param frames: how many frames it holds.
    :param size: ``(width, height)`` of a frame.
    :param evaluation: the env's metrics over the recorded episodes.
    :param records: every step's record (selection, probabilities, gaps).
    """

    path: Path
    frames: int
    size: tuple[int, int]
    evaluation: EvaluationResult
    records: list[StepRecord]


def check_video_path(path: str | Path) -> Path:
    """``path`` as a :class:`Path` if it ends in a supported suffix, else a ``ValueError`` naming it."""
    path = Path(path)
    if path.suffix.lower() not in VIDEO_FORMATS:
        raise ValueError(
            f"Expected a video path ending in {' or '.join(VIDEO_FORMATS)}, actually: {str(path)!r}"
        )
    return path


#: The render mode :func:`record_video` needs.
RGB_ARRAY = "rgb_array"


def make_recording_env(make: Callable[..., gym.Env], name: str) -> gym.Env:
    """
    The env to record, made with ``render_mode="rgb_array"``, or a one-line ``ValueError`` when the env does
    not declare that mode (an env of any kind: the snake arm, an adapted MO-Gymnasium env, a user's own).

    The mode is read from an env made without rendering (an env that cannot render may not even accept
    ``render_mode``); an adapter declares the render modes of the env it adapts.

    :param make: makes the env, taking ``render_mode`` as a keyword (e.g. ``LoadedPolicy.make_env``).
    :param name: the env's name for the message.
    :return: the env, rendering ``rgb_array`` frames; an env that cannot make an OpenGL context (MuJoCo
        without a display) raises :class:`~sb3_hddpg.envs.headless.HeadlessRenderingError`.
    """
    with rendering_errors():
        return _make_recording_env(make, name)


def _make_recording_env(make: Callable[..., gym.Env], name: str) -> gym.Env:
    probe = make()
    try:
        modes = list(probe.metadata.get("render_modes") or [])
    finally:
        probe.close()
    if RGB_ARRAY not in modes:
        raise ValueError(
            f"{name} cannot render frames to record: its render_modes are {modes}, {RGB_ARRAY!r} is needed "
            "(evaluate it with hddpg-cli evaluate instead)"
        )
    with warnings.catch_warnings():
        # An adapter's class declares no render modes (they are its inner env's): gym.make's warning is noise.
        warnings.filterwarnings("ignore", message=".*not in the possible render_modes")
        return make(render_mode=RGB_ARRAY)


def record_video(
    policy: Policy,
    env: gym.Env,
    path: str | Path,
    episodes: int = 1,
    seed: int = EVAL_SEED_BASE,
    fps: int = 10,
    deterministic: bool = True,
    title: str = "",
    names: Sequence[str] | None = None,
    stride: int = 1,
    max_frames: int | None = None,
    scale: float = 1.0,
) -> RecordingResult:
    """
    Run ``policy`` in ``env`` for ``episodes`` (episode ``k`` reset with ``seed + k``, as in
    :func:`~sb3_hddpg.evaluation.evaluate`) and write one frame per step, with the overlay of
    :func:`~hddpg_zoo.media.overlay.compose_frame`: which worker acts and the manager's probabilities for a
    hierarchy or a HAM switch, the gaps to the nearest obstacle and to the goal for any policy.

    An MP4 (H.264 through imageio-ffmpeg's bundled ffmpeg) is streamed to disk; a GIF keeps its frames in
    memory until the end, so prefer MP4 for long recordings. The file appears atomically.

    :param policy: anything with SB3's ``predict`` acting in ``env``.
    :param env: an env made with ``render_mode="rgb_array"`` (see :func:`make_recording_env`).
    :param path: the output, ending in ``.gif`` or ``.mp4``.
    :param episodes: how many episodes, 1 to 10,000 (``limits.COUNTS["episodes"]``).
    :param seed: the first episode's seed.
    :param fps: frames per second of the video.
    :param deterministic: passed to ``predict``.
    :param title: a label drawn in the overlay.
    :param names: the workers the policy selects among (default: the policy's own ``names``).
    :param stride: keep every ``stride``-th step (a shorter GIF for documentation).
    :param max_frames: stop writing frames after this many (the episodes still run to the end), at most
        100,000 (``limits.COUNTS["video_steps"]``).
    :param scale: resize frames by this factor (sizes rounded to multiples of 16).
    :return: the path, the frame count and the episodes' metrics; an env that cannot make an OpenGL
        context (MuJoCo without a display) raises :class:`~sb3_hddpg.envs.headless.HeadlessRenderingError`.
    """
    path = check_video_path(path)
    # the CLI's bounds, from the one table of counts (a LimitError is a ValueError naming the keyword)
    check_count("episodes", episodes, "episodes")
    if max_frames is not None:
        check_count("video_steps", max_frames, "max_frames")
    if fps < 1:
        raise ValueError(f"Expected `fps` to be >= 1, actually: {fps}")
    if stride < 1:
        raise ValueError(f"Expected `stride` to be >= 1, actually: {stride}")
    if not 0.0 < scale <= 4.0:
        raise ValueError(f"Expected `scale` in (0, 4], actually: {scale}")
    names = list(names) if names is not None else selected_names(policy)
    state: dict[str, Any] = {"frames": 0, "size": (0, 0), "seen": 0}

    def run(tmp: Path) -> EvaluationResult:
        with _VideoSink(tmp, path.suffix.lower(), fps) as sink:

            def on_frame(frame: np.ndarray, record: StepRecord) -> None:
                state["seen"] += 1
                if (state["seen"] - 1) % stride or (max_frames is not None and state["frames"] >= max_frames):
                    return
                composed = _resize(compose_frame(_rgb(frame), record, names, title), scale)
                sink.append(composed)
                state["frames"] += 1
                state["size"] = (composed.shape[1], composed.shape[0])

            recorder = StepRecorder(env, policy, on_frame=on_frame)
            state["recorder"] = recorder
            return evaluate(policy, recorder, n_episodes=episodes, seed=seed, deterministic=deterministic)

    result: dict[str, EvaluationResult] = {}
    with rendering_errors():
        # Recording runs the policy for as long as asked: Ctrl-C and SIGTERM must reach it at once.
        atomic_write(path, lambda tmp: result.setdefault("evaluation", run(tmp)), hold_signals=False)
    return RecordingResult(
        path=path,
        frames=state["frames"],
        size=state["size"],
        evaluation=result["evaluation"],
        records=state["recorder"].records,
    )


def _rgb(frame: object) -> np.ndarray:
    """An env's rendered frame as ``(H, W, 3)`` uint8, or a one-line ``ValueError`` saying what it was."""
    array = np.asarray(frame) if frame is not None else None
    if array is None or array.ndim != 3 or array.shape[2] not in (3, 4) or 0 in array.shape:
        shape = None if array is None else array.shape
        raise ValueError(f"Expected render() to return an RGB frame (H, W, 3), actually: shape {shape}")
    return np.ascontiguousarray(array[:, :, :3]).astype(np.uint8, copy=False)


def _resize(frame: np.ndarray, scale: float) -> np.ndarray:
    if scale == 1.0:
        return frame
    height, width = frame.shape[:2]
    size = (max(16, round(width * scale / 16) * 16), max(16, round(height * scale / 16) * 16))
    return np.asarray(Image.fromarray(frame).resize(size, Image.Resampling.LANCZOS), dtype=np.uint8)


class _VideoSink:
    """Frames to a file: streamed to ffmpeg for MP4, gathered and written by Pillow for GIF."""

    def __init__(self, path: Path, suffix: str, fps: int) -> None:
        self.path, self.suffix, self.fps = path, suffix, fps
        self._frames: list[np.ndarray] = []
        self._writer: Any = None

    def __enter__(self) -> _VideoSink:
        return self

    def append(self, frame: np.ndarray) -> None:
        if self.suffix != ".mp4":
            self._frames.append(frame)
            return
        if self._writer is None:
            # The target is a temporary name without the .mp4 suffix, so tell ffmpeg the container.
            self._writer = imageio_ffmpeg.write_frames(
                str(self.path),
                size=(frame.shape[1], frame.shape[0]),
                fps=self.fps,
                codec="libx264",
                pix_fmt_out="yuv420p",
                macro_block_size=16,
                output_params=["-f", "mp4"],
            )
            self._writer.send(None)  # start ffmpeg
        self._writer.send(np.ascontiguousarray(frame))

    def __exit__(self, *exc: object) -> None:
        if self._writer is not None:
            self._writer.close()
            return
        if exc[0] is not None:
            return
        if not self._frames:
            raise ValueError("No frame was recorded")
        # Pillow's GIF writer takes the frame duration in milliseconds; loop=0 repeats forever.
        iio.imwrite(self.path, np.stack(self._frames), extension=".gif", duration=1000 / self.fps, loop=0)
