"""Transfer of learned constraints: the transfer envs' rewards and constraints, and ``sb3-icrl transfer`` end to end."""

import fcntl
import json
import os
import pathlib
import shutil
import threading
import time

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gymnasium_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sb3_icrl.envs  # noqa: F401  (registers the environments)
from sb3_icrl.benchmark.report import constraint_metrics
from sb3_icrl.benchmark.status import progress_words
from sb3_icrl.benchmark.suite import RunSpec
from sb3_icrl.envs import BINDING_ENV_SPECS, ENV_SPECS, REWARD_TRANSFER_TASKS, TRANSFER_ENV_SPECS
from sb3_icrl.metrics.identification import _load_run_policy, run_demonstration_pairs
from sb3_icrl.metrics.transfer import (
    DYNAMICS_NOISE,
    TRAINING_LINE,
    WAITING_LINE,
    ProgressLines,
    TransferProgress,
    feasible_reward_ratio,
    read_transfers,
    train_learner,
    transfer_env,
    transfer_progress,
    transfer_spent_seconds,
)
from sb3_icrl.zoo.compare import RunResult
from sb3_icrl.zoo.hyperparams import load_hyperparams, preprocess_hyperparams
from sb3_icrl.zoo.train import cli
from sb3_icrl.zoo.train import main as train_main

# transfer task -> (direction of x that pays, a safe x, an unsafe x)
DIRECTION = {
    "BlockedHalfCheetahBackward-v0": (-1.0, 0.0, -3.5),
    "BlockedAntBackward-v0": (-1.0, 0.0, -3.5),
    "BlockedWalkerBackward-v0": (-1.0, 0.0, -3.5),
    "BlockedSwimmerForward-v0": (1.0, 0.0, 0.6),
}


def make(name: str, **kwargs) -> gym.Env:
    return gym.make(f"sb3_icrl/{name}", **kwargs)


def place(env: gym.Env, x: float, x_velocity: float = 0.0) -> None:
    """Put the robot at ``x`` in its initial pose, at rest apart from ``x_velocity``."""
    base = env.unwrapped
    qpos, qvel = base.init_qpos.copy(), np.zeros_like(base.init_qvel)
    qpos[0], qvel[0] = x, x_velocity
    base.set_state(qpos, qvel)


def test_every_reward_task_is_registered_with_its_source_spaces():
    # Every transfer env is some env's task; a binding variant's task may be a paper env
    assert set(TRANSFER_ENV_SPECS) <= set(REWARD_TRANSFER_TASKS.values()) <= {*TRANSFER_ENV_SPECS, *ENV_SPECS}
    for source, task in REWARD_TRANSFER_TASKS.items():
        assert source in ENV_SPECS or source in BINDING_ENV_SPECS
        source_env, task_env = make(source), make(task)
        assert task_env.observation_space == source_env.observation_space
        assert task_env.action_space == source_env.action_space
        assert task_env.spec.max_episode_steps == source_env.spec.max_episode_steps


@pytest.mark.filterwarnings("ignore:.*(infinity|symmetric and normalized).*:UserWarning")
@pytest.mark.parametrize("name", sorted(TRANSFER_ENV_SPECS))
def test_env_checkers(name):
    env = make(name)
    gymnasium_check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env)


@pytest.mark.filterwarnings("ignore:.*(infinity|symmetric and normalized).*:UserWarning")
@pytest.mark.parametrize("name", sorted(DIRECTION))
def test_reward_pulls_toward_the_constrained_side(name):
    direction, safe_x, _ = DIRECTION[name]
    env = make(name)
    action = np.zeros(env.action_space.shape)
    rewards = {}
    for sign in (1.0, -1.0):
        env.reset(seed=0)
        place(env, safe_x, x_velocity=2.0 * sign)
        _, reward, _, _, info = env.step(action)
        rewards[sign] = (reward, info)
    toward, away = rewards[direction], rewards[-direction]
    assert toward[0] > away[0]
    assert toward[1]["reward_forward"] > 0 > away[1]["reward_forward"]
    # Moving toward the line pays the speed (weight 1), signed
    assert toward[1]["reward_forward"] == pytest.approx(direction * toward[1]["x_velocity"])


@pytest.mark.parametrize("name", sorted(DIRECTION))
def test_true_constraint_is_the_source_envs(name):
    _, safe_x, unsafe_x = DIRECTION[name]
    env = make(name)
    action = np.zeros(env.action_space.shape)
    for x, cost in ((safe_x, 0.0), (unsafe_x, 1.0)):
        env.reset(seed=0)
        place(env, x)
        assert env.step(action)[4]["cost"] == cost


def test_pendulum_task_pays_most_beyond_the_wall():
    source, task = make("BiasedPendulum-v0").unwrapped, make("BiasedPendulumFarLeft-v0").unwrapped
    assert task.cost_threshold == source.cost_threshold
    # At x = -0.02 (just behind the wall at -0.015) the source already pays in full, the task less than deeper left
    assert source.biased_reward(-0.02) == source.high_reward
    assert task.biased_reward(-0.02) < task.biased_reward(-0.05) == task.high_reward
    assert task.biased_reward(0.0) == source.biased_reward(0.0)


def test_transfer_env_of_each_task():
    env_id = "sb3_icrl/BlockedHalfCheetah-v0"
    assert transfer_env(env_id, "same", 0.05) == (env_id, 0.05)
    assert transfer_env(env_id, "dynamics") == (env_id, DYNAMICS_NOISE) == (env_id, 1e-2)
    assert transfer_env(env_id, "reward") == ("sb3_icrl/BlockedHalfCheetahBackward-v0", 0.0)
    with pytest.raises(ValueError, match="no reward-transfer task"):
        transfer_env("sb3_icrl/GridWorldWall-v0", "reward")
    with pytest.raises(ValueError, match="Unknown transfer task"):
        transfer_env(env_id, "colour")
    assert feasible_reward_ratio(50.0, 100.0) == 0.5 and np.isnan(feasible_reward_ratio(10.0, 0.0))


def test_learned_cost_learner_reads_only_the_learned_cost():
    params = preprocess_hyperparams(load_hyperparams("ppolag", "sb3_icrl/GridWorldWall-v0")[0])
    params.update(n_steps=32, batch_size=32, n_epochs=1)
    seen = []

    def cost_fn(observations, actions):
        seen.append(len(observations))
        return np.full(len(observations), 0.25, dtype=np.float32)

    model, venv = train_learner(
        "learned", "sb3_icrl/GridWorldWall-v0", {}, 0.0, params, 32, 0, cost_fn=cost_fn, budget=0.1, budget_statistic="step"
    )
    assert sum(seen) >= 32 and model.cost_budget[0] == pytest.approx(0.1)
    np.testing.assert_allclose(model.rollout_buffer.costs, 0.25)  # never the env's own 0/1 cost
    venv.close()
    with pytest.raises(ValueError, match="cost_fn"):
        train_learner("learned", "sb3_icrl/GridWorldWall-v0", {}, 0.0, params, 32, 0)


@pytest.fixture(scope="module")
def grid_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("logs")
    argv = ["--algo", "bc2l", "--env", "GridWorldWall-v0", "-n", "256", "-f", str(root), "--seed", "0"]
    assert train_main([*argv, "--eval-freq", "0", "--save-freq", "0", "--num-threads", "1", "--verbose", "0"]) == 0
    return str(root / "bc2l" / "GridWorldWall-v0_1")


def test_the_transfer_learner_keeps_a_signed_learned_cost_floored_at_zero():
    """IRL-Plus charges its cost signed; the transfer's constrained learner counts violations, so it takes it floored."""
    from types import SimpleNamespace

    from sb3_icrl.metrics.transfer import transfer_cost_fn

    model = SimpleNamespace(constraint_cost=lambda obs, acts: np.array([-0.25, 0.0, 0.5], dtype=np.float32))
    costs = transfer_cost_fn(model)(np.zeros((3, 2)), np.zeros((3, 1)))
    np.testing.assert_array_equal(costs, [0.0, 0.0, 0.5])
    assert costs.dtype == np.float32


def test_an_off_policy_run_s_critic_budget_transfers_per_step():
    from types import SimpleNamespace

    from sb3_icrl.metrics.transfer import learned_cost_budget

    sac_run = SimpleNamespace(cost_budget=10.0, budget_statistic="critic", cost_gamma=0.99)
    budget, statistic = learned_cost_budget(sac_run, {})
    assert budget == pytest.approx(0.1) and statistic == "step"
    assert learned_cost_budget(SimpleNamespace(cost_budget=[2.0], budget_statistic="episode"), {}) == (2.0, "episode")


def test_transfer_command_end_to_end(grid_run, capsys):
    assert cli(["transfer", grid_run, "--task", "same", "-n", "64", "--eval-episodes", "2", "--seed", "1"]) == 0
    assert "feasible reward / oracle's" in capsys.readouterr().out
    with open(os.path.join(grid_run, "transfer_same.json")) as file:
        saved = json.load(file)
    assert set(saved["results"]) == {"learned", "oracle", "ppo"}
    for result in saved["results"].values():
        assert 0.0 <= result["violation_rate"] <= 1.0 and result["n_episodes"] == 2
    settings = saved["settings"]
    assert settings["task"] == "same" and settings["n_timesteps"] == 64 and settings["seed"] == 1
    assert settings["env"] == "sb3_icrl/GridWorldWall-v0" and settings["transition_noise"] == 0.0
    assert saved["violation_rate"] == saved["results"]["learned"]["violation_rate"]
    assert read_transfers(grid_run) == {"same": saved}
    # The benchmark report shows it
    root = os.path.dirname(os.path.dirname(grid_run))
    run = RunSpec("smoke", "base", "bc2l", "sb3_icrl/GridWorldWall-v0", 0, 256)
    result = RunResult(os.path.relpath(grid_run, root), "bc2l", run.env_id, 0, 256, 0.1, 0.0, 1.0, 1.0, 2)
    columns = constraint_metrics([(run, result)], root, log=lambda line: None)[result.run]
    assert columns["transfer_same_violation_rate"] == saved["violation_rate"]
    assert "identification_auroc" in columns


def test_a_gacl_run_transfers_at_the_experts_learned_cost(tmp_path):
    # GACL's policy keeps no budget: its learner keeps the expert's mean learned cost per step
    argv = ["--algo", "gacl", "--env", "GridWorldWall-v0", "-n", "256", "-f", str(tmp_path), "--seed", "0"]
    assert train_main([*argv, "--eval-freq", "0", "--save-freq", "0", "--num-threads", "1", "--verbose", "0"]) == 0
    run = os.path.join(tmp_path, "gacl", "GridWorldWall-v0_1")
    assert cli(["transfer", run, "--task", "same", "-n", "64", "--eval-episodes", "1", "--seed", "1"]) == 0
    with open(os.path.join(run, "transfer_same.json")) as file:
        settings = json.load(file)["settings"]
    model, args, _ = _load_run_policy(pathlib.Path(run))
    expected = float(np.mean(model.constraint_cost(*run_demonstration_pairs(args))))
    assert not hasattr(model, "cost_budget") and 0.0 < expected < 1.0
    assert settings["budget"] == pytest.approx(expected) and settings["budget_statistic"] == "step"


def test_transfer_command_refuses_bad_input(grid_run, tmp_path, capsys):
    assert cli(["transfer", str(tmp_path / "missing"), "--task", "same"]) == 2
    assert "No run folder" in capsys.readouterr().err
    assert cli(["transfer", grid_run, "--task", "same", "-n", "0"]) == 2
    assert "-n/--n-timesteps must be >= 1" in capsys.readouterr().err
    assert cli(["transfer", grid_run, "--task", "reward", "-n", "64"]) == 2
    assert "no reward-transfer task" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli(["transfer", grid_run, "--task", "colour"])


def fresh_copy(run: str, tmp_path) -> str:
    """A copy of a run folder, without the transfers other tests saved in it."""
    copy = tmp_path / "logs" / "bc2l" / os.path.basename(run)
    shutil.copytree(run, copy, ignore=shutil.ignore_patterns("transfer_*.json"))
    return str(copy)


def count_training(monkeypatch) -> list[str]:
    """The learners the transfer trains, in order, as a list that grows while it runs."""
    import sb3_icrl.metrics.transfer as transfer

    trained: list[str] = []
    real_train = transfer.train_learner

    def counting_train(learner, *args, **kwargs):
        trained.append(learner)
        return real_train(learner, *args, **kwargs)

    monkeypatch.setattr(transfer, "train_learner", counting_train)
    return trained


def test_references_are_trained_once_per_setting_and_shared(grid_run, tmp_path, monkeypatch):
    import sb3_icrl.metrics.transfer as transfer

    grid_run = fresh_copy(grid_run, tmp_path)
    trained = count_training(monkeypatch)
    shared = tmp_path / "references"
    settings = dict(task="same", n_timesteps=64, eval_episodes=2, seed=1, references_dir=shared, log=lambda line: None)
    first = transfer.run_transfer(grid_run, **settings)
    assert trained == ["learned", "oracle", "ppo"]
    assert sorted(path.name.split("_")[0] for path in shared.glob("*.json")) == ["oracle", "ppo"]
    # Same settings: nothing trains again, the saved results are read back
    second = transfer.run_transfer(grid_run, **settings)
    assert trained[3:] == []
    for learner in ("oracle", "ppo"):
        assert second["results"][learner] == first["results"][learner]
    assert second["settings"]["reference_files"] == first["settings"]["reference_files"]
    # Another seed is another reference; asking for a retrain trains again
    transfer.run_transfer(grid_run, **{**settings, "seed": 2})
    assert trained[3:] == ["learned", "oracle", "ppo"]
    transfer.run_transfer(grid_run, **{**settings, "seed": 2}, retrain_references=True)
    assert trained[6:] == ["oracle", "ppo"]
    # A reference file made with other settings is not reused
    path = next(shared.glob("oracle_*.json"))
    saved = json.loads(path.read_text())
    saved["settings"]["n_timesteps"] = 999
    path.write_text(json.dumps(saved))
    transfer.run_transfer(grid_run, **{**settings, "seed": int(saved["settings"]["seed"])})
    assert "oracle" in trained[8:]


def test_a_reference_another_run_is_training_is_waited_for_not_trained_twice(grid_run, tmp_path, monkeypatch):
    """Two runs reaching the same references at once split them: this one trains the free one, then reads the other."""
    import sb3_icrl.metrics.transfer as transfer

    grid_run = fresh_copy(grid_run, tmp_path)
    trained, lines = count_training(monkeypatch), []
    settings = dict(task="same", n_timesteps=64, eval_episodes=2, seed=4, log=lines.append)
    first = transfer.run_transfer(grid_run, references_dir=tmp_path / "first", **settings)
    oracle_name = pathlib.Path(first["settings"]["reference_files"]["oracle"]).name
    shared = tmp_path / "shared"
    shared.mkdir()
    lock_path = (shared / oracle_name).with_suffix(".lock")

    def other_run() -> None:
        # Holds the oracle's lock until this run waits for it, then saves the oracle it "trained" and lets go
        with open(lock_path, "a") as handle:
            fcntl.flock(handle, fcntl.LOCK_EX)
            held.set()
            deadline = time.time() + 60
            while not any(
                line.startswith(f"transfer (same) on {first['settings']['env']}: waiting for oracle") for line in lines
            ):
                assert time.time() < deadline
                time.sleep(0.01)
            shutil.copy(tmp_path / "first" / oracle_name, shared / oracle_name)
            fcntl.flock(handle, fcntl.LOCK_UN)

    held = threading.Event()
    other = threading.Thread(target=other_run)
    other.start()
    assert held.wait(10)
    second = transfer.run_transfer(grid_run, references_dir=shared, **settings)
    other.join(10)
    assert trained[3:] == ["ppo"]  # the learned-cost result is reused, the oracle read from the other run's file
    assert second["results"]["oracle"] == first["results"]["oracle"]
    assert list(second["results"]) == ["learned", "oracle", "ppo"]
    assert any(line.endswith(f"oracle reused from {shared / oracle_name}") for line in lines)


def test_told_not_to_wait_a_transfer_defers_and_keeps_what_it_trained(grid_run, tmp_path, monkeypatch, capsys):
    """--no-wait: with every missing reference in another run's hands it ends with DEFERRED_EXIT; run again once they
    are saved, it trains nothing more."""
    import sb3_icrl.metrics.transfer as transfer

    # The oracle another run trains, from a copy of the run
    other_copy = fresh_copy(grid_run, tmp_path / "other")
    first = transfer.run_transfer(
        other_copy, "same", n_timesteps=64, eval_episodes=2, seed=4, references_dir=tmp_path / "first"
    )
    grid_run = fresh_copy(grid_run, tmp_path)
    trained = count_training(monkeypatch)
    oracle_name = pathlib.Path(first["settings"]["reference_files"]["oracle"]).name
    shared = tmp_path / "shared"
    shared.mkdir()
    argv = [grid_run, "--task", "same", "-n", "64", "--eval-episodes", "2", "--seed", "4", "--references-dir", str(shared)]
    with open((shared / oracle_name).with_suffix(".lock"), "a") as other_run:  # another run trains the oracle
        fcntl.flock(other_run, fcntl.LOCK_EX)
        assert transfer.main([*argv, "--no-wait"]) == transfer.DEFERRED_EXIT
    assert trained == ["learned", "ppo"]  # what nobody else was training
    assert "oracle being trained by another run" in capsys.readouterr().out
    assert pathlib.Path(grid_run, "transfer_same.partial.json").is_file()
    assert not pathlib.Path(grid_run, "transfer_same.json").exists()
    shutil.copy(tmp_path / "first" / oracle_name, shared / oracle_name)  # the other run saved it
    assert transfer.main([*argv, "--no-wait"]) == 0
    assert trained[5:] == []
    assert (
        json.loads(pathlib.Path(grid_run, "transfer_same.json").read_text())["results"]["oracle"] == first["results"]["oracle"]
    )


def test_a_transfer_run_again_keeps_its_learned_result_and_adds_the_references(grid_run, tmp_path, monkeypatch):
    import sb3_icrl.metrics.transfer as transfer

    grid_run = fresh_copy(grid_run, tmp_path)
    trained, lines = count_training(monkeypatch), []
    settings = dict(task="same", n_timesteps=64, eval_episodes=2, seed=3, references_dir=tmp_path / "references")
    alone = transfer.run_transfer(grid_run, references=False, log=lines.append, **settings)
    assert trained == ["learned"] and set(alone["results"]) == {"learned"} and np.isnan(alone["feasible_reward_ratio"])
    assert any(line.strip().startswith("learned: ") and "/64 steps, " in line for line in lines)  # progress lines
    full = transfer.run_transfer(grid_run, log=lines.append, **settings)
    assert trained[1:] == ["oracle", "ppo"]
    assert full["results"]["learned"] == alone["results"]["learned"]
    # Other settings for the learned-cost learner: it trains again
    transfer.run_transfer(grid_run, log=lines.append, **{**settings, "eval_episodes": 3})
    assert trained[3:] == ["learned", "oracle", "ppo"]
    # The run's model changed since (continued in place): its learned-cost result is stale, the references are not
    model = os.path.join(grid_run, "GridWorldWall-v0.zip")
    later = os.path.getmtime(os.path.join(grid_run, "transfer_same.json")) + 10
    os.utime(model, (later, later))
    transfer.run_transfer(grid_run, log=lines.append, **{**settings, "eval_episodes": 3})
    assert trained[6:] == ["learned"]


def test_a_transfer_cut_before_its_references_keeps_its_learned_result(grid_run, tmp_path, monkeypatch):
    import sb3_icrl.metrics.transfer as transfer

    grid_run = fresh_copy(grid_run, tmp_path)
    trained, lines = count_training(monkeypatch), []
    real_train = transfer.train_learner

    def cut_at_the_oracle(learner, *args, **kwargs):
        if learner == "oracle":
            raise KeyboardInterrupt  # the suite's deadline, or the machine going away
        return real_train(learner, *args, **kwargs)

    monkeypatch.setattr(transfer, "train_learner", cut_at_the_oracle)
    settings = dict(task="same", n_timesteps=64, eval_episodes=2, seed=5, references_dir=tmp_path / "references")
    with pytest.raises(KeyboardInterrupt):
        transfer.run_transfer(grid_run, log=lines.append, **settings)
    partial = pathlib.Path(grid_run, "transfer_same.partial.json")
    assert trained == ["learned"] and partial.is_file()
    assert not pathlib.Path(grid_run, "transfer_same.json").exists()  # the suite still sees the test as not done
    kept = json.loads(partial.read_text())["results"]["learned"]
    # Run again: the learned-cost learner is not trained again, the references are; the partial file goes
    monkeypatch.setattr(transfer, "train_learner", real_train)  # still counting
    full = transfer.run_transfer(grid_run, log=lines.append, **settings)
    assert trained == ["learned", "oracle", "ppo"]
    assert full["results"]["learned"] == kept
    assert any(line.endswith(f"learned reused from {partial}") for line in lines)
    assert not partial.exists() and pathlib.Path(grid_run, "transfer_same.json").is_file()


def test_the_references_go_beside_the_algorithm_folders_however_the_run_is_named(grid_run, tmp_path, monkeypatch):
    import sb3_icrl.metrics.transfer as transfer

    grid_run = fresh_copy(grid_run, tmp_path)
    monkeypatch.chdir(grid_run)
    saved = transfer.run_transfer(".", task="same", n_timesteps=64, eval_episodes=1, seed=4, log=lambda line: None)
    shared = tmp_path / "logs" / "transfer_references"
    assert sorted(os.path.dirname(path) for path in saved["settings"]["reference_files"].values()) == [str(shared)] * 2
    assert len(list(shared.glob("*.json"))) == 2


def test_transfer_spent_counts_each_reference_file_once_and_untimed_learners_as_nothing():
    times = [
        (600.0, {"oracle_a.json": 900.0, "ppo_a.json": 300.0}),
        (60.0, {"oracle_a.json": 900.0, "ppo_a.json": 300.0}),  # the same env and seed: the same references
        (None, {"oracle_b.json": 120.0}),  # a run reported before its learners were timed
    ]
    assert transfer_spent_seconds(times) == 600 + 60 + 900 + 300 + 120
    assert transfer_spent_seconds([]) == 0.0


def test_transfer_progress_reads_the_learner_under_way_from_the_end_of_a_log(tmp_path):
    log = tmp_path / "run.log"
    assert transfer_progress(log) is None  # no log yet
    header = "\n=== 2026-01-01 10:30:00 python -m sb3_icrl.metrics.transfer run --task dynamics\n"
    log.write_text(header + "transfer (dynamics) on sb3_icrl/GridWorldWall-v0: learned reused from run/partial.json\n")
    assert transfer_progress(log) is None  # reusing trains nothing
    with open(log, "a") as file:
        file.write(
            "transfer (dynamics) on sb3_icrl/GridWorldWall-v0: training oracle for 1000 steps\n"
            "  learned: 900/1000 steps, 90 steps/s\n"  # not the learner under way
        )
    assert transfer_progress(log) == TransferProgress("dynamics", "oracle", 0, 1000, None)
    with open(log, "a") as file:
        file.write("  oracle: 300/1000 steps, 150 steps/s\n")
    assert transfer_progress(log) == TransferProgress("dynamics", "oracle", 300, 1000, 150.0)
    with open(log, "a") as file:
        file.write("  oracle: 1000/1000 steps, 150 steps/s\n")
    assert progress_words(transfer_progress(log)) == "the dynamics task's oracle learner trained, being evaluated"
    with open(log, "a") as file:
        file.write("transfer (dynamics) on sb3_icrl/GridWorldWall-v0: ppo reused from refs/ppo.json\n")
    assert transfer_progress(log) is None  # the oracle's numbers are not shown for the reused PPO
    with open(log, "a") as file:
        file.write("transfer (dynamics) on sb3_icrl/GridWorldWall-v0: waiting for ppo, which another run is training (x)\n")
    progress = transfer_progress(log)
    assert progress == TransferProgress("dynamics", "ppo", 0, 0, waiting=True)
    assert progress_words(progress) == "the dynamics task waits for its ppo reference, which another run is training"
    with open(log, "a") as file:
        file.write("\n=== 2026-01-01 11:00:00 python -m sb3_icrl.zoo train --algo bc2l --resume\n")
    assert transfer_progress(log) is None  # the run's last command trains the run itself


def test_transfer_progress_reads_the_lines_the_test_writes(tmp_path):
    lines = [TRAINING_LINE.format(task="same", env="sb3_icrl/GridWorldWall-v0", learner="ppo", steps=64)]
    callback = ProgressLines("ppo", 64, lines.append)
    callback.num_timesteps = 32
    callback._on_step()
    (tmp_path / "run.log").write_text("\n".join(lines) + "\n")
    progress = transfer_progress(tmp_path / "run.log")
    assert (progress.task, progress.learner, progress.steps, progress.total) == ("same", "ppo", 32, 64)
    assert progress.steps_per_s > 0
    waiting = WAITING_LINE.format(task="same", env="sb3_icrl/GridWorldWall-v0", learner="oracle", file="refs/o.json")
    (tmp_path / "run.log").write_text(waiting + "\n")
    assert transfer_progress(tmp_path / "run.log") == TransferProgress("same", "oracle", 0, 0, waiting=True)
