"""Seeing a policy work: per-step traces, frames with a selection overlay, GIF/MP4 recordings and figures."""

from sb3_hddpg.media.trace import StepRecord, StepRecorder, selected_names
from sb3_hddpg.media.video import RecordingResult, make_recording_env, record_video

__all__ = [
    "RecordingResult",
    "StepRecord",
    "StepRecorder",
    "make_recording_env",
    "record_video",
    "selected_names",
]
