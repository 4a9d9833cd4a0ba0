"""Each constraint's violation rate, for envs with several: evaluation, the driving envs' info, the benchmark report."""

import csv
import io
import json
import os
import pathlib
from dataclasses import asdict

import gymnasium as gym
import numpy as np
import pytest

from sb3_icrl.benchmark import report, summarise_suite
from sb3_icrl.benchmark.report import HELDOUT_FILE, evaluate_finished, previous_results
from sb3_icrl.benchmark.report_text import constraint_columns, csv_rows, markdown_table
from sb3_icrl.common.env_ids import registered_constraints
from sb3_icrl.common.evaluation import EpisodeAccumulator, evaluate_constraint
from sb3_icrl.zoo.compare import RunResult
from sb3_icrl.zoo.runs import FINISHED_FILE

MULTI = "sb3_icrl/HighwayVelocityDistance-v0"


def _step(velocity: float, distance: float) -> dict:
    return {"cost": max(velocity, distance), "constraint_costs": {"velocity": velocity, "distance": distance}}


def test_each_constraint_counts_the_episodes_that_broke_it():
    episodes = EpisodeAccumulator(2)
    # Sub-env 0: the speed limit broken at its second step, then both at once; sub-env 1: the gap only, then nothing
    for idx, steps in ((0, [_step(0, 0), _step(1, 0), _step(0, 0)]), (1, [_step(0, 1), _step(0, 0)])):
        for info in steps:
            episodes.add(idx, 1.0, info)
        episodes.end_episode(idx, steps[-1])
    episodes.add(0, 1.0, _step(1, 1))
    episodes.end_episode(0, _step(1, 1))
    episodes.add(1, 1.0, _step(0, 0))
    episodes.end_episode(1, _step(0, 0))
    evaluation = episodes.evaluation()
    # Episodes in the order they ended: (velocity), (distance), (both), (none)
    assert evaluation.violations.tolist() == [True, True, True, False]
    assert {name: flags.tolist() for name, flags in evaluation.constraint_violations.items()} == {
        "velocity": [True, False, True, False],
        "distance": [False, True, True, False],
    }
    assert evaluation.constraint_violation_rates == {"violation_rate_velocity": 0.5, "violation_rate_distance": 0.5}
    assert evaluation.violation_rate == 0.75  # an episode that breaks both counts once
    assert evaluation.feasible_rewards.tolist() == [1.0, 0.0, 0.0, 1.0]
    assert evaluation.summary()["violation_rate_distance"] == 0.5
    assert evaluation.to_dict()["constraint_violations"]["velocity"] == [True, False, True, False]


def test_a_constraint_not_reported_in_every_episode_has_no_rate():
    episodes = EpisodeAccumulator(1)
    episodes.add(0, 1.0, {"cost": 0.0})
    episodes.end_episode(0, {})
    episodes.add(0, 1.0, _step(1, 0))
    episodes.end_episode(0, {})
    assert episodes.evaluation().constraint_violations == {}
    # Envs with one combined cost report none
    plain = EpisodeAccumulator(1)
    plain.add(0, 1.0, {"cost": 1.0})
    plain.end_episode(0, {})
    assert plain.evaluation().constraint_violation_rates == {} and plain.evaluation().violation_rate == 1.0


class _ConstantPolicy:
    def __init__(self, action: np.ndarray):
        self.action = action

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        return np.tile(self.action, (len(observation), 1)), None


@pytest.mark.parametrize("env_id, names", [(MULTI, ["velocity", "distance"]), ("sb3_icrl/HighwayVelocity-v0", ["velocity"])])
def test_driving_envs_report_each_of_their_own_constraints(env_id, names):
    action = np.array([1.0, 0.0], dtype=np.float32)  # full throttle, straight on: over the speed limit soon
    env = gym.make(env_id)
    env.reset(seed=0)
    broken = dict.fromkeys(names, False)
    done = False
    while not done:
        _, _, terminated, truncated, info = env.step(action)
        assert list(info["constraint_costs"]) == names
        assert info["cost"] == max(info["constraint_costs"].values())
        for name in names:
            assert info["constraint_costs"][name] == info[f"cost_{name}"]
            broken[name] |= info[f"cost_{name}"] > 0
        done = terminated or truncated
    assert any(broken.values())  # the run breaks a constraint: the flags below say something
    evaluation = evaluate_constraint(_ConstantPolicy(action), gym.make(env_id), n_eval_episodes=1, seed=0)
    assert {name: bool(flags[0]) for name, flags in evaluation.constraint_violations.items()} == broken
    assert bool(evaluation.violations[0]) == any(broken.values())


# ---------------------------------------------------------------- the benchmark report

SUITE = "description: multi\nenvs: [HighwayVelocityDistance-v0]\nalgos: [mecl, vicrl]\nseeds: [0, 1]\nsteps: 512\n"
#: (algo, seed) -> (violation rate, feasible reward, speed violation rate, gap violation rate)
NUMBERS = {
    ("mecl", 0): (0.5, 10.0, 0.25, 0.5),
    ("mecl", 1): (0.25, 20.0, 0.25, 0.0),
    ("vicrl", 0): (1.0, 0.0, 1.0, 0.75),
    ("vicrl", 1): (0.0, 30.0, 0.0, 0.0),
}


@pytest.fixture
def suite(report_suite):
    return report_suite(SUITE)


def _result(algo: str, seed: int) -> RunResult:
    violation, feasible, velocity, distance = NUMBERS[(algo, seed)]
    rates = {"violation_rate_velocity": velocity, "violation_rate_distance": distance}
    return RunResult(
        f"logs/{algo}/Env_{seed}",
        algo,
        MULTI,
        seed,
        512,
        1.0,
        violation,
        feasible,
        feasible,
        20,
        constraint_violation_rates=rates,
    )


def test_report_gives_each_constraint_beside_the_overall_rate(suite):
    runs = suite.runs()
    summary = summarise_suite(suite, runs, [(run, _result(run.algo, run.seed)) for run in runs])
    mecl = next(cell for cell in summary["cells"] if cell["algo"] == "mecl")
    assert mecl["constraint_violation_rates_mean"] == {"violation_rate_velocity": 0.25, "violation_rate_distance": 0.25}
    assert [(seed["violation_rate_velocity"], seed["violation_rate_distance"]) for seed in mecl["per_seed"]] == [
        (0.25, 0.5),
        (0.25, 0.0),
    ]
    assert json.loads(json.dumps(summary))  # summary.json holds them as plain numbers

    table = markdown_table(summary).splitlines()
    start = next(i for i, line in enumerate(table) if line.startswith("Each constraint's violation rate"))
    assert table[start + 2] == (
        "| env | variant | algo | feasible reward | violation rate (any) | velocity | distance "
        "| per seed (any / velocity / distance) |"
    )
    assert table[start + 3].count("|---") == 8
    assert table[start + 4 : start + 6] == [
        "| HighwayVelocityDistance-v0 | base | mecl | 15.0 | 38% | 25% | 25% | 0: 50% / 25% / 50%, 1: 25% / 25% / 0% |",
        "| HighwayVelocityDistance-v0 | base | vicrl | 15.0 | 50% | 50% | 38% " "| 0: 100% / 100% / 75%, 1: 0% / 0% / 0% |",
    ]

    rows = list(csv.DictReader(io.StringIO(csv_rows(summary))))
    assert [(row["algo"], row["seed"], row["violation_rate_velocity"], row["violation_rate_distance"]) for row in rows] == [
        ("mecl", "0", "0.25", "0.5"),
        ("mecl", "1", "0.25", "0.0"),
        ("vicrl", "0", "1.0", "0.75"),
        ("vicrl", "1", "0.0", "0.0"),
    ]

    # An update of the report reads them back as results, not as other metrics of the run
    results, metrics, _ = previous_results(summary, suite, "logs")
    assert {result.seed: result.constraint_violation_rates for _, result in results if result.algo == "vicrl"} == {
        0: {"violation_rate_velocity": 1.0, "violation_rate_distance": 0.75},
        1: {"violation_rate_velocity": 0.0, "violation_rate_distance": 0.0},
    }
    assert not any(key.startswith("violation_rate_") for entry in metrics.values() for key in entry)


def test_constraint_columns_keep_the_env_order_through_summary_json(suite):
    runs = suite.runs()
    summary = summarise_suite(suite, runs, [(run, _result(run.algo, run.seed)) for run in runs])
    # summary.json sorts its keys (distance before velocity); the columns follow the env's registered order all the same
    reread = json.loads(json.dumps(summary, sort_keys=True))
    expected = ["violation_rate_velocity", "violation_rate_distance"]
    assert constraint_columns(summary) == constraint_columns(reread) == expected
    assert markdown_table(summary) == markdown_table(reread)


def test_report_of_envs_with_one_constraint_has_no_such_table(suite):
    runs = suite.runs()
    results = [
        (run, RunResult(f"logs/{run.algo}/Env_{run.seed}", run.algo, MULTI, run.seed, 512, 1.0, 0.5, 1.0, 1.0, 4))
        for run in runs
    ]
    summary = summarise_suite(suite, runs, results)
    assert "Each constraint's violation rate" not in markdown_table(summary)
    assert not any(column.startswith("violation_rate_") for column in next(csv.reader(io.StringIO(csv_rows(summary)))))


@pytest.mark.parametrize("env_line, evaluated_again", [("HighwayVelocityDistance-v0", True), ("GridWorldWall-v0", False)])
def test_a_cache_from_before_the_per_constraint_rates(tmp_path, monkeypatch, report_suite, env_line, evaluated_again):
    """Reused on an env with one constraint (nothing is missing); evaluated again on an env with several."""
    suite = report_suite(f"envs: [{env_line}]\nalgos: [mecl]\nseeds: [0]\nsteps: 512\n")
    run = suite.runs()[0]
    root = str(tmp_path / "logs")
    folder = pathlib.Path(run.run_folder(root))
    folder.mkdir(parents=True)
    (folder / FINISHED_FILE).write_text(json.dumps({"num_timesteps": 512}))
    fresh = _result("mecl", 0)
    calls = []

    def fake_evaluate(path, steps, seed, load_best=False, env_kwargs=None, n_episodes=None):
        calls.append(path)
        return RunResult(**asdict(fresh))

    monkeypatch.setattr(report, "evaluate_run", fake_evaluate)
    settings = report.heldout_settings(suite, run.env_id)
    older = {key: value for key, value in asdict(fresh).items() if key != "constraint_violation_rates"}
    (folder / HELDOUT_FILE).write_text(json.dumps({"settings": settings, "result": older}))
    os.utime(folder / FINISHED_FILE, (0, 0))  # the cache is newer than the run's end

    [(_, result)] = evaluate_finished([run], root, suite, log=lambda line: None)
    assert bool(calls) == evaluated_again
    assert result.constraint_violation_rates == (fresh.constraint_violation_rates if evaluated_again else {})


def test_training_evaluations_log_each_constraint(tmp_path):
    """The evaluations during training log each constraint's violation rate beside the overall one."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import DummyVecEnv

    from sb3_icrl.zoo.callbacks import ConstraintEvalCallback

    eval_env = DummyVecEnv([lambda: gym.make(MULTI)])
    model = PPO("MlpPolicy", DummyVecEnv([lambda: gym.make(MULTI)]), n_steps=32, batch_size=32, device="cpu", seed=0)
    model.set_logger(configure(str(tmp_path), ["csv"]))
    callback = ConstraintEvalCallback(eval_env, n_eval_episodes=1, eval_freq=1, verbose=0)
    callback.init_callback(model)
    callback.num_timesteps = callback.n_calls = 1
    callback.on_step()
    model.logger.close()
    logged = (tmp_path / "progress.csv").read_text().splitlines()[0].split(",")
    assert {"eval/violation_rate", "eval/violation_rate_velocity", "eval/violation_rate_distance"} <= set(logged)


def test_report_draws_each_constraint_the_feasible_reward_and_the_goal_rate_per_method(suite, tmp_path):
    from sb3_icrl.benchmark.report_figures import multi_constraint_figure, write_figures

    runs = suite.runs()
    results = [(run, _result(run.algo, run.seed)) for run in runs]
    for (_, result), goal in zip(results, (0.5, 1.0, 0.0, None), strict=True):  # vicrl's seed 1: no outcome flags
        result.outcome_rates = {} if goal is None else {"goal_reached_rate": goal}
    summary = summarise_suite(suite, runs, results)
    figure = multi_constraint_figure(summary)
    titles = [ax.get_title() for ax in figure.axes]
    assert titles == ["velocity violation rate", "distance violation rate", "feasible reward", "goal reached (success)"]
    heights = [[bar.get_height() for bar in ax.patches] for ax in figure.axes]
    assert heights == [[0.25, 0.5], [0.25, 0.375], [15.0, 15.0], [0.75, 0.0]]
    dots = [sorted(collection.get_offsets()[:, 1]) for collection in figure.axes[3].collections]
    assert dots == [[0.5, 1.0], [0.0]]  # a seed without the outcome has no dot
    assert [tick.get_text() for tick in figure.axes[0].get_xticklabels()] == ["mecl", "vicrl"]
    written = write_figures(summary, suite, str(tmp_path / "logs"), str(tmp_path))
    assert str(tmp_path / "multi_constraint.png") in written
    # A suite of single-constraint envs has no such figure
    assert (
        multi_constraint_figure({"cells": [{**cell, "constraint_violation_rates_mean": {}} for cell in summary["cells"]]})
        is None
    )


@pytest.mark.parametrize(
    "env, names",
    [
        ("HighwayVelocityDistance-v0", ("velocity", "distance")),
        (MULTI, ("velocity", "distance")),
        ("GridWorldWall-v0", ()),
        ("NotAnEnv-v0", ()),
    ],
)
def test_registered_constraints_in_their_order(env, names):
    assert registered_constraints(env) == names
