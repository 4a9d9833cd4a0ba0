"""
A suite's own judgements, written before its runs: "beats the paper" (the suite key ``beats``: each ICRL cell against
one method's row of the paper, under each evaluation column) and the aim (the key ``aim``: the best ICRL method's
feasible reward as a fraction of the oracle's, with its violation rate); in summary.json, table.md and README's table.
"""

import json
import pathlib

import numpy as np
import pytest
from script_loader import load_script

from sb3_icrl.benchmark import load_suite, summarise_suite
from sb3_icrl.benchmark.judgements import beats, oracle_problem
from sb3_icrl.benchmark.report_numbers import finite_or_null
from sb3_icrl.benchmark.report_text import markdown_table
from sb3_icrl.benchmark.suite import BeatsRule, SuiteError
from sb3_icrl.common.statistics import stratified_bootstrap_ci
from sb3_icrl.zoo.compare import RunResult

readme_table = load_script("benchmarks/readme_table.py")

SUITE = """\
description: judgements
envs: [GridWorldWall-v0, GridWorldSquare-v0]
algos: [bc2l, mecl, ppo, ppolag]
forward_recipe: mecl
seeds: [0, 1]
paper:
  GridWorldWall-v0: {vicrl: [10, 0.1]}
  GridWorldSquare-v0: {vicrl: [20, 0.0]}
"""
BEATS = "beats: {against: vicrl, envs: [GridWorldWall-v0, GridWorldSquare-v0], columns: [heldout, last_training]}\n"
AIM = "aim: {min_oracle_fraction_iqm: 0.75, max_violation_rate_iqm: 0.05}\n"


def write(tmp_path: pathlib.Path, text: str) -> str:
    path = tmp_path / "suite.yml"
    path.write_text(text)
    return str(path)


def summary_of(suite, values, last=None) -> dict:
    """
    The summary of the runs ``values`` names: ``{(env name, algo): [(feasible reward, violation rate) per seed]}`` (``None``
    for a seed not finished); with
    ``last``, the same for the last training episodes (``None`` for a seed without them).
    """
    results, metrics = [], {}
    for run in suite.runs():
        key = (run.env_id.split("/")[-1], run.algo)
        if key not in values:
            continue
        if values[key][suite.seeds.index(run.seed)] is None:  # a seed not finished
            continue
        feasible, violation = values[key][suite.seeds.index(run.seed)]
        name = f"r/{run.env_id}/{run.algo}/{run.seed}"
        results.append((run, RunResult(name, run.algo, run.env_id, run.seed, 100, 1.0, violation, feasible, feasible, 20)))
        pair = (last or {}).get(key, [None] * len(suite.seeds))[suite.seeds.index(run.seed)]
        if pair is not None:
            metrics[name] = {"last_training_feasible_reward": pair[0], "last_training_violation_rate": pair[1]}
    return summarise_suite(suite, suite.runs(), results, metrics)


# ---------------------------------------------------------------- the suite keys


def test_table3_writes_its_judgements_as_its_header_says():
    table3 = load_suite("table3", dry_build=False)
    assert table3.beats == BeatsRule(
        "vicrl", ("BlockedHalfCheetah-v0", "BlockedSwimmer-v0", "BiasedPendulum-v0"), ("heldout", "last_training")
    )
    assert table3.aim == {"min_oracle_fraction_iqm": 0.75, "max_violation_rate_iqm": 0.05}
    dev = load_suite("table3_dev", dry_build=False)
    assert dev.beats is None and dev.aim is None


@pytest.mark.parametrize(
    "text, line, message",
    [
        ("beats: {against: vicrl, envs: [GridWorldWall-v0]}\n", 9, "maps `against`, `envs` and `columns`"),
        ("beats: [vicrl]\n", 9, "maps `against`, `envs` and `columns`"),
        (BEATS.replace("against: vicrl", "against: mecl"), 9, r"names a method row of the suite's `paper` numbers \(vicrl\)"),
        (BEATS.replace("GridWorldSquare-v0]", "GridWorldZigzag-v0]"), 9, "GridWorldZigzag-v0 not among the suite's envs"),
        (BEATS.replace("GridWorldSquare-v0]", "GridWorldWall-v0]"), 9, "names an env twice"),
        (BEATS.replace("[heldout, last_training]", "[heldout, training]"), 9, "non-empty list among heldout"),
        (BEATS.replace("[heldout, last_training]", "[]"), 9, "non-empty list among heldout"),
        (BEATS.replace("[heldout, last_training]", "[heldout, heldout]"), 9, "names a column twice"),
        ("aim: {min_oracle_fraction_iqm: 0.75}\n", 9, "maps min_oracle_fraction_iqm and max_violation_rate_iqm"),
        (AIM.replace("0.75", "high"), 9, "`aim.min_oracle_fraction_iqm` is a number"),
        (AIM.replace("0.05", "5"), 9, r"`aim.max_violation_rate_iqm` is a rate within \[0, 1\]"),
    ],
)
def test_bad_judgements_name_the_line(tmp_path, text, line, message):
    with pytest.raises(SuiteError, match=rf"line {line}: .*{message}"):
        load_suite(write(tmp_path, SUITE + text), dry_build=False)


def test_a_judged_env_needs_the_papers_row(tmp_path):
    text = SUITE.replace("  GridWorldSquare-v0: {vicrl: [20, 0.0]}\n", "  GridWorldSquare-v0: {mecl: [20, 0.0]}\n")
    # The second env of `envs`, on the key's line (a flow list keeps its items on it)
    with pytest.raises(SuiteError, match="line 9: the suite's `paper` numbers have no vicrl row on GridWorldSquare-v0"):
        load_suite(write(tmp_path, text + BEATS), dry_build=False)
    with pytest.raises(SuiteError, match=r"has no `paper` numbers"):
        load_suite(write(tmp_path, SUITE.split("paper:")[0] + BEATS), dry_build=False)


def test_judgements_need_icrl_methods_and_the_aim_the_reference_rows(tmp_path):
    reference_only = SUITE.replace("algos: [bc2l, mecl, ppo, ppolag]", "algos: [ppo, ppolag]")
    for key in (BEATS, AIM):
        with pytest.raises(SuiteError, match="no ICRL algorithm"):
            load_suite(write(tmp_path, reference_only + key), dry_build=False)
    without_oracle = SUITE.replace("algos: [bc2l, mecl, ppo, ppolag]", "algos: [bc2l, mecl, ppo]")
    with pytest.raises(SuiteError, match="line 9: `aim` is judged over the envs of the cross-env aggregates"):
        load_suite(write(tmp_path, without_oracle + AIM), dry_build=False)


# ---------------------------------------------------------------- beats the paper

#: Held-out (feasible reward, violation rate) per seed; the paper's VICRL row: Wall [10, 10%], Square [20, 0%]
HELDOUT = {
    ("GridWorldWall-v0", "mecl"): [(12.0, 0.1), (14.0, 0.0)],  # 13 / 5%: beats
    ("GridWorldSquare-v0", "mecl"): [(25.0, 0.0), (25.0, 0.0)],  # 25 / 0%: beats
    ("GridWorldWall-v0", "bc2l"): [(12.0, 0.2), (12.0, 0.2)],  # 12 / 20%: violates more
    ("GridWorldSquare-v0", "bc2l"): [(21.0, 0.0), (21.0, 0.0)],  # 21 / 0%: beats
    ("GridWorldWall-v0", "ppo"): [(30.0, 1.0), (30.0, 1.0)],  # the reference rows are not judged
}
LAST = {
    ("GridWorldWall-v0", "mecl"): [(11.0, 0.1), (11.0, 0.1)],  # 11 / 10%: as many violations is no more: beats
    ("GridWorldSquare-v0", "mecl"): [(30.0, 0.0), (18.0, 0.0)],  # 24 / 0%: beats
    ("GridWorldWall-v0", "bc2l"): [(15.0, 0.0), (15.0, 0.0)],  # beats, but not under the held-out column
    ("GridWorldSquare-v0", "bc2l"): [(30.0, 0.0), None],  # seed 1 without its training episodes: missing
}


def test_each_icrl_cell_is_judged_under_each_column(tmp_path):
    suite = load_suite(write(tmp_path, SUITE + BEATS), dry_build=False)
    summary = summary_of(suite, HELDOUT, LAST)
    cells = {(cell["env"], cell["algo"]): cell for cell in summary["cells"]}
    assert cells[("GridWorldWall-v0", "mecl")]["beats_judgement"] == {"heldout": True, "last_training": True, "beats": True}
    assert cells[("GridWorldWall-v0", "bc2l")]["beats_judgement"] == {"heldout": False, "last_training": True, "beats": False}
    assert cells[("GridWorldSquare-v0", "bc2l")]["beats_judgement"] == {"heldout": True, "last_training": None, "beats": None}
    assert "beats_judgement" not in cells[("GridWorldWall-v0", "ppo")]
    judgement = summary["beats_judgement"]
    assert judgement["against"] == "vicrl" and judgement["columns"] == ["heldout", "last_training"]
    assert judgement["paper"] == {"GridWorldWall-v0": [10, 0.1], "GridWorldSquare-v0": [20, 0.0]}
    methods = {method["algo"]: method for method in judgement["methods"]}
    assert list(methods) == ["bc2l", "mecl"]
    assert methods["mecl"]["beaten"] == [["GridWorldWall-v0", "base"], ["GridWorldSquare-v0", "base"]]
    assert methods["bc2l"]["not_beaten"] == [["GridWorldWall-v0", "base"]]
    assert methods["bc2l"]["undecided"] == [["GridWorldSquare-v0", "base"]]
    assert judgement["best"] == ["mecl"] and judgement["outcome"] is True
    table = markdown_table(summary)
    assert "| algo | GridWorldWall-v0 (10 / 10%) | GridWorldSquare-v0 (20 / 0%) | envs beaten |" in table
    assert "| bc2l | no / yes | yes / - | 0 of 2 |" in table and "| mecl | yes / yes | yes / yes | 2 of 2 |" in table
    assert (
        "MECL on 2 of 2 (GridWorldWall-v0, GridWorldSquare-v0). Outcome: MECL on every judged env." in table
        and "BC2L on 0 of 2 (1 not decided yet)" in table
    )


def test_the_outcome_waits_for_missing_values_and_fails_where_every_method_fails(tmp_path):
    suite = load_suite(write(tmp_path, SUITE + BEATS), dry_build=False)
    # MECL's Square cell has no training episodes for seed 1: it may still beat the row everywhere
    last = {**LAST, ("GridWorldSquare-v0", "mecl"): [(30.0, 0.0), None]}
    judgement = summary_of(suite, HELDOUT, last)["beats_judgement"]
    assert judgement["outcome"] is None and judgement["best"] == ["mecl"]
    assert "Outcome: not decided yet, values missing; the most, 1 of 2: MECL so far." in readme_table.scoreboard(
        {"suite": "s", "beats_judgement": judgement, "cells": []}
    )
    # MECL's Square cell not finished: undecided too
    held = {key: value for key, value in HELDOUT.items() if key != ("GridWorldSquare-v0", "mecl")}
    assert summary_of(suite, held, LAST)["beats_judgement"]["outcome"] is None
    # MECL below the paper on Square under the held-out column: no method can beat it everywhere
    held = {**HELDOUT, ("GridWorldSquare-v0", "mecl"): [(19.0, 0.0), (19.0, 0.0)]}
    judgement = summary_of(suite, held, LAST)["beats_judgement"]
    assert judgement["outcome"] is False and judgement["best"] == ["mecl"]
    assert judgement["methods"][1]["tasks"][1] == {
        "env": "GridWorldSquare-v0",
        "variant": "base",
        "heldout": False,
        "last_training": True,
        "beats": False,
        "n_seeds": 2,
        "of_seeds": 2,
    }


def test_a_verdict_on_fewer_seeds_than_the_suite_runs_says_on_how_many(tmp_path):
    suite = load_suite(write(tmp_path, SUITE + BEATS), dry_build=False)
    # MECL's wall cell has seed 0 only: it beats the row there on one of two seeds
    held = {**HELDOUT, ("GridWorldWall-v0", "mecl"): [(12.0, 0.0), None]}
    summary = summary_of(suite, held, LAST)
    mecl = summary["beats_judgement"]["methods"][1]
    assert [(task["n_seeds"], task["of_seeds"]) for task in mecl["tasks"]] == [(1, 2), (2, 2)]
    table = markdown_table(summary)
    assert "| mecl | yes / yes (1 of 2 seeds) | yes / yes | 2 of 2 |" in table
    assert "MECL on 2 of 2 (GridWorldWall-v0 (1 of 2 seeds), GridWorldSquare-v0)" in table
    # A summary written before the counts were kept reads as before
    for task in mecl["tasks"]:
        del task["n_seeds"], task["of_seeds"]
    assert "MECL on 2 of 2 (GridWorldWall-v0, GridWorldSquare-v0)" in readme_table.scoreboard(
        {"suite": "s", "beats_judgement": summary["beats_judgement"], "cells": []}
    )


def test_a_judgement_under_the_heldout_column_alone_ignores_the_training_episodes(tmp_path):
    suite = load_suite(write(tmp_path, SUITE + BEATS.replace("[heldout, last_training]", "[heldout]")), dry_build=False)
    judgement = summary_of(suite, HELDOUT)["beats_judgement"]
    methods = {method["algo"]: method for method in judgement["methods"]}
    assert len(methods["bc2l"]["beaten"]) == 1 and judgement["outcome"] is True
    assert set(methods["bc2l"]["tasks"][0]) == {"env", "variant", "heldout", "beats", "n_seeds", "of_seeds"}


# ---------------------------------------------------------------- the aim

#: Oracle means: Wall 20, Square 40
AIM_VALUES = {
    ("GridWorldWall-v0", "ppo"): [(0.0, 1.0), (0.0, 1.0)],
    ("GridWorldWall-v0", "ppolag"): [(10.0, 0.0), (30.0, 0.0)],
    ("GridWorldWall-v0", "mecl"): [(10.0, 0.0), (16.0, 0.1)],  # 0.5, 0.8
    ("GridWorldWall-v0", "bc2l"): [(4.0, 0.0), (20.0, 0.2)],  # 0.2, 1.0
    ("GridWorldSquare-v0", "ppo"): [(0.0, 1.0), (0.0, 1.0)],
    ("GridWorldSquare-v0", "ppolag"): [(40.0, 0.0), (40.0, 0.0)],
    ("GridWorldSquare-v0", "mecl"): [(20.0, 0.0), (36.0, 0.0)],  # 0.5, 0.9
    ("GridWorldSquare-v0", "bc2l"): [(40.0, 0.3), (40.0, 0.1)],  # 1.0, 1.0
}


def test_the_oracle_fraction_by_hand(tmp_path):
    suite = load_suite(write(tmp_path, SUITE + AIM), dry_build=False)
    summary = summary_of(suite, AIM_VALUES)
    aim = summary["aim"]
    assert aim["envs"] == [["GridWorldWall-v0", "base"], ["GridWorldSquare-v0", "base"]] and aim["left_out"] == []
    assert aim["oracle_feasible_reward"] == [["GridWorldWall-v0", "base", 20.0], ["GridWorldSquare-v0", "base", 40.0]]
    entries = {entry["algo"]: entry for entry in aim["aggregates"]}
    assert list(entries) == suite.algos
    mecl, bc2l = entries["mecl"], entries["bc2l"]
    # Four runs: the IQM is the mean of the middle two; the mean, of the per-env means
    assert mecl["n_cells"] == 2 and mecl["n_runs"] == 4
    assert mecl["oracle_fraction_iqm"] == pytest.approx((0.5 + 0.8) / 2)
    assert mecl["oracle_fraction_mean"] == pytest.approx((0.65 + 0.7) / 2)
    assert mecl["violation_rate_iqm"] == pytest.approx(0.0)
    assert bc2l["oracle_fraction_iqm"] == pytest.approx(1.0) and bc2l["oracle_fraction_mean"] == pytest.approx(0.8)
    assert bc2l["violation_rate_iqm"] == pytest.approx((0.1 + 0.2) / 2)
    assert entries["ppolag"]["oracle_fraction_mean"] == pytest.approx(1.0)
    # The stratified bootstrap of the other aggregates, over the seeds of each env
    assert mecl["oracle_fraction_iqm_ci95"] == pytest.approx(list(stratified_bootstrap_ci([[0.5, 0.8], [0.5, 0.9]])))
    assert mecl["oracle_fraction_mean_ci95"] == pytest.approx(
        list(stratified_bootstrap_ci([[0.5, 0.8], [0.5, 0.9]], statistic=np.mean))
    )
    assert bc2l["violation_rate_iqm_ci95"] == pytest.approx(list(stratified_bootstrap_ci([[0.0, 0.2], [0.3, 0.1]])))
    # The best ICRL method by its fraction alone (the oracle's own row is no candidate): BC2L, which violates too often
    assert aim["best"] == "bc2l" and aim["met"] is False
    table = markdown_table(summary)
    assert "| mecl | 2 | 4 | 0.65 [" in table and "| 0.68 [" in table
    assert "the best, BC2L (highest IQM of that fraction), has 1.00 [" in table
    assert "not met, its violation-rate IQM is above 5%." in table


def test_the_aim_is_met_or_missed_on_its_thresholds(tmp_path):
    met = load_suite(write(tmp_path, SUITE + AIM.replace("0.05", "0.2")), dry_build=False)
    aim = summary_of(met, AIM_VALUES)["aim"]
    assert aim["best"] == "bc2l" and aim["met"] is True
    assert aim_text_of(aim).endswith(": met.")
    strict = load_suite(write(tmp_path, SUITE + AIM.replace("0.75", "1.1")), dry_build=False)
    text = aim_text_of(summary_of(strict, AIM_VALUES)["aim"])
    assert "not met, its fraction's IQM is below 1.1 and its violation-rate IQM is above 5%." in text


def aim_text_of(aim: dict) -> str:
    return readme_table.aim_line({"suite": "s", "aim": aim}).removeprefix("s: ")


def test_an_oracle_without_positive_feasible_reward_is_left_out_and_named(tmp_path):
    suite = load_suite(write(tmp_path, SUITE + AIM), dry_build=False)
    values = {
        **AIM_VALUES,
        # The oracle keeps the constraint and earns more than PPO, so the env is aggregated, but its mean is -2
        ("GridWorldSquare-v0", "ppo"): [(-10.0, 1.0), (-10.0, 1.0)],
        ("GridWorldSquare-v0", "ppolag"): [(-2.0, 0.0), (-2.0, 0.0)],
    }
    summary = summary_of(suite, values)
    assert summary["aggregated_envs"] == [["GridWorldWall-v0", "base"], ["GridWorldSquare-v0", "base"]]
    aim = summary["aim"]
    assert aim["envs"] == [["GridWorldWall-v0", "base"]]
    assert aim["left_out"] == [
        {"env": "GridWorldSquare-v0", "variant": "base", "reason": "the oracle's mean feasible reward, -2.00, is not positive"}
    ]
    mecl = next(entry for entry in aim["aggregates"] if entry["algo"] == "mecl")
    assert mecl["n_cells"] == 1 and mecl["oracle_fraction_iqm"] == pytest.approx(0.65)
    left_out = "Left out: GridWorldSquare-v0 (the oracle's mean feasible reward, -2.00, is not positive)."
    assert left_out in markdown_table(summary)


def test_one_run_per_env_gives_no_interval_and_no_env_no_outcome(tmp_path):
    suite = load_suite(write(tmp_path, SUITE.replace("seeds: [0, 1]", "seeds: [0]") + AIM), dry_build=False)
    values = {key: pairs[:1] for key, pairs in AIM_VALUES.items()}
    summary = summary_of(suite, values)
    assert all(entry[key] is None for entry in summary["aim"]["aggregates"] for key in entry if key.endswith("_ci95"))
    table = markdown_table(summary)
    # Wall: 10 / 10, Square: 20 / 40
    assert "| mecl | 2 | 2 | 0.75 | 0.75 | 0% |" in table and "no interval: one run per env" in table
    # The oracle not finished anywhere: nothing to judge, and the table says why
    values = {key: pairs for key, pairs in values.items() if key[1] != "ppolag"}
    summary = summary_of(suite, values)
    assert summary["aim"]["best"] is None and summary["aim"]["met"] is None
    assert "not judged yet, no env to judge it on. Left out: GridWorldWall-v0 (no finished run of ppolag)" in markdown_table(
        summary
    )


def test_suites_without_the_keys_show_nothing_new(tmp_path):
    suite = load_suite(write(tmp_path, SUITE), dry_build=False)
    summary = summary_of(suite, AIM_VALUES, LAST)
    assert "beats_judgement" not in summary and "aim" not in summary
    assert not any("beats_judgement" in cell for cell in summary["cells"])
    table = markdown_table(summary)
    assert "Beats the paper" not in table and "F / F_oracle" not in table and "the suite's aim" not in table


# ---------------------------------------------------------------- README's table


def test_readme_reports_the_judgement_and_the_aim(tmp_path):
    suite = load_suite(write(tmp_path, SUITE + BEATS + AIM), dry_build=False)
    methods = {key: pairs for key, pairs in HELDOUT.items() if key[1] != "ppo"}
    summary = json.loads(json.dumps(finite_or_null(summary_of(suite, {**AIM_VALUES, **methods}, LAST))))
    (tmp_path / "results" / "suite").mkdir(parents=True)
    (tmp_path / "results" / "suite" / "summary.json").write_text(json.dumps(summary))
    lines = readme_table.table(tmp_path / "results").splitlines()
    # The judgement replaces the count against each method's own row (the paper has VICRL's only here)
    assert (
        "suite: beats the paper's VICRL row (a higher mean feasible reward and a mean violation rate no higher, under the "
        "held-out and last training columns alike; the suite's `beats`) on GridWorldWall-v0, GridWorldSquare-v0: BC2L on 0 "
        "of 2 (1 not decided yet); MECL on 2 of 2 (GridWorldWall-v0, GridWorldSquare-v0). Outcome: MECL on every judged env."
    ) in lines
    (aim,) = [line for line in lines if line.startswith("suite: the suite's aim")]
    # MECL: 0.6, 0.7 on the wall map and 0.625 twice on the square one
    assert "the best, MECL (highest IQM of that fraction), has 0.62 [" in aim
    assert aim.endswith(": not met, its fraction's IQM is below 0.75.")


# ---------------------------------------------------------------- verdicts on runs still coming


def test_a_verdict_with_runs_still_coming_is_the_verdict_so_far(tmp_path):
    suite = load_suite(write(tmp_path, SUITE + BEATS + AIM.replace("0.75", "0.5")), dry_build=False)
    complete = summary_of(suite, AIM_VALUES, LAST)
    assert complete["beats_judgement"]["pending_runs"] == 0 and complete["aim"]["pending_runs"] == 0
    assert "so far" not in aim_text_of(complete["aim"])
    # BC2L's Square cell not finished: the judged cells lack two ICRL runs, the headline envs two runs in all
    values = {key: pairs for key, pairs in AIM_VALUES.items() if key != ("GridWorldSquare-v0", "bc2l")}
    summary = summary_of(suite, values, LAST)
    judgement, aim = summary["beats_judgement"], summary["aim"]
    assert judgement["pending_runs"] == 2 and aim["pending_runs"] == 2
    assert judgement["outcome"] is True  # MECL beats the row on both envs already
    table = markdown_table(summary)
    assert "Outcome: MECL on every judged env so far, 2 runs of the judged envs not finished." in table
    assert aim["met"] is not None
    assert " so far (provisional: 2 runs of the headline envs not finished). Left out: GridWorldSquare-v0" in aim_text_of(aim)
    # A reference row's runs missing leave "beats" final (it judges ICRL cells alone) but not the aim
    summary = summary_of(suite, {key: pairs for key, pairs in AIM_VALUES.items() if key[1] != "ppo"}, LAST)
    assert summary["beats_judgement"]["pending_runs"] == 0 and summary["aim"]["pending_runs"] == 4


def test_a_variant_some_methods_do_not_run_is_judged_for_those_that_do(tmp_path):
    text = (
        SUITE.replace(
            "algos: [bc2l, mecl, ppo, ppolag]",
            "algos: [bc2l, mecl, ppo, ppolag]\nvariants:\n  base: {}\n" "  only-mecl: {algos: [mecl, ppo, ppolag]}",
        )
        + BEATS.replace("[heldout, last_training]", "[heldout]")
        + AIM
    )
    suite = load_suite(write(tmp_path, text), dry_build=False)
    results = []
    for run in suite.runs():
        feasible, violation = AIM_VALUES[(run.env_id.split("/")[-1], run.algo)][suite.seeds.index(run.seed)]
        results.append((run, RunResult(run.name, run.algo, run.env_id, run.seed, 100, 1.0, violation, feasible, feasible, 20)))
    summary = summarise_suite(suite, suite.runs(), results)
    judgement = summary["beats_judgement"]
    methods = {method["algo"]: method for method in judgement["methods"]}
    # BC2L is judged on the two base tasks only, and decided there: no "not decided yet" for a variant it does not run
    assert methods["bc2l"]["n_tasks"] == 2 and methods["mecl"]["n_tasks"] == 4
    assert methods["bc2l"]["undecided"] == [] and judgement["pending_runs"] == 0
    assert judgement["outcome"] is not None
    table = markdown_table(summary)
    assert "| bc2l | " in table and "not run" in table
    # The aggregates take every method over the same envs: the variant without BC2L is left out, and why
    assert summary["aggregated_envs"] == [["GridWorldWall-v0", "base"], ["GridWorldSquare-v0", "base"]]
    reasons = {entry["variant"]: entry["reason"] for entry in summary["aggregates_left_out"]}
    assert reasons == {"only-mecl": "the variant does not run bc2l (its `algos`)"}


def test_a_method_that_runs_no_judged_variant_neither_holds_the_outcome_open_nor_counts_as_best(tmp_path):
    text = SUITE.replace(
        "algos: [bc2l, mecl, ppo, ppolag]", "algos: [bc2l, mecl, ppo, ppolag]\nvariants:\n  base: {algos: [mecl, ppo, ppolag]}"
    )
    suite = load_suite(write(tmp_path, text + BEATS.replace("[heldout, last_training]", "[heldout]")), dry_build=False)
    # MECL, the one method judged, is below the paper on Square: the outcome is decided, not met
    held = {**HELDOUT, ("GridWorldSquare-v0", "mecl"): [(19.0, 0.0), (19.0, 0.0)]}
    judgement = summary_of(suite, held)["beats_judgement"]
    methods = {method["algo"]: method for method in judgement["methods"]}
    assert methods["bc2l"]["n_tasks"] == 0 and methods["mecl"]["n_tasks"] == 2
    assert judgement["outcome"] is False and judgement["best"] == ["mecl"]


def test_a_mean_that_is_not_a_number_is_not_judged_and_an_oracle_without_a_violation_rate_normalises_nothing():
    nan = float("nan")
    assert beats({"feasible_reward_mean": 10.0, "violation_rate_mean": nan}, [5.0, 0.5]) is None
    assert beats({"feasible_reward_mean": nan, "violation_rate_mean": 0.0}, [5.0, 0.5]) is None
    assert beats({"feasible_reward_mean": 10.0, "violation_rate_mean": 0.5}, [5.0, 0.5]) is True
    ppo = {"feasible_reward_mean": 0.0, "violation_rate_mean": 1.0}
    assert (
        oracle_problem(ppo, {"feasible_reward_mean": 10.0, "violation_rate_mean": nan}) == "the oracle has no violation rate"
    )
    assert oracle_problem(ppo, {"feasible_reward_mean": 10.0, "violation_rate_mean": 0.05}) is None
    assert "6% of episodes" in oracle_problem(ppo, {"feasible_reward_mean": 10.0, "violation_rate_mean": 0.06})


def test_a_partial_report_keeps_its_verdict_provisional(tmp_path):
    suite = load_suite(write(tmp_path, SUITE + AIM.replace("0.05", "0.2")), dry_build=False)
    chosen = [run for run in suite.runs() if run.seed == 0]
    results = []
    for run in chosen:
        feasible, violation = AIM_VALUES[(run.env_id.split("/")[-1], run.algo)][0]
        results.append((run, RunResult(run.name, run.algo, run.env_id, run.seed, 100, 1.0, violation, feasible, feasible, 20)))
    # A report of seed 0 alone (--only seed=0): every run it selected is in, the suite's seed 1 is not
    summary = summarise_suite(suite, chosen, results)
    assert summary["runs_missing"] == [] and summary["aim"]["pending_runs"] == 8
    assert "so far (provisional: 8 runs of the headline envs not finished)" in aim_text_of(summary["aim"])
