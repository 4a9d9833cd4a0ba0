"""benchmarks/lagrangian_state.py: a finished run's budget, last cost per step and multiplier, and their trajectory."""

import json
from pathlib import Path

import numpy as np
import pytest
from script_loader import load_script
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_icrl import PPOLagrangian
from sb3_icrl.common.envs import ConstrainedCorridorEnv

lagrangian_state = load_script("benchmarks/lagrangian_state.py")

TINY = dict(n_steps=16, batch_size=8, n_epochs=1, policy_kwargs=dict(net_arch=[8]), seed=0)


class HalfCostCorridor(ConstrainedCorridorEnv):
    """The corridor, every step costing 0.5."""

    def step(self, action):
        obs, reward, terminated, truncated, info = super().step(action)
        info["cost"] = 0.5
        return obs, reward, terminated, truncated, info


def logger_table(steps: int, multiplier: float, value: float) -> str:
    """A logger table as SB3 prints it, with the rows the trajectory reads."""
    rows = [("total_timesteps", steps), ("constraint_value", value), ("lagrange_multiplier", multiplier)]
    body = "\n".join(f"|    {key:<20} | {val:<8} |" for key, val in rows)
    return f"---------------------\n{body}\n---------------------\n"


def finished_run(folder: Path, algo: str, seed: int) -> Path:
    run = folder / "base" / algo / f"Corridor-v0_{seed}"
    run.mkdir(parents=True)
    (run / "finished.json").write_text("{}")
    return run


def test_saved_state_and_line_of_a_lagrangian_run(tmp_path: Path) -> None:
    env = DummyVecEnv([HalfCostCorridor])
    model = PPOLagrangian("MlpPolicy", env, cost_budget=0.1, budget_statistic="step", lagrange_update="pid", **TINY)
    model.learn(32)
    run = finished_run(tmp_path, "ppolag", 7)
    model.save(run / "Corridor-v0.zip")
    sources = {"expert": {"mean_cost": 0.25}, "learner": {"mean_cost": 0.75}}
    (run / "identification.json").write_text(json.dumps({"scores": {"sources": sources}}))
    (tmp_path / "logs").mkdir()
    log = logger_table(16, 1.5, 0.5) + "Eval num_timesteps=16\n" + logger_table(32, 2.0, 0.5)
    (tmp_path / "logs" / "base_ppolag_Corridor-v0_7.log").write_text(log)

    state = lagrangian_state.saved_state(run / "Corridor-v0.zip")
    assert state["budget"] == pytest.approx(0.1)
    assert state["step_cost"] == pytest.approx(0.5)  # every step of the last rollout cost 0.5
    assert state["multiplier"] == pytest.approx(float(np.asarray(model.lagrange_multiplier.value)[0]))

    lines = lagrangian_state.describe(run, tmp_path, points=5)
    assert lines[0].startswith("base/ppolag/Corridor-v0 seed 7: budget 0.1 per step, last cost per step 0.5 (5x the budget)")
    assert lines[0].endswith("learned cost on the expert 0.25, on the learner 0.75")
    assert lines[1] == "    through training (steps: multiplier / constraint value per step): 16: 1.5 / 0.5, 32: 2 / 0.5"


def test_a_budget_per_episode_is_not_compared_with_a_cost_per_step(tmp_path: Path) -> None:
    model = PPOLagrangian("MlpPolicy", DummyVecEnv([HalfCostCorridor]), cost_budget=5.0, budget_statistic="episode", **TINY)
    run = finished_run(tmp_path, "ppolag", 8)
    model.learn(32).save(run / "Corridor-v0.zip")
    (line,) = lagrangian_state.describe(run, tmp_path, points=0)
    assert "budget 5 per episode, last cost per step 0.5, multiplier" in line
    assert "x the budget" not in line


def test_a_damaged_model_is_named_and_the_listing_goes_on(tmp_path: Path) -> None:
    run = finished_run(tmp_path, "mecl", 4)
    (run / "Corridor-v0.zip").write_text("not a zip")
    (line,) = lagrangian_state.describe(run, tmp_path, points=0)
    assert line.startswith("base/mecl/Corridor-v0 seed 4: cannot read its model or identification scores")


def test_a_run_without_a_multiplier_prints_nothing(tmp_path: Path) -> None:
    run = finished_run(tmp_path, "ppo", 0)
    PPO("MlpPolicy", DummyVecEnv([ConstrainedCorridorEnv]), **TINY).save(run / "Corridor-v0.zip")
    assert lagrangian_state.describe(run, tmp_path, points=3) == []


def test_a_finished_run_without_its_model_says_so(tmp_path: Path) -> None:
    run = finished_run(tmp_path, "bc2l", 3)
    assert lagrangian_state.describe(run, tmp_path, points=0) == [
        f"base/bc2l/Corridor-v0 seed 3: no final model (Corridor-v0.zip) in {run}"
    ]


def test_trajectory_keeps_evenly_spaced_points_and_the_last(tmp_path: Path) -> None:
    log = tmp_path / "run.log"
    log.write_text("".join(logger_table(step, step / 10, 0.1) for step in range(10, 110, 10)))
    assert [steps for steps, _, _ in lagrangian_state.logged_trajectory(log, 3)] == [10, 50, 100]
    assert len(lagrangian_state.logged_trajectory(log, 50)) == 10


def test_trajectory_follows_a_resumed_attempt_and_leaves_out_the_transfer_test(tmp_path: Path) -> None:
    log = tmp_path / "run.log"
    log.write_text(
        "=== 2026-01-01 00:00:00 python -m sb3_icrl.zoo train --algo mecl\n"
        + "".join(logger_table(step, 1.0, 0.1) for step in (10, 20, 30))
        + "=== 2026-01-01 01:00:00 python -m sb3_icrl.zoo train --algo mecl --resume\n"
        + "".join(logger_table(step, 2.0, 0.2) for step in (20, 30, 40))  # back to the checkpoint at 10
        + "=== 2026-01-01 02:00:00 python -m sb3_icrl.metrics.transfer RUN --task reward\n"
        + logger_table(50, 9.0, 0.9)  # the transfer learner's table
    )
    assert lagrangian_state.logged_trajectory(log, 10) == [(10, 1.0, 0.1), (20, 2.0, 0.2), (30, 2.0, 0.2), (40, 2.0, 0.2)]


def test_unfinished_runs_are_skipped_and_bad_input_is_named(tmp_path: Path, capsys) -> None:
    finished_run(tmp_path, "mecl", 1)
    (tmp_path / "base" / "mecl" / "Corridor-v0_2").mkdir()  # not finished
    assert [run.name for run in lagrangian_state.run_folders(tmp_path, "Corridor-v0")] == ["Corridor-v0_1"]
    assert lagrangian_state.run_folders(tmp_path, "Other-v0") == []
    with pytest.raises(SystemExit):
        lagrangian_state.main([str(tmp_path / "missing")])
    assert "is not a folder" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        lagrangian_state.main([str(tmp_path), "--env", "Other-v0"])
    assert "no finished run under" in capsys.readouterr().err
