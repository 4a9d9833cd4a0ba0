"""Run folders in the layout rl_zoo3's plot scripts read: ``evaluations.npz`` holds SB3's per-episode arrays only."""

import pathlib
import pickle
import shutil
import sys

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_icrl.zoo import main
from sb3_icrl.zoo.callbacks import SELECTION_FILE, ConstraintEvalCallback, split_evaluation_history

FAST = ["-n", "256", "-params", "n_steps:128", "batch_size:32", "forward_solver:policy_gradient", "--eval-freq", "128"]
FAST += ["--eval-episodes", "2", "--seed", "1", "--verbose", "0"]


def all_plots_post_processing(logs: list[dict[str, np.ndarray]], key: str) -> dict[str, np.ndarray]:
    """
    What ``rl_zoo3.plots.all_plots.all_plots`` (rl_zoo3 2.7.0) computes from the ``evaluations.npz`` of each trial
    for ``--key key``, step by step with its own expressions (no ``--min-timesteps``, no truncation).

    :param logs: The arrays of each trial's ``evaluations.npz``
    :param key: Its ``--key``
    :return: The values it pickles for ``plot_from_file``: ``mean``, ``mean_per_eval`` and ``last_evals``
    """
    max_len, merged_results, last_eval = 0, [], []
    timesteps = np.empty(0)
    for log in logs:
        mean_ = np.squeeze(log["results"].mean(axis=1))
        max_len = max(max_len, len(mean_))
        if len(log["timesteps"]) >= max_len:
            timesteps = log["timesteps"]
        merged_results.append(log[key])
        last_eval.append(log[key][max_len - 1] if len(log[key]) >= max_len else log[key][-1])
    n_trials, n_eval = len(merged_results), len(timesteps)
    evaluations = np.swapaxes(np.array(merged_results).reshape((n_trials, n_eval, -1)), 0, 1)
    return {
        "mean": np.mean(evaluations, axis=(1, 2)),
        "mean_per_eval": np.mean(evaluations, axis=-1),
        "last_evals": np.array(last_eval).squeeze().mean(axis=-1),  # fails on a 0-d array: one trial of 1-D values
    }


@pytest.fixture(scope="module")
def run_folders(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    """Two MECL trials on the grid world (the second a copy of the first), as ``sb3-icrl train`` writes them."""
    folder = tmp_path_factory.mktemp("logs")
    assert main(["--algo", "mecl", "--env", "GridWorldWall-v0", *FAST, "-f", str(folder)]) == 0
    shutil.copytree(folder / "mecl" / "GridWorldWall-v0_1", folder / "mecl" / "GridWorldWall-v0_2")
    return folder


def test_every_key_has_the_shape_rl_zoo3_all_plots_needs(run_folders: pathlib.Path) -> None:
    runs = sorted((run_folders / "mecl").iterdir())
    logs = [dict(np.load(run / "evaluations.npz")) for run in runs]
    n_eval = len(logs[0]["timesteps"])
    assert n_eval == 2
    for key in logs[0]:
        if key == "timesteps":
            continue
        assert logs[0][key].shape == (n_eval, 2), key
        for trials in (logs[:1], logs):  # one trial, and several
            processed = all_plots_post_processing(trials, key)
            assert processed["mean_per_eval"].shape == (n_eval, len(trials)), key
            # One trial: a scalar, as for SB3's own results (plot_from_file then skips it); several: one per trial
            assert processed["last_evals"].shape == (() if len(trials) == 1 else (len(trials),)), key
            np.testing.assert_allclose(processed["last_evals"], logs[0][key][-1].mean(), err_msg=key)
    assert {"learned_feasible_rewards", "learned_episode_costs", "learned_penalised_rewards"} <= set(logs[0])
    # The model selection's values, one per evaluation, are beside it
    with np.load(runs[0] / SELECTION_FILE) as selection:
        assert selection["timesteps"].tolist() == logs[0]["timesteps"].tolist()
        assert selection["selection_score"].shape == (n_eval,)


def test_rl_zoo3_all_plots_reads_every_key(
    run_folders: pathlib.Path, tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """rl_zoo3's own ``all_plots`` where it is installed (with its plotting dependencies)."""
    all_plots = pytest.importorskip("rl_zoo3.plots.all_plots").all_plots
    monkeypatch.setattr("matplotlib.pyplot.show", lambda *args, **kwargs: None)
    with np.load(run_folders / "mecl" / "GridWorldWall-v0_1" / "evaluations.npz") as saved:
        keys = [key for key in saved.files if key != "timesteps"]
    for key in keys:
        output = tmp_path / key
        argv = ["all_plots", "-a", "mecl", "-e", "GridWorldWall", "-f", str(run_folders), "-k", key, "--no-display"]
        monkeypatch.setattr(sys, "argv", [*argv, "-o", str(output)])
        all_plots()
        with open(f"{output}.pkl", "rb") as file:
            processed = pickle.load(file)["GridWorldWall"][f"MECL-{run_folders}"]
        assert np.shape(processed["last_evals"]) == (2,), key  # one per trial


def test_older_files_with_one_value_per_evaluation_are_read(tmp_path: pathlib.Path) -> None:
    """A run written before the per-episode layout resumes: its means are kept, its selection scores too."""
    old = {
        "timesteps": np.array([100, 200, 300]),
        "results": np.arange(6.0).reshape(3, 2),
        "ep_lengths": np.full((3, 2), 10),
        "learned_feasible_reward": np.array([1.0, 2.0, 3.0]),
        "mean_learned_cost": np.array([0.5, 0.25, 0.0]),
        "learned_penalised_reward": np.array([np.nan, np.nan, np.nan]),
        "best_model_rescored": np.array([np.nan, 1.5, 2.5]),
        "selection_score": np.array([1.0, 4.0, 3.0]),
    }
    evaluations, selection = split_evaluation_history(old)
    assert {key: value.shape for key, value in evaluations.items()} == {
        "timesteps": (3,),
        "results": (3, 2),
        "ep_lengths": (3, 2),
        "learned_feasible_rewards": (3, 2),
        "learned_episode_costs": (3, 2),
        "learned_penalised_rewards": (3, 2),
    }
    np.testing.assert_allclose(evaluations["learned_feasible_rewards"].mean(axis=1), [1.0, 2.0, 3.0])
    assert sorted(selection) == ["best_model_rescored", "lagrange_multiplier", "selection_score", "timesteps"]
    assert np.isnan(selection["lagrange_multiplier"]).all()  # not recorded then

    np.savez(tmp_path / "evaluations.npz", **old)
    (tmp_path / "best_model.zip").write_bytes(b"")
    env = DummyVecEnv([lambda: gym.make("CartPole-v1")])
    callback = ConstraintEvalCallback(env, log_path=str(tmp_path), best_model_save_path=str(tmp_path))
    callback.resume_history(up_to_timesteps=200)
    assert callback.history["timesteps"] == [100, 200]
    assert np.array(callback.history["learned_episode_costs"]).shape == (2, 2)
    assert callback.selection_history["selection_score"] == [1.0, 4.0]
    assert callback.best_score == 4.0
    env.close()
