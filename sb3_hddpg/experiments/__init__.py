"""Experiments built on the library: benchmark, tuning, quickstart, packaging and model export."""
