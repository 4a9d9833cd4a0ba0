"""
The report's columns beside our numbers: other published re-runs (``others:``), the feasible reward as a fraction of
our expert's return, and the compute the runs took; in summary.json, the tables and README's table.
"""

import csv
import dataclasses
import functools
import io
import json
import os
import pathlib
import shutil

import numpy as np
import pytest
import yaml
from script_loader import load_script

from sb3_icrl.benchmark import judgements, load_suite, report, report_numbers, report_text, summarise_suite
from sb3_icrl.benchmark import suite as suite_module
from sb3_icrl.benchmark.report import constraint_metrics, run_facts, write_report
from sb3_icrl.benchmark.report_text import csv_rows, latex_table, markdown_table
from sb3_icrl.benchmark.suite import RunSpec, SuiteError
from sb3_icrl.data import Trajectory, save
from sb3_icrl.registry import env_name
from sb3_icrl.zoo.compare import RunResult
from sb3_icrl.zoo.runs import FINISHED_FILE, run_cpu_time, run_wall_time

readme_table = load_script("benchmarks/readme_table.py")

# GridWorldWall has shipped demonstrations (every trajectory returns 1.0), GridWorld-v0 has none
SUITE = """\
description: columns
envs: [GridWorldWall-v0, GridWorld-v0]
algos: [bc2l, vicrl]
seeds: [0, 1]
steps: 512
reference: vicrl
others:
  simple-icrl:
    GridWorldWall-v0: {bc2l: [0.9, 0.004]}
  another re-run:
    GridWorldWall-v0: {vicrl: [0.5, 0.25]}
"""
HEAD = "envs: [GridWorldWall-v0]\nalgos: [bc2l]\nseeds: [0]\n"
PAIR = r"expected \[feasible reward, violation rate\]"


def write(tmp_path: pathlib.Path, text: str, name: str = "suite.yml") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


# ---------------------------------------------------------------- the suite key


def test_table3_carries_the_simple_icrl_rerun():
    others = load_suite("table3").others
    assert list(others) == ["simple-icrl"]
    assert others["simple-icrl"]["BlockedAnt-v0"] == {"mecl": (7006.0, 0.004)}
    assert others["simple-icrl"]["BlockedWalker-v0"]["mecl"] == (318.0, 0.36)
    assert "HighwayVelocity-v0" not in others["simple-icrl"]


@pytest.mark.parametrize(
    "text, line, message",
    [
        (HEAD + "others: [1, 2]\n", 4, "`others` maps a source name"),
        (HEAD + "others:\n  src:\n    NoSuchEnv-v0: {bc2l: [1, 0.1]}\n", 6, "Unknown env 'NoSuchEnv-v0'"),
        (HEAD + "others:\n  src:\n    GridWorldWall-v0:\n      airl: [1, 0.1]\n", 7, "unknown algorithm 'airl'"),
        (HEAD + "others:\n  src:\n    GridWorldWall-v0: {bc2l: [1]}\n", 6, PAIR),
        (HEAD + "others:\n  src:\n    GridWorldWall-v0: {bc2l: [a, 0.1]}\n", 6, PAIR),
        (HEAD + "others:\n  src:\n    GridWorldWall-v0: {bc2l: [1, 1.5]}\n", 6, r"violation rate is within \[0, 1\]"),
        (HEAD + "others:\n  src:\n    GridWorldWall-v0: [1, 0.1]\n", 6, "map algo -> "),
        (HEAD + "others:\n  src: 3\n", 5, "source 'src' numbers map env"),
        (HEAD + "others:\n  a|b: {}\n", 5, "a source name is a non-empty string"),
        (HEAD + "others:\n  Paper: {}\n", 5, "'paper' is the `paper` key's own column"),
        (HEAD + "paper:\n  GridWorldWall-v0: {bc2l: [1, 0.1, 2]}\n", 5, PAIR),
    ],
)
def test_bad_others_name_file_and_line(tmp_path, text, line, message):
    path = write(tmp_path, text)
    with pytest.raises(SuiteError, match=f"line {line}: .*{message}") as error:
        load_suite(path)
    assert path in str(error.value)


# ---------------------------------------------------------------- fake finished runs


def _finish(folder: str, **finished) -> None:
    """What train.py leaves in a run folder that matters here: ``finished.json`` and ``<EnvName>/args.yml``."""
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, FINISHED_FILE), "w") as file:
        json.dump({"num_timesteps": 512, **finished}, file)


def _args(folder: str, env: str, **args) -> None:
    os.makedirs(os.path.join(folder, env), exist_ok=True)
    with open(os.path.join(folder, env, "args.yml"), "w") as file:
        yaml.safe_dump({"env": f"sb3_icrl/{env}", "demonstrations": None, "violating_fraction": None, **args}, file)


def _own_demonstrations(path: str) -> None:
    """Two trajectories returning 1 + 2 + 3 = 6 and 4: a mean return of 5."""
    trajectories = [
        Trajectory(np.zeros((len(r) + 1, 2)), np.zeros(len(r), dtype=np.int64), None, True, np.array(r), np.zeros(len(r)))
        for r in ([1.0, 2.0, 3.0], [4.0])
    ]
    save(path, trajectories)


# Per run: (feasible reward, violation rate, finished.json wall-time keys)
FEASIBLE = {
    ("GridWorldWall-v0", "bc2l", 0): (0.5, 0.0, {"wall_time_s": 1800.0}),
    # A resumed run: its whole time wins over its last segment's
    ("GridWorldWall-v0", "bc2l", 1): (0.7, 0.5, {"wall_time_s": 100.0, "wall_time_total_s": 3600.0}),
    ("GridWorldWall-v0", "vicrl", 0): (4.0, 0.0, {"wall_time_s": 900.0}),
    ("GridWorldWall-v0", "vicrl", 1): (4.0, 0.0, {"wall_time_s": 900.0}),
    ("GridWorld-v0", "bc2l", 0): (2.0, 0.0, {"wall_time_s": 360.0}),
    ("GridWorld-v0", "bc2l", 1): (3.0, 0.0, {}),  # an older finished.json: no time recorded
    ("GridWorld-v0", "vicrl", 0): (1.0, 0.0, {"wall_time_s": 0.0}),
    ("GridWorld-v0", "vicrl", 1): (1.0, 0.0, {"wall_time_s": 0.0}),
}


@pytest.fixture
def finished_suite(tmp_path, monkeypatch):
    """The suite, its log root and the held-out results of its eight fake finished runs."""
    # These columns do not depend on the confidence intervals: a short bootstrap keeps the tests quick
    for module in (report, judgements):  # the report's aggregates; the cells' spreads, scores and aim
        monkeypatch.setattr(module, "stratified_bootstrap_ci", functools.partial(module.stratified_bootstrap_ci, reps=20))
    # Runs on an env without demonstrations (their dataset gone since, or from a user's own file): the suite check, which
    # refuses such a suite before it runs, is not what these tests are about
    monkeypatch.setattr(suite_module._SuiteReader, "check_demonstrations", lambda *args: None)
    suite = load_suite(write(tmp_path, SUITE))
    root = str(tmp_path / "logs")
    demonstrations = str(tmp_path / "mine.npz")
    _own_demonstrations(demonstrations)
    results = []
    for run in suite.runs():
        env = run.env_id.split("/")[-1]
        feasible, violation, times = FEASIBLE[(env, run.algo, run.seed)]
        folder = run.run_folder(root)
        _finish(folder, **times)
        # vicrl on GridWorldWall learned from the user's own file, as its args.yml says
        _args(folder, env, **({"demonstrations": demonstrations} if (env, run.algo) == ("GridWorldWall-v0", "vicrl") else {}))
        name = os.path.relpath(folder, root)
        results.append((run, RunResult(name, run.algo, run.env_id, run.seed, 100, 1.0, violation, feasible, feasible, 2)))
    return suite, root, results


def _cell(summary: dict, env: str, algo: str) -> dict:
    return next(cell for cell in summary["cells"] if cell["env"] == env and cell["algo"] == algo)


def test_an_imperfect_run_is_measured_against_the_clean_expert(tmp_path):
    # The shipped GridWorldWall mix with 80% violating trajectories returns 0.98 on average, the clean expert 1.0
    assert report.expert_return("GridWorldWall-v0", 0.8) == pytest.approx(0.98)
    run = RunSpec("imperfect", "violating-0.8", "bc2l", "sb3_icrl/GridWorldWall-v0", 0, 512)
    folder = run.run_folder(str(tmp_path))
    _finish(folder, wall_time_s=60.0)
    _args(folder, "GridWorldWall-v0", violating_fraction=0.8)
    result = RunResult(os.path.relpath(folder, tmp_path), "bc2l", run.env_id, 0, 100, 1.0, 0.0, 0.5, 0.5, 2)
    assert report.demonstrations_source(run, folder) == ("GridWorldWall-v0", 0.8)  # what it learned from
    assert report.expert_source(run, folder) == ("GridWorldWall-v0", None)  # what it is measured against
    assert run_facts([(run, result)], str(tmp_path))[result.run]["expert_return"] == pytest.approx(1.0)


def test_demonstrations_facts_count_the_trajectories_and_steps_that_break_the_constraint(tmp_path):
    # Two constraints, three trajectories of 4, 2 and 2 steps: the first breaks one of them on two steps, the third on one
    costs = [np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 0.5], [0.0, 0.0]]), np.zeros((2, 2)), np.array([[0.0, 0.0], [0.0, 2.0]])]
    trajectories = [
        Trajectory(np.zeros((len(c) + 1, 2)), np.zeros(len(c), dtype=np.int64), None, True, np.full(len(c), reward), c)
        for c, reward in zip(costs, (1.0, 3.0, 0.5), strict=True)
    ]
    path = str(tmp_path / "mixed.npz")
    save(path, trajectories)
    assert report.demonstrations_facts(path) == {
        "trajectories": 3,
        "violating_trajectories": 2,
        "violating_step_share": pytest.approx(3 / 8),
        "mean_return": pytest.approx((4 * 1.0 + 2 * 3.0 + 2 * 0.5) / 3),
    }
    assert report.expert_return(path) == pytest.approx(11 / 3)
    assert report.demonstrations_facts(str(tmp_path / "none.npz")) is None


def test_wall_time_prefers_the_whole_runs(tmp_path):
    _finish(str(tmp_path / "a"), wall_time_s=10.0, wall_time_total_s=30.0)
    _finish(str(tmp_path / "b"), wall_time_s=10.0)
    _finish(str(tmp_path / "c"))
    assert [run_wall_time(tmp_path / name) for name in "abcd"] == [30.0, 10.0, None, None]


def test_summary_carries_others_expert_fraction_and_core_hours(finished_suite):
    suite, root, results = finished_suite
    facts = run_facts(results, root)
    assert facts[results[0][1].run] == {"wall_time_s": 1800.0, "expert_return": 1.0}
    # constraint_metrics, which the report command calls, carries them too (the fake runs cannot be scored)
    metrics = constraint_metrics(results, root, log=lambda line: None)
    assert metrics[results[1][1].run]["wall_time_s"] == 3600.0
    summary = summarise_suite(suite, suite.runs(), results, metrics)

    bc2l = _cell(summary, "GridWorldWall-v0", "bc2l")
    assert bc2l["others"] == {"simple-icrl": [0.9, 0.004]}
    assert bc2l["expert_return"] == pytest.approx(1.0)  # the shipped GridWorldWall dataset: every return is 1
    assert bc2l["feasible_reward_fraction"] == pytest.approx(0.6)  # mean of 0.5 and 0.7
    assert bc2l["core_hours"] == pytest.approx((1800 + 3600) / 3600)
    assert [seed["wall_time_s"] for seed in bc2l["per_seed"]] == [1800.0, 3600.0]

    vicrl = _cell(summary, "GridWorldWall-v0", "vicrl")
    assert vicrl["others"] == {"another re-run": [0.5, 0.25]}
    assert vicrl["expert_return"] == pytest.approx(5.0)  # its args.yml's own file: returns 6 and 4
    assert vicrl["feasible_reward_fraction"] == pytest.approx(0.8)
    assert vicrl["core_hours"] == pytest.approx(0.5)

    # No shipped demonstrations for GridWorld-v0: no expert return, no fraction; a run without a time is left out
    plain = _cell(summary, "GridWorld-v0", "bc2l")
    assert plain["others"] == {}
    assert plain["expert_return"] is None and plain["feasible_reward_fraction"] is None
    assert plain["core_hours"] == pytest.approx(0.1)
    assert _cell(summary, "GridWorld-v0", "vicrl")["core_hours"] == 0.0

    assert summary["others_sources"] == ["simple-icrl", "another re-run"]
    assert summary["core_hours"] == pytest.approx((1800 + 3600 + 900 + 900 + 360) / 3600)
    assert summary["core_hours_runs"] == 7


def test_cpu_time_is_reported_beside_the_wall_clock(finished_suite, tmp_path):
    """The CPU time a run's process spent is read from finished.json (a resumed run's whole time first), kept per seed,
    summed over the runs that recorded one and shown against the same runs' wall time; runs without one are counted."""
    _finish(str(tmp_path / "a"), cpu_time_s=5.0, cpu_time_total_s=20.0)
    _finish(str(tmp_path / "b"), cpu_time_s=5.0)
    _finish(str(tmp_path / "c"), wall_time_s=10.0)
    assert [run_cpu_time(tmp_path / name) for name in "abcd"] == [20.0, 5.0, None, None]

    suite, root, results = finished_suite
    folders = {(run.env_id.split("/")[-1], run.algo, run.seed): run.run_folder(root) for run, _ in results}
    _finish(folders[("GridWorldWall-v0", "bc2l", 0)], wall_time_s=1800.0, cpu_time_s=1440.0)
    _finish(folders[("GridWorldWall-v0", "vicrl", 1)], wall_time_s=900.0, cpu_time_s=720.0)
    metrics = run_facts(results, root)
    summary = summarise_suite(suite, suite.runs(), results, metrics)
    assert [seed.get("cpu_time_s") for seed in _cell(summary, "GridWorldWall-v0", "bc2l")["per_seed"]] == [1440.0, None]
    assert summary["cpu_hours_runs"] == 2
    assert summary["cpu_hours"] == pytest.approx((1440 + 720) / 3600)
    assert summary["cpu_runs_wall_hours"] == pytest.approx((1800 + 900) / 3600)
    assert markdown_table(summary).splitlines()[-1] == (
        "Compute: 2.1 core-hours of training over 7 runs (wall clock; 2 runs recorded CPU time too: "
        "0.60 CPU-hours against 0.75 wall)"
    )
    rows = list(csv.DictReader(io.StringIO(csv_rows(summary))))
    assert sorted(row["cpu_time_s"] for row in rows if row["cpu_time_s"]) == ["1440.0", "720.0"]
    # An updated report keeps them from summary.json
    strict = _strict(summary)
    kept, kept_metrics, _ = report.previous_results(strict, suite, root)
    assert _strict(summarise_suite(suite, suite.runs(), kept, kept_metrics)) == strict
    # Every run with a wall time recorded its CPU time too: "all of them"
    every = {name: {**entry, "cpu_time_s": 60.0} if "wall_time_s" in entry else entry for name, entry in metrics.items()}
    line = markdown_table(summarise_suite(suite, suite.runs(), results, every)).splitlines()[-1]
    assert line == (
        "Compute: 2.1 core-hours of training over 7 runs (wall clock; all of them recorded CPU time too: "
        "0.12 CPU-hours against 2.1 wall)"
    )


def _transfer(folder: str, task: str, learned_min: float, references: dict[str, tuple[str, float]]) -> None:
    """A ``transfer_<task>.json`` as ``sb3-icrl transfer`` writes it: per learner its wall time, the reference files."""
    results = {"learned": {"wall_time_min": learned_min}}
    results.update({learner: {"wall_time_min": minutes} for learner, (_, minutes) in references.items()})
    files = {learner: f"/elsewhere/transfer_references/{name}" for learner, (name, _) in references.items()}
    transfer = {
        "settings": {"task": task, "reference_files": files},
        "results": results,
        "violation_rate": 0.0,
        "feasible_reward_ratio": 1.0,
    }
    with open(os.path.join(folder, f"transfer_{task}.json"), "w") as file:
        json.dump(transfer, file)


def test_transfer_tests_count_each_reference_learner_once(finished_suite, tmp_path):
    """Runs of one env and seed share their reference learners: the compute counts them once, the learned ones per run."""
    suite, root, results = finished_suite
    folders = {(run.env_id.split("/")[-1], run.algo, run.seed): run.run_folder(root) for run, _ in results}
    shared = {"oracle": ("oracle_GridWorldWall-v0_a.json", 30.0), "ppo": ("ppo_GridWorldWall-v0_b.json", 15.0)}
    _transfer(folders[("GridWorldWall-v0", "bc2l", 0)], "reward", 20.0, shared)
    _transfer(folders[("GridWorldWall-v0", "vicrl", 0)], "reward", 10.0, shared)
    # A second task of the same run: its time adds to the run's, its references are others
    _transfer(folders[("GridWorldWall-v0", "bc2l", 0)], "same", 6.0, {"oracle": ("oracle_GridWorldWall-v0_c.json", 12.0)})
    metrics = constraint_metrics(results, root, log=lambda line: None)
    bc2l = metrics[os.path.relpath(folders[("GridWorldWall-v0", "bc2l", 0)], root)]
    assert bc2l["transfer_wall_time_s"] == pytest.approx(60 * (20.0 + 6.0))
    assert bc2l["transfer_reference_wall_time_s"] == {
        "oracle_GridWorldWall-v0_a.json": 1800.0,
        "ppo_GridWorldWall-v0_b.json": 900.0,
        "oracle_GridWorldWall-v0_c.json": 720.0,
    }
    summary = summarise_suite(suite, suite.runs(), results, metrics)
    # Learned: 26 + 10 minutes; references: 30 + 15 + 12 minutes, once each
    assert summary["transfer_core_hours"] == pytest.approx((26 + 10 + 30 + 15 + 12) / 60)
    assert summary["transfer_core_hours_runs"] == summary["transfer_runs"] == 2
    line = "Compute: 2.1 core-hours of training over 7 runs; transfer tests 1.6 core-hours over 2 runs (references once)"
    assert markdown_table(summary).splitlines()[-1] == line
    assert csv_rows(summary).splitlines()[0].split(",").index("transfer_wall_time_s") > 0
    # Read back from summary.json (the run folders gone): the same compute; a run whose time was never recorded is named
    strict = _strict(summary)
    kept, kept_metrics, _ = report.previous_results(strict, suite, root)
    assert _strict(summarise_suite(suite, suite.runs(), kept, kept_metrics)) == strict
    untimed = json.loads(json.dumps(strict))
    seed = _cell(untimed, "GridWorldWall-v0", "vicrl")["per_seed"][0]
    del seed["transfer_wall_time_s"], seed["transfer_reference_wall_time_s"]
    assert report_text.transfer_compute_text(untimed) == (
        "transfer tests 1.4 core-hours over 1 run (references once), 1 more not timed"
    )
    write_report(summary, str(tmp_path / "results" / "suite"))
    readme = readme_table.table(tmp_path / "results").splitlines()
    assert readme[-1] == (
        "Compute: 2.1 core-hours of training over 7 runs (suite 2.1 over 7); "
        "suite transfer tests 1.6 core-hours over 2 runs (references once)."
    )


def test_the_report_names_finished_runs_without_their_transfer_tests(finished_suite, tmp_path):
    """A finished run without a transfer result its suite asks for (a test not run yet, or a result older than its final
    model) is named, in the suite's order, and still named when an updated report keeps it from summary.json."""
    suite, root, results = finished_suite
    assert summarise_suite(suite, suite.runs(), results, {})["transfer_tests_missing"] == []  # a suite without tests
    text = SUITE + "transfer: {tasks: [same, dynamics], envs: [GridWorldWall-v0]}\n"
    tested_suite = load_suite(write(tmp_path, text))
    by_name = {run.name: run for run in tested_suite.runs()}
    tested = [(by_name[run.name], result) for run, result in results]
    folders = {(run.env_id.split("/")[-1], run.algo, run.seed): run.run_folder(root) for run, _ in tested}
    for key, tasks in {("bc2l", 0): ["same", "dynamics"], ("bc2l", 1): ["same"], ("vicrl", 0): ["same", "dynamics"]}.items():
        for task in tasks:
            _transfer(folders[("GridWorldWall-v0", *key)], task, 5.0, {})
    os.utime(os.path.join(folders[("GridWorldWall-v0", "vicrl", 0)], "transfer_same.json"), (1.0, 1.0))  # of an earlier model
    lines: list[str] = []
    metrics = constraint_metrics(tested, root, log=lines.append)
    summary = summarise_suite(tested_suite, tested_suite.runs(), tested, metrics)
    # GridWorld-v0 takes no test: its runs are complete without one
    named = {"base/bc2l/GridWorldWall-v0/seed 1", "base/vicrl/GridWorldWall-v0/seed 0", "base/vicrl/GridWorldWall-v0/seed 1"}
    in_order = [run.name for run in tested_suite.runs() if run.name in named]
    assert summary["transfer_tests_missing"] == in_order
    assert {line.split(":")[0]: line.split(" (")[0].split("task ")[1] for line in lines if "no transfer result" in line} == {
        "base/bc2l/GridWorldWall-v0/seed 1": "dynamics",
        "base/vicrl/GridWorldWall-v0/seed 1": "same, dynamics",
    }
    assert any(line.startswith("base/vicrl/GridWorldWall-v0/seed 0") and "predates its final model" in line for line in lines)
    table = markdown_table(summary).splitlines()
    line = "Finished without the transfer tests the suite asks for, their transfer columns empty (3): " + ", ".join(in_order)
    assert line in table and table.index(line) < next(i for i, text in enumerate(table) if text.startswith("Compute:"))
    # An updated report keeps them from summary.json, their folders gone: the same runs named
    kept, kept_metrics, _ = report.previous_results(_strict(summary), tested_suite, str(tmp_path / "elsewhere"))
    assert summarise_suite(tested_suite, tested_suite.runs(), kept, kept_metrics)["transfer_tests_missing"] == in_order
    # No columns to look in, or the best models (transfer tests are of the final model): none named
    assert summarise_suite(tested_suite, tested_suite.runs(), tested)["transfer_tests_missing"] == []
    best_metrics = constraint_metrics(tested, root, lambda line: None, "best")
    assert summarise_suite(tested_suite, tested_suite.runs(), tested, best_metrics, "best")["transfer_tests_missing"] == []
    # Only ICRL runs take the tests
    assert dataclasses.replace(by_name["base/bc2l/GridWorldWall-v0/seed 1"], algo="ppo").transfer_tasks() == []
    # Many: counted, all of them in summary.json
    many = {**summary, "transfer_tests_missing": [f"base/bc2l/GridWorldWall-v0/seed {seed}" for seed in range(13)]}
    assert report_text.untested_text(many) == (
        "Finished without the transfer tests the suite asks for, their transfer columns empty (13), all named in "
        "summary.json's `transfer_tests_missing`."
    )


def test_without_run_folders_the_variant_settings_name_the_demonstrations(finished_suite):
    suite, _, results = finished_suite
    summary = summarise_suite(suite, suite.runs(), results)
    # The shipped dataset of each env: no args.yml is read, no time is known
    assert _cell(summary, "GridWorldWall-v0", "vicrl")["expert_return"] == pytest.approx(1.0)
    assert _cell(summary, "GridWorld-v0", "vicrl")["expert_return"] is None
    assert summary["core_hours"] is None and _cell(summary, "GridWorldWall-v0", "bc2l")["core_hours"] is None
    assert "Compute:" not in markdown_table(summary)


def test_tables_and_readme_show_the_columns(finished_suite, tmp_path):
    suite, root, results = finished_suite
    summary = summarise_suite(suite, suite.runs(), results, run_facts(results, root))

    table = markdown_table(summary).splitlines()
    assert "| vs our expert |" in table[0] and "| paper | simple-icrl | another re-run |" in table[0]
    assert table[1].count("|---") == 15 and "Wilcoxon" not in table[0]  # no cell has the 6 pairs a p-value needs
    row = next(line for line in table if line.startswith("| GridWorldWall-v0 | base | bc2l |"))
    assert "| 0.60 of expert |" in row and "| - | 0.9 / 0.4% | - |" in row and row.endswith("| 1.5 |")
    row = next(line for line in table if line.startswith("| GridWorld-v0 | base | bc2l |"))
    assert "| mean 2.50 [2.00, 3.00] |" in row and "| - | - | - |" in row  # two seeds: mean and [min, max], no IQM
    assert table[-1] == "Compute: 2.1 core-hours of training over 7 runs"  # 7560 s, one run without a time

    rows = list(csv.DictReader(io.StringIO(csv_rows(summary))))
    first = rows[0]
    assert (first["env"], first["algo"], first["seed"]) == ("GridWorld-v0", "bc2l", "0")
    assert first["wall_time_s"] == "360.0" and first["expert_return"] == "" and first["simple-icrl_feasible_reward"] == ""
    wall = next(row for row in rows if (row["env"], row["algo"], row["seed"]) == ("GridWorldWall-v0", "bc2l", "1"))
    assert wall["wall_time_s"] == "3600.0" and wall["expert_return"] == "1.0"
    assert (wall["simple-icrl_feasible_reward"], wall["simple-icrl_violation_rate"]) == ("0.9", "0.004")

    tex = latex_table(summary)
    assert "simple-icrl reward & simple-icrl violation & another re-run reward" in tex
    assert "\\begin{tabular}{lllrrrrrrrrr}" in tex
    assert (
        "GridWorldWall-v0 & base & BC2L & $0.6 \\pm 0.1$ & 0.60 & $25\\% \\pm 35\\%$ & -- & -- & 0.9 & 0.4\\% & -- & --"
        in (tex)
    )

    # summary.json: strict JSON, a run without demonstrations has a null expert return
    results_folder = tmp_path / "results"
    write_report(summary, str(results_folder / "columns"))
    written = json.loads((results_folder / "columns" / "summary.json").read_text())
    assert _cell(written, "GridWorld-v0", "bc2l")["per_seed"][0]["expert_return"] is None
    assert _cell(written, "GridWorldWall-v0", "bc2l")["others"] == {"simple-icrl": [0.9, 0.004]}

    readme = readme_table.table(results_folder).splitlines()
    assert readme[0] == (
        "| suite | env | variant | method | seeds | violation rate | feasible reward | vs our expert | "
        "paper (reward / violation) | simple-icrl (reward / violation) | another re-run (reward / violation) |"
    )
    assert readme[1] == "|---" * 11 + "|"
    row = "| suite | GridWorldWall-v0 | base | BC2L | 0, 1 | 25% ± 35% | 0.60 ± 0.14 | 0.60 of expert | - | 0.9 / 0.4% | - |"
    assert row in readme
    assert "| suite | GridWorld-v0 | base | BC2L | 0, 1 | 0% ± 0% | 2.50 ± 0.71 | - | - | - | - |" in readme
    assert readme[-1] == "Compute: 2.1 core-hours of training over 7 runs (suite 2.1 over 7); no transfer tests."


def test_readme_table_keeps_older_summaries_readable(finished_suite, tmp_path):
    """A summary written before these columns shows ``-`` in them; without any such summary they do not appear."""
    suite, root, results = finished_suite
    summary = summarise_suite(suite, suite.runs(), results, run_facts(results, root))
    write_report(summary, str(tmp_path / "new"))
    old = {
        "suite": "old",
        "cells": [
            {
                "env": "BlockedAnt-v0",
                "variant": "base",
                "algo": "mecl",
                "per_seed": [{"seed": 0}],
                "violation_rate_mean": 0.0,
                "violation_rate_std": 0.0,
                "feasible_reward_mean": 1000.0,
                "feasible_reward_std": 0.0,
                "paper_feasible_reward": 8546.0,
                "paper_violation_rate": 0.0,
            }
        ],
    }
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "summary.json").write_text(json.dumps(old))
    row = "| old | BlockedAnt-v0 | base | MECL | 0 | 0% ± 0% | 1000 ± 0 | - | 8546 / 0% | - | - |"
    assert row in readme_table.table(tmp_path)
    (tmp_path / "new" / "summary.json").unlink()
    only_old = readme_table.table(tmp_path)
    assert only_old.splitlines()[-3] == "| old | BlockedAnt-v0 | base | MECL | 0 | 0% ± 0% | 1000 ± 0 | 8546 / 0% |"
    # The published numbers an older summary carries are enough to score it
    assert only_old.splitlines()[-1] == (
        "old: our cell beats (higher feasible reward, violation rate no higher) the paper's MECL on 0 of 1 envs."
    )
    assert "Compute" not in only_old


def test_cells_say_which_published_numbers_they_beat(finished_suite):
    suite, root, results = finished_suite
    summary = summarise_suite(suite, suite.runs(), results, run_facts(results, root))
    # bc2l: 0.6 / 25% against simple-icrl's 0.9 / 0.4%: lower reward, more violations
    assert _cell(summary, "GridWorldWall-v0", "bc2l")["beats"] == {"simple-icrl": False}
    # vicrl: 4.0 / 0% against another re-run's 0.5 / 25%
    assert _cell(summary, "GridWorldWall-v0", "vicrl")["beats"] == {"another re-run": True}
    assert _cell(summary, "GridWorld-v0", "vicrl")["beats"] == {}
    assert readme_table.scoreboard(summary) == (
        "suite: our cell beats (higher feasible reward, violation rate no higher) simple-icrl's BC2L on 0 of 1 envs; "
        "another re-run's VICRL on 1 of 1 envs (GridWorldWall-v0)."
    )


@pytest.mark.parametrize(
    "reward, violation, expected",
    [
        (2.0, 0.1, True),
        (2.0, 0.2, True),
        (2.0, float(np.mean([0.1, 0.2, 0.3])), True),  # 0.20000000000000004: the same rate
        (1.0, 0.1, False),
        (2.0, 0.3, False),
        (0.5, 0.5, False),
    ],
)
def test_beating_needs_more_reward_and_no_more_violations(reward, violation, expected):
    cell = {"feasible_reward_mean": reward, "violation_rate_mean": violation}
    assert judgements.beats(cell, (1.0, 0.2)) is expected
    assert judgements.beats(cell, None) is None


# ---------------------------------------------------------------- best models


def test_report_of_best_models_evaluates_best_model_zip_with_its_own_cache(finished_suite, tmp_path, monkeypatch):
    """
    ``--model best``: each finished run's ``best_model.zip`` (a run without one left out, said so), cached beside the
    final model's evaluation, never in its place; the tables say which models they show, and the README's table
    labels the suite and does not count its compute twice.
    """
    suite, root, results = finished_suite
    evaluated = []

    def fake_evaluate_run(folder, steps, seed, load_best=False, env_kwargs=None, n_episodes=None):
        evaluated.append((os.path.relpath(folder, root), load_best))
        feasible = 9.0 if load_best else 1.0
        return RunResult(folder, "bc2l", "sb3_icrl/GridWorldWall-v0", 0, 100, 1.0, 0.0, feasible, feasible, 2)

    monkeypatch.setattr(report, "evaluate_run", fake_evaluate_run)
    with_best = [run for run in suite.runs() if run.seed == 0]
    for run in with_best:
        pathlib.Path(run.run_folder(root), "best_model.zip").write_bytes(b"")
    logged = []
    best = report.evaluate_finished(suite.runs(), root, suite, log=logged.append, model="best")
    assert [run for run, _ in best] == with_best and all(result.feasible_reward == 9.0 for _, result in best)
    assert sorted(evaluated) == sorted((os.path.relpath(run.run_folder(root), root), True) for run in with_best)
    assert sum("has no best_model.zip" in line for line in logged) == len(suite.runs()) - len(with_best)
    folder = with_best[0].run_folder(root)
    assert os.path.isfile(os.path.join(folder, report.HELDOUT_BEST_FILE))
    assert not os.path.isfile(os.path.join(folder, report.HELDOUT_FILE))
    # Cached: a second report evaluates nothing; the final models' report has its own cache
    evaluated.clear()
    report.evaluate_finished(suite.runs(), root, suite, log=logged.append, model="best")
    assert evaluated == []
    report.evaluate_finished(with_best[:1], root, suite, log=logged.append)
    assert evaluated == [(os.path.relpath(folder, root), False)]
    with pytest.raises(ValueError, match="`model` must be one of final, best, got 'last'"):
        report.evaluate_finished(suite.runs(), root, suite, model="last")
    # A normalising run (final statistics in <EnvName>/) whose best model has no statistics of its own: left out
    first = with_best[0]
    stats = pathlib.Path(first.run_folder(root), first.env_id.split("/")[-1], "vecnormalize.pkl")
    stats.write_bytes(b"")
    logged.clear()
    kept = report.evaluate_finished(suite.runs(), root, suite, log=logged.append, model="best")
    assert first not in [run for run, _ in kept] and len(kept) == len(with_best) - 1
    assert any("no normalisation statistics of its own" in line for line in logged)
    pathlib.Path(first.run_folder(root), "best_model_vecnormalize.pkl").write_bytes(b"")
    assert first in [run for run, _ in report.evaluate_finished(suite.runs(), root, suite, log=logged.append, model="best")]

    final_summary = summarise_suite(suite, suite.runs(), results, run_facts(results, root))
    best_summary = summarise_suite(suite, suite.runs(), results, run_facts(results, root), model="best")
    assert final_summary["model"] == "final" and best_summary["model"] == "best"
    assert report_text.BEST_MODELS_NOTE in markdown_table(best_summary)
    assert report_text.BEST_MODELS_NOTE not in markdown_table(final_summary)
    write_report(final_summary, str(tmp_path / "results" / "final"))
    write_report(best_summary, str(tmp_path / "results" / "best"))
    readme = readme_table.table(tmp_path / "results").splitlines()
    assert sum(line.startswith("| suite (best models) | ") for line in readme) == 4
    assert sum(line.startswith("| suite | GridWorld") for line in readme) == 4
    assert (
        readme[-1] == "Compute: 2.1 core-hours of training over 7 runs (suite 2.1 over 7); no transfer tests."
    )  # counted once
    # A suite committed only as a report of best models still counts
    (tmp_path / "results" / "final" / "summary.json").unlink()
    only_best = readme_table.table(tmp_path / "results").splitlines()
    assert only_best[-1] == "Compute: 2.1 core-hours of training over 7 runs (suite 2.1 over 7); no transfer tests."


# ---------------------------------------------------------------- report --update: re-runs of some cells


def _strict(summary: dict) -> dict:
    """A summary as its summary.json reads back."""
    return json.loads(json.dumps(report_numbers.finite_or_null(summary)))


def test_an_earlier_report_reads_back_into_the_same_summary(finished_suite):
    suite, root, results = finished_suite
    # Every kind of column a run can carry: driving outcome rates, a non-finite feasible reward, identification scores
    # with each kind of threshold error (a crossing; a cost at or above 0.5 everywhere; one that never reaches it, as
    # the identification headline pairs them), transfer results
    results = [
        (run, dataclasses.replace(result, outcome_rates={"collision_rate": 0.25, "off_road_rate": 0.0}, episode_length=9.5))
        for run, result in results
    ]
    results[0] = (results[0][0], dataclasses.replace(results[0][1], feasible_reward=float("nan")))
    facts = run_facts(results, root)
    for index, (_, result) in enumerate(results):
        facts[result.run].update(
            identification_auroc=0.5 + index / 100,
            threshold_error=[-0.25 * index, float("inf"), float("nan")][index % 3],
            threshold_crossing=["crosses", "everywhere", "nowhere"][index % 3],
            transfer_same_violation_rate=0.1 * index,
            transfer_same_feasible_ratio=0.9,
        )
    original = summarise_suite(suite, suite.runs(), results, facts)
    summary = _strict(original)
    kept, metrics, missing = report.previous_results(summary, suite, root)
    assert sorted(run.name for run, _ in kept) == sorted(run.name for run in suite.runs()) and missing == []
    assert {result.run for _, result in kept} == {result.run for _, result in results}  # keyed as the fresh ones
    assert {result.outcome_rates["collision_rate"] for _, result in kept} == {0.25}
    assert _strict(summarise_suite(suite, suite.runs(), kept, metrics)) == summary
    assert markdown_table(summarise_suite(suite, suite.runs(), kept, metrics)) == markdown_table(original)
    # The CSV too, the infinite threshold error included (empty, its reason in threshold_crossing)
    assert csv_rows(summarise_suite(suite, suite.runs(), kept, metrics)) == csv_rows(original)

    other = {**summary, "suite": "noise"}
    with pytest.raises(ValueError, match="report to update is of suite 'noise', not 'suite'"):
        report.previous_results(other, suite, root)
    renamed = json.loads(json.dumps(summary))
    renamed["cells"][0]["variant"] = "gone"
    with pytest.raises(ValueError, match="holds run 'gone/bc2l/GridWorld-v0/seed 0', which suite 'suite' no longer has"):
        report.previous_results(renamed, suite, root)


def _report_of_every_run(finished_suite, tmp_path) -> tuple[str, str, dict]:
    """The suite's file, a report of all its finished runs in ``results/suite``, and that report's summary."""
    suite, root, results = finished_suite
    path = write(tmp_path, SUITE)
    output = str(tmp_path / "results" / "suite")
    write_report(summarise_suite(suite, suite.runs(), results, run_facts(results, root)), output)
    return path, output, json.loads(pathlib.Path(output, "summary.json").read_text())


def test_update_keeps_the_runs_whose_folders_are_elsewhere(finished_suite, tmp_path, monkeypatch, capsys):
    from sb3_icrl.benchmark import cli

    _, root, results = finished_suite
    path, output, earlier = _report_of_every_run(finished_suite, tmp_path)
    # This log folder holds one run only (the report's other runs trained elsewhere); --update without --only
    here = results[0][0]
    for run, _ in results[1:]:
        shutil.rmtree(run.run_folder(root))

    def evaluated(first: int, last: int):
        return lambda runs, *args, **kwargs: [item for item in results[first:last] if item[0] in runs]

    monkeypatch.setattr(cli, "evaluate_finished", evaluated(0, 1))
    assert cli.main(["report", path, "-f", root, "-o", output, "--no-figures", "--update"]) == 0
    assert f"--update: {len(results) - 1} runs of the report in" in capsys.readouterr().out
    updated = json.loads(pathlib.Path(output, "summary.json").read_text())
    assert [(c["env"], c["algo"], c["per_seed"]) for c in updated["cells"]] == [
        (c["env"], c["algo"], c["per_seed"]) for c in earlier["cells"]
    ]
    assert updated["runs_missing"] == [] and here.name not in updated["runs_missing"]
    # A run whose folder is here but has not finished (being trained again) still loses its old result
    os.remove(os.path.join(here.run_folder(root), "finished.json"))
    monkeypatch.setattr(cli, "evaluate_finished", evaluated(1, 2))
    assert cli.main(["report", path, "-f", root, "-o", output, "--no-figures", "--update", "--replace"]) == 0
    assert here.name in json.loads(pathlib.Path(output, "summary.json").read_text())["runs_missing"]


def test_update_refuses_a_reported_run_trained_again_unless_told(finished_suite, tmp_path, monkeypatch, capsys):
    """A reported row trained again here (a probe copy of `run --reported`, say) does not silently replace it."""
    from sb3_icrl.benchmark import cli

    suite, root, results = finished_suite
    path, output, earlier = _report_of_every_run(finished_suite, tmp_path)
    again = results[0][0]
    assert report.reported_runs_trained_again(earlier, suite, suite.runs(), root) == []  # the very trainings it reported
    reported_minutes = report.finished_wall_time(report.read_finished(again.run_folder(root))) / 60
    # Another git revision tells a training apart too, where both the folder and the report record one
    versions = pathlib.Path(again.run_folder(root), again.env_id.split("/")[-1], "versions.yml")
    versions.write_text("git_revision: 0123456789abcdef\n")
    with_revision = json.loads(json.dumps(earlier))
    for cell in with_revision["cells"]:
        for seed in cell["per_seed"]:
            seed["git_revision"] = "fedcba9876543210"
    assert report.reported_runs_trained_again(with_revision, suite, suite.runs(), root) == [
        f"{again.name}: git revision 0123456 here against the report's fedcba9"
    ]
    versions.unlink()
    _finish(again.run_folder(root), wall_time_s=4321.0)
    assert report.reported_runs_trained_again(earlier, suite, suite.runs(), root) == [
        f"{again.name}: trained 72.0 min here against the report's {reported_minutes:.1f}"
    ]
    assert report.reported_runs_trained_again(earlier, suite, [run for run in suite.runs() if run != again], root) == []
    # A git revision of a working tree with changes keeps its suffix: the short forms alone could read the same
    versions.write_text("git_revision: fedcba9876543210-dirty\n")
    _finish(again.run_folder(root), wall_time_s=reported_minutes * 60)
    assert report.reported_runs_trained_again(with_revision, suite, suite.runs(), root) == [
        f"{again.name}: git revision fedcba9-dirty here against the report's fedcba9"
    ]
    versions.unlink()
    # A run of another recipe version than its reported row is that recipe's run, not a copy of the row
    args_file = pathlib.Path(again.run_folder(root), again.env_id.split("/")[-1], "args.yml")
    original_args = args_file.read_text()
    _args(again.run_folder(root), again.env_id.split("/")[-1], recipe_version="v2")
    with_version = json.loads(json.dumps(earlier))
    for cell in with_version["cells"]:
        for seed in cell["per_seed"]:
            seed["recipe_version"] = "v1"
    _finish(again.run_folder(root), wall_time_s=4321.0)
    assert report.reported_runs_trained_again(with_version, suite, suite.runs(), root) == []
    assert len(report.reported_runs_trained_again(earlier, suite, suite.runs(), root)) == 1  # the row recorded none
    args_file.write_text(original_args)
    # A training not finished yet counts where a selected run has finished: otherwise the update changes nothing
    os.remove(os.path.join(again.run_folder(root), FINISHED_FILE))
    assert report.reported_runs_trained_again(earlier, suite, suite.runs(), root) == [
        f"{again.name}: its training here has not finished"
    ]
    assert report.reported_runs_trained_again(earlier, suite, [again], root) == []
    _finish(again.run_folder(root), wall_time_s=4321.0)

    monkeypatch.setattr(cli, "evaluate_finished", lambda runs, *args, **kwargs: [item for item in results if item[0] in runs])
    argv = ["report", path, "-f", root, "-o", output, "--no-figures", "--update"]
    assert cli.main(argv) == 2
    error = capsys.readouterr().err
    assert "1 of the selected runs" in error and again.name in error and "add --replace" in error
    assert json.loads(pathlib.Path(output, "summary.json").read_text()) == earlier  # nothing written
    other = [f"algo={algo}" for algo in sorted({run.algo for run in suite.runs()} - {again.algo})]
    assert cli.main([*argv, "--only", *other]) == 0  # the copy left out of --only
    # --withdraw says what it needs (the folders out of -f), --replace needs --update
    assert cli.main([*argv, "--withdraw", "--only", f"algo={again.algo}"]) == 2
    assert "have a folder under" in capsys.readouterr().err
    assert cli.main([*argv[:-1], "--replace"]) == 2
    assert "--replace lets runs trained again replace rows of an existing report: add --update" in capsys.readouterr().err
    assert cli.main([*argv, "--replace"]) == 0
    summary = json.loads(pathlib.Path(output, "summary.json").read_text())
    replaced = _cell(summary, again.env_id.split("/")[-1], again.algo)
    assert 4321.0 in [seed.get("wall_time_s") for seed in replaced["per_seed"]]


def test_update_lists_a_run_still_to_come_once(finished_suite, tmp_path, monkeypatch):
    """A run the earlier report listed as not finished, still not started here, is counted once."""
    from sb3_icrl.benchmark import cli

    suite, root, results = finished_suite
    path = write(tmp_path, SUITE)
    output = str(tmp_path / "results" / "suite")
    waiting = results[0][0]
    write_report(summarise_suite(suite, suite.runs(), results[1:], run_facts(results[1:], root)), output)
    shutil.rmtree(waiting.run_folder(root))
    monkeypatch.setattr(
        cli, "evaluate_finished", lambda runs, *args, **kwargs: [item for item in results[1:] if item[0] in runs]
    )
    assert cli.main(["report", path, "-f", root, "-o", output, "--no-figures", "--update"]) == 0
    updated = json.loads(pathlib.Path(output, "summary.json").read_text())
    expected = sorted({run.name for run in suite.runs()} - {run.name for run, _ in results[1:]})
    assert waiting.name in expected and sorted(updated["runs_missing"]) == expected  # each once
    assert sum(left for _, _, left, _ in updated["runs_missing_by_env"]) == len(expected)
    assert all(left <= total for _, _, left, total in updated["runs_missing_by_env"])


def test_withdraw_takes_runs_out_of_a_report_to_be_trained_again(finished_suite, tmp_path, monkeypatch, capsys):
    from sb3_icrl.benchmark import cli

    _, root, results = finished_suite
    path, output, earlier = _report_of_every_run(finished_suite, tmp_path)
    monkeypatch.setattr(cli, "evaluate_finished", lambda *args, **kwargs: pytest.fail("--withdraw evaluates nothing"))
    argv = ["report", path, "-f", root, "-o", output, "--no-figures", "--only", "env=GridWorldWall-v0", "algo=vicrl"]

    # Clear errors: not without --update, not without --only, not while the runs' folders are under -f
    assert cli.main([*argv, "--withdraw"]) == 2
    assert "add --update" in capsys.readouterr().err
    assert cli.main([*argv[:-3], "--update", "--withdraw"]) == 2
    assert "name the runs to take out of the report with --only" in capsys.readouterr().err
    assert cli.main([*argv, "--update", "--withdraw"]) == 2
    assert "have a folder under" in capsys.readouterr().err
    assert json.loads(pathlib.Path(output, "summary.json").read_text()) == earlier  # nothing written

    withdrawn = sorted(run.name for run, _ in results if run.cell == ("GridWorldWall-v0", "base", "vicrl"))
    for run, _ in results:
        if run.name in withdrawn:
            shutil.rmtree(run.run_folder(root))
    assert cli.main([*argv, "--update", "--withdraw"]) == 0
    assert "--withdraw: 2 runs taken out of the report" in capsys.readouterr().out
    assert cli.main([*argv, "--update", "--withdraw"]) == 2  # a second time: the report no longer holds them
    assert "holds none of the runs --only selects" in capsys.readouterr().err
    updated = json.loads(pathlib.Path(output, "summary.json").read_text())
    assert sorted(updated["runs_missing"]) == withdrawn
    assert [(c["env"], c["algo"]) for c in updated["cells"] if c["per_seed"]] == [
        (c["env"], c["algo"]) for c in earlier["cells"] if (c["env"], c["algo"]) != ("GridWorldWall-v0", "vicrl")
    ]
    for key in [("GridWorldWall-v0", "bc2l"), ("GridWorld-v0", "bc2l"), ("GridWorld-v0", "vicrl")]:
        assert _cell(updated, *key)["per_seed"] == _cell(earlier, *key)["per_seed"]


def test_update_replaces_the_rerun_seeds_and_keeps_every_other_cell(finished_suite, tmp_path, monkeypatch, capsys):
    from sb3_icrl.benchmark import cli

    suite, root, results = finished_suite
    path = write(tmp_path, SUITE)
    output = str(tmp_path / "results" / "suite")
    # The earlier report: one run had not finished
    earlier_results = [(run, result) for run, result in results if run.name != "base/vicrl/GridWorld-v0/seed 1"]
    earlier = summarise_suite(suite, suite.runs(), earlier_results, run_facts(earlier_results, root))
    write_report(earlier, output)
    assert earlier["runs_missing"] == ["base/vicrl/GridWorld-v0/seed 1"]

    # VICRL on GridWorldWall run again, with other results
    rerun = {run.name: run for run, _ in results if run.cell == ("GridWorldWall-v0", "base", "vicrl")}
    fresh = [
        (
            run,
            RunResult(
                os.path.relpath(run.run_folder(root), root), "vicrl", run.env_id, run.seed, 100, 1.0, 0.5, feasible, 3.0, 2
            ),
        )
        for feasible, run in zip([2.0, 3.0], rerun.values(), strict=True)
    ]
    monkeypatch.setattr(cli, "evaluate_finished", lambda runs, *args, **kwargs: [item for item in fresh if item[0] in runs])
    argv = ["report", path, "-f", root, "--only", "env=GridWorldWall-v0", "algo=vicrl", "-o", output, "--no-figures"]
    assert cli.main([*argv, "--update"]) == 0
    updated = json.loads(pathlib.Path(output, "summary.json").read_text())

    vicrl = _cell(updated, "GridWorldWall-v0", "vicrl")
    assert [seed["feasible_reward"] for seed in vicrl["per_seed"]] == [2.0, 3.0]
    assert vicrl["feasible_reward_mean"] == pytest.approx(2.5) and vicrl["violation_rate_mean"] == pytest.approx(0.5)
    old_cells = {(cell["env"], cell["algo"]): cell for cell in _strict(earlier)["cells"]}
    for key in [("GridWorldWall-v0", "bc2l"), ("GridWorld-v0", "bc2l"), ("GridWorld-v0", "vicrl")]:
        assert _cell(updated, *key)["per_seed"] == old_cells[key]["per_seed"]
    # bc2l's test against VICRL is made again, against the new VICRL seeds: 0.5 / 0.7 against 2.0 / 3.0
    assert _cell(updated, "GridWorldWall-v0", "bc2l")["wilcoxon_pairs"] == 2
    assert _cell(updated, "GridWorldWall-v0", "bc2l")["feasible_reward_mean"] == pytest.approx(0.6)
    assert updated["runs_missing"] == ["base/vicrl/GridWorld-v0/seed 1"]
    assert updated["core_hours"] == pytest.approx(earlier["core_hours"])  # the re-runs' own times: 900 s each again
    assert "| GridWorld-v0 | base | bc2l |" in pathlib.Path(output, "table.md").read_text()

    # A selected seed that has not finished this time loses its old result (its cell must not mix two recipes) and is
    # listed as not finished; the earlier report here is the one just updated
    def only_the_first(runs, *args, **kwargs):
        return [item for item in fresh[:1] if item[0] in runs]

    monkeypatch.setattr(cli, "evaluate_finished", only_the_first)
    assert cli.main([*argv, "--update"]) == 0
    partly = json.loads(pathlib.Path(output, "summary.json").read_text())
    assert [seed["feasible_reward"] for seed in _cell(partly, "GridWorldWall-v0", "vicrl")["per_seed"]] == [2.0]
    assert sorted(partly["runs_missing"]) == ["base/vicrl/GridWorld-v0/seed 1", "base/vicrl/GridWorldWall-v0/seed 1"]
    assert _cell(partly, "GridWorldWall-v0", "bc2l")["per_seed"] == old_cells[("GridWorldWall-v0", "bc2l")]["per_seed"]

    # Without --update the report holds the selected cell only
    assert cli.main(argv) == 0
    assert [(cell["env"], cell["algo"]) for cell in json.loads(pathlib.Path(output, "summary.json").read_text())["cells"]] == [
        ("GridWorldWall-v0", "vicrl")
    ]
    capsys.readouterr()
    # Nothing to update, or a report of the other models: said so
    assert cli.main([*argv[:-3], "-o", str(tmp_path / "empty"), "--no-figures", "--update"]) == 2
    assert "--update: no report in" in capsys.readouterr().err

    # ... before any evaluation, which takes minutes on a real suite
    def no_evaluation(*args, **kwargs):
        raise AssertionError("evaluated the runs before finding that there is no report to update")

    monkeypatch.setattr(cli, "evaluate_finished", no_evaluation)
    assert cli.main([*argv[:-3], "-o", str(tmp_path / "empty"), "--no-figures", "--update"]) == 2
    assert "--update: no report in" in capsys.readouterr().err
    monkeypatch.setattr(cli, "evaluate_finished", only_the_first)
    assert cli.main([*argv, "--update", "--model", "best"]) == 2
    assert "evaluated the final models, this one the best models: pass --model final" in capsys.readouterr().err


def test_update_refuses_a_report_evaluated_with_the_other_budget(finished_suite, tmp_path, monkeypatch, capsys):
    """Its cells would count their held-out episodes two ways; a report from before the key was evaluated by steps."""
    from sb3_icrl.benchmark import cli

    suite, root, results = finished_suite
    output = str(tmp_path / "results" / "suite")
    earlier = summarise_suite(suite, suite.runs(), results, run_facts(results, root))
    assert earlier["eval_budget"] == "episodes"
    del earlier["eval_budget"]
    write_report(earlier, output)
    monkeypatch.setattr(cli, "evaluate_finished", lambda runs, *args, **kwargs: [])
    argv = ["report", write(tmp_path, SUITE), "-f", root, "-o", output, "--no-figures", "--update"]
    assert cli.main(argv) == 2
    assert "evaluated its runs by steps, suite 'suite' evaluates them by episodes (eval_budget)" in capsys.readouterr().err
    argv[1] = write(tmp_path, SUITE + "eval_budget: steps\n")
    assert cli.main(argv) == 0
    assert json.loads(pathlib.Path(output, "summary.json").read_text())["eval_budget"] == "steps"


def test_compute_line_names_the_variants_of_a_suite_reported_in_parts(finished_suite, tmp_path):
    """Two reports of one suite (one per variant): the compute line tells them apart by their variants."""
    suite, root, results = finished_suite
    for variant in ("n4", "n4-match"):
        summary = summarise_suite(suite, suite.runs(), results, run_facts(results, root))
        for cell in summary["cells"]:
            cell["variant"] = variant
        write_report(summary, str(tmp_path / "results" / f"suite_{variant}"))
    line = readme_table.table(tmp_path / "results").splitlines()[-1]
    assert line == (
        "Compute: 4.2 core-hours of training over 14 runs (suite (n4) 2.1 over 7, suite (n4-match) 2.1 over 7); "
        "no transfer tests."
    )
    # A suite reported once keeps its plain name
    (tmp_path / "results" / "suite_n4" / "summary.json").unlink()
    line = readme_table.table(tmp_path / "results").splitlines()[-1]
    assert line == "Compute: 2.1 core-hours of training over 7 runs (suite 2.1 over 7); no transfer tests."


def test_update_with_no_finished_run_writes_the_report_again_as_it_was(finished_suite, tmp_path, monkeypatch):
    from sb3_icrl.benchmark import cli

    suite, root, results = finished_suite
    path = write(tmp_path, SUITE)
    output = str(tmp_path / "results" / "suite")
    # A report of part of the suite (its GridWorldWall cells), with the statistics of an earlier version
    part = [(run, result) for run, result in results if run.env_id.endswith("GridWorldWall-v0")]
    earlier = summarise_suite(suite, [run for run, _ in part], part, run_facts(part, root))
    for cell in earlier["cells"]:
        cell["feasible_reward_std"] = 0.0  # what an older version wrote
    write_report(earlier, output)
    monkeypatch.setattr(cli, "evaluate_finished", lambda runs, *args, **kwargs: [])  # the run folders are gone
    assert cli.main(["report", path, "-f", str(tmp_path / "gone"), "-o", output, "--no-figures", "--update"]) == 0
    again = json.loads(pathlib.Path(output, "summary.json").read_text())
    assert [(c["env"], c["algo"]) for c in again["cells"]] == [(c["env"], c["algo"]) for c in _strict(earlier)["cells"]]
    for cell, old in zip(again["cells"], _strict(earlier)["cells"], strict=True):
        assert cell["per_seed"] == old["per_seed"]
        # The sample std of today, from the same per-seed values
        assert cell["feasible_reward_std"] == pytest.approx(np.std([s["feasible_reward"] for s in old["per_seed"]], ddof=1))
    assert again["runs_missing"] == []  # the GridWorld cells it never reported are not listed as unfinished


def test_many_unfinished_runs_are_counted_per_env_few_are_named():
    from sb3_icrl.benchmark.report_text import MAX_MISSING_NAMED, not_finished_text

    few = {"runs_missing": ["base/gacl/A-v0/seed 1", "base/gacl/B-v0/seed 1"], "runs_missing_by_env": [["A-v0", "base", 1, 4]]}
    assert not_finished_text(few) == "Not finished yet (2): base/gacl/A-v0/seed 1, base/gacl/B-v0/seed 1"
    names = [f"base/gacl/A-v0/seed {seed}" for seed in range(MAX_MISSING_NAMED)] + ["noise/gacl/A-v0/seed 0"]
    many = {"runs_missing": names, "runs_missing_by_env": [["A-v0", "base", 12, 20], ["A-v0", "noise", 1, 20]]}
    assert not_finished_text(many) == (
        "Not finished yet (13 runs, all named in summary.json's `runs_missing`): A-v0 12 of 20; A-v0 (noise) 1 of 20."
    )


def test_a_study_draws_each_method_against_its_level(tmp_path):
    from sb3_icrl.benchmark.report_figures import study_axis, study_figure

    text = """\
envs: [GridWorldWall-v0]
algos: [bc2l, mecl]
seeds: [0, 1]
variants:
  sigma-0.1: {transition_noise: 0.1}
  sigma-0.01: {transition_noise: 0.01}
"""
    path = tmp_path / "study.yml"
    path.write_text(text)
    suite = load_suite(str(path), dry_build=False)
    key, levels = study_axis(suite)
    assert key == "transition_noise" and levels == {"sigma-0.1": 0.1, "sigma-0.01": 0.01}
    values = {("sigma-0.1", "mecl"): [(5.0, 0.5), (7.0, 0.0)], ("sigma-0.01", "mecl"): [(9.0, 0.0), (11.0, 0.0)]}
    results = [
        (run, RunResult(run.name, run.algo, run.env_id, run.seed, 100, 1.0, violation, feasible, feasible, 20))
        for run in suite.runs()
        if (run.variant, run.algo) in values
        for feasible, violation in [values[(run.variant, run.algo)][run.seed]]
    ]
    figure = study_figure(summarise_suite(suite, suite.runs(), results), key, levels)
    violation_ax, reward_ax = figure.axes
    assert violation_ax.get_xscale() == "log" and violation_ax.get_title() == "GridWorldWall-v0"
    # The means joined by a line, in order of the level; each seed a dot
    [line] = reward_ax.get_lines()
    assert list(line.get_xdata()) == [0.01, 0.1] and list(line.get_ydata()) == [10.0, 6.0]
    assert sorted(np.concatenate([c.get_offsets()[:, 1] for c in reward_ax.collections])) == [5.0, 7.0, 9.0, 11.0]
    assert list(violation_ax.get_lines()[0].get_ydata()) == [0.0, 0.25]
    # A level of 0 (no noise) stays on the axis: symlog, linear up to the smallest level above 0
    assert (
        study_figure(summarise_suite(suite, suite.runs(), results), key, {"sigma-0.1": 0.1, "sigma-0.01": 0.0})
        .axes[0]
        .get_xscale()
        == "symlog"
    )
    # A suite whose variants do not all set one number is no study
    path.write_text(text.replace("sigma-0.01: {transition_noise: 0.01}", "plain: {}"))
    assert study_axis(load_suite(str(path), dry_build=False)) is None
    shipped = {name: study_axis(load_suite(name, dry_build=False)) for name in ("noise", "imperfect", "table3")}
    assert shipped["noise"][0] == "transition_noise" and shipped["imperfect"][1]["violating-0.8"] == 0.8
    assert shipped["table3"] is None


def test_unfinished_runs_are_counted_per_env_over_the_reports_runs(tmp_path):
    text = "envs: [GridWorldWall-v0, GridWorldSquare-v0]\nalgos: [bc2l]\nseeds: [0, 1]\n"
    text += "env_seeds: {GridWorldSquare-v0: [0, 1, 2]}\n"
    path = tmp_path / "suite.yml"
    path.write_text(text)
    suite = load_suite(str(path), dry_build=False)
    finished = [run for run in suite.runs() if run.seed == 0]
    results = [(run, RunResult(run.name, run.algo, run.env_id, run.seed, 100, 1.0, 0.0, 1.0, 1.0, 20)) for run in finished]
    summary = summarise_suite(suite, suite.runs(), results)
    assert summary["runs_missing_by_env"] == [["GridWorldWall-v0", "base", 1, 2], ["GridWorldSquare-v0", "base", 2, 3]]
    # An updated report passes the runs it re-selected; the finished ones it keeps still count in the totals
    unfinished = [run for run in suite.runs() if run.seed != 0]
    summary = summarise_suite(suite, unfinished, results)
    assert summary["runs_missing_by_env"] == [["GridWorldWall-v0", "base", 1, 2], ["GridWorldSquare-v0", "base", 2, 3]]


def test_a_study_report_writes_its_figure(tmp_path, monkeypatch):
    import sb3_icrl.benchmark.report_figures as report_figures
    from sb3_icrl.benchmark.report_figures import write_figures

    text = """\
envs: [GridWorldWall-v0]
algos: [bc2l]
seeds: [0]
variants:
  none: {violating_fraction: 0.0}
  most: {violating_fraction: 0.8}
"""
    path = tmp_path / "study.yml"
    path.write_text(text)
    suite = load_suite(str(path), dry_build=False)
    results = [(run, RunResult(run.name, run.algo, run.env_id, run.seed, 100, 1.0, 0.0, 1.0, 1.0, 20)) for run in suite.runs()]
    summary = summarise_suite(suite, suite.runs(), results)
    monkeypatch.setattr(report_figures, "figure_data", lambda *args: {})  # no run folder: no curves
    monkeypatch.setattr(report_figures, "constraint_figures", lambda *args, **kwargs: [])
    written = write_figures(summary, suite, str(tmp_path / "logs"), str(tmp_path / "report"))
    assert [os.path.basename(path) for path in written] == [report_figures.FIGURE_DATA_FILE, "study.png"]
    assert os.path.isfile(written[1])


def test_saved_data_text_is_read_without_loading_and_leaves_a_file_where_it_was(tmp_path):
    """A model zip's ``data`` entry comes back as text; a file object is left at its position; unreadable -> None."""
    import io
    import zipfile

    from sb3_icrl.common.saved import read_saved_data_text

    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("data", '{"gamma": 0.99}')
    buffer.seek(0)
    assert read_saved_data_text(buffer) == '{"gamma": 0.99}'
    assert buffer.tell() == 0  # SB3's load reads the same file object again
    with zipfile.ZipFile(tmp_path / "no_data.zip", "w") as archive:
        archive.writestr("policy.pth", b"weights")
    assert read_saved_data_text(tmp_path / "no_data.zip") is None
    assert read_saved_data_text(tmp_path / "missing.zip") is None
    (tmp_path / "broken.zip").write_text("not a zip")
    assert read_saved_data_text(tmp_path / "broken.zip") is None


def test_constraint_updates_made_reach_the_csv(tmp_path, finished_suite):
    """An ICRL run's count of constraint updates, read from its final model's data, is a CSV column."""
    import zipfile

    from sb3_icrl.benchmark.report import constraint_updates_made

    model = tmp_path / "model.zip"
    with zipfile.ZipFile(model, "w") as archive:
        archive.writestr("data", json.dumps({"n_constraint_updates": 6, "gamma": 0.99}))
    assert constraint_updates_made(model) == 6
    assert constraint_updates_made(tmp_path / "missing.zip") is None
    with zipfile.ZipFile(tmp_path / "plain.zip", "w") as archive:
        archive.writestr("data", json.dumps({"gamma": 0.99}))  # a model without a constraint
    assert constraint_updates_made(tmp_path / "plain.zip") is None
    (tmp_path / "broken.zip").write_text("not a zip")
    assert constraint_updates_made(tmp_path / "broken.zip") is None

    suite, root, results = finished_suite
    first = results[0][0]
    shutil.copy(model, os.path.join(root, results[0][1].run, f"{env_name(first.env_id)}.zip"))
    summary = summarise_suite(suite, suite.runs(), results, constraint_metrics(results, root, log=lambda line: None))
    rows = list(csv.DictReader(io.StringIO(csv_rows(summary))))
    updates = {(row["env"], row["algo"], row["seed"]): row["constraint_updates"] for row in rows}
    assert updates.pop((env_name(first.env_id), first.algo, str(first.seed))) == "6"
    assert set(updates.values()) == {""}  # the other runs saved no model


def test_training_provenance_says_which_code_and_how_many_starts(tmp_path, finished_suite):
    """A run's code revision (versions.yml at its start) and its training starts (command.txt lines) reach the CSV."""
    from sb3_icrl.benchmark.report import training_provenance

    run = tmp_path / "run"
    (run / "Env-v0").mkdir(parents=True)
    assert training_provenance(run) == {}
    (run / "Env-v0" / "versions.yml").write_text("git_revision: abc123\nsb3_icrl: 0.1.0\n")
    (run / "command.txt").write_text("python train.py --seed 1\npython train.py --seed 1\n")  # resumed once
    assert training_provenance(run) == {"git_revision": "abc123", "training_starts": 2}
    suite, root, results = finished_suite
    folder = os.path.join(root, results[0][1].run)
    (pathlib.Path(folder) / "command.txt").write_text("python train.py\n")
    summary = summarise_suite(suite, suite.runs(), results, constraint_metrics(results, root, log=lambda line: None))
    rows = list(csv.DictReader(io.StringIO(csv_rows(summary))))
    first = results[0][0]
    starts = {(row["env"], row["algo"], row["seed"]): (row["training_starts"], row["git_revision"]) for row in rows}
    assert starts.pop((env_name(first.env_id), first.algo, str(first.seed))) == ("1", "")
    assert set(starts.values()) == {("", "")}  # the others record neither


def test_the_report_keeps_the_transfer_references_its_runs_read(finished_suite, tmp_path, monkeypatch):
    from sb3_icrl.benchmark import cli

    suite, root, results = finished_suite
    run = results[0][0]
    shared = pathlib.Path(run.log_folder(root), "transfer_references")
    shared.mkdir(parents=True)
    oracle = shared / "oracle_GridWorldWall-v0_0123456789abcdef.json"
    oracle.write_text('{"settings": {}, "result": {"feasible_reward": 2.0, "wall_time_min": 3.0}}')
    transfer = {
        "settings": {"reference_files": {"oracle": str(oracle)}},
        "results": {"learned": {"wall_time_min": 1.0}, "oracle": {"wall_time_min": 3.0}},
        "violation_rate": 0.0,
        "feasible_reward_ratio": 0.5,
    }
    pathlib.Path(run.run_folder(root), "transfer_same.json").write_text(json.dumps(transfer))
    monkeypatch.setattr(cli, "evaluate_finished", lambda runs, *args, **kwargs: [item for item in results if item[0] in runs])
    output = str(tmp_path / "report")
    assert cli.main(["report", suite.path, "-f", root, "-o", output, "--no-figures"]) == 0
    kept = pathlib.Path(output, "transfer_references", run.variant, oracle.name)
    assert kept.read_text() == oracle.read_text()


def test_the_report_says_when_a_run_s_probes_lack_its_own_seed_s_ppo_episodes(finished_suite, monkeypatch):
    _, root, results = finished_suite
    icrl = [(run, result) for run, result in results if run.algo in ("bc2l", "vicrl")][:3]
    found = {
        icrl[0][1].run: None,  # no PPO run finished
        icrl[1][1].run: "../../ppo/GridWorldWall-v0_7",  # another seed's
        icrl[2][1].run: f"../../ppo/{os.path.basename(icrl[2][1].run)}",  # its own seed's: nothing to say
    }

    def identified(folder, model="final"):
        name = os.path.relpath(folder, root)
        return {"settings": {"unconstrained_run": found[name]}, "scores": {"auroc": 0.5, "sources": {"learner": {}}}}

    monkeypatch.setattr(report, "identify_run", identified)
    monkeypatch.setattr(report, "identification_cached", lambda *args: True)
    monkeypatch.setattr(report, "headline", lambda scores: {"identification_auroc": scores["auroc"]})
    lines: list[str] = []
    metrics = report.constraint_metrics(icrl, root, log=lines.append)
    assert [metrics[result.run]["identification_unconstrained_run"] for _, result in icrl] == list(found.values())
    assert [line.split(":")[0] for line in lines] == [icrl[0][0].name, icrl[1][0].name]
    assert "its probes hold no unconstrained PPO episodes" in lines[0]
    assert "another seed's (../../ppo/GridWorldWall-v0_7)" in lines[1]
    assert f"no finished ppo run of seed {icrl[1][0].seed} being beside it" in lines[1]
