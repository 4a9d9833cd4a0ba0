"""A study's level 0 from another report: which runs it takes, what it refuses, the figure, the report's note, the CLI."""

import json
import math
import pathlib

import numpy as np
import pytest

from sb3_icrl.benchmark import cli, load_suite, summarise_suite
from sb3_icrl.benchmark.report_figures import study_axis, study_figure
from sb3_icrl.benchmark.report_text import _level_identification_text, markdown_table, study_level_lines
from sb3_icrl.benchmark.study import baseline_line, read_report_summary, study_baseline
from sb3_icrl.benchmark.suite import SuiteError
from sb3_icrl.zoo.compare import RunResult

STUDY = """\
recipe_version: v2
envs: [GridWorldWall-v0, GridWorldSquare-v0]
algos: [bc2l, mecl]
seeds: [0, 1]
env_seeds: {GridWorldSquare-v0: [0]}
variants:
  sigma-0.1: {transition_noise: 0.1}
  sigma-0.01: {transition_noise: 0.01}
eval_episodes: 20
eval_budget: episodes
"""


def _seed(seed: int, feasible: float, violation: float, version: str = "v2") -> dict:
    return {"seed": seed, "feasible_reward": feasible, "violation_rate": violation, "recipe_version": version}


def table_summary(**changes) -> dict:
    """A report of another suite with the study's recipes: seeds 0-2 of bc2l and mecl, and a method the study lacks."""
    summary = {
        "suite": "table",
        "model": "final",
        "eval_budget": "episodes",
        "eval_episodes": 20,
        "eval_seed": 100,
        "cells": [
            {
                "env": "GridWorldWall-v0",
                "algo": "bc2l",
                "variant": "base",
                "per_seed": [_seed(0, 10, 0.0), _seed(1, 20, 0.5), _seed(2, 99, 1.0)],
            },
            {"env": "GridWorldWall-v0", "algo": "vicrl", "variant": "base", "per_seed": [_seed(0, 5, 0.0)]},
            {
                "env": "GridWorldSquare-v0",
                "algo": "mecl",
                "variant": "base",
                "per_seed": [_seed(0, 7, None), _seed(1, 8, 0.0)],
            },
            {"env": "GridWorldZigzag-v0", "algo": "mecl", "variant": "base", "per_seed": [_seed(0, 1, 0.0)]},
        ],
    }
    summary.update(changes)
    return summary


@pytest.fixture
def study(tmp_path):
    path = tmp_path / "study.yml"
    path.write_text(STUDY)
    return load_suite(str(path), dry_build=False), str(path)


def test_the_level_0_is_the_other_reports_runs_of_the_studys_envs_methods_and_seeds(study):
    suite, _ = study
    baseline = study_baseline(table_summary(), suite, "results/table")
    assert baseline["source"] == "results/table" and baseline["suite"] == "table" and baseline["recipe_version"] == "v2"
    wall, square = baseline["cells"]
    # The study's seeds only (seed 2 is not one of them; GridWorldSquare trains seed 0 alone); vicrl is no method of it
    assert (wall["env"], wall["algo"], [s["seed"] for s in wall["per_seed"]]) == ("GridWorldWall-v0", "bc2l", [0, 1])
    assert wall["feasible_reward_mean"] == 15.0 and wall["violation_rate_mean"] == 0.25
    assert (square["env"], square["algo"], [s["seed"] for s in square["per_seed"]]) == ("GridWorldSquare-v0", "mecl", [0])
    # A violation rate its report has as null is no number, and the mean of none is nan
    assert math.isnan(square["per_seed"][0]["violation_rate"]) and math.isnan(square["violation_rate_mean"])
    assert square["feasible_reward_mean"] == 7.0


@pytest.mark.parametrize(
    "change, message",
    [
        ({"eval_episodes": 10}, r"evaluates its runs otherwise than suite 'study' \(eval_episodes 10 there, 20 here\)"),
        ({"model": "best"}, r"model 'best' there, 'final' here"),
        ({"suite": "study"}, "is a report of suite 'study' itself"),
        ({"cells": []}, "has no run of the envs, methods and seeds of suite 'study'"),
    ],
)
def test_a_report_that_is_not_the_level_0_is_refused(study, change, message):
    suite, _ = study
    with pytest.raises(SuiteError, match=message):
        study_baseline(table_summary(**change), suite, "results/table")


def test_other_recipes_several_variants_or_no_recipe_version_are_refused(study, tmp_path):
    suite, path = study
    summary = table_summary()
    summary["cells"][0]["per_seed"][1]["recipe_version"] = "v1"
    with pytest.raises(SuiteError, match="bc2l on GridWorldWall-v0 in 'r' ran recipe version v1, suite 'study' runs v2"):
        study_baseline(summary, suite, "r")
    del summary["cells"][0]["per_seed"][1]["recipe_version"]
    with pytest.raises(SuiteError, match="ran recipe version none recorded, suite 'study' runs v2"):
        study_baseline(summary, suite, "r")
    # Seeds the study does not train do not count: seed 2 at another version is left out, not refused
    summary = table_summary()
    summary["cells"][0]["per_seed"][2]["recipe_version"] = "v1"
    assert len(study_baseline(summary, suite, "r")["cells"]) == 2
    summary["cells"].append({**summary["cells"][0], "variant": "other"})
    with pytest.raises(SuiteError, match="several variants of bc2l on GridWorldWall-v0"):
        study_baseline(summary, suite, "r")
    pathlib.Path(path).write_text(STUDY.replace("recipe_version: v2\n", ""))
    with pytest.raises(SuiteError, match="suite 'study' names no recipe_version"):
        study_baseline(table_summary(), load_suite(path, dry_build=False), "r")


def test_reading_a_folder_without_an_intact_report_is_refused(tmp_path):
    with pytest.raises(SuiteError, match=r"--baseline: no report in .* \(no summary.json\)"):
        read_report_summary(str(tmp_path))
    (tmp_path / "summary.json").write_text('{"cells": [')
    with pytest.raises(SuiteError, match="is not a report's summary"):
        read_report_summary(str(tmp_path))


def _results(suite) -> list:
    """bc2l on GridWorldWall at both levels: feasible reward 30 and 40 (0.01), 50 and 60 (0.1), no violation."""
    values = {"sigma-0.01": (30.0, 40.0), "sigma-0.1": (50.0, 60.0)}
    return [
        (run, RunResult(run.name, run.algo, run.env_id, run.seed, 100, 1.0, 0.0, values[run.variant][run.seed], 1.0, 20))
        for run in suite.runs()
        if run.algo == "bc2l" and run.env_id.endswith("GridWorldWall-v0")
    ]


def _facts(results: list) -> dict:
    """Each run's recorded recipe version: the study's."""
    return {result.run: {"recipe_version": "v2"} for _, result in results}


def test_the_figure_draws_the_level_0_beside_the_studys_levels(study):
    suite, _ = study
    summary = summarise_suite(suite, suite.runs(), _results(suite), _facts(_results(suite)))
    summary["study_baseline"] = study_baseline(table_summary(), suite, "results/table")
    figure = study_figure(summary, *study_axis(suite), baseline=summary["study_baseline"])
    violation_ax, reward_ax = figure.axes  # GridWorldSquare has no run of the study: no column of its own
    [line] = reward_ax.get_lines()
    assert list(line.get_xdata()) == [0.0, 0.01, 0.1] and list(line.get_ydata()) == [15.0, 35.0, 55.0]
    assert list(violation_ax.get_lines()[0].get_ydata()) == [0.25, 0.0, 0.0]
    # Level 0 on a noise axis: symlog, linear up to the smallest noise
    assert violation_ax.get_xscale() == "symlog"
    dots = sorted(np.concatenate([c.get_offsets()[:, 1] for c in reward_ax.collections]))
    assert dots == [10.0, 20.0, 30.0, 40.0, 50.0, 60.0]
    # While the study holds fewer seeds than its level 0, the level 0 takes the study's seeds only
    partial = [(run, result) for run, result in _results(suite) if run.seed == 0]
    summary_0 = summarise_suite(suite, suite.runs(), partial, _facts(partial))
    reward_ax = study_figure(summary_0, *study_axis(suite), baseline=summary["study_baseline"]).axes[1]
    assert list(reward_ax.get_lines()[0].get_ydata()) == [10.0, 30.0, 50.0]
    # The report says whose runs the level 0 is
    assert baseline_line(summary) == (
        "Level 0 of study.png: 3 runs of the report of suite 'table' (results/table) on GridWorldWall-v0, GridWorldSquare-v0, "
        "the same seeds, recipe version (v2) and evaluation as this study, without its change."
    )
    assert baseline_line(summary) in markdown_table(summary)
    assert "Level 0" not in markdown_table({**summary, "study_baseline": None})


def test_report_keeps_the_baseline_through_updates_and_refuses_it_for_a_suite_that_is_no_study(study, tmp_path, monkeypatch):
    suite, path = study
    table = tmp_path / "table"
    table.mkdir()
    (table / "summary.json").write_text(json.dumps(table_summary()))
    results = _results(suite)
    monkeypatch.setattr(cli, "evaluate_finished", lambda runs, *args, **kwargs: [item for item in results if item[0] in runs])
    monkeypatch.setattr(cli, "constraint_metrics", lambda results, *args, **kwargs: _facts(results))
    monkeypatch.setattr(cli, "keep_transfer_references", lambda *args, **kwargs: [])
    monkeypatch.setattr(cli, "keep_probe_policies", lambda *args, **kwargs: [])
    root, output = str(tmp_path / "logs"), str(tmp_path / "results" / "study")
    argv = ["report", path, "-f", root, "-o", output, "--no-figures"]
    assert cli.main([*argv, "--baseline", str(table)]) == 0
    summary = json.loads(pathlib.Path(output, "summary.json").read_text())
    assert summary["study_baseline"]["source"] == str(table) and len(summary["study_baseline"]["cells"]) == 2
    assert "Level 0 of study.png: 3 runs" in pathlib.Path(output, "table.md").read_text()
    # --update without --baseline keeps the level 0 the report had; a report written anew without it has none
    assert cli.main([*argv, "--update", "--only", "variant=sigma-0.1"]) == 0
    assert json.loads(pathlib.Path(output, "summary.json").read_text())["study_baseline"] == summary["study_baseline"]
    assert cli.main(argv) == 0
    assert "study_baseline" not in json.loads(pathlib.Path(output, "summary.json").read_text())
    # A suite whose variants vary nothing has no level 0
    pathlib.Path(path).write_text(STUDY.replace("sigma-0.01: {transition_noise: 0.01}", "plain: {}"))
    assert cli.main([*argv, "--baseline", str(table)]) != 0


def test_the_report_tables_each_method_by_level_with_its_level_0(study):
    suite, _ = study
    results = _results(suite)
    summary = summarise_suite(suite, suite.runs(), results, _facts(results))
    assert summary["study"] == {"setting": "transition_noise", "levels": {"sigma-0.1": 0.1, "sigma-0.01": 0.01}}
    without = study_level_lines(summary)
    assert without[-2:] == ["|---|---|---|---|", "| GridWorldWall-v0 | bc2l | 35.0 / 0% (2) | 55.0 / 0% (2) |"]
    assert without[-3] == "| env | algo | sigma-0.01 | sigma-0.1 |"  # in order of the level
    # With the level 0, as summary.json gives it back (a rate with no number is null there)
    baseline = study_baseline(table_summary(), suite, "results/table")
    summary["study_baseline"] = json.loads(json.dumps(baseline, allow_nan=True).replace("NaN", "null"))
    lines = study_level_lines(summary)
    assert "level 0: the same seeds' runs of suite 'table'" in lines[1]
    by_level = lines.index("| env | algo | level 0 (table) | sigma-0.01 | sigma-0.1 |")
    assert lines[by_level : by_level + 3] == [
        "| env | algo | level 0 (table) | sigma-0.01 | sigma-0.1 |",
        "|---|---|---|---|---|",
        "| GridWorldWall-v0 | bc2l | 15.0 / 25% (2) | 35.0 / 0% (2) | 55.0 / 0% (2) |",
    ]
    assert "\n".join(lines) in markdown_table(summary)
    # Then each level's change from level 0, paired by seed: +20 and +20 in reward, -0.5 and 0 in rate, at sigma 1e-2
    paired = lines.index("| env | algo | sigma-0.01 | sigma-0.1 |")
    assert lines[paired - 2].startswith("Change from level 0, paired by seed")
    assert lines[paired + 2] == (
        "| GridWorldWall-v0 | bc2l | +20.0 / -25 pts (2 paired, 0 lower, sign test p = 0.5) "
        "| +40.0 / -25 pts (2 paired, 0 lower, sign test p = 0.5) |"
    )
    assert "Change from level 0" not in "\n".join(without)
    # A method with runs at one level only, and one whose level-0 rate has no number: "-"
    mecl = [(run, RunResult(run.name, "mecl", run.env_id, 0, 100, 1.0, 0.5, 7.0, 7.0, 20)) for run in suite.runs()]
    mecl = [item for item in mecl if item[0].algo == "mecl" and item[0].variant == "sigma-0.1" and "Square" in item[0].env_id]
    summary = summarise_suite(suite, suite.runs(), [*results, *mecl], _facts([*results, *mecl]))
    summary["study_baseline"] = json.loads(json.dumps(baseline, allow_nan=True).replace("NaN", "null"))
    assert "| GridWorldSquare-v0 | mecl | 7.00 / - (1) | - | 7.00 / 50% (1) |" in study_level_lines(summary)
    # A pair without a level-0 rate changes the reward alone; a level without the method's runs has no pair
    assert "| GridWorldSquare-v0 | mecl | - | +0.00 / - (1 paired, 0 lower, no seed changed) |" in study_level_lines(summary)
    # A suite that is no study has no such table
    assert study_level_lines({**summary, "study": None}) == [] and "study" not in summarise_suite(
        load_suite("smoke", dry_build=False), [], []
    )


def test_the_study_tables_and_draws_each_learned_costs_identification_by_level(study):
    suite, _ = study
    results = _results(suite)
    # bc2l's AUROC 0.9 / 0.6 at sigma 1e-2 and 0.7 / 0.8 at 1e-1 (seeds 0 / 1), its untrained nets 0.2-0.75 on every run
    auroc = {("sigma-0.01", 0): 0.9, ("sigma-0.01", 1): 0.6, ("sigma-0.1", 0): 0.7, ("sigma-0.1", 1): 0.8}
    facts = {
        result.run: {
            "recipe_version": "v2",
            "identification_auroc": auroc[(run.variant, run.seed)],
            "untrained_auroc_low": 0.2,
            "untrained_auroc_high": 0.75,
        }
        for run, result in results
    }
    summary = summarise_suite(suite, suite.runs(), results, facts)
    # Level 0: seed 0 above its untrained nets, seed 1 at their highest (not above); seed 2 is not the study's
    table = table_summary()
    for seed, value in zip(table["cells"][0]["per_seed"], (0.95, 0.5, 0.99), strict=True):
        seed.update(identification_auroc=value, untrained_auroc_low=0.1, untrained_auroc_high=0.5)
    baseline = study_baseline(table, suite, "results/table")
    summary["study_baseline"] = json.loads(json.dumps(baseline, allow_nan=True).replace("NaN", "null"))
    lines = study_level_lines(summary)
    heading = next(index for index, line in enumerate(lines) if line.startswith("Identification by level"))
    assert lines[heading + 2 :] == [
        "| env | algo | level 0 (table) | sigma-0.01 | sigma-0.1 |",
        "|---|---|---|---|---|",
        "| GridWorldWall-v0 | bc2l | 0.72 (1 of 2 above untrained) | 0.75 (1 of 2 above untrained) | "
        "0.75 (1 of 2 above untrained) |",
    ]
    # Untrained nets that all scored alike are named: above them is a low bar
    for cell in summary["cells"]:
        for seed in cell["per_seed"]:
            seed.update(untrained_auroc_low=0.5, untrained_auroc_high=0.5)
    assert "| 0.75 (2 of 2 above untrained, all 0.50) |" in study_level_lines(summary)[-1]
    # The figure's third row: the mean AUROC per level, the seeds as dots, over the untrained nets' band
    figure = study_figure(summary, *study_axis(suite), baseline=baseline)
    auroc_ax = figure.axes[2]
    assert list(auroc_ax.get_lines()[0].get_ydata()) == pytest.approx([0.725, 0.75, 0.75])
    assert sorted(np.concatenate([c.get_offsets()[:, 1] for c in auroc_ax.collections])) == [0.5, 0.6, 0.7, 0.8, 0.9, 0.95]
    [band] = auroc_ax.patches  # level 0's runs still have a range (0.1-0.5); the study's now score alike
    assert band.get_y() == pytest.approx(0.1) and band.get_height() == pytest.approx(0.4)
    # A study without identification keeps its two rows and no identification table
    plain = summarise_suite(suite, suite.runs(), results, _facts(results))
    assert len(study_figure(plain, *study_axis(suite)).axes) == 2
    assert not any(line.startswith("Identification by level") for line in study_level_lines(plain))


def test_the_level_0_keeps_null_identification_as_nan_and_a_seed_without_untrained_nets_is_not_above(study):
    suite, _ = study
    table = table_summary()
    # Seed 0 scored above its untrained nets; seed 1's AUROC is null in its report; seed 2 is not the study's
    table["cells"][0]["per_seed"][0].update(identification_auroc=0.9, untrained_auroc_low=0.1, untrained_auroc_high=0.5)
    table["cells"][0]["per_seed"][1].update(identification_auroc=None, untrained_auroc_low=None, untrained_auroc_high=None)
    baseline = study_baseline(table, suite, "results/table")
    wall = next(cell for cell in baseline["cells"] if cell["env"] == "GridWorldWall-v0")
    assert wall["per_seed"][0]["identification_auroc"] == 0.9
    assert all(math.isnan(wall["per_seed"][1][key]) for key in ("identification_auroc", "untrained_auroc_high"))
    # A run whose report has no identification keys (a reference row) gains none
    square = next(cell for cell in baseline["cells"] if cell["env"] == "GridWorldSquare-v0")
    assert all("identification_auroc" not in seed for seed in square["per_seed"])
    # In the table: the null seed is left out of the mean and the count; a seed with an AUROC but no untrained range
    # counts, and is not above
    assert _level_identification_text(wall) == "0.90 (1 of 1 above untrained)"
    wall["per_seed"][1].update(identification_auroc=0.95)
    assert _level_identification_text(wall) == "0.93 (1 of 2 above untrained)"
    assert _level_identification_text(square) == ""


DEMONSTRATION_STUDY = """\
recipe_version: v2
envs: [GridWorldWall-v0]
algos: [bc2l]
seeds: [0, 1]
variants:
  violating-0.2: {violating_fraction: 0.2}
  violating-0.5: {violating_fraction: 0.5}
eval_episodes: 20
eval_budget: episodes
"""


def test_a_study_of_the_demonstrations_takes_the_reference_rows_from_level_0_for_every_level(study, tmp_path):
    path = tmp_path / "demonstrations.yml"
    path.write_text(DEMONSTRATION_STUDY)
    suite = load_suite(str(path), dry_build=False)
    table = table_summary()
    table["cells"] += [
        {"env": "GridWorldWall-v0", "algo": "ppo", "variant": "base", "per_seed": [_seed(0, 2, 1.0), _seed(1, 4, 0.5)]},
        {"env": "GridWorldWall-v0", "algo": "ppolag", "variant": "base", "per_seed": [_seed(0, 8, 0.0), _seed(1, 9, 0.0)]},
    ]
    baseline = study_baseline(table, suite, "results/table")
    # PPO and the oracle learn from no demonstrations: their level-0 runs stand for every share; vicrl is no row of it
    assert [(cell["algo"], cell.get("every_level", False)) for cell in baseline["cells"]] == [
        ("bc2l", False),
        ("ppo", True),
        ("ppolag", True),
    ]
    # A noise study changes what the reference rows meet: it trains them itself and takes none from level 0
    assert [cell["algo"] for cell in study_baseline(table, study[0], "results/table")["cells"]] == ["bc2l", "mecl"]
    values = {"violating-0.2": (30.0, 40.0), "violating-0.5": (50.0, 60.0)}
    results = [
        (run, RunResult(run.name, run.algo, run.env_id, run.seed, 100, 1.0, 0.0, values[run.variant][run.seed], 1.0, 20))
        for run in suite.runs()
    ]
    summary = summarise_suite(suite, suite.runs(), results, _facts(results))
    # What each level's demonstrations hold, the clean dataset as level 0: 10 and 25 of 50 trajectories break the wall
    held = summary["study"]["demonstrations"]["GridWorldWall-v0"]
    assert [held[level]["violating_trajectories"] for level in ("level 0", "violating-0.2", "violating-0.5")] == [0, 10, 25]
    assert held["level 0"] == {
        "trajectories": 50,
        "violating_trajectories": 0,
        "violating_step_share": 0.0,
        "mean_return": 1.0,
    }
    summary["study_baseline"] = baseline
    lines = study_level_lines(summary)
    assert "ppo and ppolag learn from no demonstrations: their level-0 runs stand for every level" in lines[1]
    assert "| GridWorldWall-v0 | 0 of 50 / 0% / 1.00 | 10 of 50 / 3% / 1.00 | 25 of 50 / 6% / 1.00 |" in lines
    # An env of the suite the report has no run of (a report --only one env) has no row
    summary["study"]["demonstrations"]["GridWorldSquare-v0"] = held
    assert not any(line.startswith("| GridWorldSquare-v0") for line in study_level_lines(summary))
    noise = summarise_suite(study[0], study[0].runs(), _results(study[0]), _facts(_results(study[0])))
    assert "demonstrations" not in noise["study"]
    by_level = lines.index("| env | algo | level 0 (table) | violating-0.2 | violating-0.5 |")
    assert lines[by_level + 2 : by_level + 5] == [
        "| GridWorldWall-v0 | bc2l | 15.0 / 25% (2) | 35.0 / 0% (2) | 55.0 / 0% (2) |",
        "| GridWorldWall-v0 | ppo | 3.00 / 75% (2) | as level 0 | as level 0 |",
        "| GridWorldWall-v0 | ppolag | 8.50 / 0% (2) | as level 0 | as level 0 |",
    ]
    # No change from level 0 to pair for them
    assert not any(line.startswith("| GridWorldWall-v0 | ppo") for line in lines[by_level + 5 :])
    # The figure: each a dashed line across every share at its level-0 mean, its seeds' dots at level 0
    reward_ax = study_figure(summary, *study_axis(suite), baseline=baseline).axes[1]
    dashed = [line for line in reward_ax.get_lines() if line.get_linestyle() == "--"]
    assert [(list(line.get_xdata()), list(line.get_ydata())) for line in dashed] == [
        ([0.0, 0.5], [3.0, 3.0]),
        ([0.0, 0.5], [8.5, 8.5]),
    ]
    # While the study holds seed 0 only, they take that seed too
    partial = [(run, result) for run, result in results if run.seed == 0]
    summary_0 = summarise_suite(suite, suite.runs(), partial, _facts(partial))
    summary_0["study_baseline"] = baseline
    assert "| GridWorldWall-v0 | ppolag | 8.00 / 0% (1) | as level 0 | as level 0 |" in study_level_lines(summary_0)
