"""Seeing a policy work: per-step traces (recordings and figures are the harness's, :mod:`hddpg_zoo.media`)."""

from sb3_hddpg.media.trace import StepRecord, StepRecorder, selected_names

__all__ = ["StepRecord", "StepRecorder", "selected_names"]
