"""The paper's protocol: each training episode's true-constraint totals in the Monitor files, the last 100 read back."""

import os

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.monitor import Monitor

from sb3_icrl.benchmark.report_text import markdown_table
from sb3_icrl.envs.wrappers import EPISODE_CONSTRAINT_KEYS, EpisodeConstraintWrapper
from sb3_icrl.run_env import _monitor_keywords
from sb3_icrl.zoo.runs import last_training_episodes
from sb3_icrl.zoo.train import main as train_main


class Scripted(gym.Env):
    """Rewards and costs played back from a script, one episode of ``len(rewards)`` steps."""

    observation_space = gym.spaces.Box(-1, 1, (1,))
    action_space = gym.spaces.Discrete(2)

    def __init__(self, rewards, costs):
        self.rewards, self.costs, self.t = rewards, costs, 0

    def reset(self, *, seed=None, options=None):
        self.t = 0
        return np.zeros(1, dtype=np.float32), {}

    def step(self, action):
        info = {} if self.costs is None else {"cost": self.costs[self.t]}
        reward = self.rewards[self.t]
        self.t += 1
        return np.zeros(1, dtype=np.float32), reward, False, self.t == len(self.rewards), info


def play(env):
    env.reset()
    done, info = False, {}
    while not done:
        _, _, terminated, truncated, info = env.step(0)
        done = terminated or truncated
    return info


def test_totals_stop_the_feasible_reward_at_the_first_violation():
    info = play(EpisodeConstraintWrapper(Scripted([1.0, 2.0, 4.0, 8.0], [0.0, 0.0, 1.0, 0.0])))
    assert (info["true_violation"], info["true_feasible_reward"], info["true_episode_cost"]) == (1.0, 3.0, 1.0)
    # A cost per constraint counts as their sum; a clean episode keeps its whole reward
    info = play(EpisodeConstraintWrapper(Scripted([1.0, 2.0], [np.zeros(2), np.zeros(2)])))
    assert (info["true_violation"], info["true_feasible_reward"], info["true_episode_cost"]) == (0.0, 3.0, 0.0)
    info = play(EpisodeConstraintWrapper(Scripted([1.0, 2.0], None)))
    assert all(np.isnan(info[key]) for key in EPISODE_CONSTRAINT_KEYS)


def test_monitor_writes_the_totals_and_the_reader_takes_the_last_episodes_in_step_order(tmp_path):
    run = str(tmp_path)
    # Env 0: episodes of 4 steps; env 1: of 2 steps. Both step together, so env 1's second episode ends at step 4
    # alongside env 0's first, and its fourth at step 8 with env 0's second
    scripts = {0: ([1.0] * 4, [0.0, 0.0, 0.0, 1.0]), 1: ([2.0] * 2, [0.0, 0.0])}
    for index, (rewards, costs) in scripts.items():
        env = Monitor(
            EpisodeConstraintWrapper(Scripted(rewards, costs)),
            os.path.join(run, str(index)),
            info_keywords=EPISODE_CONSTRAINT_KEYS,
        )
        for _ in range(8 // len(rewards)):
            play(env)
        env.close()
    os.makedirs(os.path.join(run, "eval"))
    with open(os.path.join(run, "eval", "0.monitor.csv"), "w") as file:  # evaluation envs do not count
        file.write('#{"t_start": 0}\nr,l,t,true_violation,true_feasible_reward,true_episode_cost\n9,1,0,1.0,9.0,1.0\n')
    everything = last_training_episodes(run)
    assert everything == {"violation_rate": pytest.approx(2 / 6), "feasible_reward": pytest.approx(22 / 6), "n_episodes": 6.0}
    # The last three to end: env 1's fourth (step 8), env 0's second (step 8), env 1's third (step 6)
    assert last_training_episodes(run, n_episodes=3) == {
        "violation_rate": pytest.approx(1 / 3),
        "feasible_reward": pytest.approx((4.0 + 3.0 + 4.0) / 3),
        "n_episodes": 3.0,
    }


def test_runs_without_the_columns_have_no_such_figure(tmp_path):
    with open(tmp_path / "0.monitor.csv", "w") as file:
        file.write('#{"t_start": 0}\nr,l,t\n1.0,10,0.1\n')
    assert last_training_episodes(str(tmp_path)) is None
    assert last_training_episodes(str(tmp_path / "missing")) is None


def test_train_writes_the_columns_and_the_report_shows_them(tmp_path):
    folder = str(tmp_path / "logs")
    args = ["--algo", "ppolag", "--env", "BiasedPendulum-v0", "-n", "512", "--seed", "0", "-f", folder, "--eval-freq", "-1"]
    train_main(
        [*args, "-params", "n_envs:2", "n_steps:256", "batch_size:64", "n_epochs:1", "policy_kwargs:dict(net_arch=[8])"]
    )
    run = os.path.join(folder, "ppolag", "BiasedPendulum-v0_1")
    with open(os.path.join(run, "0.monitor.csv")) as file:
        assert file.read().splitlines()[1] == "r,l,t," + ",".join(EPISODE_CONSTRAINT_KEYS)
    last = last_training_episodes(run)
    assert last is not None and 0.0 <= last["violation_rate"] <= 1.0 and last["n_episodes"] > 2
    cell = {
        "env": "BiasedPendulum-v0",
        "variant": "base",
        "algo": "ppolag",
        "n_seeds": 1,
        "per_seed": [{"seed": 0, "feasible_reward": 1.0, "violation_rate": 0.0}],
        "feasible_reward_mean": 1.0,
        "feasible_reward_std": 0.0,
        "violation_rate_mean": 0.0,
        "violation_rate_std": 0.0,
        "paper_feasible_reward": None,
        "paper_violation_rate": None,
        "last_training_feasible_reward_mean": 2.5,
        "last_training_violation_rate_mean": 0.25,
    }
    table = markdown_table({"cells": [cell], "runs_missing": []}).splitlines()
    assert "| last 100 training episodes (feasible / violation) |" in table[0] and "| 2.50 / 25% |" in table[2]


def test_a_resumed_run_keeps_the_columns_its_monitor_files_started_with(tmp_path):
    assert _monitor_keywords(str(tmp_path), append_monitor=False) == EPISODE_CONSTRAINT_KEYS
    with open(tmp_path / "0.monitor.csv", "w") as file:  # written before the columns existed
        file.write('#{"t_start": 0}\nr,l,t\n1.0,10,0.1\n')
    assert _monitor_keywords(str(tmp_path), append_monitor=True) == ()
    with open(tmp_path / "0.monitor.csv", "w") as file:
        file.write('#{"t_start": 0}\nr,l,t,' + ",".join(EPISODE_CONSTRAINT_KEYS) + "\n")
    assert _monitor_keywords(str(tmp_path), append_monitor=True) == EPISODE_CONSTRAINT_KEYS
