"""The README's benchmark table is generated from the committed suite summaries, and kept up to date."""

import importlib.util
import json
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("readme_table", ROOT / "benchmarks" / "readme_table.py")
readme_table = importlib.util.module_from_spec(spec)
spec.loader.exec_module(readme_table)


def test_readme_table_is_not_stale():
    readme = (ROOT / "README.md").read_text()
    assert readme_table.render(readme, readme_table.table()) == readme, "run python benchmarks/readme_table.py"


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


def test_rewards_keep_the_digits_their_size_needs():
    from sb3_icrl.benchmark.report import format_mean_std

    assert format_mean_std(3254.3, 576.2) == "3254 ± 576"
    assert format_mean_std(-19.14, 2.26) == "-19.1 ± 2.3"
    assert format_mean_std(0.462, 0.298) == "0.46 ± 0.30"  # a Pendulum cell, not "0 ± 0"
