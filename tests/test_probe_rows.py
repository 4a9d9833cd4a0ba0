"""
``report --update`` names an ICRL run whose identification probes read a ``ppo`` folder that is not the ``ppo`` row
the report keeps (a row trained again, stopped and resumed, differs from the reported one); the identification's cache
is not read once that folder's model is newer than it.
"""

import json
import os
import pathlib
import types

import pytest
from model_files import write_whole_zip

from sb3_icrl.benchmark import load_suite
from sb3_icrl.benchmark.report import probe_rows_unlike_report
from sb3_icrl.metrics.identification import IDENTIFICATION_FILE, identify_run
from sb3_icrl.zoo.train import main as train_main

SUITE = """\
description: probe rows
envs: [BiasedPendulum-v0]
algos: [mecl, vicrl, ppo]
seeds: [0]
steps: 1000
"""

REPORTED = {"last_training_feasible_reward": 4.0, "last_training_violation_rate": 0.5, "training_starts": 1}


@pytest.fixture
def probed(tmp_path):
    """
    The suite, its MECL, VICRL and PPO runs, the log root, and the report's results and metrics: the PPO row kept from
    an earlier summary with :data:`REPORTED`, the two ICRL runs scored now on the PPO folder here, whose last training
    episodes are 1 of 2 broken at 4.0 feasible, in one training start.
    """
    path = tmp_path / "probes.yml"
    path.write_text(SUITE)
    suite = load_suite(path)
    mecl, vicrl, ppo = (next(run for run in suite.runs() if run.algo == algo) for algo in ("mecl", "vicrl", "ppo"))
    root = str(tmp_path / "logs")
    folder = ppo.run_folder(root)
    os.makedirs(folder)
    with open(os.path.join(folder, "0.monitor.csv"), "w") as file:
        file.write('#{"t_start": 0}\nr,l,t,true_violation,true_feasible_reward\n3.0,10,1,1.0,3.0\n5.0,10,2,0.0,5.0\n')
    with open(os.path.join(folder, "command.txt"), "w") as file:
        file.write("python train.py --algo ppo\n")
    keys = {run: os.path.relpath(run.run_folder(root), root) for run in (mecl, vicrl, ppo)}
    results = [(run, types.SimpleNamespace(run=key)) for run, key in keys.items()]
    metrics = {keys[ppo]: dict(REPORTED)}
    for run in (mecl, vicrl):  # as the identification records it: relative to the ICRL run's folder
        metrics[keys[run]] = {"identification_unconstrained_run": os.path.relpath(folder, run.run_folder(root))}
    return suite, (mecl, vicrl, ppo), root, results, metrics, keys


def test_a_folder_that_is_the_reported_row_is_not_named(probed):
    suite, (mecl, vicrl, _), root, results, metrics, _ = probed
    assert probe_rows_unlike_report(suite, [mecl, vicrl], results, metrics, root) == []


def test_other_last_episodes_name_the_row_and_every_run_it_probed(probed):
    suite, (mecl, vicrl, ppo), root, results, metrics, keys = probed
    metrics[keys[ppo]]["last_training_feasible_reward"] = 4.5
    (line,) = probe_rows_unlike_report(suite, [mecl, vicrl], results, metrics, root)
    assert line.startswith(f"{ppo.name}: its folder here is not the reported row (last training episodes 4.0 / 50% against")
    assert f"the report's 4.5 / 50%), yet it probed {mecl.name}, {vicrl.name}: move that folder out" in line
    assert "train the row again without a stop" in line


def test_another_start_count_names_the_row_and_a_resumed_reported_row_has_no_remedy(probed):
    suite, (mecl, _, ppo), root, results, metrics, keys = probed
    with open(os.path.join(ppo.run_folder(root), "command.txt"), "a") as file:
        file.write("python train.py --algo ppo\n")  # resumed once here
    (line,) = probe_rows_unlike_report(suite, [mecl], results, metrics, root)
    assert "(training starts 2 against 1)" in line and "train the row again without a stop" in line
    # The reported row itself resumed: no training here gives its episodes
    metrics[keys[ppo]]["training_starts"] = 3
    (line,) = probe_rows_unlike_report(suite, [mecl], results, metrics, root)
    assert "training starts 2 against 3" in line and "the reported row itself started 3 times" in line


def test_a_folder_without_readable_episodes_is_judged_by_its_training_starts(probed):
    suite, (mecl, _, ppo), root, results, metrics, keys = probed
    with open(os.path.join(ppo.run_folder(root), "0.monitor.csv"), "w") as file:
        file.write('#{"t_start": 0}\nr,l,t\n3.0,10,1\n')  # no true_* columns
    metrics[keys[ppo]]["last_training_feasible_reward"] = 4.5
    assert probe_rows_unlike_report(suite, [mecl], results, metrics, root) == []
    metrics[keys[ppo]]["training_starts"] = 2
    (line,) = probe_rows_unlike_report(suite, [mecl], results, metrics, root)
    assert "(training starts 1 against 2)" in line and "last training episodes" not in line


def test_runs_not_scored_on_that_folder_or_a_row_reported_now_are_not_named(probed, tmp_path):
    suite, (mecl, vicrl, ppo), root, results, metrics, keys = probed
    metrics[keys[ppo]]["last_training_feasible_reward"] = 4.5
    # The PPO row reported by this same report (scored now): the report shows that folder's own numbers
    assert probe_rows_unlike_report(suite, [mecl, ppo], results, metrics, root) == []
    # A run whose identification read another folder (the folder here unfinished, say) or none, or was not scored
    metrics[keys[mecl]]["identification_unconstrained_run"] = "../../ppo/BiasedPendulum-v0_7"
    metrics[keys[vicrl]].pop("identification_unconstrained_run")
    assert probe_rows_unlike_report(suite, [mecl, vicrl], results, metrics, root) == []
    # A kept row from an older report without last-training values or training starts: nothing to compare
    metrics[keys[mecl]]["identification_unconstrained_run"] = os.path.relpath(ppo.run_folder(root), mecl.run_folder(root))
    metrics[keys[ppo]] = {}
    assert probe_rows_unlike_report(suite, [mecl], results, metrics, root) == []
    # No ICRL run scored now
    assert probe_rows_unlike_report(suite, [], results, metrics, root) == []


def test_the_identification_cache_is_not_read_once_the_probe_agent_is_newer(tmp_path):
    root = tmp_path / "logs"
    argv = ["--algo", "mecl", "--env", "GridWorldWall-v0", "-n", "256", "-f", str(root), "--seed", "0"]
    assert train_main([*argv, "--eval-freq", "0", "--save-freq", "0", "--num-threads", "1", "--verbose", "0"]) == 0
    run = root / "mecl" / "GridWorldWall-v0_1"
    agent = root / "ppo" / "GridWorldWall-v0_1"  # (grid worlds run no agent episodes: only the cache is at stake)
    agent.mkdir(parents=True)
    write_whole_zip(str(agent / "GridWorldWall-v0.zip"))
    first = identify_run(run, unconstrained_run=agent)
    cache = run / IDENTIFICATION_FILE
    written = cache.stat().st_mtime
    os.utime(agent / "GridWorldWall-v0.zip", (written - 10, written - 10))
    assert identify_run(run, unconstrained_run=agent) == json.loads(json.dumps(first))
    assert cache.stat().st_mtime == written  # read from the cache
    os.utime(agent / "GridWorldWall-v0.zip", (written + 10, written + 10))  # the agent trained again since
    assert identify_run(run, unconstrained_run=agent)["settings"] == first["settings"]
    assert cache.stat().st_mtime != written  # scored again


def _finish_ppo_folder(folder: str) -> dict[str, bytes]:
    """The files of a finished PPO run that its kept policy holds (stand-ins: only copied, never loaded here)."""
    files = {
        "BiasedPendulum-v0.zip": b"model",
        "BiasedPendulum-v0/args.yml": b"algo: ppo\n",
        "BiasedPendulum-v0/vecnormalize.pkl": b"statistics",
        "finished.json": b'{"timesteps": 1000}',
        "command.txt": b"python train.py --algo ppo\n",
    }
    for path, data in files.items():
        os.makedirs(os.path.dirname(os.path.join(folder, path)), exist_ok=True)
        with open(os.path.join(folder, path), "wb") as file:
            file.write(data)
    with open(os.path.join(folder, "rl_model_1000_steps.zip"), "wb") as file:
        file.write(b"checkpoint")  # not kept
    return files


def test_a_report_keeps_the_reported_ppo_row_s_policy_and_run_restores_it(probed, tmp_path):
    from sb3_icrl.benchmark.report import (
        keep_probe_policies,
        kept_probe_policy_folder,
        probe_policy_folder,
        restore_probe_policies,
    )
    from sb3_icrl.metrics.identification import find_unconstrained_run

    suite, (mecl, _, ppo), root, results, metrics, keys = probed
    files = _finish_ppo_folder(ppo.run_folder(root))
    report = str(tmp_path / "report")
    kept = kept_probe_policy_folder(report, ppo)
    assert kept == os.path.join(report, "probe_policies", "base", "ppo", "BiasedPendulum-v0_0")
    written = keep_probe_policies(suite, results, metrics, root, report)
    assert sorted(os.path.relpath(path, kept) for path in written) == sorted(files)  # the ICRL runs' folders: none
    assert not os.path.exists(os.path.join(kept, "rl_model_1000_steps.zip"))
    assert keep_probe_policies(suite, results, metrics, root, report) == []  # kept as it is: not written again

    # A folder that is not the reported row (other last training episodes, or another training start) is not kept
    other_report = str(tmp_path / "other_report")
    metrics[keys[ppo]]["last_training_feasible_reward"] = 4.5
    assert keep_probe_policies(suite, results, metrics, root, other_report) == []
    metrics[keys[ppo]].update(last_training_feasible_reward=4.0, training_starts=2)
    assert keep_probe_policies(suite, results, metrics, root, other_report) == []

    # Restored where the identification of the seed's ICRL runs finds it, never over a folder there
    other_root = str(tmp_path / "other")
    restored = probe_policy_folder(other_root, ppo)
    assert restored == os.path.join(other_root, suite.name, "base", "probe_policies", "ppo", "BiasedPendulum-v0_0")
    lines: list[str] = []
    assert restore_probe_policies(report, other_root, suite, log=lines.append) == [restored] and lines == []
    for path, data in files.items():
        with open(os.path.join(restored, path), "rb") as file:
            assert file.read() == data
    os.makedirs(mecl.run_folder(other_root))
    assert find_unconstrained_run(mecl.run_folder(other_root)) == pathlib.Path(restored).resolve()
    os.remove(os.path.join(restored, "finished.json"))
    assert restore_probe_policies(report, other_root, suite, log=lines.append) == []
    assert not os.path.exists(os.path.join(restored, "finished.json"))

    # A kept policy that lacks a file it needs stays in the report, named
    os.remove(os.path.join(kept, "BiasedPendulum-v0", "args.yml"))
    assert restore_probe_policies(report, str(tmp_path / "third"), suite, log=lines.append) == []
    assert lines == [f"probe policies: {kept} lacks BiasedPendulum-v0/args.yml: not restored"]
