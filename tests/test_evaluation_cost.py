"""What evaluation costs a run: batched eval envs, no second evaluation of a final model, its time recorded."""

import json

import numpy as np

from sb3_icrl.zoo.callbacks import LearnedCostRecorder
from sb3_icrl.zoo.train import get_parser, train


def _train(tmp_path, *extra: str, steps: int = 96) -> str:
    argv = ["--algo", "ppolag", "--env", "ConstrainedCorridor-v0", "--seed", "0", "-f", str(tmp_path), "-n", str(steps)]
    argv += ["-params", "n_envs:2", "n_steps:32", "batch_size:32", "n_epochs:1", *extra]
    return train(get_parser().parse_args(argv), argv)


def test_a_final_model_evaluated_within_its_last_rollout_is_not_evaluated_again(tmp_path) -> None:
    # 96 steps round up to two rollouts of 2 x 32 (128 steps); evaluations every 48 steps come at 48 and 96
    run = _train(tmp_path, "--eval-freq", "48", "--eval-episodes", "2")
    assert list(np.load(f"{run}/evaluations.npz")["timesteps"]) == [48, 96]
    with open(f"{run}/finished.json") as file:
        finished = json.load(file)
    assert finished["num_timesteps"] == 128
    assert 0 < finished["evaluation_cpu_time_s"] < finished["cpu_time_s"]


def test_a_final_model_a_rollout_past_its_last_evaluation_is_evaluated(tmp_path) -> None:
    # 200 steps round up to four rollouts (256 steps); the evaluation at 160 is more than a rollout before the end
    run = _train(tmp_path, "--eval-freq", "160", "--eval-episodes", "2", steps=200)
    assert list(np.load(f"{run}/evaluations.npz")["timesteps"]) == [160, 256]


class _Episodes(LearnedCostRecorder):
    """A recorder without an env, holding given episodes."""

    def __init__(self, num_envs: int, envs: list[int]):
        self.num_envs = num_envs
        self.episodes = [f"episode {i} of env {idx}" for i, idx in enumerate(envs)]  # type: ignore[misc]
        self.episode_envs = envs


def test_counted_episodes_are_each_sub_envs_first_share() -> None:
    # 5 episodes over 2 envs: env 0 counts 2, env 1 counts 3; env 0's third episode finished before env 1's last
    recorder = _Episodes(2, [0, 1, 0, 1, 0, 1, 1])
    assert recorder.counted_episodes(5) == [
        "episode 0 of env 0",
        "episode 1 of env 1",
        "episode 2 of env 0",
        "episode 3 of env 1",
        "episode 5 of env 1",
    ]


def test_a_resumed_run_keeps_its_checkpoint_and_counts_each_episode_once(tmp_path) -> None:
    import hashlib
    import os

    import pandas as pd

    argv = ["--algo", "ppolag", "--env", "ConstrainedCorridor-v0", "--seed", "0", "-f", str(tmp_path), "--exp-id", "1"]
    argv += ["--resume", "--save-freq", "64", "--eval-freq", "32", "--eval-episodes", "2", "-n", "160"]
    argv += ["-params", "n_steps:32", "batch_size:32", "n_epochs:1"]
    run = train(get_parser().parse_args(argv), argv)
    # A crash after the last checkpoint (128 steps): the steps after it are lost
    os.remove(f"{run}/finished.json")
    os.remove(f"{run}/ConstrainedCorridor-v0.zip")
    checkpoint = f"{run}/rl_model_128_steps.zip"
    with open(checkpoint, "rb") as file:
        before = hashlib.sha256(file.read()).hexdigest()
    monitor = pd.read_csv(f"{run}/0.monitor.csv", skiprows=1)
    assert monitor["l"].sum() > 128  # episodes finished after the checkpoint, which the resumed run replays
    train(get_parser().parse_args(argv), argv)
    with open(checkpoint, "rb") as file:
        assert hashlib.sha256(file.read()).hexdigest() == before  # the checkpoint it went on from is not written again
    monitor = pd.read_csv(f"{run}/0.monitor.csv", skiprows=1)
    assert monitor["l"].sum() <= 160  # no episode of the replayed steps twice
    evaluations = pd.read_csv(f"{run}/eval/0.monitor.csv", skiprows=1)
    with np.load(f"{run}/evaluations.npz") as history:
        assert list(history["timesteps"]) == [32, 64, 96, 128, 160]
    assert len(evaluations) == 5 * 2  # two episodes per evaluation, none of the lost segment's twice
