"""
``report --update`` names an ICRL run whose identification probes read a ``ppo`` folder that is not the ``ppo`` row
the report keeps (a row trained again, stopped and resumed, differs from the reported one).
"""

import os
import types

import pytest

from sb3_icrl.benchmark import load_suite
from sb3_icrl.benchmark.report import probe_rows_unlike_report

SUITE = """\
description: probe rows
envs: [BiasedPendulum-v0]
algos: [mecl, ppo]
seeds: [0]
steps: 1000
"""

#: The kept ``ppo`` row's key in the report (its ``result.run``)
KEY = "base/ppo/BiasedPendulum-v0_0"


@pytest.fixture
def suite_with_ppo_folder(tmp_path):
    """The suite, its MECL and PPO runs, and a PPO folder whose last training episodes are 1 of 2 broken, 4.0 feasible."""
    path = tmp_path / "probes.yml"
    path.write_text(SUITE)
    suite = load_suite(path)
    mecl, ppo = (next(run for run in suite.runs() if run.algo == algo) for algo in ("mecl", "ppo"))
    root = str(tmp_path / "logs")
    folder = ppo.run_folder(root)
    os.makedirs(folder)
    with open(os.path.join(folder, "0.monitor.csv"), "w") as file:
        file.write('#{"t_start": 0}\nr,l,t,true_violation,true_feasible_reward\n3.0,10,1,1.0,3.0\n5.0,10,2,0.0,5.0\n')
    with open(os.path.join(folder, "command.txt"), "w") as file:
        file.write("python train.py --algo ppo\n")
    return suite, mecl, ppo, root


def _kept(ppo, **values):
    """The report's results and metrics with ``ppo`` kept from an earlier summary with these per-seed values."""
    return [(ppo, types.SimpleNamespace(run=KEY))], {KEY: values}


def test_a_folder_that_is_the_reported_row_is_not_named(suite_with_ppo_folder):
    suite, mecl, ppo, root = suite_with_ppo_folder
    results, metrics = _kept(ppo, last_training_feasible_reward=4.0, last_training_violation_rate=0.5, training_starts=1)
    assert probe_rows_unlike_report(suite, [mecl], results, metrics, root) == []


def test_other_last_episodes_or_another_start_count_name_the_row_and_the_runs_it_probed(suite_with_ppo_folder):
    suite, mecl, ppo, root = suite_with_ppo_folder
    results, metrics = _kept(ppo, last_training_feasible_reward=4.5, last_training_violation_rate=0.5, training_starts=1)
    (line,) = probe_rows_unlike_report(suite, [mecl], results, metrics, root)
    assert line.startswith(f"{ppo.name}: its folder here is not the reported row")
    assert "4.0 / 50% against the report's 4.5 / 50%" in line and mecl.name in line and "without a stop" in line
    # The same episodes from a row the report says started twice (resumed): not the same policy either
    results, metrics = _kept(ppo, last_training_feasible_reward=4.0, last_training_violation_rate=0.5, training_starts=2)
    (line,) = probe_rows_unlike_report(suite, [mecl], results, metrics, root)
    assert "training starts 1 against 2" in line


def test_nothing_to_compare_names_nothing(suite_with_ppo_folder, tmp_path):
    suite, mecl, ppo, root = suite_with_ppo_folder
    results, metrics = _kept(ppo, last_training_feasible_reward=4.5, last_training_violation_rate=0.5)
    # The PPO row reported by this same report (scored now): the report shows that folder's own numbers
    assert probe_rows_unlike_report(suite, [mecl, ppo], results, metrics, root) == []
    # A kept row from an older report without last-training values
    assert probe_rows_unlike_report(suite, [mecl], *_kept(ppo, training_starts=1), root) == []
    # No PPO folder here: the probes hold no PPO episodes (the report says so elsewhere)
    assert probe_rows_unlike_report(suite, [mecl], results, metrics, str(tmp_path / "elsewhere")) == []
    # No ICRL run scored now
    assert probe_rows_unlike_report(suite, [], results, metrics, root) == []
