"""Crash safety: atomic writes, training killed while checkpointing, and resuming in the same run folder."""

import json
import os
import pathlib
import pickle
import random
import signal
import subprocess
import sys
import time
import zipfile

import gymnasium as gym
import numpy as np
import pytest
import torch as th
import yaml
from stable_baselines3.common.monitor import load_results
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_icrl import MECL
from sb3_icrl.common.utils import atomic_save_npz, atomic_write_text, atomic_write_yaml, remove_temporaries
from sb3_icrl.zoo.callbacks import (
    AtomicCheckpointCallback,
    ConstraintEvalCallback,
    LearnedCostRecorder,
    load_training_state,
    training_state_path,
)
from sb3_icrl.zoo.hyperparams import ALGOS
from sb3_icrl.zoo.train import main

ROOT = pathlib.Path(__file__).resolve().parents[1]
ENV = "sb3_icrl/GridWorldWall-v0"


def test_atomic_text_yaml_and_npz_helpers(tmp_path: pathlib.Path, monkeypatch) -> None:
    atomic_write_text(tmp_path / "command.txt", "first\n")
    atomic_write_text(tmp_path / "command.txt", "second\n", append=True)
    assert (tmp_path / "command.txt").read_text() == "first\nsecond\n"
    atomic_write_yaml(tmp_path / "config.yml", {"n_steps": 64, "policy": "MlpPolicy"})
    assert yaml.safe_load((tmp_path / "config.yml").read_text()) == {"n_steps": 64, "policy": "MlpPolicy"}
    path = atomic_save_npz(tmp_path / "evaluations", {"timesteps": np.array([1, 2])})
    assert path.endswith("evaluations.npz")
    with np.load(path) as saved:
        assert saved["timesteps"].tolist() == [1, 2]

    def half_written(file, **arrays):
        file.write(b"PK half an archive")
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez", half_written)
    with pytest.raises(OSError, match="disk full"):
        atomic_save_npz(tmp_path / "evaluations.npz", {"timesteps": np.array([3])})
    with np.load(path) as saved:  # the failed write left the old file
        assert saved["timesteps"].tolist() == [1, 2]
    assert sorted(entry.name for entry in tmp_path.iterdir()) == ["command.txt", "config.yml", "evaluations.npz"]
    # What a kill in the middle of a write leaves: a hidden temporary file, which remove_temporaries deletes
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / ".rl_model_64_steps.zip.abc123.tmp").write_bytes(b"PK half")
    assert remove_temporaries(tmp_path) == [str(tmp_path / "sub" / ".rl_model_64_steps.zip.abc123.tmp")]
    assert sorted(entry.name for entry in (tmp_path / "sub").iterdir()) == []


def _mecl(seed: int = 0) -> MECL:
    return MECL(
        "MlpPolicy",
        DummyVecEnv([lambda: gym.make(ENV)]),
        demonstrations="GridWorldWall-v0",
        n_steps=64,
        batch_size=32,
        n_epochs=1,
        policy_kwargs=dict(net_arch=[16]),
        constraint_net_kwargs=dict(hidden_sizes=[8]),
        # Updates every other rollout: the trajectories waiting for the next update are part of the state
        update_every=128,
        trainer_kwargs=dict(nominal_memory=3),
        seed=seed,
        device="cpu",
    )


def _eval_callback(log_path: pathlib.Path) -> ConstraintEvalCallback:
    recorder = LearnedCostRecorder(DummyVecEnv([lambda: gym.make(ENV)]))
    return ConstraintEvalCallback(
        recorder,
        recorder=recorder,
        n_eval_episodes=1,
        eval_freq=64,
        log_path=str(log_path),
        best_model_save_path=None,
        verbose=0,
    )


def test_training_state_round_trip(tmp_path: pathlib.Path) -> None:
    """A checkpoint's training state holds the trainer's memory, sampler, counters and the model selection."""
    model = _mecl()
    evaluation = _eval_callback(tmp_path)
    checkpoint = AtomicCheckpointCallback(64, str(tmp_path), save_training_state=True, evaluation=evaluation)
    model.learn(448, callback=[evaluation, checkpoint])
    trainer = model.icrl_trainer
    assert trainer is not None and trainer.n_updates >= 2 and len(trainer.remembered) == 3  # a real memory
    assert np.isfinite(evaluation.best_score) and evaluation.best_episodes
    # The last checkpoint is taken at the end of training: it is the live state
    zip_path = tmp_path / f"rl_model_{model.num_timesteps}_steps.zip"
    state_path = training_state_path(str(zip_path), "GridWorldWall-v0")
    assert state_path == str(tmp_path / f"rl_model_training_state_{model.num_timesteps}_steps.pkl")

    restored = MECL.load(str(zip_path), env=DummyVecEnv([lambda: gym.make(ENV)]), demonstrations="GridWorldWall-v0")
    restored_evaluation = _eval_callback(tmp_path)
    assert load_training_state(restored, state_path, restored_evaluation)
    other = restored.icrl_trainer
    assert other is not None and other is not trainer
    assert (other.n_updates, other._last_update) == (trainer.n_updates, trainer._last_update)
    assert other._rng.bit_generator.state == trainer._rng.bit_generator.state
    assert len(other.remembered) == len(trainer.remembered)
    for mine, theirs in zip(other.remembered, trainer.remembered, strict=True):
        np.testing.assert_array_equal(mine.obs, theirs.obs)
        np.testing.assert_array_equal(mine.acts, theirs.acts)
    assert other.recorder is not None and trainer.recorder is not None
    assert [len(t) for t in other.recorder.finished] == [len(t) for t in trainer.recorder.finished]
    assert restored_evaluation.best_score == evaluation.best_score
    for episode, saved in zip(restored_evaluation.best_episodes, evaluation.best_episodes, strict=True):
        np.testing.assert_array_equal(episode.observations, saved.observations)
        np.testing.assert_array_equal(episode.rewards, saved.rewards)
    # The constraint optimiser travels in the zip
    assert other.optimizer.state_dict()["state"].keys() == trainer.optimizer.state_dict()["state"].keys()
    for key, value in trainer.optimizer.state_dict()["state"][0].items():
        assert th.equal(th.as_tensor(other.optimizer.state_dict()["state"][0][key]), th.as_tensor(value))

    # learn() keeps the restored trainer and its step of the last update (384, not 448 where it resumes), so the
    # update due at 512 is made, as in an uninterrupted run
    assert (model.num_timesteps, trainer._last_update) == (448, 384)
    restored.learn(64, callback=[restored_evaluation], reset_num_timesteps=False)
    assert restored.icrl_trainer is other
    assert (other._last_update, other.n_updates) == (512, trainer.n_updates + 1)

    # A state saved at another step count is not used
    restored.num_timesteps += 1
    with pytest.warns(UserWarning, match="not used"):
        assert not load_training_state(restored, state_path, None)
    with pytest.raises(ValueError, match="Not an ICRL trainer state"):
        other.load_state_dict({"n_updates": 1})


def _check_every_file_loads(run: pathlib.Path) -> None:
    """No partial file under a final name: every zip, pickle, JSON and npz of the run folder reads back whole."""
    for path in sorted(run.rglob("*")):
        if path.name.startswith("."):  # a temporary file of a write cut short: never under a final name
            assert path.name.endswith(".tmp"), path
            continue
        if path.suffix == ".zip":
            with zipfile.ZipFile(path) as archive:
                assert archive.testzip() is None and "data" in archive.namelist(), path
        elif path.suffix == ".pkl":
            with open(path, "rb") as file:
                pickle.load(file)
        elif path.suffix == ".json":
            json.loads(path.read_text())
        elif path.suffix == ".npz":
            with np.load(path) as saved:
                [saved[key] for key in saved.files]
        elif path.suffix == ".yml":
            yaml.safe_load(path.read_text())


def _checkpoint_steps(run: pathlib.Path) -> list[int]:
    return sorted(
        int(path.name.split("_")[2]) for path in run.glob("rl_model_*_steps.zip") if path.name.split("_")[2].isdigit()
    )


def test_killed_while_checkpointing_leaves_whole_files_and_resumes(tmp_path: pathlib.Path) -> None:
    """SIGKILL at random moments of a run that checkpoints every rollout; each time, --resume goes on from there."""
    command = [sys.executable, str(ROOT / "train.py"), "--algo", "ppolag", "--env", "ConstrainedCorridor-v0"]
    command += ["-n", "1000000", "-params", "n_steps:32", "batch_size:32", "n_epochs:1", "normalize:True"]
    command += ["--save-freq", "32", "--eval-freq", "64", "--eval-episodes", "1", "--seed", "0", "--verbose", "0"]
    command += ["-f", str(tmp_path), "--exp-id", "1", "--resume"]
    run = tmp_path / "ppolag" / "ConstrainedCorridor-v0_1"
    rng = random.Random(0)
    reached = 0
    for attempt in range(3):
        log = tmp_path / f"attempt_{attempt}.log"
        with open(log, "wb") as output:
            process = subprocess.Popen(command, cwd=tmp_path, stdout=output, stderr=subprocess.STDOUT)
            deadline = time.time() + 300  # generous: a busy machine starts python slowly
            # Kill once this process has written checkpoints of its own, at a random moment of its writes
            while time.time() < deadline and process.poll() is None and (_checkpoint_steps(run) or [0])[-1] <= reached + 64:
                time.sleep(0.05)
            time.sleep(rng.uniform(0.0, 0.3))
            process.send_signal(signal.SIGKILL)
            assert process.wait() == -signal.SIGKILL, log.read_text()
        steps = _checkpoint_steps(run)
        assert steps and steps[-1] > reached, "the resumed run went on from the previous checkpoint"
        reached = steps[-1]
        assert not (run / "finished.json").exists()
        _check_every_file_loads(run)
        with np.load(run / "evaluations.npz") as evaluations:
            assert np.all(np.diff(evaluations["timesteps"]) > 0)  # one run's history, not two interleaved

    # The last checkpoint continues in place with -i: the step count goes on, the history is one run's
    latest = run / f"rl_model_{reached}_steps.zip"
    assert main([*command[2:-3], "-n", "64", "-f", str(tmp_path), "-i", str(latest)]) == 0
    assert json.loads((run / "finished.json").read_text())["num_timesteps"] == reached + 64
    assert ALGOS["ppolag"].load(run / "ConstrainedCorridor-v0.zip").num_timesteps == reached + 64
    _check_every_file_loads(run)
    with np.load(run / "evaluations.npz") as evaluations:
        timesteps = evaluations["timesteps"]
    assert timesteps[-1] == reached + 64 and np.all(np.diff(timesteps) > 0)
    monitor = load_results(str(run))
    assert np.all(np.diff(monitor["t"].to_numpy()) >= 0)  # the appended episodes come after the earlier ones
    assert len([line for line in (run / "command.txt").read_text().splitlines() if line]) == 4
    assert not list(run.rglob(".*.tmp")), "the resumed run removed the temporary files of the killed writes"


#: A recipe of its own: the test does not depend on the shipped one's forward solver and rollout length
MECL_RECIPE = """
GridWorldWall-v0:
  n_timesteps: 256
  policy: 'MlpPolicy'
  n_steps: 64
  batch_size: 32
  n_epochs: 1
  update_every: 128
  trainer_kwargs: "dict(nominal_memory=3)"
  policy_kwargs: "dict(net_arch=[16])"
"""


def test_i_continues_in_the_run_folder_unless_new_folder(tmp_path: pathlib.Path, capsys) -> None:
    (tmp_path / "mecl.yml").write_text(MECL_RECIPE)
    base = ["--algo", "mecl", "--env", "GridWorldWall-v0", "-conf", str(tmp_path / "mecl.yml")]
    base += ["--eval-freq", "64", "--eval-episodes", "1", "--seed", "0"]
    base += ["--save-freq", "64", "-f", str(tmp_path), "--verbose", "0", "-tb", str(tmp_path / "tb")]
    assert main([*base, "-n", "256"]) == 0
    run = tmp_path / "mecl" / "GridWorldWall-v0_1"
    assert main([*base, "-n", "128"]) == 0  # another run, logging to the same TensorBoard folder
    tensorboard = (run / "GridWorldWall-v0" / "tensorboard.txt").read_text().strip()
    assert tensorboard.endswith("mecl_GridWorldWall-v0_1")

    # An earlier checkpoint: the folder went further, so it is refused unless it branches into a new folder
    assert main([*base, "-n", "64", "-i", str(run / "rl_model_128_steps.zip")]) == 2
    assert "pass --new-folder" in capsys.readouterr().err
    assert main([*base, "-n", "64", "-i", str(run / "rl_model_128_steps.zip"), "--new-folder"]) == 0
    assert (tmp_path / "mecl" / "GridWorldWall-v0_3" / "rl_model_192_steps.zip").is_file()

    # The final model of a finished run: it goes on in place, with its training state
    assert main([*base, "-n", "128", "-i", str(run / "GridWorldWall-v0.zip")]) == 0
    assert sorted(path.name for path in (tmp_path / "mecl").iterdir()) == [f"GridWorldWall-v0_{n}" for n in (1, 2, 3)]
    assert json.loads((run / "finished.json").read_text())["num_timesteps"] == 384
    with np.load(run / "evaluations.npz") as evaluations:
        assert evaluations["timesteps"].tolist() == [64, 128, 192, 256, 320, 384]
    assert (run / "GridWorldWall-v0" / "tensorboard.txt").read_text().strip() == tensorboard
    assert len(list(pathlib.Path(tensorboard).glob("events.out.tfevents.*"))) == 2  # one curve in one folder
    state = pickle.loads((run / "rl_model_training_state_384_steps.pkl").read_bytes())
    assert state["num_timesteps"] == 384 and state["icrl_trainer"]["n_updates"] == 3
    assert len(state["icrl_trainer"]["remembered"]) == 3
    assert state["evaluation"]["best_episodes"]

    # --exp-id naming another folder than the model's is refused
    assert main([*base, "-n", "64", "-i", str(run / "GridWorldWall-v0.zip"), "--exp-id", "9"]) == 2
    assert "leave out --exp-id" in capsys.readouterr().err
    assert main([*base, "-n", "64", "--new-folder"]) == 2
    assert "pass -i MODEL.zip too" in capsys.readouterr().err
    assert os.path.isfile(run / "finished.json")
