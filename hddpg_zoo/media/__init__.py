"""Recordings and figures of a policy at work: GIF/MP4 with a selection overlay, selection and result plots."""

from hddpg_zoo.media.video import RecordingResult, make_recording_env, record_video

__all__ = ["RecordingResult", "make_recording_env", "record_video"]
