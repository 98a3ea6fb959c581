"""Hand-written policies the benchmark compares against, beyond the library's (:mod:`sb3_hddpg.baselines`)."""
