"""``record_video``: any policy acting in its env, rendered to a GIF or an MP4 with imageio."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from PIL import Image

from sb3_hddpg.artifacts.io import atomic_write
from sb3_hddpg.evaluation import EVAL_SEED_BASE, EvaluationResult, evaluate
from sb3_hddpg.media.overlay import compose_frame
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
    :func:`~sb3_hddpg.media.overlay.compose_frame`: which worker acts and the manager's probabilities for a
    hierarchy or a HAM switch, the gaps to the nearest obstacle and to the goal for any policy.

    An MP4 (H.264 through imageio-ffmpeg's bundled ffmpeg) is streamed to disk; a GIF keeps its frames in
    memory until the end, so prefer MP4 for long recordings. The file appears atomically.

    :param policy: anything with SB3's ``predict`` acting in ``env``.
    :param env: a snake env made with ``render_mode="rgb_array"``.
    :param path: the output, ending in ``.gif`` or ``.mp4``.
    :param episodes: how many episodes, at least 1.
    :param seed: the first episode's seed.
    :param fps: frames per second of the video.
    :param deterministic: passed to ``predict``.
    :param title: a label drawn in the overlay.
    :param names: the workers the policy selects among (default: the policy's own ``names``).
    :param stride: keep every ``stride``-th step (a shorter GIF for documentation).
    :param max_frames: stop writing frames after this many (the episodes still run to the end).
    :param scale: resize frames by this factor (sizes rounded to multiples of 16).
    :return: the path, the frame count and the episodes' metrics.
    """
    path = check_video_path(path)
    if episodes < 1:
        raise ValueError(f"Expected `episodes` to be >= 1, actually: {episodes}")
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
                composed = _resize(compose_frame(frame, record, names, title), scale)
                sink.append(composed)
                state["frames"] += 1
                state["size"] = (composed.shape[1], composed.shape[0])

            recorder = StepRecorder(env, policy, on_frame=on_frame)
            state["recorder"] = recorder
            return evaluate(policy, recorder, n_episodes=episodes, seed=seed, deterministic=deterministic)

    result: dict[str, EvaluationResult] = {}
    atomic_write(path, lambda tmp: result.setdefault("evaluation", run(tmp)))
    return RecordingResult(
        path=path,
        frames=state["frames"],
        size=state["size"],
        evaluation=result["evaluation"],
        records=state["recorder"].records,
    )


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
            import imageio_ffmpeg

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
        import imageio.v3 as iio

        # Pillow's GIF writer takes the frame duration in milliseconds; loop=0 repeats forever.
        iio.imwrite(self.path, np.stack(self._frames), extension=".gif", duration=1000 / self.fps, loop=0)
