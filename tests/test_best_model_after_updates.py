"""A kept "best" model is one taken after at least one update, never the untrained network."""

import gymnasium as gym
from stable_baselines3 import DDPG
from stable_baselines3.common.logger import configure

from sb3_hddpg.callbacks.evaluation import MetricsEvalCallback, best_entry


def test_an_untrained_network_is_never_kept_as_the_best(tmp_path):
    env = gym.make("hddpg/SnakeReach-v0", max_episode_steps=20)
    model = DDPG("MlpPolicy", env, learning_starts=50, train_freq=1, seed=0, device="cpu")
    model.set_logger(configure(None, []))
    callback = MetricsEvalCallback(env, n_eval_episodes=1, eval_freq=10**9, best_model_save_path=tmp_path)
    callback.init_callback(model)
    callback.run_evaluation()
    assert callback.history[-1]["updates"] == 0
    assert not (tmp_path / "best_model.zip").exists()  # a finite score, but of the random initialisation
    model.learn(80)
    callback.run_evaluation()
    assert callback.history[-1]["updates"] > 0
    assert (tmp_path / "best_model.zip").exists()
    assert best_entry(callback.history) is callback.history[-1]


def test_best_entry_skips_evaluations_before_the_first_update():
    history = [
        {"timesteps": 0, "mean_reward": 50.0, "updates": 0},
        {"timesteps": 10, "mean_reward": 10.0, "updates": 5},
        {"timesteps": 20, "mean_reward": 20.0, "updates": 15},
    ]
    assert best_entry(history)["timesteps"] == 20
    # Without any update the final evaluation describes the model that is saved (the final one).
    assert best_entry(history[:1])["timesteps"] == 0
    # Histories written before updates were counted keep their old meaning.
    assert (
        best_entry([{"timesteps": 0, "mean_reward": 1.0}, {"timesteps": 5, "mean_reward": 0.0}])["timesteps"]
        == 0
    )
