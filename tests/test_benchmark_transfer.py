"""A suite's ``transfer`` key: the engine runs the transfer tests of every ICRL run once it has finished training."""

import json
import os
import textwrap

import pytest

from sb3_icrl.benchmark import load_suite
from sb3_icrl.benchmark.cli import main as benchmark_main
from sb3_icrl.benchmark.report import constraint_metrics
from sb3_icrl.benchmark.report_text import _transfer_text
from sb3_icrl.benchmark.suite import SuiteError, TransferSpec, run_complete
from sb3_icrl.run_evaluation import RunResult
from sb3_icrl.run_folder import FINISHED_FILE

SUITE = """\
description: transfer
envs: [GridWorldWall-v0]
algos: [bc2l, ppo]
seeds: [0]
steps: 512
eval_episodes: 2
train_args: {eval_freq: 256, eval_episodes: 1, save_freq: 0}
variants: {base: {hyperparams: {forward_solver: policy_gradient}}}
"""


def write(tmp_path, text: str) -> str:
    path = tmp_path / "suite.yml"
    path.write_text(textwrap.dedent(text))
    return str(path)


def test_the_icrl_runs_get_one_transfer_job_per_task(tmp_path):
    suite = load_suite(write(tmp_path, SUITE + "transfer: {tasks: [same, dynamics], n_timesteps: 256}\n"))
    assert suite.transfer == TransferSpec(("same", "dynamics"), 256)
    icrl, reference = suite.runs()
    jobs = icrl.transfer_jobs("logs")
    assert [file for file, _ in jobs] == ["transfer_same.json", "transfer_dynamics.json"]
    assert jobs[0][1] == [icrl.run_folder("logs"), "--task", "same", "--seed", "0", "-n", "256"]
    assert reference.transfer_jobs("logs") == []  # PPO learns no constraint to transfer
    assert load_suite(write(tmp_path, SUITE)).runs()[0].transfer_jobs("logs") == []


@pytest.mark.parametrize(
    "text, message",
    [
        ("transfer: [reward]\n", "`transfer` maps `tasks`"),
        ("transfer: {tasks: [colour]}\n", "`transfer.tasks` is a list among same, reward, dynamics"),
        ("transfer: {tasks: [same, same]}\n", "names a task twice"),
        ("transfer: {tasks: [same], n_timesteps: -3}\n", "transfer"),
        ("transfer: {tasks: [reward]}\n", "no reward-transfer task for GridWorldWall-v0"),
        ("transfer: {tasks: [same], envs: [GridWorldSquare-v0]}\n", "GridWorldSquare-v0 not among the suite's envs"),
        ("transfer: {tasks: [same], envs: []}\n", "`transfer.envs` is a non-empty list"),
    ],
)
def test_bad_transfer_settings_name_file_and_line(tmp_path, text, message):
    with pytest.raises(SuiteError, match=f"line 9: .*{message}"):
        load_suite(write(tmp_path, SUITE + text))


def test_transfer_envs_choose_whose_runs_take_the_tests(tmp_path):
    two_envs = SUITE.replace("envs: [GridWorldWall-v0]", "envs: [GridWorldWall-v0, GridWorldSquare-v0]")
    # A reward-transfer task only where the env has one: the other env's runs take none
    suite = load_suite(write(tmp_path, two_envs + "transfer: {tasks: [same], envs: [GridWorldSquare-v0]}\n"))
    assert suite.transfer == TransferSpec(("same",), None, ("GridWorldSquare-v0",))
    jobs = {run.env_id: run.transfer_jobs("logs") for run in suite.runs() if run.algo == "bc2l"}
    assert jobs["sb3_icrl/GridWorldWall-v0"] == [] and len(jobs["sb3_icrl/GridWorldSquare-v0"]) == 1


def test_a_suite_without_icrl_algorithms_has_nothing_to_transfer(tmp_path):
    text = SUITE.replace("algos: [bc2l, ppo]", "algos: [ppo]") + "transfer: {tasks: [same]}\n"
    with pytest.raises(SuiteError, match="no ICRL algorithm"):
        load_suite(write(tmp_path, text))


def test_the_engine_runs_the_missing_transfers_of_finished_runs(tmp_path, capsys):
    path = write(tmp_path, SUITE + "transfer: {tasks: [same], n_timesteps: 256}\n")
    root = str(tmp_path / "logs")
    arguments = ["run", path, "-f", root, "--jobs", "1", "--only", "algo=bc2l", "--no-report"]
    assert benchmark_main(arguments) == 0
    (run,) = load_suite(path).select({"algo": ["bc2l"]})
    result = os.path.join(run.run_folder(root), "transfer_same.json")
    assert os.path.isfile(result)
    with open(run.log_file(root)) as file:
        commands = [line for line in file if line.startswith("=== ")]
    assert len(commands) == 2 and "sb3_icrl.zoo train" in commands[0] and "sb3_icrl.metrics.transfer" in commands[1]
    # Complete: nothing runs again. Without its transfer result, only the transfer runs
    assert benchmark_main(arguments) == 0
    os.remove(result)
    assert benchmark_main(arguments) == 0
    with open(run.log_file(root)) as file:
        commands = [line for line in file if line.startswith("=== ")]
    assert len(commands) == 3 and "sb3_icrl.metrics.transfer" in commands[2] and os.path.isfile(result)


def test_a_transfer_result_older_than_the_runs_final_model_does_not_count(tmp_path):
    suite = load_suite(write(tmp_path, SUITE + "transfer: {tasks: [same], n_timesteps: 256}\n"))
    icrl, _ = suite.runs()
    folder = icrl.run_folder(tmp_path)
    os.makedirs(folder)
    result = os.path.join(folder, "transfer_same.json")
    with open(result, "w") as file:
        json.dump({"violation_rate": 0.25, "feasible_reward_ratio": 0.5}, file)
    with open(os.path.join(folder, FINISHED_FILE), "w") as file:
        json.dump({"num_timesteps": 512}, file)
    os.utime(result, (1_000_000, 1_000_000))  # written before the run was trained again (finished.json deleted)
    files = [file for file, _ in icrl.transfer_jobs(tmp_path)]
    assert not run_complete(folder, files)
    lines: list[str] = []
    entry = RunResult(os.path.relpath(folder, tmp_path), "bc2l", icrl.env_id, 0, 512, 1.0, 0.0, 1.0, 1.0, 2)
    metrics = constraint_metrics([(icrl, entry)], str(tmp_path), log=lines.append)[entry.run]
    assert "transfer_same_violation_rate" not in metrics
    assert any("transfer_same.json predates its final model" in line for line in lines)
    os.utime(result)  # a transfer of the final model
    assert run_complete(folder, files)
    assert (
        constraint_metrics([(icrl, entry)], str(tmp_path), log=lines.append)[entry.run]["transfer_same_violation_rate"] == 0.25
    )


@pytest.mark.parametrize("oracle, note", [(27.6, " (oracle 27.6 <= PPO 49.3)"), (4000.0, "")])
def test_a_transfer_ratio_over_an_oracle_no_better_than_ppo_says_so(tmp_path, oracle, note):
    suite = load_suite(write(tmp_path, SUITE + "transfer: {tasks: [same], n_timesteps: 256}\n"))
    icrl, _ = suite.runs()
    folder = icrl.run_folder(tmp_path)
    os.makedirs(folder)
    with open(os.path.join(folder, FINISHED_FILE), "w") as file:
        json.dump({"num_timesteps": 512}, file)
    results = {"learned": {"feasible_reward": 52.7}, "oracle": {"feasible_reward": oracle}, "ppo": {"feasible_reward": 49.3}}
    with open(os.path.join(folder, "transfer_same.json"), "w") as file:
        json.dump({"violation_rate": 1.0, "feasible_reward_ratio": 52.7 / oracle, "results": results}, file)
    entry = RunResult(os.path.relpath(folder, tmp_path), "bc2l", icrl.env_id, 0, 512, 1.0, 0.0, 1.0, 1.0, 2)
    metrics = constraint_metrics([(icrl, entry)], str(tmp_path), log=lambda line: None)[entry.run]
    assert metrics["transfer_same_oracle_feasible_reward"] == oracle and metrics["transfer_same_ppo_feasible_reward"] == 49.3
    # The ratio stays in the table (per-seed values are shown as they are), read by its references where they say it is void
    assert _transfer_text(metrics) == f"same 100% / {52.7 / oracle:.2f}{note}"
