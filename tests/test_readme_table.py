"""The README's and the results page's benchmark tables are generated from the committed suite summaries, and kept up to
date; the README stays short."""

import json
import pathlib

import pytest
from script_loader import load_script

ROOT = pathlib.Path(__file__).resolve().parents[1]
readme_table = load_script("benchmarks/readme_table.py")


def test_tables_are_not_stale():
    stale = [path.name for path, (current, updated) in readme_table.updates().items() if updated != current]
    assert not stale, f"{stale}: run python benchmarks/readme_table.py"


def test_readme_is_at_most_120_lines():
    assert len((ROOT / "README.md").read_text().splitlines()) <= 120


def test_glance_table_has_a_row_per_headline_env_and_a_column_per_method(tmp_path):
    def cell(algo, env, score, rate, seeds, successes=0, reward=100.0):
        scores = {"normalised_score_mean": score, "success_count": successes} if score is not None else {}
        return {
            "algo": algo,
            "env": env,
            "variant": "base",
            "feasible_reward_mean": reward,
            "violation_rate_mean": rate,
            "n_seeds": seeds,
            "per_seed": [{"seed": seed} for seed in range(seeds)],
            **scores,
        }

    cells = [
        cell("mecl", "BlockedSwimmer-v0", 0.2214, 0.425, 2, 1),
        cell("ppo", "BlockedSwimmer-v0", -1.6e-17, 0.7, 3),  # a mean that is 0 but for rounding
        cell("mecl", "BiasedPendulum-v0", None, 0.5, 5, reward=2.356),  # its reference rows give no scores
        cell("mecl", "BlockedHalfCheetah-v0", 0.5, 0.0, 1),  # not a headline env
        cell("mecl", "BlockedSwimmer-v0", 1.0, 1.0, 1) | {"variant": "other"},  # not the base variant
    ]
    summary = {
        "suite": "table3",
        "cells": cells,
        "headline_envs": ["BiasedPendulum-v0", "BlockedSwimmer-v0", "BlockedWalkerReach-v0"],
        "eval_episodes": 20,
        "success_rule": {"max_violation_rate": 0.05, "min_normalised_score": 0.5},
        "core_hours": 2.5,
        "core_hours_runs": 11,
        "runs_missing": ["a", "b"],
    }
    (tmp_path / "table3").mkdir()
    (tmp_path / "table3" / "summary.json").write_text(json.dumps(summary))
    lines = readme_table.glance(tmp_path, "table3").splitlines()
    assert lines[:4] == [
        "| | MECL | PPO |",
        "|---|---|---|",
        "| BiasedPendulum | 2.36 / 50% (n=5) | - |",
        "| BlockedSwimmer | 0.22 / 42% (1/2) | 0.00 / 70% (0/3) |",
    ]  # no run of BlockedWalkerReach yet: no row
    note = lines[5]
    assert "2 to 5 seeds per cell so far (11 runs, 2.5 core-hours of training; 2 runs to come)" in note
    assert "a violation rate of at most 5% and a normalised score of at least 0.5" in note
    assert note.endswith("outside its headline envs, are in its report: BlockedHalfCheetah-v0.")

    summary["runs_missing"] = []
    (tmp_path / "table3" / "summary.json").write_text(json.dumps(summary))
    note = readme_table.glance(tmp_path, "table3").splitlines()[5]
    assert "2 to 5 seeds per cell (11 runs, 2.5 core-hours of training, every run of the suite in)" in note
    assert "so far" not in note and "to come" not in note


def test_table_rows_come_from_the_summaries(tmp_path):
    cell = {
        "env": "BlockedHalfCheetah-v0",
        "variant": "base",
        "algo": "vicrl",
        "per_seed": [{"seed": 0}, {"seed": 1}],
        "violation_rate_mean": 0.05,
        "violation_rate_std": 0.05,
        "feasible_reward_mean": 3500.4,
        "feasible_reward_std": 200.0,
        "paper_feasible_reward": 3806.0,
        "paper_violation_rate": 0.0,
    }
    (tmp_path / "mysuite").mkdir()
    (tmp_path / "mysuite" / "summary.json").write_text(json.dumps({"suite": "mysuite", "cells": [cell]}))
    rows = readme_table.table(tmp_path).splitlines()
    assert rows[2] == "| mysuite | BlockedHalfCheetah-v0 | base | VICRL | 0, 1 | 5% ± 5% | 3500 ± 200 | 3806 / 0% |"
    with pytest.raises(ValueError, match="marker"):
        readme_table.render("no markers here", "")


def test_one_seed_cells_show_their_mean_alone():
    assert readme_table.rate_mean_std(0.1, None) == "10%"
    assert readme_table.reward_mean_std(2353.02, None) == "2353"
    assert readme_table.rate_mean_std(0.1, 0.05) == "10% ± 5%"


def test_rewards_keep_the_digits_their_size_needs():
    from sb3_icrl.benchmark.report_numbers import format_mean_std

    assert format_mean_std(3254.3, 576.2) == "3254 ± 576"
    assert format_mean_std(-19.14, 2.26) == "-19.1 ± 2.3"
    assert format_mean_std(0.462, 0.298) == "0.46 ± 0.30"  # a Pendulum cell, not "0 ± 0"


def test_study_tables_come_from_the_study_summaries(tmp_path):
    from sb3_icrl.benchmark.report_text import study_level_lines

    cell = {
        "env": "A-v0",
        "algo": "mecl",
        "variant": "sigma-0.1",
        "per_seed": [{"seed": 0}],
        "feasible_reward_mean": 12.5,
        "violation_rate_mean": 0.25,
    }
    study = {"suite": "noise", "cells": [cell], "study": {"setting": "transition_noise", "levels": {"sigma-0.1": 0.1}}}
    for name, summary in (("noise", study), ("table3", {"suite": "table3", "cells": [{**cell, "variant": "base"}]})):
        (tmp_path / name).mkdir()
        (tmp_path / name / "summary.json").write_text(json.dumps(summary))
    text = readme_table.study_tables(tmp_path)
    assert text.startswith("`noise` (`benchmarks/results/noise`): By level of transition_noise")
    assert text.rstrip("\n").endswith("| A-v0 | mecl | 12.5 / 25% (1) |") and "table3" not in text
    assert "\n".join(study_level_lines(study)[3:]) in text
    (tmp_path / "noise" / "summary.json").unlink()
    assert readme_table.study_tables(tmp_path) == "No study has reported yet.\n"
