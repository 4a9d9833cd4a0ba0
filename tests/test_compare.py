"""sb3-icrl compare: held-out evaluation of finished runs, summaries over seeds, and clear errors."""

import builtins
import json
import os
import pathlib
import shutil
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import yaml

from sb3_icrl import run_evaluation
from sb3_icrl.common.evaluation import EPISODE_FIELDS, ConstraintEvaluation
from sb3_icrl.run_evaluation import UnfinishedEpisodesError
from sb3_icrl.zoo import enjoy
from sb3_icrl.zoo import main as train_main
from sb3_icrl.zoo.compare import (
    RunFolderError,
    RunResult,
    check_runs,
    evaluate_run,
    main,
    recipe_differences,
    summarise,
    training_wall_time,
    wilcoxon_warnings,
)
from sb3_icrl.zoo.train import cli

TINY = ["-n", "128", "-params", "n_steps:64", "batch_size:32", "--eval-freq", "-1", "--verbose", "0"]


def _result(algo: str, seed: int, feasible: float, violation: float = 0.0) -> RunResult:
    return RunResult(f"logs/{algo}/Env_{seed}", algo, "Env-v0", seed, 100, 1.0, violation, feasible, feasible, 10)


def test_summary_means_stds_and_wilcoxon_by_seed() -> None:
    results = [_result("vicrl", seed, 10.0) for seed in (1, 2, 3, 4, 5)]
    results += [
        _result("mecl", seed, 10.0 + gap, violation)
        for seed, gap, violation in [(1, 1, 0), (2, 2, 0.5), (3, 3, 0), (4, 4, 0), (5, 5, 0)]
    ]
    results.append(_result("mecl", 6, 100.0))  # no vicrl run with seed 6: not a pair
    summary = summarise(results, reference="vicrl")
    mecl = summary["mecl"]
    assert mecl["seeds"] == [1, 2, 3, 4, 5, 6]
    feasible = np.array([11.0, 12.0, 13.0, 14.0, 15.0, 100.0])
    assert mecl["feasible_reward_mean"] == pytest.approx(feasible.mean())
    # the sample std: squared deviations over n - 1
    assert mecl["feasible_reward_std"] == pytest.approx(np.sqrt(np.sum((feasible - feasible.mean()) ** 2) / 5))
    assert mecl["violation_rate_mean"] == pytest.approx(0.5 / 6)
    # five positive paired differences: the exact two-sided p is 2 / 2**5
    assert mecl["wilcoxon_pairs"] == 5 and mecl["wilcoxon_p"] == pytest.approx(2 / 32)
    assert "wilcoxon_p" not in summary["vicrl"] and summary["vicrl"]["feasible_reward_std"] == 0.0
    assert np.isnan(summarise([*results[:5], _result("mecl", 1, 10.0)], "vicrl")["mecl"]["wilcoxon_p"])  # no difference
    # A tied seed carries no sign: six pairs, one tied, test as five (the smallest p of five pairs, not of six)
    tied = summarise([*results, _result("vicrl", 6, 100.0)], reference="vicrl")["mecl"]
    assert tied["wilcoxon_pairs"] == 6 and tied["wilcoxon_ranked_pairs"] == 5 and tied["wilcoxon_p"] == pytest.approx(2 / 32)
    (warning,) = wilcoxon_warnings({"mecl": tied}, "vicrl")
    assert "6 seed pair(s) (1 tied, which the test does not rank)" in warning and "smallest p with 5 is 0.0625" in warning


def test_training_wall_time_is_the_runs_own_record_not_the_time_it_was_stopped(tmp_path: pathlib.Path) -> None:
    # A resumed run's monitor counts from the first start, across the hours the run was stopped
    run = tmp_path / "run"
    run.mkdir()
    (run / "0.monitor.csv").write_text('#{"t_start": 0.0}\nr,l,t\n1.0,500,60.0\n2.0,500,7200.0\n')
    assert training_wall_time(str(run)) == pytest.approx(120.0)
    (run / "finished.json").write_text(json.dumps({"wall_time_s": 300.0, "wall_time_total_s": 1500.0}))
    assert training_wall_time(str(run)) == pytest.approx(25.0)
    assert np.isnan(training_wall_time(str(tmp_path / "missing")))


def test_summary_rejects_two_runs_of_one_seed_and_an_absent_reference() -> None:
    with pytest.raises(RunFolderError, match="Two mecl runs trained with seed 1"):
        summarise([_result("mecl", 1, 1.0), _result("mecl", 1, 2.0)])
    with pytest.raises(RunFolderError, match="--reference 'vicrl' has no run"):
        summarise([_result("mecl", 1, 1.0)], reference="vicrl")


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    """Tiny PPO-Lagrangian and PPO runs on the corridor, seeds 1 and 2, and one more PPO-Lag run with other settings."""
    folder = tmp_path_factory.mktemp("runs")
    for algo in ("ppolag", "ppo"):
        for seed in (1, 2):
            assert (
                train_main(["--algo", algo, "--env", "ConstrainedCorridor-v0", *TINY, "--seed", str(seed), "-f", str(folder)])
                == 0
            )
    other = [*TINY[:3], "n_steps:32", *TINY[4:]]
    assert train_main(["--algo", "ppolag", "--env", "ConstrainedCorridor-v0", *other, "--seed", "3", "-f", str(folder)]) == 0
    return folder


def test_compare_evaluates_final_models_as_enjoy_does(runs: pathlib.Path, tmp_path: pathlib.Path, capsys) -> None:
    paths = [str(runs / algo / f"ConstrainedCorridor-v0_{n}") for algo in ("ppolag", "ppo") for n in (1, 2)]
    output = tmp_path / "compare.json"
    assert main([*paths, "-n", "300", "--seed", "7", "--reference", "ppolag", "--json", str(output)]) == 0
    table = capsys.readouterr().out
    assert "| ppo | 1, 2 |" in table and "Wilcoxon p vs ppolag" in table
    payload = json.loads(output.read_text())
    assert [(run["algo"], run["seed"]) for run in payload["runs"]] == [("ppolag", 1), ("ppolag", 2), ("ppo", 1), ("ppo", 2)]
    first = payload["runs"][0]
    assert first["timesteps"] == 128 and np.isfinite(first["wall_time_min"]) and first["wall_time_min"] >= 0
    enjoy_args = ["--algo", "ppolag", "--env", "ConstrainedCorridor-v0", "-f", str(runs), "--exp-id", "1", "-n", "300"]
    args = enjoy.get_parser().parse_args([*enjoy_args, "--no-render", "--seed", "7", "--verbose", "0"])
    evaluation = enjoy.enjoy(args)
    assert first["n_episodes"] == len(evaluation.violations)
    assert first["feasible_reward"] == pytest.approx(evaluation.mean_feasible_reward)
    assert first["violation_rate"] == pytest.approx(evaluation.violation_rate)
    assert payload["summary"]["ppo"]["wilcoxon_pairs"] == 2


def test_compare_reads_each_runs_monitor_once_for_its_wall_time_and_its_notes(
    runs: pathlib.Path, tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    # finished.json's time is text, so the wall time (and a note that says so) come from the monitor
    run = tmp_path / "ppo" / "ConstrainedCorridor-v0_1"
    shutil.copytree(runs / "ppo" / "ConstrainedCorridor-v0_1", run)
    finished = json.loads((run / "finished.json").read_text())
    (run / "finished.json").write_text(json.dumps({**finished, "wall_time_s": "abc", "wall_time_total_s": "abc"}))
    monitor = run / "0.monitor.csv"
    monitor.write_text('#{"t_start": 0.0}\nr,l,t\n1.0,5,30.0\n2.0,5,90.0\n')
    opened = []
    original_open = builtins.open

    def counting_open(file: Any, *args: Any, **kwargs: Any) -> Any:
        if isinstance(file, (str, os.PathLike)) and os.path.abspath(file) == str(monitor):
            opened.append(file)
        return original_open(file, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", counting_open)
    output = tmp_path / "compare.json"
    assert main([str(run), "-n", "50", "--json", str(output)]) == 0
    assert len(opened) == 1
    assert json.loads(output.read_text())["runs"][0]["wall_time_min"] == pytest.approx(1.5)
    assert capsys.readouterr().err.count("the wall time comes from the training monitor instead") == 1


def test_compare_warns_when_runs_of_one_algorithm_differ_in_recipe(runs: pathlib.Path) -> None:
    paths = [str(runs / "ppolag" / f"ConstrainedCorridor-v0_{n}") for n in (1, 2, 3)]
    differences = recipe_differences(paths)
    assert differences == {"ppolag": {"n_steps": ["64", "64", "32"]}}
    assert recipe_differences(paths[:2]) == {}  # n_timesteps aside, seeds 1 and 2 share their recipe
    config = yaml.safe_load(
        (runs / "ppolag" / "ConstrainedCorridor-v0_3" / "ConstrainedCorridor-v0" / "config.yml").read_text()
    )
    assert config["n_steps"] == 32


def test_compare_errors_before_evaluating(runs: pathlib.Path, tmp_path: pathlib.Path, capsys) -> None:
    first = str(runs / "ppolag" / "ConstrainedCorridor-v0_1")
    with pytest.raises(RunFolderError, match="Two ppolag runs trained with seed 1"):
        check_runs([first, first])
    assert main([str(runs)]) == 2
    assert "is not a train.py run folder" in capsys.readouterr().err
    assert cli(["compare", str(runs)]) == 2  # sb3-icrl compare
    assert "is not a train.py run folder" in capsys.readouterr().err
    copy = tmp_path / "ppolag" / "GridWorldWall-v0_1" / "GridWorldWall-v0"
    copy.mkdir(parents=True)
    (copy / "args.yml").write_text("env: sb3_icrl/GridWorldWall-v0\nseed: 4\n")
    with pytest.raises(RunFolderError, match="different envs"):
        check_runs([first, str(copy.parent)])
    (copy / "args.yml").write_text("env: sb3_icrl/GridWorldWall-v0\nseed: null\n")
    with pytest.raises(RunFolderError, match="without a fixed --seed"):
        check_runs([str(copy.parent)])


def test_merge_compare_joins_the_json_of_several_calls(tmp_path: pathlib.Path) -> None:
    """benchmarks/merge_compare.py: one table from runs evaluated in separate calls; files of other eval seeds refused."""
    import dataclasses
    import subprocess
    import sys

    script = pathlib.Path(__file__).resolve().parents[1] / "benchmarks" / "merge_compare.py"
    calls = [[_result("vicrl", 1, 10.0), _result("mecl", 1, 12.0)], [_result("vicrl", 2, 20.0), _result("mecl", 2, 26.0)]]
    paths = []
    for index, call in enumerate(calls):
        path = tmp_path / f"call{index}.json"
        path.write_text(json.dumps({"runs": [dataclasses.asdict(result) for result in call], "eval_seed": 100}))
        paths.append(str(path))
    merged = subprocess.run(
        [sys.executable, str(script), *paths, "--reference", "vicrl"], capture_output=True, text=True, check=True
    ).stdout
    assert "| mecl | 1, 2 | 0% +- 0% | 19 +- 10 |" in merged and "| vicrl | 1, 2 | 0% +- 0% | 15 +- 7 |" in merged
    other_seed = tmp_path / "other.json"
    other_seed.write_text(json.dumps({"runs": [], "eval_seed": 7}))
    refused = subprocess.run([sys.executable, str(script), paths[0], str(other_seed)], capture_output=True, text=True)
    assert refused.returncode != 0 and "different held-out seeds" in refused.stderr
    absent = subprocess.run([sys.executable, str(script), *paths, "--reference", "gacl"], capture_output=True, text=True)
    assert absent.returncode != 0 and "--reference 'gacl' has no run" in absent.stderr


def test_evaluate_run_loads_the_model_of_the_folder_it_is_given(tmp_path, monkeypatch):
    """A run numbered 0 (a suite's seed 0) beside a run numbered 1: each folder is evaluated with its own model."""
    base = ["--algo", "ppo", "--env", "ConstrainedCorridor-v0", "-n", "64", "-f", str(tmp_path), "--verbose", "0"]
    base += ["--eval-freq", "-1", "-params", "n_steps:64", "batch_size:32"]
    for exp_id in ("0", "1"):
        assert train_main([*base, "--seed", exp_id, "--exp-id", exp_id]) == 0
    loaded = []
    original = run_evaluation.check_trained_agent
    monkeypatch.setattr(run_evaluation, "check_trained_agent", lambda path, algo: (loaded.append(path), original(path, algo)))
    for exp_id in ("0", "1"):
        run = str(tmp_path / "ppo" / f"ConstrainedCorridor-v0_{exp_id}")
        result = evaluate_run(run, 40, eval_seed=100)
        assert result.seed == int(exp_id)
        # The held-out episodes' mean length: episodes that ended within the 40 evaluation steps
        assert 1 <= result.episode_length <= 40
        assert loaded[-1].startswith(run + os.sep), (loaded[-1], run)


def _rl_zoo3_run(folder: pathlib.Path, env_id: str, seed: int) -> pathlib.Path:
    """A run folder as ``python -m rl_zoo3.train --algo ppo --env ENV --seed N`` leaves it (PPO with VecNormalize)."""
    from collections import OrderedDict

    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    name = env_id.replace("/", "-")  # rl_zoo3's EnvironmentName
    run = folder / "ppo" / f"{name}_1"
    (run / name).mkdir(parents=True)
    hyperparams = {"n_steps": 64, "batch_size": 32, "n_timesteps": 128.0, "normalize": True, "policy": "MlpPolicy"}
    env = VecNormalize(make_vec_env(env_id, n_envs=1, seed=seed, monitor_dir=str(run)))
    model = PPO("MlpPolicy", env, n_steps=64, batch_size=32, seed=seed, device="cpu").learn(128)
    model.save(run / f"{name}.zip")
    env.save(str(run / name / "vecnormalize.pkl"))
    np.savez(run / "evaluations.npz", timesteps=np.array([128]), results=np.zeros((1, 2)), ep_lengths=np.ones((1, 2)))
    # rl_zoo3 dumps OrderedDicts, which yaml.safe_load refuses
    args = {"algo": "ppo", "env": env_id, "seed": seed, "env_kwargs": None, "gym_packages": [], "n_timesteps": -1}
    for file, content in (("config.yml", hyperparams), ("args.yml", args)):
        (run / name / file).write_text(yaml.dump(OrderedDict(sorted(content.items()))))
    return run


def test_compare_evaluates_rl_zoo3_run_folders(tmp_path: pathlib.Path, capsys) -> None:
    run = _rl_zoo3_run(tmp_path / "logs", "sb3_icrl/ConstrainedCorridor-v0", seed=5)
    assert (run / "sb3_icrl-ConstrainedCorridor-v0" / "args.yml").read_text().startswith("!!python/object/apply")
    output = tmp_path / "compare.json"
    assert main([str(run), "-n", "300", "--seed", "7", "--json", str(output)]) == 0
    captured = capsys.readouterr()
    assert "rl_zoo3 run, which records no end of training" in captured.err
    [result] = json.loads(output.read_text())["runs"]
    assert (result["algo"], result["env"], result["seed"], result["timesteps"]) == (
        "ppo",
        "sb3_icrl/ConstrainedCorridor-v0",
        5,
        128,
    )
    assert result["n_episodes"] > 0 and np.isfinite(result["wall_time_min"])
    assert recipe_differences([str(run)]) == {}
    # enjoy finds it by -f and --exp-id too, under rl_zoo3's name of the env
    enjoy_args = ["--algo", "ppo", "--env", "ConstrainedCorridor-v0", "-f", str(tmp_path / "logs"), "-n", "300"]
    evaluation = enjoy.enjoy(enjoy.get_parser().parse_args([*enjoy_args, "--no-render", "--seed", "7", "--verbose", "0"]))
    assert len(evaluation.violations) == result["n_episodes"]


# ---------------------------------------------------------------- an exact number of episodes


@pytest.fixture(scope="module")
def pendulum_run(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A 64-step PPO run on BiasedPendulum-v0: its policy lets the pendulum fall, after 19-27 steps of the 100 allowed."""
    folder = tmp_path_factory.mktemp("pendulum")
    argv = ["--algo", "ppo", "--env", "BiasedPendulum-v0", "--seed", "0", "-f", str(folder), "-n", "64", *TINY[2:]]
    assert train_main(argv) == 0
    return str(folder / "ppo" / "BiasedPendulum-v0_1")


def test_an_evaluation_by_episodes_is_the_first_episodes_of_one_by_steps(pendulum_run: str, monkeypatch) -> None:
    """The same seeded env stepped the same way: stopping after N episodes keeps the first N episodes of the steps."""
    evaluations: list[ConstraintEvaluation] = []
    original = run_evaluation.run_episodes

    def recorded(*args: Any, **kwargs: Any) -> ConstraintEvaluation:
        evaluations.append(original(*args, **kwargs))
        return evaluations[-1]

    monkeypatch.setattr(run_evaluation, "run_episodes", recorded)
    by_steps = evaluate_run(pendulum_run, 500, eval_seed=100)
    by_episodes = evaluate_run(pendulum_run, 500, eval_seed=100, n_episodes=5)
    steps, episodes = evaluations
    # Episodes end early: the steps of 5 full-length episodes hold many more of them
    assert by_steps.n_episodes == len(steps.violations) > 5 and by_episodes.n_episodes == 5
    for key in EPISODE_FIELDS:
        np.testing.assert_array_equal(getattr(episodes, key), getattr(steps, key)[:5])
    assert by_episodes.episode_length == pytest.approx(float(np.mean(steps.episode_lengths[:5])))
    assert by_episodes.violation_rate == pytest.approx(float(np.mean(steps.violations[:5])))
    # Fewer episodes than asked for within the step cap: no result, and why
    with pytest.raises(UnfinishedEpisodesError, match="only 0 of its 5 evaluation episodes ended within 10 steps, the cap"):
        evaluate_run(pendulum_run, 10, eval_seed=100, n_episodes=5)


class _EndlessEnv(gym.Env):
    """An env without a time limit whose episodes never end."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,))
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        return np.zeros(1, dtype=np.float32), {}

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict]:
        return np.zeros(1, dtype=np.float32), 1.0, False, False, {"cost": 0.0}


class _FirstAction:
    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return np.zeros(1, dtype=int), None


def test_a_policy_whose_episodes_never_end_stops_at_the_step_cap() -> None:
    from stable_baselines3.common.vec_env import DummyVecEnv

    env = DummyVecEnv([_EndlessEnv])
    evaluation = run_evaluation.run_episodes(_FirstAction(), env, 30, True, 0, n_episodes=3)
    assert len(evaluation.violations) == 0
    with pytest.raises(ValueError, match="n_episodes must be at least 1, got 0"):
        run_evaluation.run_episodes(_FirstAction(), env, 30, True, 0, n_episodes=0)


def test_compare_evaluates_exactly_n_episodes_as_the_reports_do(pendulum_run: str, tmp_path: pathlib.Path, capsys) -> None:
    from sb3_icrl.zoo.compare import DEFAULT_EVAL_STEPS, evaluation_budget

    # The step cap: twice the steps of as many full-length episodes (BiasedPendulum: 100 steps), or -n when given
    assert evaluation_budget(pendulum_run, None, 5) == (1000, 5)
    assert evaluation_budget(pendulum_run, 300, 5) == (300, 5)
    assert evaluation_budget(pendulum_run, None, None) == (DEFAULT_EVAL_STEPS, None)
    output = tmp_path / "compare.json"
    assert main([pendulum_run, "--n-episodes", "4", "--seed", "100", "--json", str(output)]) == 0
    payload = json.loads(output.read_text())
    assert payload["eval_episodes"] == 4 and payload["runs"][0]["n_episodes"] == 4
    expected = evaluate_run(pendulum_run, 800, eval_seed=100, n_episodes=4)
    assert payload["runs"][0]["feasible_reward"] == pytest.approx(expected.feasible_reward)
    # Too few steps for the episodes asked for: an error that says so, no table
    capsys.readouterr()
    assert main([pendulum_run, "-e", "4", "-n", "10"]) == 2
    assert "only 0 of its 4 evaluation episodes ended within 10 steps" in capsys.readouterr().err
