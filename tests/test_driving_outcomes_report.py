"""How driving episodes ended (collision, off road, time out, goal) in ``sb3-icrl compare`` and the benchmark report."""

import csv
import io
import json
import os
import pathlib
from dataclasses import asdict

import pytest

from sb3_icrl.benchmark import report, summarise_suite
from sb3_icrl.benchmark.report import HELDOUT_FILE, evaluate_finished
from sb3_icrl.benchmark.report_text import csv_rows, markdown_table
from sb3_icrl.zoo.compare import RunResult, format_table, summarise
from sb3_icrl.zoo.runs import FINISHED_FILE

ENV = "sb3_icrl/GridWorldWall-v0"


def _rates(collision: float, off_road: float, time_out: float, goal: float) -> dict[str, float]:
    return {"collision_rate": collision, "off_road_rate": off_road, "time_out_rate": time_out, "goal_reached_rate": goal}


def _result(algo: str, seed: int, outcome_rates: dict[str, float] | None = None) -> RunResult:
    rates = outcome_rates or {}
    return RunResult(f"logs/{algo}/Env_{seed}", algo, ENV, seed, 100, 1.0, 0.25, 2.0, 3.0, 4, outcome_rates=rates)


def test_summarise_averages_the_outcome_rates_of_runs_that_all_have_them():
    results = [
        _result("mecl", 0, _rates(0.5, 0.0, 0.25, 0.25)),
        _result("mecl", 1, _rates(0.0, 0.5, 0.25, 0.25)),
        _result("vicrl", 0, _rates(0.0, 0.0, 0.0, 1.0)),
        _result("vicrl", 1),  # evaluated on an env without outcome flags: no mean to take
    ]
    summary = summarise(results)
    assert summary["mecl"]["outcome_rates_mean"] == _rates(0.25, 0.25, 0.25, 0.25)
    assert list(summary["mecl"]["outcome_rates_mean"]) == list(_rates(0, 0, 0, 0))  # in OUTCOME_KEYS order
    assert "outcome_rates_mean" not in summary["vicrl"]


def test_compare_table_lists_the_outcomes_per_run_only_when_some_run_has_them():
    plain = [_result("mecl", 0), _result("mecl", 1)]
    assert "collision" not in format_table(plain, summarise(plain), None)

    driving = [_result("mecl", 1, _rates(0.1, 0.2, 0.3, 0.4)), _result("mecl", 0, _rates(1.0, 0.0, 0.0, 0.0))]
    lines = format_table(driving, summarise(driving), None).splitlines()
    header = lines.index("| algo | seed | collision | off road | time out | goal reached |")
    assert lines[header + 2 :] == ["| mecl | 0 | 100% | 0% | 0% | 0% |", "| mecl | 1 | 10% | 20% | 30% | 40% |"]


SUITE = "description: outcomes\nenvs: [GridWorldWall-v0]\nalgos: [bc2l, vicrl]\nseeds: [0, 1]\nsteps: 512\n"


@pytest.fixture
def suite(report_suite):
    return report_suite(SUITE)


def test_report_shows_how_the_episodes_ended_per_cell_and_per_seed(suite):
    runs = suite.runs()
    rates = {("bc2l", 0): _rates(0.5, 0.0, 0.0, 0.5), ("bc2l", 1): _rates(0.0, 0.0, 0.0, 1.0)}
    results = [(run, _result(run.algo, run.seed, rates.get((run.algo, run.seed)))) for run in runs]
    summary = summarise_suite(suite, runs, results)

    bc2l = next(cell for cell in summary["cells"] if cell["algo"] == "bc2l")
    assert bc2l["outcome_rates_mean"] == _rates(0.25, 0.0, 0.0, 0.75)
    assert [seed["goal_reached_rate"] for seed in bc2l["per_seed"]] == [0.5, 1.0]
    vicrl = next(cell for cell in summary["cells"] if cell["algo"] == "vicrl")
    assert "outcome_rates_mean" not in vicrl and "collision_rate" not in vicrl["per_seed"][0]

    table = markdown_table(summary).splitlines()
    start = next(i for i, line in enumerate(table) if line.startswith("How the held-out episodes ended (driving envs;"))
    assert table[start + 2] == (
        "| env | variant | algo | collision | off road | time out | goal reached "
        "| per seed (collision / off road / time out / goal reached) |"
    )
    assert table[start + 3].count("|---") == table[start + 4].count(" | ") + 1 == 8  # as many columns as cells
    assert table[start + 4 :] == [
        "| GridWorldWall-v0 | base | bc2l | 25% | 0% | 0% | 75% | 0: 50% / 0% / 0% / 50%, 1: 0% / 0% / 0% / 100% |"
    ]

    rows = list(csv.DictReader(io.StringIO(csv_rows(summary))))
    assert [(row["algo"], row["seed"], row["collision_rate"], row["goal_reached_rate"]) for row in rows] == [
        ("bc2l", "0", "0.5", "0.5"),
        ("bc2l", "1", "0.0", "1.0"),
        ("vicrl", "0", "", ""),
        ("vicrl", "1", "", ""),
    ]


def test_report_without_driving_cells_has_no_outcome_table(suite):
    runs = suite.runs()
    summary = summarise_suite(suite, runs, [(run, _result(run.algo, run.seed)) for run in runs])
    assert "How the held-out episodes ended" not in markdown_table(summary)


def test_a_cached_evaluation_missing_a_field_is_evaluated_again(suite, tmp_path, monkeypatch):
    """Results cached before the outcome rates were kept would hide them for ever: such a cache is stale."""
    run = suite.runs()[0]
    root = str(tmp_path / "logs")
    folder = pathlib.Path(run.run_folder(root))
    folder.mkdir(parents=True)
    (folder / FINISHED_FILE).write_text(json.dumps({"num_timesteps": 512}))
    fresh = _result(run.algo, run.seed, _rates(0.0, 0.0, 1.0, 0.0))
    calls = []

    def fake_evaluate(path, steps, seed, load_best=False, env_kwargs=None, n_episodes=None):
        calls.append(path)
        return RunResult(**asdict(fresh))

    monkeypatch.setattr(report, "evaluate_run", fake_evaluate)
    settings = report.heldout_settings(suite, run.env_id)  # the cache's settings fit: its missing field alone is stale
    older = {key: value for key, value in asdict(fresh).items() if key != "outcome_rates"}
    (folder / HELDOUT_FILE).write_text(json.dumps({"settings": settings, "result": older}))
    os.utime(folder / FINISHED_FILE, (0, 0))  # the cache is newer than the run's end

    [(_, result)] = evaluate_finished([run], root, suite, log=lambda line: None)
    assert calls == [str(folder)] and result.outcome_rates == fresh.outcome_rates
    assert json.loads((folder / HELDOUT_FILE).read_text())["result"]["outcome_rates"] == fresh.outcome_rates

    # Now complete: reused as it is
    [(_, again)] = evaluate_finished([run], root, suite, log=lambda line: None)
    assert len(calls) == 1 and again.outcome_rates == fresh.outcome_rates

    # Written by a later version, with a field this one does not know: evaluated again rather than a crash
    (folder / HELDOUT_FILE).write_text(json.dumps({"settings": settings, "result": {**asdict(fresh), "later": 1.0}}))
    evaluate_finished([run], root, suite, log=lambda line: None)
    assert len(calls) == 2
