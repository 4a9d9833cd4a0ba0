"""The reference rows of a benchmark: PPO and the oracle on the ICRL cells' forward learner, normalised scores, success."""

import dataclasses
import json
import math
import pathlib

import pytest

from sb3_icrl.benchmark import load_suite, summarise_suite
from sb3_icrl.benchmark.report import previous_results
from sb3_icrl.benchmark.report_figures import normalised_scores_by_algo, performance_profile_figure
from sb3_icrl.benchmark.report_numbers import finite_or_null
from sb3_icrl.benchmark.report_text import markdown_table
from sb3_icrl.benchmark.suite import SuiteError
from sb3_icrl.common.statistics import wilson_interval
from sb3_icrl.zoo.compare import RunResult
from sb3_icrl.zoo.hyperparams import HyperparameterError, load_hyperparams
from sb3_icrl.zoo.train import get_parser, train

SUITE = """\
description: reference rows
envs: [GridWorldWall-v0]
algos: [mecl, ppo, ppolag]
forward_recipe: mecl
seeds: [0, 1, 2]
success: {max_violation_rate: 0.05, min_normalised_score: 0.5}
"""


def write(tmp_path, text: str) -> str:
    path = tmp_path / "suite.yml"
    path.write_text(text)
    return str(path)


def test_reference_rows_take_the_forward_learner_of_the_recipe() -> None:
    mecl, _ = load_hyperparams("mecl", "BlockedHalfCheetah-v0")
    oracle, source = load_hyperparams("ppolag", "BlockedHalfCheetah-v0", forward_recipe="mecl")
    ppo, _ = load_hyperparams("ppo", "BlockedHalfCheetah-v0", forward_recipe="mecl")
    assert source == "mecl:BlockedHalfCheetah-v0"
    shared = ("n_timesteps", "n_envs", "n_steps", "batch_size", "n_epochs", "learning_rate", "gamma", "policy_kwargs")
    assert all(oracle[key] == mecl[key] == ppo[key] for key in shared)
    # The constraint model's settings go; the multiplier stays for the oracle, on the true cost's budget
    assert not any(key.startswith("constraint_") or key in ("update_every", "regularizer_coef") for key in oracle)
    assert mecl["cost_budget"] == "expert" and oracle["cost_budget"] == 0.0
    assert oracle["lagrange_update"] == mecl["lagrange_update"] == "pid"
    # MECL's per-step budget statistic is its default, PPOLagrangian's is per episode: it is written out
    assert "budget_statistic" not in mecl and oracle["budget_statistic"] == "step"
    assert not any(key in ppo for key in ("cost_budget", "lagrange_update", "lagrange_kwargs", "budget_statistic"))
    # Overrides still apply last
    assert load_hyperparams("ppo", "BlockedHalfCheetah-v0", {"n_envs": 8}, forward_recipe="mecl")[0]["n_envs"] == 8


def test_a_forward_recipe_is_for_the_reference_rows_only() -> None:
    with pytest.raises(HyperparameterError, match="reference rows"):
        load_hyperparams("vicrl", "BlockedHalfCheetah-v0", forward_recipe="mecl")
    with pytest.raises(HyperparameterError, match="Unknown forward recipe"):
        load_hyperparams("ppo", "BlockedHalfCheetah-v0", forward_recipe="airl")


def test_train_records_the_reference_rows_recipe(tmp_path) -> None:
    argv = ["--algo", "ppo", "--env", "GridWorldWall-v0", "--forward-recipe", "mecl", "-n", "64", "--seed", "0"]
    # The grid recipes plan; a reference row learns by policy gradient
    argv += [
        "-f",
        str(tmp_path),
        "--eval-freq",
        "0",
        "-params",
        "n_steps:32",
        "batch_size:32",
        "forward_solver:policy_gradient",
    ]
    folder = train(get_parser().parse_args(argv), argv)
    config = (tmp_path / "ppo" / "GridWorldWall-v0_1" / "GridWorldWall-v0" / "config.yml").read_text()
    assert folder.endswith("GridWorldWall-v0_1") and "n_steps: 32" in config and "cost_budget" not in config
    with pytest.raises(ValueError, match="leave out -conf"):
        train(get_parser().parse_args([*argv, "-conf", '{"n_steps": 16}']), argv)


def test_suite_passes_the_forward_recipe_to_the_reference_rows_alone(tmp_path) -> None:
    suite = load_suite(write(tmp_path, SUITE))
    assert suite.forward_recipe == "mecl" and suite.success == {"max_violation_rate": 0.05, "min_normalised_score": 0.5}
    for run in suite.runs():
        argv = run.train_argv("logs")
        assert ("--forward-recipe" in argv) == (run.algo != "mecl")
        if run.algo != "mecl":
            assert argv[argv.index("--forward-recipe") + 1] == "mecl"


@pytest.mark.parametrize(
    "change, line, message",
    [
        (("forward_recipe: mecl", "forward_recipe: airl"), 4, "unknown algorithm 'airl'"),
        (("algos: [mecl, ppo, ppolag]", "algos: [mecl]"), 6, "needs the normalised score"),
        (("min_normalised_score: 0.5}", "min_normalised_score: high}"), 6, "is a number"),
        (("max_violation_rate: 0.05", "max_violation_rate: 5"), 6, r"within \[0, 1\]"),
        (("success: {max_violation_rate: 0.05, min_normalised_score: 0.5}", "success: {max_violation: 0.05}"), 6, "maps"),
    ],
)
def test_bad_reference_settings_name_the_line(tmp_path, change, line, message) -> None:
    text = SUITE.replace(*change)
    if change[1] == "algos: [mecl]":
        text = text.replace("forward_recipe: mecl\n", "")
        line -= 1
    with pytest.raises(SuiteError, match=rf"line {line}: .*{message}"):
        load_suite(write(tmp_path, text))


def _result(algo: str, seed: int, feasible: float, violation: float) -> RunResult:
    return RunResult(f"r/{algo}/{seed}", algo, "sb3_icrl/GridWorldWall-v0", seed, 100, 1.0, violation, feasible, feasible, 20)


def test_normalised_scores_and_success_by_hand(tmp_path) -> None:
    suite = load_suite(write(tmp_path, SUITE))
    values = {
        "ppo": [(10.0, 0.9), (20.0, 1.0), (30.0, 0.8)],  # mean 20: the score's 0
        "ppolag": [(100.0, 0.0), (120.0, 0.0), (140.0, 0.0)],  # mean 120: the score's 1
        "mecl": [(70.0, 0.0), (95.0, 0.1), (170.0, 0.05)],
    }
    results = [(run, _result(run.algo, run.seed, *values[run.algo][run.seed])) for run in suite.runs()]
    summary = summarise_suite(suite, suite.runs(), results)
    mecl = next(cell for cell in summary["cells"] if cell["algo"] == "mecl")
    assert [seed["normalised_score"] for seed in mecl["per_seed"]] == pytest.approx([0.5, 0.75, 1.5])
    assert mecl["reference_feasible_reward"] == {"ppo": 20.0, "ppolag": 120.0}
    # seed 1 breaks the constraint too often; seeds 0 and 2 are feasible enough and score at least 0.5
    assert [seed["success"] for seed in mecl["per_seed"]] == [True, False, True]
    assert mecl["success_count"] == 2 and mecl["success_ci95"] == pytest.approx(list(wilson_interval(2, 3)))
    # Three seeds: the cell shows mean and [min, max], not an IQM with an interval
    assert mecl["normalised_score_spread"] == {
        "kind": "mean",
        "centre": pytest.approx(11 / 12),
        "interval": [0.5, 1.5],
        "n": 3,
    }
    assert "feasible_reward_iqm" not in mecl and mecl["feasible_reward_spread"]["interval"] == [70.0, 170.0]
    ppo = next(cell for cell in summary["cells"] if cell["algo"] == "ppo")
    assert [seed["normalised_score"] for seed in ppo["per_seed"]] == pytest.approx([-0.1, 0.0, 0.1])
    (aggregate,) = [entry for entry in summary["normalised_aggregates"] if entry["algo"] == "mecl"]
    assert aggregate["normalised_score_mean"] == pytest.approx(11 / 12) and aggregate["n_runs"] == 3
    assert aggregate["optimality_gap"] == pytest.approx((0.5 + 0.25 + 0.0) / 3)
    assert summary["improvements"] == []  # one method besides the reference rows: nothing to compare
    table = markdown_table(summary)
    assert "| mean 0.92 [0.50, 1.50] | 2/3 [" in table and "0: 70.0 / 0% / 0.50" in table
    assert "Success: violation rate <= 5% and normalised score >= 0.5" in table


def test_cells_without_both_reference_rows_have_no_score(tmp_path) -> None:
    suite = load_suite(
        write(
            tmp_path,
            SUITE.replace("algos: [mecl, ppo, ppolag]", "algos: [mecl, ppo]").replace(
                "success: {max_violation_rate: 0.05, min_normalised_score: 0.5}\n", ""
            ),
        )
    )
    results = [(run, _result(run.algo, run.seed, 1.0 + run.seed, 0.0)) for run in suite.runs()]
    summary = summarise_suite(suite, suite.runs(), results)
    assert not any("normalised_score_mean" in cell for cell in summary["cells"])
    assert summary["normalised_aggregates"] == [] and "normalised score" not in markdown_table(summary)
    assert math.isnan(summary["cells"][0]["per_seed"][0].get("normalised_score", math.nan))


def test_an_updated_report_keeps_no_score_its_reference_rows_no_longer_give(tmp_path) -> None:
    suite = load_suite(write(tmp_path, SUITE))
    values = {"ppo": (0.0, 1.0), "ppolag": (10.0, 0.0), "mecl": (8.0, 0.0)}
    results = [(run, _result(run.algo, run.seed, *values[run.algo])) for run in suite.runs()]
    earlier = json.loads(json.dumps(finite_or_null(summarise_suite(suite, suite.runs(), results))))
    assert earlier["cells"][0]["per_seed"][0]["normalised_score"] == pytest.approx(0.8)
    kept, metrics, _ = previous_results(earlier, suite, "logs")
    # report --update of the oracle's seeds, which have not finished again: its row leaves the report
    summary = summarise_suite(suite, suite.runs(), [(run, result) for run, result in kept if run.algo != "ppolag"], metrics)
    mecl = next(cell for cell in summary["cells"] if cell["algo"] == "mecl")
    assert not any("normalised_score" in seed or "success" in seed for seed in mecl["per_seed"])
    assert normalised_scores_by_algo(summary) == {} and "/ 0.80" not in markdown_table(summary)
    # An oracle that now breaks its constraint normalises nothing either, whatever the earlier report held
    broken = [
        (run, dataclasses.replace(result, violation_rate=1.0) if run.algo == "ppolag" else result) for run, result in kept
    ]
    summary = summarise_suite(suite, suite.runs(), broken, metrics)
    assert next(cell for cell in summary["cells"] if cell["algo"] == "mecl")["normalisation_problem"]
    assert not any("normalised_score" in seed for cell in summary["cells"] for seed in cell["per_seed"])


def test_runs_record_the_suites_recipe_version_and_a_report_refuses_to_mix_them(tmp_path) -> None:
    suite = load_suite(write(tmp_path, SUITE + "recipe_version: 2026-11-a\n"))
    assert suite.recipe_version == "2026-11-a"
    argv = suite.runs()[0].train_argv("logs")
    assert argv[argv.index("--recipe-version") + 1] == "2026-11-a"
    args = get_parser().parse_args(["--algo", "ppo", "--env", "GridWorldWall-v0", "--recipe-version", "2026-11-a"])
    assert args.recipe_version == "2026-11-a"  # args.yml records every argument

    values = {"ppo": (10.0, 1.0), "ppolag": (20.0, 0.0), "mecl": (15.0, 0.0)}
    results = [(run, _result(run.algo, run.seed, *values[run.algo])) for run in suite.runs()]
    metrics = {result.run: {"recipe_version": "2026-11-a"} for _, result in results}
    summary = summarise_suite(suite, suite.runs(), results, metrics)
    assert {cell["recipe_version"] for cell in summary["cells"]} == {"2026-11-a"}
    mecl_seed_1 = next(result.run for run, result in results if run.algo == "mecl" and run.seed == 1)
    metrics[mecl_seed_1] = {"recipe_version": "2026-11-b"}
    with pytest.raises(
        ValueError, match=r"mecl runs on GridWorldWall-v0 \(base\) used different recipe versions .*seed 1: 2026-11-b"
    ):
        summarise_suite(suite, suite.runs(), results, metrics)
    metrics[mecl_seed_1] = {}
    with pytest.raises(ValueError, match="seed 1: none recorded"):
        summarise_suite(suite, suite.runs(), results, metrics)


def test_a_recipe_version_is_a_name(tmp_path) -> None:
    with pytest.raises(SuiteError, match="line 7: `recipe_version` is a name or a number"):
        load_suite(write(tmp_path, SUITE + "recipe_version: [a, b]\n"))


def test_an_oracle_that_breaks_its_constraint_normalises_nothing(tmp_path) -> None:
    suite = load_suite(write(tmp_path, SUITE))
    values = {"ppo": (10.0, 1.0), "ppolag": (12.0, 1.0), "mecl": (11.0, 0.0)}  # the oracle violates in every episode
    results = [(run, _result(run.algo, run.seed, *values[run.algo])) for run in suite.runs()]
    summary = summarise_suite(suite, suite.runs(), results)
    mecl = next(cell for cell in summary["cells"] if cell["algo"] == "mecl")
    assert mecl["normalisation_problem"] == "the oracle breaks the constraint in 100% of episodes"
    assert "normalised_score" not in mecl["per_seed"][0] and "success_probability" not in mecl
    assert "| none: the oracle breaks the constraint in 100% of episodes |" in markdown_table(summary)
    values["ppolag"] = (9.0, 0.0)  # feasible, but below PPO
    results = [(run, _result(run.algo, run.seed, *values[run.algo])) for run in suite.runs()]
    cell = next(c for c in summarise_suite(suite, suite.runs(), results)["cells"] if c["algo"] == "mecl")
    assert cell["normalisation_problem"] == "the oracle earns no more feasible reward than PPO"


def test_driving_envs_are_evaluated_on_their_test_recordings(tmp_path, monkeypatch) -> None:
    import json as json_module

    from sb3_icrl.benchmark import report
    from sb3_icrl.envs import heldout_env_kwargs

    assert heldout_env_kwargs("sb3_icrl/HighwayVelocity-v0") == {"split": "test"}
    assert heldout_env_kwargs("sb3_icrl/BlockedHalfCheetah-v0") == {}
    suite = load_suite(write(tmp_path, SUITE.replace("GridWorldWall-v0", "HighwayVelocity-v0").replace("mecl, ", "")))
    run = suite.runs()[0]
    folder = pathlib.Path(run.run_folder(tmp_path))
    folder.mkdir(parents=True)
    (folder / "finished.json").write_text("{}")
    asked = []

    def evaluate(path, steps, seed, load_best=False, env_kwargs=None, n_episodes=None):
        asked.append(env_kwargs)
        return _result(run.algo, run.seed, 1.0, 0.0)

    monkeypatch.setattr(report, "evaluate_run", evaluate)
    report.evaluate_finished([run], str(tmp_path), suite, log=lambda line: None)
    assert asked == [{"split": "test"}]
    cache = json_module.loads((folder / report.HELDOUT_FILE).read_text())
    assert cache["settings"]["env_kwargs"] == {"split": "test"}
    # A cache made before, on the training recordings, is evaluated again
    del cache["settings"]["env_kwargs"]
    (folder / report.HELDOUT_FILE).write_text(json_module.dumps(cache))
    report.evaluate_finished([run], str(tmp_path), suite, log=lambda line: None)
    assert len(asked) == 2


def test_performance_profile_figure_draws_each_algorithm_with_normalised_scores():
    def cell(env, algo, scores):
        return {"env": env, "algo": algo, "per_seed": [{"normalised_score": score} for score in scores]}

    summary = {
        "cells": [
            cell("A-v0", "mecl", [0.2, 0.9]),
            cell("B-v0", "mecl", [0.5, float("nan")]),  # a seed without a score is left out
            cell("A-v0", "vicrl", [1.0, 1.1]),
            {"env": "A-v0", "algo": "gacl", "per_seed": [{"feasible_reward": 1.0}]},  # no reference rows: no score
        ]
    }
    assert normalised_scores_by_algo(summary) == {"mecl": [[0.2, 0.9], [0.5]], "vicrl": [[1.0, 1.1]]}
    figure = performance_profile_figure(summary)
    (ax,) = figure.axes
    assert [line.get_label() for line in ax.get_lines() if not line.get_label().startswith("_")] == [
        "mecl (2 envs, 3 runs)",
        "vicrl (1 env, 2 runs)",
    ]
    assert performance_profile_figure({"cells": [summary["cells"][3]]}) is None


def test_headline_envs_alone_make_the_aggregates_and_the_others_are_marked(tmp_path) -> None:
    text = SUITE.replace("envs: [GridWorldWall-v0]", "envs: [GridWorldWall-v0, GridWorldSquare-v0]")
    suite = load_suite(write(tmp_path, text + "headline_envs: [GridWorldSquare-v0]\n"))
    assert suite.headline_envs == ("GridWorldSquare-v0",)
    values = {"ppo": 0.0, "ppolag": 10.0, "mecl": 5.0}
    results = []
    for run in suite.runs():
        # On the wall map MECL matches the oracle; on the headline square map it scores 0.5
        feasible = 10.0 if (run.algo, run.env_id) == ("mecl", "sb3_icrl/GridWorldWall-v0") else values[run.algo]
        results.append(
            (
                run,
                RunResult(
                    f"r/{run.env_id}/{run.algo}/{run.seed}",
                    run.algo,
                    run.env_id,
                    run.seed,
                    100,
                    1.0,
                    0.0,
                    feasible,
                    feasible,
                    20,
                ),
            )
        )
    summary = summarise_suite(suite, suite.runs(), results)
    (aggregate,) = [entry for entry in summary["normalised_aggregates"] if entry["algo"] == "mecl"]
    assert aggregate["n_cells"] == 1 and aggregate["normalised_score_mean"] == pytest.approx(0.5)
    assert normalised_scores_by_algo(summary)["mecl"] == [[0.5, 0.5, 0.5]]
    assert {entry["algo"]: entry["n_cells"] for entry in summary["aggregates"]} == dict.fromkeys(suite.algos, 1)
    table = markdown_table(summary)
    assert "| GridWorldWall-v0 † | base | mecl |" in table and "| GridWorldSquare-v0 | base | mecl |" in table
    assert "the headline envs only (GridWorldSquare-v0;" in table
    with pytest.raises(SuiteError, match="GridWorldZigzag-v0 not among the suite's envs"):
        load_suite(write(tmp_path, text + "headline_envs: [GridWorldZigzag-v0]\n"))


def _suite_results(suite, values) -> list:
    """``(run, result)`` of the suite's runs that ``values`` names: ``{(env name, algo): feasible reward}``, no violation."""
    results = []
    for run in suite.runs():
        feasible = values.get((run.env_id.split("/")[-1], run.algo))
        if feasible is not None:
            name = f"r/{run.env_id}/{run.algo}/{run.seed}"
            results.append((run, RunResult(name, run.algo, run.env_id, run.seed, 100, 1.0, 0.0, feasible, feasible, 20)))
    return results


def test_aggregates_take_the_headline_envs_where_every_row_has_scores(tmp_path) -> None:
    text = SUITE.replace("envs: [GridWorldWall-v0]", "envs: [GridWorldWall-v0, GridWorldSquare-v0]")
    text = text.replace("algos: [mecl, ppo, ppolag]", "algos: [bc2l, mecl, ppo, ppolag]").replace("[0, 1, 2]", "[0, 1]")
    suite = load_suite(write(tmp_path, text))
    values = {
        (env, algo): value
        for env in ("GridWorldWall-v0", "GridWorldSquare-v0")
        for algo, value in (("ppo", 0.0), ("ppolag", 10.0), ("bc2l", 2.0), ("mecl", 6.0))
    }
    # A suite part-way: MECL has not finished on the square map, where BC2L scores 0.9
    del values[("GridWorldSquare-v0", "mecl")]
    values[("GridWorldSquare-v0", "bc2l")] = 9.0
    summary = summarise_suite(suite, suite.runs(), _suite_results(suite, values))
    aggregates = {entry["algo"]: entry for entry in summary["normalised_aggregates"]}
    # Both methods over the one env where every row has scores: BC2L's 0.9 on the other is not averaged in
    assert {algo: entry["n_cells"] for algo, entry in aggregates.items()} == dict.fromkeys(suite.algos, 1)
    assert aggregates["bc2l"]["normalised_score_mean"] == pytest.approx(0.2)
    assert normalised_scores_by_algo(summary)["bc2l"] == [[0.2, 0.2]]
    assert [(entry["x"], entry["n_cells"]) for entry in summary["improvements"]] == [("bc2l", 1), ("mecl", 1)]
    assert summary["aggregated_envs"] == [["GridWorldWall-v0", "base"]]
    assert summary["aggregates_left_out"] == [
        {"env": "GridWorldSquare-v0", "variant": "base", "reason": "no finished run of mecl"}
    ]
    square = next(cell for cell in summary["cells"] if (cell["env"], cell["algo"]) == ("GridWorldSquare-v0", "bc2l"))
    assert square["normalised_score_mean"] == pytest.approx(0.9) and not square["aggregated"]  # still in its row
    table = markdown_table(summary)
    assert "Across envs (stratified bootstrap 95% CIs over the seeds of each env), over GridWorldWall-v0:" in table
    assert "Left out of them: GridWorldSquare-v0 (no finished run of mecl)." in table


def test_aggregates_of_one_seed_per_env_have_no_interval(tmp_path) -> None:
    text = SUITE.replace("envs: [GridWorldWall-v0]", "envs: [GridWorldWall-v0, GridWorldSquare-v0]")
    text = text.replace("algos: [mecl, ppo, ppolag]", "algos: [bc2l, mecl, ppo, ppolag]").replace("[0, 1, 2]", "[0]")
    suite = load_suite(write(tmp_path, text))
    values = {("GridWorldWall-v0", "ppolag"): 10.0, ("GridWorldSquare-v0", "ppolag"): 10.0}
    values.update({(env, "ppo"): 0.0 for env in ("GridWorldWall-v0", "GridWorldSquare-v0")})
    values.update({("GridWorldWall-v0", "bc2l"): 2.0, ("GridWorldSquare-v0", "bc2l"): 4.0})
    values.update({("GridWorldWall-v0", "mecl"): 6.0, ("GridWorldSquare-v0", "mecl"): 8.0})
    summary = summarise_suite(suite, suite.runs(), _suite_results(suite, values))
    bc2l = next(entry for entry in summary["normalised_aggregates"] if entry["algo"] == "bc2l")
    # One run per env: a bootstrap over the seeds of each env draws the same runs every time, a zero-width "interval"
    assert bc2l["n_runs"] == 2 and bc2l["normalised_score_mean"] == pytest.approx(0.3)
    assert all(bc2l[key] is None for key in bc2l if key.endswith("_ci95"))
    assert summary["improvements"][0]["probability"] == 0.0 and summary["improvements"][0]["ci95"] is None
    table = markdown_table(summary)
    assert "| bc2l | 2 | 2 | 0.30 | 0.30 | 0.70 |" in table and "| bc2l | mecl | 2 | 0.00 |" in table
    assert "no interval: one run per env" in table
    # The violation rate's aggregate alike, over the same envs
    violation = next(entry for entry in summary["aggregates"] if entry["algo"] == "bc2l")
    assert violation["n_cells"] == 2 and violation["violation_rate_iqm_ci95"] is None
    (ax,) = performance_profile_figure(summary).axes
    assert not ax.collections  # no band either


def test_a_report_without_aggregates_yet_says_why(tmp_path) -> None:
    suite = load_suite(write(tmp_path, SUITE))
    values = {("GridWorldWall-v0", "ppo"): 0.0, ("GridWorldWall-v0", "mecl"): 5.0}  # the oracle has not finished
    table = markdown_table(summarise_suite(suite, suite.runs(), _suite_results(suite, values)))
    assert "No cross-env aggregates yet: GridWorldWall-v0 (no finished run of ppolag)." in table


def test_a_report_refuses_runs_of_another_recipe_version_than_its_suites(tmp_path) -> None:
    suite = load_suite(write(tmp_path, SUITE + "recipe_version: 2026-11-a\n"))
    values = {"ppo": (10.0, 1.0), "ppolag": (20.0, 0.0), "mecl": (15.0, 0.0)}
    results = [(run, _result(run.algo, run.seed, *values[run.algo])) for run in suite.runs()]
    # Every oracle run recorded the same version, another than the suite's: its cell is one recipe, not the suite's
    metrics = {result.run: {"recipe_version": "2026-11-a" if run.algo != "ppolag" else "2026-10"} for run, result in results}
    with pytest.raises(
        ValueError, match=r"ppolag runs on GridWorldWall-v0 \(base; seeds 0, 1, 2\) used recipe version 2026-10, not 2026-11-a"
    ):
        summarise_suite(suite, suite.runs(), results, metrics)
    metrics = {result.run: {"recipe_version": "2026-11-a"} for run, result in results if run.algo != "mecl"}
    with pytest.raises(ValueError, match=r"mecl runs on .* used recipe version none recorded, not 2026-11-a"):
        summarise_suite(suite, suite.runs(), results, metrics)
    # A suite without a version takes what its runs recorded, one version a cell
    plain = load_suite(write(tmp_path, SUITE))
    assert summarise_suite(plain, plain.runs(), results, metrics)["cells"]


def test_aggregates_of_few_runs_are_labelled_rough(tmp_path) -> None:
    suite = load_suite(write(tmp_path, SUITE))
    values = {("GridWorldWall-v0", "ppo"): 0.0, ("GridWorldWall-v0", "ppolag"): 10.0, ("GridWorldWall-v0", "mecl"): 6.0}
    summary = summarise_suite(suite, suite.runs(), _suite_results(suite, values))
    assert {entry["n_runs"] for entry in summary["normalised_aggregates"]} == {3}
    table = markdown_table(summary)
    assert "Few runs: 3 per method in these aggregates (under 10)." in table
    # Ten seeds a method: no such label
    many = load_suite(write(tmp_path, SUITE.replace("[0, 1, 2]", str(list(range(10))))))
    assert "Few runs" not in markdown_table(summarise_suite(many, many.runs(), _suite_results(many, values)))
