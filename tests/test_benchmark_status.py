"""``sb3-icrl benchmark status``: where each run of a suite stands, read from the run folders alone."""

import dataclasses
import fcntl
import io
import json
import os
import pathlib
import shutil
import textwrap
import time
import zipfile

import pytest
import torch as th
from model_files import write_whole_zip

from sb3_icrl.benchmark import load_suite
from sb3_icrl.benchmark.cli import main as benchmark_main
from sb3_icrl.benchmark.runner import run_lock
from sb3_icrl.benchmark.status import (
    RunStatus,
    held_lock_inodes,
    mark_reported,
    seconds_left,
    status_lines,
    suite_status,
    transfer_seconds,
)
from sb3_icrl.run_folder import training_progress, training_time_so_far, write_attempt
from sb3_icrl.zoo.hyperparams import load_hyperparams
from sb3_icrl.zoo.runs import FAILED_FILE, FINISHED_FILE

#: Tests that need this machine's lock table (/proc/locks: Linux, and not every sandbox)
LINUX_LOCKS = pytest.mark.skipif(held_lock_inodes() is None, reason="no readable /proc/locks")
SUITE = """\
description: five runs in five states
envs: [GridWorldWall-v0]
algos: [bc2l]
seeds: [0, 1, 2, 3, 4]
steps: 1000
"""


@pytest.fixture
def suite_in_five_states(tmp_path):
    """Seed 0 finished (1000 steps in 500 s), 1 failed at 200, 2 interrupted at 400, 3 training now at 600, 4 not
    started."""
    path = tmp_path / "five.yml"
    path.write_text(textwrap.dedent(SUITE))
    suite = load_suite(str(path))
    root = str(tmp_path / "logs")
    runs = suite.runs()
    folders = [run.run_folder(root) for run in runs]
    for folder in folders[:4]:
        os.makedirs(folder)
    with open(os.path.join(folders[0], FINISHED_FILE), "w") as file:
        json.dump({"num_timesteps": 1000, "wall_time_total_s": 500.0}, file)
    write_whole_zip(os.path.join(folders[0], "GridWorldWall-v0.zip"))  # its final model
    for folder, steps in zip(folders[1:4], (200, 400, 600), strict=True):
        write_whole_zip(os.path.join(folder, f"rl_model_{steps}_steps.zip"))
        write_whole_zip(os.path.join(folder, f"rl_model_{steps // 2}_steps.zip"))
    with open(os.path.join(folders[1], FAILED_FILE), "w") as file:
        json.dump({"error": "ValueError: bad things"}, file)
    return suite, root, runs


@LINUX_LOCKS
def test_each_state_and_the_time_left(suite_in_five_states):
    _, root, runs = suite_in_five_states
    with run_lock(runs[3].run_folder(root)) as locked:  # the suite trains seed 3 now
        assert locked
        statuses = suite_status(runs, root)
    assert [status.state for status in statuses] == ["finished", "failed", "interrupted", "running", "not started"]
    assert [status.steps_done for status in statuses] == [1000, 200, 400, 600, None]
    assert all(status.steps_total == 1000 for status in statuses)
    assert statuses[0].wall_time_s == 500.0 and statuses[1].error == "ValueError: bad things"
    # 0.5 s per step: (800 + 600 + 400 + 1000) steps left
    assert seconds_left(statuses) == (pytest.approx(1400.0), 0)
    lines = status_lines(statuses)
    assert len(lines) == 1 + 4 + 1 + 1  # header, the four runs not finished, blank, summary
    assert "bc2l/GridWorldWall-v0/seed 0" not in "\n".join(lines)
    assert "bc2l/GridWorldWall-v0/seed 0" in "\n".join(status_lines(statuses, verbose=True))
    assert lines[-1] == (
        "1 finished · 1 running · 1 interrupted · 1 failed · 1 not started · 0.1 core-hours in the finished runs · "
        "about 0.4 core-hours left at the finished runs' pace"
    )


def test_a_lock_released_is_no_longer_running(suite_in_five_states):
    _, root, runs = suite_in_five_states
    with run_lock(runs[3].run_folder(root)):
        pass
    assert suite_status(runs, root)[3].state == "interrupted"


def test_without_a_finished_run_the_time_left_is_not_guessed(suite_in_five_states):
    _, root, runs = suite_in_five_states
    os.remove(os.path.join(runs[0].run_folder(root), FINISHED_FILE))
    statuses = suite_status(runs, root)
    assert seconds_left(statuses) == (0.0, 5)
    assert status_lines(statuses)[-1].endswith(" · time left unknown until a run of an env finishes")


def _write_monitor(folder: str, rows: list[tuple[int, float]], written: float) -> None:
    """A training Monitor file with episodes of (steps, end time in seconds), last written at ``written``."""
    path = os.path.join(folder, "0.monitor.csv")
    with open(path, "w") as file:
        file.write('#{"t_start": 0.0, "env_id": "GridWorldWall-v0"}\nr,l,t\n')
        file.writelines(f"1.0,{steps},{end}\n" for steps, end in rows)
    os.utime(path, (written, written))


def test_training_progress_counts_each_attempt_of_a_resumed_run(tmp_path):
    run = str(tmp_path)
    assert training_progress(run) is None  # no Monitor file yet
    # One attempt to 30 s, then a resumed one (its Monitor counts from zero again) to 15 s, written 10 s ago
    _write_monitor(run, [(100, 10.0), (100, 20.0), (100, 30.0), (100, 5.0), (100, 15.0)], written=1000.0)
    os.makedirs(os.path.join(run, "eval"))
    _write_monitor(os.path.join(run, "eval"), [(9999, 99999.0)], written=1000.0)  # evaluation episodes do not count
    assert training_progress(run, now=1010.0) == (500, pytest.approx(30.0 + 15.0 + 10.0))
    with open(os.path.join(run, "0.monitor.csv"), "a") as file:
        file.write("1.0,10")  # an episode cut short while it is written
    assert training_progress(run, now=1010.0)[0] == 500


@LINUX_LOCKS
def test_a_running_run_shows_its_steps_time_and_pace_from_its_monitor(suite_in_five_states):
    _, root, runs = suite_in_five_states
    folder = runs[3].run_folder(root)  # its last checkpoint is at 600 steps
    now = time.time()
    _write_monitor(folder, [(350, 100.0), (350, 200.0)], written=now - 50.0)
    with run_lock(folder):
        statuses = suite_status(runs, root)
    running = statuses[3]
    assert running.state == "running" and running.steps_done == 700  # the episodes are newer than the checkpoint
    assert running.wall_time_s == pytest.approx(250.0, abs=5.0)
    lines = status_lines(statuses)
    # Its own pace: 300 steps left at about 250 s / 700 steps
    line = next(line for line in lines if line.startswith("running"))
    assert "700 / 1,000" in line and "4.2 min" in line and line.endswith("(about 2 min of training left at its pace so far)")
    assert "the running runs' at their own so far" in lines[-1]
    # (800 + 600 + 1000) steps at the finished run's 0.5 s a step, and 300 at the running run's
    assert seconds_left(statuses) == (pytest.approx(1200.0 + 300 * running.wall_time_s / 700), 0)
    assert "core-hours in the finished runs" in lines[-1]  # the running run's time is not counted as spent


def test_a_resumed_runs_time_so_far_leaves_out_the_time_it_lay_stopped(tmp_path):
    run = str(tmp_path)
    assert training_time_so_far(run) is None  # no attempt record: the Monitor tells the time
    # The current attempt's clock started at t=5000, the run having trained 300 s before it stopped
    write_attempt(run, started=5000.0, resumed_wall_time_s=300.0)
    assert training_time_so_far(run, now=5030.0) == pytest.approx(330.0)
    # A record from before the attempt began (its lock taken at t=6000) is the previous attempt's: no time yet
    assert training_time_so_far(run, now=6010.0, not_before=6000.0) is None
    # A record that does not read, or holds no times, tells none
    (tmp_path / "attempt.json").write_text('{"started": "soon"}')
    assert training_time_so_far(run, now=5030.0) is None
    (tmp_path / "attempt.json").write_text("{cut")
    assert training_time_so_far(run, now=5030.0) is None


@LINUX_LOCKS
def test_a_running_resumed_run_takes_its_time_from_its_attempt_record_not_its_monitor_clock(suite_in_five_states):
    _, root, runs = suite_in_five_states
    folder = runs[3].run_folder(root)  # its last checkpoint is at 600 steps
    now = time.time()
    # An earlier attempt trained 300 s; this one's clock started 60 s ago, the Monitor clock carried on over the
    # 10,000 s between them
    _write_monitor(folder, [(350, 100.0), (350, 10_350.0)], written=now - 10.0)
    write_attempt(folder, started=now - 20_000.0, resumed_wall_time_s=0.0)  # the earlier attempt's record
    with run_lock(folder):  # taking the lock marks when this attempt began: now, after that record
        setting_up = suite_status(runs, root)[3]
        assert setting_up.wall_time_s == pytest.approx(10_360.0, abs=5.0)  # no record of its own yet: the Monitor's
        # As if the lock was taken 70 s ago and the attempt's clock started 60 s ago
        os.utime(folder + ".lock", (now - 70.0, now - 70.0))
        write_attempt(folder, started=now - 60.0, resumed_wall_time_s=300.0)
        running = suite_status(runs, root)[3]
    assert running.steps_done == 700 and running.wall_time_s == pytest.approx(360.0, abs=5.0)


def test_lock_table_parsing(tmp_path):
    table = tmp_path / "locks"
    table.write_text(
        "1: FLOCK  ADVISORY  WRITE 1234 00:2f:5678 0 EOF\n"
        "2: POSIX  ADVISORY  WRITE 99 08:01:42 0 EOF\n"
        "3: FLOCK  ADVISORY  WRITE 77 fd:00:9 0 EOF\n"
        "garbage\n"
    )
    assert held_lock_inodes(str(table)) == {5678, 9}  # flock locks only: the runner's run_lock
    assert held_lock_inodes(str(tmp_path / "missing")) is None


@LINUX_LOCKS
def test_the_lock_table_sees_a_lock_of_this_process(tmp_path):
    path = tmp_path / "run.lock"
    with open(path, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert os.stat(path).st_ino in held_lock_inodes()
        fcntl.flock(handle, fcntl.LOCK_UN)


def test_recipe_steps_when_the_suite_gives_none(tmp_path):
    path = tmp_path / "recipe.yml"
    path.write_text(textwrap.dedent(SUITE).replace("steps: 1000\n", ""))
    runs = load_suite(str(path)).runs()
    status = suite_status(runs[:1], str(tmp_path / "logs"))[0]
    recipe, _ = load_hyperparams("bc2l", "GridWorldWall-v0")
    assert status.state == "not started" and status.steps_total == int(float(recipe["n_timesteps"]))


def test_cli_prints_the_table_and_the_summary(suite_in_five_states, capsys):
    suite, root, _ = suite_in_five_states
    assert benchmark_main(["status", suite.path, "-f", root, "--only", "seed=0,4"]) == 0
    out = capsys.readouterr().out
    assert "suite five: 2 runs" in out
    assert "not started" in out and "- / 1,000" in out
    assert out.strip().splitlines()[-1].startswith("1 finished · 0 running · 0 interrupted · 0 failed · 1 not started")
    assert benchmark_main(["status", suite.path, "-f", root, "--only", "seed=9"]) == 2  # matches no run


def test_runs_of_an_env_without_a_finished_run_are_left_out_of_the_estimate(suite_in_five_states):
    _, root, runs = suite_in_five_states
    statuses = suite_status(runs, root)
    other_env = dataclasses.replace(runs[4], env_id="sb3_icrl/GridWorldSquare-v0")
    statuses.append(RunStatus(other_env, "not started", None, 1000))
    assert seconds_left(statuses)[1] == 1
    assert status_lines(statuses)[-1].endswith(
        "about 0.4 core-hours left at the finished runs' pace (not counting 1 run of unknown pace or steps)"
    )


@LINUX_LOCKS
def test_a_failed_run_tried_again_is_running_and_saved_steps_come_first(suite_in_five_states):
    _, root, runs = suite_in_five_states
    with run_lock(runs[1].run_folder(root)):  # the suite tries the failed run again; failed.json is still there
        assert suite_status(runs, root)[1].state == "running"
    config = os.path.join(runs[2].run_folder(root), "GridWorldWall-v0")
    os.makedirs(config)
    with open(os.path.join(config, "config.yml"), "w") as file:
        file.write("n_timesteps: 5000\n")
    steps_from_suite = suite_status(runs, root)[2].steps_total
    assert steps_from_suite == 1000  # the suite's steps are passed with -n: they win over the saved recipe
    unsized = [dataclasses.replace(run, steps=None) for run in runs]
    assert suite_status(unsized, root)[2].steps_total == 5000  # the recipe the run saved
    varied = dataclasses.replace(unsized[4], variant_settings={"hyperparams": {"n_timesteps": 777}})
    assert suite_status([varied], root)[0].steps_total == 777  # a variant's n_timesteps


def test_cli_says_when_the_log_folder_holds_no_run_of_the_suite(suite_in_five_states, tmp_path, capsys):
    suite, _, _ = suite_in_five_states
    assert benchmark_main(["status", suite.path, "-f", str(tmp_path / "typo")]) == 0
    assert "no run has started there; check -f" in capsys.readouterr().out


def test_another_variant_s_pace_is_not_used(suite_in_five_states):
    """A variant may train at another throughput (a faster recipe): its runs wait for a finished run of their own."""
    _, root, runs = suite_in_five_states
    statuses = suite_status(runs, root)
    faster = dataclasses.replace(runs[4], variant="family")
    statuses.append(RunStatus(faster, "not started", None, 1000))
    assert seconds_left(statuses) == (pytest.approx(1400.0), 1)
    statuses.append(RunStatus(dataclasses.replace(runs[0], variant="family"), "finished", 1000, 1000, wall_time_s=100.0))
    assert seconds_left(statuses) == (pytest.approx(1400.0 + 100.0), 0)  # 1000 steps at 0.1 s


def test_a_finished_run_whose_tensor_entry_is_cut_short_gets_a_note(suite_in_five_states, capsys):
    """A whole zip (every CRC holds) with a cut-short ``policy.pth``: status names it without loading the model."""
    suite, root, runs = suite_in_five_states
    tensors = io.BytesIO()
    th.save({"weight": th.zeros(8)}, tensors)
    final = os.path.join(runs[0].run_folder(root), "GridWorldWall-v0.zip")
    with zipfile.ZipFile(final, "w") as archive:
        archive.writestr("data", "{}")
        archive.writestr("policy.pth", tensors.getvalue())
    assert suite_status(runs[:1], root)[0].note is None  # a whole tensor archive
    with zipfile.ZipFile(final, "w") as archive:
        archive.writestr("data", "{}")
        archive.writestr("policy.pth", tensors.getvalue()[:100])
    status = suite_status(runs[:1], root)[0]
    assert status.state == "finished"
    assert status.note == (
        f"its final model {final} is damaged (its tensor entry 'policy.pth' is cut short or is not a torch archive): the "
        "report leaves it out; delete its finished.json to train it again"
    )
    assert benchmark_main(["status", suite.path, "-f", root, "--only", "seed=0"]) == 0
    assert "its tensor entry 'policy.pth' is cut short" in capsys.readouterr().out


def _committed_report(folder, suite_name: str, seeds: dict[int, float], recipe_version: str | None = None) -> str:
    """A report's summary.json holding bc2l on GridWorldWall, seed -> training time (1000 steps each)."""
    os.makedirs(folder, exist_ok=True)
    per_seed = [
        {"seed": seed, "wall_time_s": wall_time, "timesteps": 1000, "recipe_version": recipe_version}
        for seed, wall_time in seeds.items()
    ]
    cell = {"env": "GridWorldWall-v0", "variant": "base", "algo": "bc2l", "per_seed": per_seed}
    with open(os.path.join(folder, "summary.json"), "w") as file:
        json.dump({"suite": suite_name, "cells": [cell]}, file)
    return str(folder)


def test_runs_a_committed_report_holds_count_as_reported(suite_in_five_states, tmp_path):
    from sb3_icrl.benchmark.status import mark_reported, reported_runs

    suite, root, runs = suite_in_five_states
    # Seed 0 finished here, seed 2 stopped part-way here, seed 4 has no folder: only seed 4 takes the report's word
    report = _committed_report(tmp_path / "report", suite.name, {0: 900.0, 2: 900.0, 4: 300.0})
    statuses = mark_reported(suite_status(runs, root), reported_runs(report, suite.name, suite.recipe_version))
    assert [status.state for status in statuses] == ["finished", "failed", "interrupted", "interrupted", "reported"]
    assert (statuses[4].steps_done, statuses[4].wall_time_s) == (1000, 300.0)
    assert statuses[0].wall_time_s == 500.0  # a folder here is read, not the report
    # The pace is the finished and reported runs' (0.5 and 0.3 s a step): (800 + 600 + 400) steps left
    assert seconds_left(statuses) == (pytest.approx(1800 * 0.4), 0)
    assert status_lines(statuses)[-1].startswith(
        "1 finished · 1 reported · 0 running · 2 interrupted · 1 failed · 0 not started · 0.2 core-hours in the finished "
        "and reported runs"
    )


def test_a_report_at_another_recipe_version_or_of_another_suite_is_not_taken(suite_in_five_states, tmp_path):
    from sb3_icrl.benchmark.status import reported_runs

    suite, _, _ = suite_in_five_states
    report = _committed_report(tmp_path / "report", suite.name, {4: 300.0}, recipe_version="v1")
    assert reported_runs(report, suite.name, "v2") == {}
    assert set(reported_runs(report, suite.name, "v1")) == {("GridWorldWall-v0", "base", "bc2l", 4)}
    with pytest.raises(ValueError, match="a report of suite 'five', not of 'table3'"):
        reported_runs(report, "table3", None)
    with pytest.raises(ValueError, match=r"no report in .* \(no summary\.json\)"):
        reported_runs(str(tmp_path), suite.name, None)
    (tmp_path / "report" / "summary.json").write_text("{cut short")
    with pytest.raises(ValueError, match="is not a report's summary"):
        reported_runs(report, suite.name, None)


def test_cli_leaves_the_reported_runs_untrained(suite_in_five_states, tmp_path, capsys):
    suite, root, _ = suite_in_five_states
    report = _committed_report(tmp_path / "report", suite.name, {4: 300.0})
    assert benchmark_main(["status", suite.path, "-f", root, "--only", "seed=4", "--reported", report]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1].startswith("0 finished · 1 reported")
    assert benchmark_main(["run", suite.path, "-f", root, "--only", "seed=4", "--reported", report, "--no-report"]) == 0
    assert f"not trained again: 1 run that {report} holds" in capsys.readouterr().out
    assert not os.path.exists(suite.runs()[4].run_folder(root))  # nothing trained
    assert benchmark_main(["status", suite.path, "-f", root, "--reported", str(tmp_path)]) == 2
    assert "--reported: no report in" in capsys.readouterr().err


def test_a_reported_ppo_row_is_trained_again_before_its_seeds_icrl_runs(tmp_path, monkeypatch, capsys):
    """The identification of an ICRL run reads its seed's PPO episodes: a reported PPO run with no folder here is
    trained again, before that seed's ICRL runs, when they are to train (grid worlds read no such episodes)."""
    import sb3_icrl.benchmark.cli as cli

    path = tmp_path / "probes.yml"
    path.write_text(
        "description: two methods and PPO, two seeds\nenvs: [BiasedPendulum-v0, GridWorldWall-v0]\n"
        "algos: [bc2l, mecl, ppo]\nseeds: [0, 1]\n"
    )
    suite = load_suite(str(path))
    pendulum = [run for run in suite.runs() if run.env_id.endswith("BiasedPendulum-v0")]
    assert suite.probe_run(pendulum[0]) == pendulum[4]  # bc2l seed 0 -> ppo seed 0
    assert suite.probe_run(pendulum[4]) is None  # PPO's own run reads none
    assert all(suite.probe_run(run) is None for run in suite.runs() if run.env_id.endswith("GridWorldWall-v0"))
    assert dataclasses.replace(suite, algos=["bc2l", "mecl"]).probe_run(pendulum[0]) is None
    # All at once: each pendulum ICRL run to its seed's PPO run, nothing for PPO or the grid world
    assert suite.probe_runs(suite.runs()) == {run: pendulum[4 + run.seed] for run in pendulum[:4]}

    # The report holds PPO on both envs and seeds, and bc2l seed 0 on the pendulum
    report = tmp_path / "report"
    report.mkdir()
    cells = [
        {"env": env, "variant": "base", "algo": "ppo", "per_seed": [{"seed": 0}, {"seed": 1}]}
        for env in ("BiasedPendulum-v0", "GridWorldWall-v0")
    ]
    cells.append({"env": "BiasedPendulum-v0", "variant": "base", "algo": "bc2l", "per_seed": [{"seed": 0}]})
    (report / "summary.json").write_text(json.dumps({"suite": suite.name, "cells": cells}))
    started: list[list[str]] = []
    monkeypatch.setattr(cli, "run_all", lambda runs, *args, **kwargs: started.append([r.name for r in runs]) or [])
    root = str(tmp_path / "logs")
    base = ["run", str(path), "-f", root, "--no-report", "--reported", str(report), "--order", "seed"]
    assert benchmark_main([*base, "--only", "env=BiasedPendulum-v0"]) == 0
    assert started[-1] == [
        "base/ppo/BiasedPendulum-v0/seed 0",  # bc2l seed 0 is reported, mecl seed 0 is not
        "base/mecl/BiasedPendulum-v0/seed 0",
        "base/ppo/BiasedPendulum-v0/seed 1",
        "base/bc2l/BiasedPendulum-v0/seed 1",
        "base/mecl/BiasedPendulum-v0/seed 1",
    ]
    assert "trained again: 2 reported PPO runs with no folder here" in capsys.readouterr().out
    assert benchmark_main(["status", str(path), "-f", root, "--reported", str(report), "--only", "env=BiasedPendulum-v0"]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-2] == (
        "`run --reported` also trains again 2 reported PPO runs with no folder here, whose episodes the identification "
        "probes of their seed's ICRL runs read (base/ppo/BiasedPendulum-v0/seed 0, base/ppo/BiasedPendulum-v0/seed 1)"
    )
    # Selected alone, an ICRL run brings its PPO row; a PPO folder here, or a grid world, brings none
    assert benchmark_main([*base, "--only", "env=BiasedPendulum-v0", "seed=1", "algo=mecl"]) == 0
    assert started[-1] == ["base/ppo/BiasedPendulum-v0/seed 1", "base/mecl/BiasedPendulum-v0/seed 1"]
    capsys.readouterr()
    os.makedirs(pendulum[5].run_folder(root))
    assert benchmark_main([*base, "--only", "env=BiasedPendulum-v0", "seed=1", "algo=mecl"]) == 0
    assert started[-1] == ["base/mecl/BiasedPendulum-v0/seed 1"]
    assert benchmark_main([*base, "--only", "env=GridWorldWall-v0", "seed=1", "algo=mecl"]) == 0
    assert started[-1] == ["base/mecl/GridWorldWall-v0/seed 1"]
    assert "trained again" not in capsys.readouterr().out

    # Without --reported, a PPO row neither selected nor finished here is named, with the way to bring it
    no_report = ["run", str(path), "-f", root, "--no-report"]
    assert benchmark_main([*no_report, "--only", "env=BiasedPendulum-v0", "seed=0", "algo=mecl"]) == 0
    assert started[-1] == ["base/mecl/BiasedPendulum-v0/seed 0"]
    assert (
        "1 of those PPO runs is neither selected nor finished here (base/ppo/BiasedPendulum-v0/seed 0): add algo=ppo to "
        "--only" in capsys.readouterr().out
    )
    assert benchmark_main([*no_report, "--only", "env=BiasedPendulum-v0", "seed=0", "algo=mecl,ppo"]) == 0
    assert "note: the identification" not in capsys.readouterr().out
    ppo_folder = pendulum[4].run_folder(root)
    os.makedirs(ppo_folder)
    with open(os.path.join(ppo_folder, FINISHED_FILE), "w") as file:
        json.dump({"num_timesteps": 1000, "wall_time_total_s": 500.0}, file)
    write_whole_zip(os.path.join(ppo_folder, "BiasedPendulum-v0.zip"))
    assert benchmark_main([*no_report, "--only", "env=BiasedPendulum-v0", "seed=0", "algo=mecl"]) == 0
    assert "note: the identification" not in capsys.readouterr().out
    assert benchmark_main([*no_report, "--only", "env=GridWorldWall-v0", "seed=0", "algo=mecl"]) == 0
    assert "note: the identification" not in capsys.readouterr().out
    # status names the same rows: seed 0's PPO is finished now, seed 1's folder holds no model
    assert benchmark_main(["status", str(path), "-f", root, "--only", "env=BiasedPendulum-v0", "algo=mecl"]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last.startswith("note: the identification") and "1 of those PPO runs" in last
    assert "(base/ppo/BiasedPendulum-v0/seed 1)" in last


def test_a_reported_ppo_row_whose_policy_the_report_keeps_is_not_trained_again(tmp_path, monkeypatch, capsys):
    """``run --reported`` restores the PPO rows' policies the report keeps, and trains again only the others."""
    import sb3_icrl.benchmark.cli as cli

    path = tmp_path / "probes.yml"
    path.write_text("description: a method and PPO, two seeds\nenvs: [BiasedPendulum-v0]\nalgos: [mecl, ppo]\nseeds: [0, 1]\n")
    report = tmp_path / "report"
    report.mkdir()
    cells = [{"env": "BiasedPendulum-v0", "variant": "base", "algo": "ppo", "per_seed": [{"seed": 0}, {"seed": 1}]}]
    (report / "summary.json").write_text(json.dumps({"suite": "probes", "cells": cells}))
    kept = report / "probe_policies" / "base" / "ppo" / "BiasedPendulum-v0_0"
    (kept / "BiasedPendulum-v0").mkdir(parents=True)
    for name, text in (
        ("BiasedPendulum-v0.zip", "model"),
        ("BiasedPendulum-v0/args.yml", "algo: ppo\n"),
        (FINISHED_FILE, "{}"),
    ):
        (kept / name).write_text(text)
    root = str(tmp_path / "logs")
    base = ["--only", "env=BiasedPendulum-v0", "algo=mecl", "--reported", str(report)]
    assert benchmark_main(["status", str(path), "-f", root, *base]) == 0
    assert "also trains again 1 reported PPO run with no folder here" in capsys.readouterr().out
    started: list[list[str]] = []
    monkeypatch.setattr(cli, "run_all", lambda runs, *args, **kwargs: started.append([r.name for r in runs]) or [])
    assert benchmark_main(["run", str(path), "-f", root, "--no-report", "--order", "seed", *base]) == 0
    assert started[-1] == [
        "base/mecl/BiasedPendulum-v0/seed 0",
        "base/ppo/BiasedPendulum-v0/seed 1",
        "base/mecl/BiasedPendulum-v0/seed 1",
    ]
    out = capsys.readouterr().out
    assert f"probe policies: 1 restored from {report}" in out and "trained again: 1 reported PPO run" in out
    assert os.path.isfile(os.path.join(root, "probes", "base", "probe_policies", "ppo", "BiasedPendulum-v0_0", FINISHED_FILE))


def test_runs_start_seed_by_seed_when_asked(tmp_path, monkeypatch):
    import sb3_icrl.benchmark.cli as cli

    path = tmp_path / "two.yml"
    path.write_text("description: two algorithms, two seeds\nenvs: [GridWorldWall-v0]\nalgos: [bc2l, mecl]\nseeds: [0, 1]\n")
    started: list[list[tuple[str, int]]] = []
    monkeypatch.setattr(cli, "run_all", lambda runs, *args, **kwargs: started.append([(r.algo, r.seed) for r in runs]) or [])
    root = str(tmp_path / "logs")
    assert benchmark_main(["run", str(path), "-f", root, "--no-report", "--jobs", "1"]) == 0
    assert benchmark_main(["run", str(path), "-f", root, "--no-report", "--jobs", "1", "--order", "seed"]) == 0
    assert started == [
        [("bc2l", 0), ("bc2l", 1), ("mecl", 0), ("mecl", 1)],  # the suite's order: algorithm, then seed
        [("bc2l", 0), ("mecl", 0), ("bc2l", 1), ("mecl", 1)],  # every algorithm's seed 0 first
    ]


def test_seed_by_seed_starts_each_seeds_ppo_row_first(tmp_path, monkeypatch):
    """Within a seed, the PPO row whose episodes the seed's ICRL runs are scored on comes before them."""
    import sb3_icrl.benchmark.cli as cli

    path = tmp_path / "mixed.yml"
    path.write_text(
        "description: ICRL and reference rows\nenvs: [BiasedPendulum-v0]\nalgos: [mecl, ppo, ppolag]\nseeds: [0, 1]\n"
    )
    started: list[list[tuple[str, int]]] = []
    monkeypatch.setattr(cli, "run_all", lambda runs, *args, **kwargs: started.append([(r.algo, r.seed) for r in runs]) or [])
    root = str(tmp_path / "logs")
    assert benchmark_main(["run", str(path), "-f", root, "--no-report", "--jobs", "1", "--order", "seed"]) == 0
    assert (
        benchmark_main(
            ["run", str(path), "-f", root, "--no-report", "--jobs", "1", "--order", "seed", "--only", "algo=mecl,ppolag"]
        )
        == 0
    )
    assert started == [
        [("ppo", 0), ("mecl", 0), ("ppolag", 0), ("ppo", 1), ("mecl", 1), ("ppolag", 1)],
        [("mecl", 0), ("ppolag", 0), ("mecl", 1), ("ppolag", 1)],  # an unselected PPO row is not brought
    ]


def test_transfer_tests_to_come_and_their_time(tmp_path):
    """A suite with transfer tests: those done are timed (each reference learner once), those to come estimated."""
    path = tmp_path / "transfer.yml"
    path.write_text(
        textwrap.dedent(SUITE).replace("seeds: [0, 1, 2, 3, 4]\n", "seeds: [0, 1, 2]\ntransfer: {tasks: [same]}\n")
    )
    suite = load_suite(str(path))
    root = str(tmp_path / "logs")
    runs = suite.runs()
    for run in runs[:2]:  # seeds 0 and 1 trained, 1000 steps in 500 s; seed 2 not started
        folder = run.run_folder(root)
        os.makedirs(folder)
        with open(os.path.join(folder, FINISHED_FILE), "w") as file:
            json.dump({"num_timesteps": 1000, "wall_time_total_s": 500.0}, file)
        write_whole_zip(os.path.join(folder, "GridWorldWall-v0.zip"))
    # Seed 0's transfer test done: its learned-cost learner 10 minutes, the oracle 20 and PPO 30
    transfer = {
        "settings": {"reference_files": {"oracle": "/refs/oracle_0.json", "ppo": "/refs/ppo_0.json"}},
        "results": {"learned": {"wall_time_min": 10.0}, "oracle": {"wall_time_min": 20.0}, "ppo": {"wall_time_min": 30.0}},
    }
    with open(os.path.join(runs[0].run_folder(root), "transfer_same.json"), "w") as file:
        json.dump(transfer, file)
    statuses = suite_status(runs, root)
    assert [(status.transfers_due, status.transfers_left) for status in statuses] == [(1, 0), (1, 1), (1, 1)]
    assert statuses[0].transfer_wall_time_s == 600.0
    assert statuses[0].transfer_references_s == {"oracle_0.json": 1200.0, "ppo_0.json": 1800.0}
    assert statuses[1].note == "1 transfer test to come"
    # Spent: 600 + 1200 + 1800 s. Left: two tests of 600 s, and seeds 1 and 2 train their references (3000 s each)
    assert transfer_seconds(statuses) == (3600.0, pytest.approx(2 * 600 + 2 * 3000), 0)
    assert status_lines(statuses)[-1] == (
        "2 finished · 0 running · 0 interrupted · 0 failed · 1 not started · 2 transfer tests to come · 0.3 core-hours in "
        "the finished runs and 1.0 in their transfer tests · about 2.1 core-hours left at the finished runs' pace "
        "(0.1 training, 2.0 transfer tests)"
    )
    # Seed 2 reported with its transfer test (its own references): nothing of it is left to come
    reported = {
        (*runs[2].cell, 2): {
            "wall_time_s": 500.0,
            "timesteps": 1000,
            "transfer_wall_time_s": 600.0,
            "transfer_reference_wall_time_s": {"oracle_2.json": 1200.0, "ppo_2.json": 1800.0},
        }
    }
    marked = mark_reported(statuses, reported)
    assert (marked[2].state, marked[2].transfers_left) == ("reported", 0)
    assert transfer_seconds(marked) == (7200.0, pytest.approx(600 + 3000), 0)
    assert status_lines(marked)[-1].endswith(
        "1 transfer test to come · 0.4 core-hours in the finished and reported runs and 2.0 in their transfer tests · "
        "about 1.0 core-hours left at the finished runs' pace (0.0 training, 1.0 transfer tests)"
    )


@LINUX_LOCKS
def test_a_running_transfer_test_shows_its_learner_s_steps_from_the_run_s_log(tmp_path):
    path = tmp_path / "transfer.yml"
    path.write_text(textwrap.dedent(SUITE).replace("seeds: [0, 1, 2, 3, 4]\n", "seeds: [0]\ntransfer: {tasks: [same]}\n"))
    run = load_suite(str(path)).runs()[0]
    root = str(tmp_path / "logs")
    folder = run.run_folder(root)
    os.makedirs(folder)
    with open(os.path.join(folder, FINISHED_FILE), "w") as file:
        json.dump({"num_timesteps": 1000, "wall_time_total_s": 500.0}, file)
    write_whole_zip(os.path.join(folder, "GridWorldWall-v0.zip"))
    os.makedirs(os.path.dirname(run.log_file(root)))
    with open(run.log_file(root), "w") as file:
        file.write(
            "\n=== 2026-01-01 10:00:00 python -m sb3_icrl.zoo train --algo bc2l\n...training output...\n"
            "\n=== 2026-01-01 10:30:00 python -m sb3_icrl.metrics.transfer logs/bc2l/GridWorldWall-v0_1 --task same\n"
            "transfer (same) on sb3_icrl/GridWorldWall-v0: training learned for 2000000 steps\n"
            "  learned: 200000/2000000 steps, 2000 steps/s\n"
            "  learned: 400000/2000000 steps, 2000 steps/s\n"
        )
    with run_lock(folder) as taken:  # the engine's lock while it runs the test
        assert taken
        (status,) = suite_status([run], root)
    learner = "the same task's learned learner at 400,000 / 2,000,000 steps, about 13 min left at its pace"
    assert status.note == f"1 transfer test running: {learner}"
    (status,) = suite_status([run], root)  # the lock released: the test is to come, whatever its log says
    assert status.note == "1 transfer test to come"


def _transfer_with_references(run, root: str, outside: str) -> tuple[dict[str, str], dict]:
    """A transfer result in the run's folder that read an oracle kept beside the suite's runs and a PPO kept elsewhere,
    each saved as ``sb3-icrl transfer`` saves a reference (its file named by its settings)."""
    from sb3_icrl import __version__
    from sb3_icrl.metrics.transfer import reference_file

    shared = os.path.join(run.log_folder(root), "transfer_references")
    os.makedirs(shared, exist_ok=True)
    os.makedirs(outside, exist_ok=True)
    settings = {learner: {"env": "sb3_icrl/GridWorldWall-v0", "seed": 0, "learner": learner} for learner in ("oracle", "ppo")}
    files = {
        "oracle": str(reference_file(shared, "oracle", settings["oracle"])),
        "ppo": str(reference_file(outside, "ppo", settings["ppo"])),
    }
    for learner, path in files.items():
        with open(path, "w") as file:
            json.dump(
                {"settings": settings[learner], "result": {"feasible_reward": 1.0}, "sb3_icrl_version": __version__}, file
            )
    with open(os.path.join(run.run_folder(root), "transfer_same.json"), "w") as file:
        json.dump({"settings": {"reference_files": files}, "results": {}, "violation_rate": 0.0}, file)
    return files, settings


def test_a_report_keeps_the_transfer_references_and_run_reported_restores_them(suite_in_five_states, tmp_path, capsys):
    from sb3_icrl.benchmark.report import keep_transfer_references, restore_transfer_references
    from sb3_icrl.metrics.transfer import _cached_reference

    suite, root, runs = suite_in_five_states
    files, settings = _transfer_with_references(runs[0], root, str(tmp_path / "elsewhere"))
    report = _committed_report(tmp_path / "report", suite.name, {4: 300.0})
    name = os.path.basename(files["oracle"])
    kept = os.path.join(report, "transfer_references", "base", name)
    # Only the reference kept beside the suite's runs; a run with no folder here (seed 4) is passed over
    assert keep_transfer_references([runs[0], runs[4]], root, report) == [kept]
    with open(kept) as file, open(files["oracle"]) as original:
        assert file.read() == original.read()
    assert keep_transfer_references([runs[0]], root, report) == []  # kept as it is: not written again
    # A log root moved since its transfer tests ran (their results name the old folder): found by name all the same
    moved_root = str(tmp_path / "moved")
    shutil.move(root, moved_root)
    os.remove(kept)
    assert keep_transfer_references([runs[0]], moved_root, report) == [kept]

    # On a machine without the log folder: restored where the transfer tests look them up, never over a file there,
    # and read by a transfer test with the same settings
    other_root = str(tmp_path / "other")
    restored = os.path.join(other_root, suite.name, "base", "transfer_references", name)
    os.makedirs(os.path.join(report, "transfer_references", "no-such-variant"))
    with open(os.path.join(report, "transfer_references", "no-such-variant", name), "w") as file:
        file.write("{}")
    damaged = os.path.join(report, "transfer_references", "base", "ppo_GridWorldWall-v0_0000000000000000.json")
    with open(damaged, "w") as file:
        file.write('{"settings": {"env": ')
    lines: list[str] = []
    assert restore_transfer_references(report, other_root, suite, log=lines.append) == [restored]
    assert lines == [f"transfer references: {damaged} is not a reference's result (no settings and result): not restored"]
    assert _cached_reference(pathlib.Path(restored), settings["oracle"], log=lines.append) == {"feasible_reward": 1.0}
    with open(restored, "w") as file:
        file.write('{"made": "here"}')
    assert restore_transfer_references(report, other_root, suite, log=lines.append) == []
    with open(restored) as file:
        assert json.load(file) == {"made": "here"}

    # `run --reported` restores them before any run starts
    fresh_root = str(tmp_path / "fresh")
    args = ["run", suite.path, "-f", fresh_root, "--only", "seed=4", "--reported", report, "--no-report"]
    assert benchmark_main(args) == 0
    out = capsys.readouterr().out
    assert "transfer references: 1 restored from" in out and "not restored" in out
    assert os.path.isfile(os.path.join(fresh_root, suite.name, "base", "transfer_references", name))


def _pace_report(folder, cells: list[tuple[str, str, list[tuple[float | None, int | None]]]]) -> str:
    """A report of another suite: per (env, algo) its runs' (training seconds, steps)."""
    os.makedirs(folder, exist_ok=True)
    summary = {
        "suite": "table",
        "cells": [
            {
                "env": env,
                "variant": "base",
                "algo": algo,
                "per_seed": [{"seed": i, "wall_time_s": wall, "timesteps": steps} for i, (wall, steps) in enumerate(runs)],
            }
            for env, algo, runs in cells
        ],
    }
    with open(os.path.join(folder, "summary.json"), "w") as file:
        json.dump(summary, file)
    return str(folder)


def test_a_report_lends_its_pace_to_runs_whose_env_has_no_finished_run(suite_in_five_states, tmp_path):
    from sb3_icrl.benchmark.status import report_pace

    _, root, runs = suite_in_five_states
    report = _pace_report(
        tmp_path / "table",
        [
            # 0.2 and 0.4 s a step (a run without a time is left out); bc2l on the wall at 5 s a step, not used: the
            # suite's own finished run gives the wall's pace
            ("GridWorldSquare-v0", "bc2l", [(200.0, 1000), (400.0, 1000), (None, 1000)]),
            ("GridWorldWall-v0", "bc2l", [(5000.0, 1000)]),
            ("GridWorldSquare-v0", "mecl", [(9000.0, 1000)]),
        ],
    )
    pace = report_pace(report)
    assert pace[("GridWorldSquare-v0", "bc2l")] == pytest.approx([0.2, 0.4])
    statuses = suite_status(runs, root)
    square = dataclasses.replace(runs[4], env_id="sb3_icrl/GridWorldSquare-v0")
    statuses.append(RunStatus(square, "not started", None, 1000))
    assert seconds_left(statuses) == (pytest.approx(1400.0), 1)
    # The square run: 1000 steps at the report's mean 0.3 s a step
    assert seconds_left(statuses, pace) == (pytest.approx(1400.0 + 300.0), 0)
    assert status_lines(statuses, lent_pace=(report, pace))[-1].endswith(
        "about 0.5 core-hours left at the finished runs' pace (0.1 of them for 1 run at the pace of the runs of the same "
        f"env and algorithm in {report})"
    )
    # Where no run of the suite has a pace of its own, the estimate is the report's alone
    alone = [status for status in statuses if status.run.env_id == square.env_id]
    assert status_lines(alone, lent_pace=(report, pace))[-1].endswith(
        f"about 0.1 core-hours left at the pace of the runs of the same env and algorithm in {report}"
    )
    # A finished run of another algorithm of the same variant and env (PPO at 10 s a step) does not price the square
    # bc2l run: the report's bc2l pace comes first
    ppo = dataclasses.replace(square, algo="ppo")
    priced = [*statuses, RunStatus(ppo, "finished", 1000, 1000, wall_time_s=10_000.0)]
    assert seconds_left(priced, pace) == (pytest.approx(1400.0 + 300.0), 0)
    # An algorithm the report lacks stays unknown
    other = [RunStatus(dataclasses.replace(square, algo="vicrl"), "not started", None, 1000)]
    assert seconds_left(other, pace) == (0.0, 1)


def test_cli_status_takes_a_pace_from_a_report_and_refuses_a_folder_without_one(suite_in_five_states, tmp_path, capsys):
    suite, root, _ = suite_in_five_states
    shutil.rmtree(os.path.join(root, suite.name))  # no run has started: the suite's own pace is unknown
    report = _pace_report(tmp_path / "table", [("GridWorldWall-v0", "bc2l", [(720.0, 1000)])])
    assert benchmark_main(["status", suite.path, "-f", root, "--pace-from", report]) == 0
    # Five runs of 1000 steps at 0.72 s a step
    assert f"about 1.0 core-hours left at the pace of the runs of the same env and algorithm in {report}" in (
        capsys.readouterr().out
    )
    assert benchmark_main(["status", suite.path, "-f", root, "--pace-from", str(tmp_path)]) == 2
    assert f"--pace-from: no report in {str(tmp_path)!r} (no summary.json)" in capsys.readouterr().err
    # Times that are no number of seconds are left out; a cell without an algorithm is refused by name
    unusable = [(None, None), (float("nan"), 1000), (-5.0, 1000)]
    empty = _pace_report(tmp_path / "empty", [("GridWorldWall-v0", "bc2l", unusable)])
    assert benchmark_main(["status", suite.path, "-f", root, "--pace-from", empty]) == 2
    assert "its runs have no training time and steps to take a pace from" in capsys.readouterr().err
    nameless = tmp_path / "nameless"
    nameless.mkdir()
    (nameless / "summary.json").write_text(json.dumps({"suite": "table", "cells": [{"env": "GridWorldWall-v0"}]}))
    assert benchmark_main(["status", suite.path, "-f", root, "--pace-from", str(nameless)]) == 2
    assert "a cell of its summary.json names no env and algo" in capsys.readouterr().err
