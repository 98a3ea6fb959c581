"""TensorBoard curves of how often the manager chooses each worker, and of each reward term."""

from __future__ import annotations

from collections import Counter, defaultdict

from stable_baselines3.common.callbacks import BaseCallback


class SelectionStatsCallback(BaseCallback):
    """
    Log, every ``log_freq`` steps, the fraction of steps each worker was chosen (``selection/<name>``) and
    the mean raw and normalised reward terms (``reward_terms/<term>``, ``normalised_terms/<term>``), read
    from the ``info`` of :class:`~sb3_hddpg.hierarchy.wrapper.WorkerSelectionWrapper`.

    :param log_freq: environment steps between log records.
    """

    def __init__(self, log_freq: int = 1000) -> None:
        super().__init__()
        self.log_freq = log_freq
        self._counts: Counter[str] = Counter()
        self._sums: dict[str, float] = defaultdict(float)
        self._n = 0
        self._last_log = 0

    def _on_step(self) -> bool:
        for info in self.locals.get("infos", []):
            if "selected_worker" not in info:
                continue
            self._counts[info["selected_worker"]] += 1
            for term, value in info["reward_terms"].items():
                self._sums[f"reward_terms/{term}"] += value
            for term, value in info["normalised_terms"].items():
                self._sums[f"normalised_terms/{term}"] += value
            self._n += 1
        if self._n and self.num_timesteps - self._last_log >= self.log_freq:
            total = sum(self._counts.values())
            for name, count in self._counts.items():
                self.logger.record(f"selection/{name}", count / total)
            for key, value in self._sums.items():
                self.logger.record(key, value / self._n)
            self._counts.clear()
            self._sums.clear()
            self._n = 0
            self._last_log = self.num_timesteps
        return True
