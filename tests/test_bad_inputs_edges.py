"""
Bad inputs at the edges, each with a clear error that names the bad file or option: damaged model zips and
checkpoints, output folders that cannot be written, ``MODULE:EnvId`` mistakes, partial run folders, importer data
with NaNs, suite mistakes caught before any run.
"""

import builtins
import errno
import importlib
import io
import json
import os
import pathlib
import pickle
import re
import shutil
import zipfile
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize
from test_bad_inputs import TRAIN_TINY, CLIError, run_cli

from sb3_icrl import PILagrangian
from sb3_icrl.benchmark import load_suite, runner
from sb3_icrl.benchmark.suite import SuiteError
from sb3_icrl.common import utils
from sb3_icrl.common.env_ids import resolve_env_id
from sb3_icrl.common.vec_env import load_vec_normalize
from sb3_icrl.data import Trajectory, load_imitation_dataset, save_imitation_dataset
from sb3_icrl.data.importers import from_arrays, from_liu_pickles, from_malik_rollouts
from sb3_icrl.data.serialize import DemonstrationError
from sb3_icrl.plots.figures import load_evaluations, load_runs
from sb3_icrl.run_folder import FINISHED_FILE, latest_checkpoint

train_module = importlib.import_module("sb3_icrl.zoo.train")
enjoy_module = importlib.import_module("sb3_icrl.zoo.enjoy")
compare_module = importlib.import_module("sb3_icrl.zoo.compare")
data_cli = importlib.import_module("sb3_icrl.data.__main__")
benchmark_cli = importlib.import_module("sb3_icrl.benchmark.cli")
plots_cli = importlib.import_module("sb3_icrl.plots.__main__")

ENV = "GridWorldWall-v0"
#: How each damaged copy of a model zip is made, and the words the error uses for it
DAMAGES = {
    "truncated": "is cut short or damaged",
    "empty": "is empty (0 bytes)",
    "broken-tensor": "is damaged (its tensor entry 'policy.pth' is cut short",
    "broken-json": "is damaged (JSONDecodeError",
    "broken-pickle": "is damaged (UnpicklingError",
}


def damage(source: pathlib.Path, target: pathlib.Path, how: str) -> None:
    """Write a damaged copy of the model zip ``source`` to ``target``, as ``how`` (a key of :data:`DAMAGES`) says."""
    content = source.read_bytes()
    if how == "truncated":
        target.write_bytes(content[: len(content) // 2])
        return
    if how == "empty":
        target.write_bytes(b"")
        return
    with zipfile.ZipFile(source) as original:
        entries = {info.filename: original.read(info.filename) for info in original.infolist()}
    if how == "broken-tensor":
        entries["policy.pth"] = entries["policy.pth"][:100]
    elif how == "broken-json":
        entries["data"] = b"{not json"
    else:  # a cloudpickled value cut short inside valid JSON
        data = json.loads(entries["data"])
        blob = data["observation_space"][":serialized:"]
        data["observation_space"][":serialized:"] = blob[: len(blob) // 8 * 4]
        entries["data"] = json.dumps(data).encode()
    target.unlink(missing_ok=True)
    with zipfile.ZipFile(target, "w") as archive:
        for name, value in entries.items():
            archive.writestr(name, value)


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    """A finished tiny PPO-Lagrangian run with checkpoints and evaluations at 16 and 32 steps."""
    root = tmp_path_factory.mktemp("edges")
    argv = ["--algo", "ppolag", "--env", ENV, "-n", "32", "--seed", "0", "-f", str(root), "--save-freq", "16"]
    run_cli(train_module.main, [*argv, "--eval-freq", "16", "--eval-episodes", "1", *TRAIN_TINY[2:]])
    return root / "ppolag" / f"{ENV}_1"


def _copy(run: pathlib.Path, tmp_path: pathlib.Path) -> pathlib.Path:
    copy = tmp_path / "ppolag" / f"{ENV}_1"
    shutil.copytree(run, copy)
    return copy


# -------------------------------------------------------------------- damaged models and checkpoints


@pytest.mark.parametrize("how", DAMAGES)
def test_a_damaged_model_is_named_by_every_command(run: pathlib.Path, tmp_path: pathlib.Path, how: str) -> None:
    copy = _copy(run, tmp_path)
    model = copy / f"{ENV}.zip"
    damage(run / f"{ENV}.zip", model, how)
    expected = f"{model}' {DAMAGES[how]}"
    with pytest.raises(CLIError, match="trained agent") as raised:
        argv = ["--algo", "ppolag", "--env", ENV, "-n", "16", "-i", str(model), "--new-folder", "-f", str(tmp_path)]
        run_cli(train_module.main, argv)
    assert expected in str(raised.value)
    with pytest.raises(CLIError) as raised:
        run_cli(enjoy_module.main, ["--algo", "ppolag", "--env", ENV, "--run", str(copy), "--no-render", "-n", "10"])
    assert expected in str(raised.value)
    with pytest.raises(CLIError) as raised:
        run_cli(compare_module.main, [str(copy), "-n", "50"])
    assert expected in str(raised.value)
    with pytest.raises(CLIError) as raised:
        run_cli(data_cli.main, ["generate", "--run", str(copy), "--n", "1", "--out", str(tmp_path / "demos.npz")])
    assert f"The expert {model} {DAMAGES[how]}" in str(raised.value)


@pytest.mark.parametrize("how", DAMAGES)
def test_resume_falls_back_past_a_damaged_checkpoint_and_names_it(run: pathlib.Path, tmp_path: pathlib.Path, how: str) -> None:
    copy = _copy(run, tmp_path)
    (copy / FINISHED_FILE).unlink()
    (copy / f"{ENV}.zip").unlink()
    latest = copy / "rl_model_32_steps.zip"
    damage(run / latest.name, latest, how)
    with pytest.warns(UserWarning, match=re.escape(f"{latest} {DAMAGES[how]}") + ".*resuming from an earlier checkpoint"):
        assert latest_checkpoint(str(copy)) == str(copy / "rl_model_16_steps.zip")
    argv = ["--algo", "ppolag", "--env", ENV, "-n", "32", "--seed", "0", "-f", str(tmp_path), "--exp-id", "1", "--resume"]
    with pytest.warns(UserWarning, match="resuming from an earlier checkpoint"):
        run_cli(train_module.main, [*argv, "--save-freq", "16", *TRAIN_TINY])
    finished: dict[str, Any] = json.loads((copy / FINISHED_FILE).read_text())
    assert finished["resumed_from"] == str(copy / "rl_model_16_steps.zip") and finished["num_timesteps"] == 32


def test_resume_without_a_loadable_checkpoint_says_it_starts_afresh(run: pathlib.Path, tmp_path: pathlib.Path) -> None:
    copy = _copy(run, tmp_path)
    (copy / FINISHED_FILE).unlink()
    for steps in (16, 32):
        damage(run / f"rl_model_{steps}_steps.zip", copy / f"rl_model_{steps}_steps.zip", "truncated")
    argv = ["--algo", "ppolag", "--env", ENV, "-n", "32", "--seed", "0", "-f", str(tmp_path), "--exp-id", "1", "--resume"]
    with pytest.warns(UserWarning) as caught:
        run_cli(train_module.main, [*argv, *TRAIN_TINY])
    messages = [str(warning.message) for warning in caught]
    first = "rl_model_16_steps.zip is cut short or damaged (it has no `data` entry): no earlier checkpoint"
    assert any(first in message for message in messages)
    assert any(
        "No checkpoint of" in message
        and "can be loaded (rl_model_32_steps.zip, rl_model_16_steps.zip): the run starts afresh" in message
        for message in messages
    )
    assert json.loads((copy / FINISHED_FILE).read_text())["resumed_from"] is None


def test_a_damaged_pi_lagrangian_expert_is_named(tmp_path: pathlib.Path) -> None:
    saved = tmp_path / "expert.npz"
    PILagrangian(gym.make(f"sb3_icrl/{ENV}")).learn(2).save(saved)
    cut = tmp_path / "cut.npz"
    cut.write_bytes(saved.read_bytes()[:300])
    out = str(tmp_path / "demos.npz")
    with pytest.raises(CLIError, match=f"{cut} cannot be read \\(BadZipFile.*it is cut short or damaged"):
        run_cli(data_cli.main, ["generate", "--env", ENV, "--expert", str(cut), "--n", "1", "--out", out])
    other = tmp_path / "other.npz"
    np.savez(other, timesteps=np.arange(3))
    with pytest.raises(ValueError, match=f"{other} is not a model saved by PILagrangian.save: it lacks \\['params'"):
        PILagrangian.load(other)


# -------------------------------------------------------------------- output folders that cannot be written


@pytest.fixture
def full_disk(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every atomic write fails as on a full disk (where the data reaches it: ``fsync``)."""

    def no_space(descriptor: int) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(utils.os, "fsync", no_space)


def test_a_full_disk_ends_train_and_generate_with_one_line_naming_the_file(tmp_path: pathlib.Path, full_disk: None) -> None:
    with pytest.raises(CLIError, match=r"cannot write .*config\.yml: No space left on device; free some space there"):
        run_cli(train_module.main, ["--algo", "ppolag", "--env", ENV, "-n", "16", "-f", str(tmp_path), *TRAIN_TINY])
    out = tmp_path / "demos.npz"
    with pytest.raises(CLIError, match=f"cannot write {out}: No space left on device"):
        run_cli(data_cli.main, ["generate", "--env", ENV, "--expert", "pilag", "--n", "1", "--out", str(out)])


def test_a_full_disk_names_a_runs_log_in_the_suites_failures(tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch) -> None:
    class FullLog(io.RawIOBase):
        def writable(self) -> bool:
            return True

        def write(self, data: Any) -> int:
            raise OSError(errno.ENOSPC, "No space left on device")

    log = str(tmp_path / "logs" / "run.log")
    opened = builtins.open
    # The run's log only: its lock is opened too
    monkeypatch.setattr(
        runner,
        "open",
        lambda path, *args, **kwargs: FullLog() if path == log else opened(path, *args, **kwargs),
        raising=False,
    )
    with pytest.raises(OSError, match=f"No space left on device: '{log}'"):
        runner.execute_run(["--algo", "ppolag"], log, str(tmp_path / "run"))


def test_a_read_only_folder_is_refused_before_anything_runs(
    run: pathlib.Path, tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    read_only = tmp_path / "read_only"
    read_only.mkdir()
    access = os.access
    monkeypatch.setattr(os, "access", lambda path, mode: not str(path).startswith(str(read_only)) and access(path, mode))
    suite = tmp_path / "suite.yml"
    suite.write_text(f"envs: [{ENV}]\nalgos: [ppolag]\nseeds: [0]\nsteps: 16\n")
    with pytest.raises(CLIError, match=f"-f/--log-folder '{read_only}' is not writable"):
        run_cli(benchmark_cli.main, ["run", str(suite), "-f", str(read_only)])
    with pytest.raises(CLIError, match=f"-o/--output '{read_only}/report' is not writable"):
        run_cli(benchmark_cli.main, ["report", str(suite), "-f", str(tmp_path), "-o", str(read_only / "report")])
    with pytest.raises(CLIError, match=f"--out '{read_only}/x.npz' cannot be written: {read_only} is not writable"):
        run_cli(data_cli.main, ["generate", "--env", ENV, "--expert", "pilag", "--n", "1", "--out", str(read_only / "x.npz")])
    with pytest.raises(CLIError, match=f"--json '{read_only}/x.json' cannot be written: {read_only} is not writable"):
        run_cli(compare_module.main, [str(run), "--json", str(read_only / "x.json")])
    with pytest.raises(CLIError, match=f"-f/--log-folder '{read_only}' is not writable"):
        run_cli(train_module.main, ["--algo", "ppolag", "--env", ENV, "-n", "16", "-f", str(read_only)])


def test_enjoy_record_and_figures_into_folders_that_cannot_be_written_end_with_one_line(
    run: pathlib.Path, tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch, full_disk: None
) -> None:
    copy = _copy(run, tmp_path)
    access = os.access
    monkeypatch.setattr(os, "access", lambda path, mode: not str(path).startswith(str(copy)) and access(path, mode))
    with pytest.raises(
        CLIError, match=re.escape(f"--record writes into {copy}/videos, which cannot be written (not writable)")
    ):
        run_cli(
            enjoy_module.main, ["--algo", "ppolag", "--env", ENV, "--run", str(copy), "--no-render", "--record", "-n", "10"]
        )
    figure = tmp_path / "curves.png"
    with pytest.raises(CLIError, match=re.escape(f"cannot write {figure}: No space left on device")):
        run_cli(plots_cli.main, ["curves", "-f", str(run.parent.parent), "--algos", "ppolag", "--env", ENV, "-o", str(figure)])


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--load-best", "--load-checkpoint", "16"], "argument --load-checkpoint: not allowed with argument --load-best"),
        (["--load-last-checkpoint", "--load-best"], "argument --load-best: not allowed with argument --load-last-checkpoint"),
        (["--exp-id", "1"], "--run names the run folder itself: leave out --exp-id (or give -f and --exp-id instead)"),
        (["--load-checkpoint", "-16"], "argument --load-checkpoint: expected an integer >= 0, got '-16'"),
    ],
)
def test_enjoy_refuses_flags_it_would_ignore(run: pathlib.Path, extra: list[str], message: str) -> None:
    with pytest.raises(CLIError, match=re.escape(message)):
        run_cli(enjoy_module.main, ["--algo", "ppolag", "--env", ENV, "--run", str(run), "--no-render", "-n", "10", *extra])
    with pytest.raises(CLIError, match=re.escape("argument --exp-id: expected an integer >= 0, got '-1'")):
        run_cli(enjoy_module.main, ["--algo", "ppolag", "--env", ENV, "-f", str(run.parent.parent), "--exp-id", "-1"])


def test_enjoy_refuses_a_run_of_another_env_or_algorithm(run: pathlib.Path) -> None:
    argv = ["--run", str(run), "--no-render", "-n", "10"]
    expected = f"{run} trained on {ENV}, not on BiasedPendulum-v0: pass --env {ENV}."
    with pytest.raises(CLIError, match=re.escape(expected)):
        run_cli(enjoy_module.main, ["--algo", "ppolag", "--env", "sb3_icrl/BiasedPendulum-v0", *argv])
    with pytest.raises(CLIError, match=re.escape(f"{run} trained with ppolag, not with mecl: use --algo ppolag.")):
        run_cli(enjoy_module.main, ["--algo", "mecl", "--env", ENV, *argv])


# -------------------------------------------------------------------- MODULE:EnvId


@pytest.mark.parametrize(
    "env, message",
    [
        ("no_such_module_xyz:Env-v0", "Env 'no_such_module_xyz:Env-v0': cannot import its module 'no_such_module_xyz'"),
        (":GridWorldWall-v0", "Env ':GridWorldWall-v0': write MODULE:EnvId, both parts given"),
        ("sb3_icrl.envs:", "Env 'sb3_icrl.envs:': write MODULE:EnvId"),
        ("sb3_icrl.envs:NoSuch-v0", "sb3_icrl.envs is imported, but no env 'NoSuch-v0' is registered: check the id"),
        ("sb3_icrl.envs:GridWorldWal-v0", "Did you mean sb3_icrl.envs:sb3_icrl/GridWorldWall-v0?"),
    ],
)
def test_module_colon_env_id_mistakes_name_the_module_and_the_id(tmp_path: pathlib.Path, env: str, message: str) -> None:
    with pytest.raises(ValueError, match=re.escape(message)):
        resolve_env_id(env)
    with pytest.raises(CLIError, match=re.escape(message)):
        run_cli(train_module.main, ["--algo", "ppolag", "--env", env, "-n", "16", "-f", str(tmp_path)])
    suite = tmp_path / "suite.yml"
    suite.write_text(f"envs: ['{env}']\nalgos: [ppolag]\nseeds: [0]\n")
    with pytest.raises(SuiteError, match=f"line 1: .*{re.escape(message)}"):
        load_suite(str(suite))


def test_a_typo_in_a_users_env_id_lists_what_its_module_registered(
    tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    name = f"edges_envs_{tmp_path.name.replace('-', '_')}"
    register = "gym.register('edges/Corridor-v0', entry_point='sb3_icrl.envs.grid_world:GridWorldEnv')"
    (tmp_path / f"{name}.py").write_text(f"import gymnasium as gym\n{register}\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ValueError) as raised:
        resolve_env_id(f"{name}:edges/Coridor-v0")
    assert "It registered: edges/Corridor-v0." in str(raised.value)
    assert f"Did you mean {name}:edges/Corridor-v0?" in str(raised.value)


@pytest.mark.parametrize(
    "code, error",
    [
        ("raise RuntimeError('no licence file')", "raised RuntimeError: no licence file (at {path}, line 1)"),
        ("def broken(:\n", "raised SyntaxError: invalid syntax (at {path}, line 1)"),
    ],
)
def test_a_users_module_that_fails_as_it_is_imported_is_named_with_its_line(
    tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch, code: str, error: str
) -> None:
    name = f"failing_envs_{tmp_path.name.replace('-', '_')}"
    path = tmp_path / f"{name}.py"
    path.write_text(code)
    monkeypatch.syspath_prepend(str(tmp_path))
    expected = f"importing {name!r} {error.format(path=path)}: fix the module."
    with pytest.raises(CLIError, match=re.escape(f"--gym-packages: {expected}")):
        run_cli(train_module.main, ["--algo", "ppolag", "--env", ENV, "-n", "16", "-f", str(tmp_path), "--gym-packages", name])
    with pytest.raises(ValueError, match=re.escape(f"Env '{name}:My-v0': {expected}")):
        resolve_env_id(f"{name}:My-v0")


def test_an_env_whose_entry_point_cannot_be_imported_is_named(tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch) -> None:
    name = f"entry_envs_{tmp_path.name.replace('-', '_')}"
    register = "gym.register('edges/Broken-v0', entry_point='no_such_module_xyz:Env')"
    (tmp_path / f"{name}.py").write_text(f"import gymnasium as gym\n{register}\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    message = "Cannot make edges/Broken-v0: its entry point 'no_such_module_xyz:Env' cannot be imported (No module named"
    with pytest.raises(CLIError, match=re.escape(message)):
        run_cli(train_module.main, ["--algo", "ppolag", "--env", f"{name}:edges/Broken-v0", "-n", "16", "-f", str(tmp_path)])


# -------------------------------------------------------------------- partial run folders


def test_a_folder_in_place_of_a_replay_buffer_stops_the_resume(tmp_path: pathlib.Path) -> None:
    argv = ["--algo", "irlplus", "--env", "BiasedPendulum-v0", "-n", "128", "--seed", "0", "-f", str(tmp_path)]
    argv += ["--exp-id", "1", "--save-freq", "64", "--eval-freq", "-1", "--verbose", "0", "-params", "learning_starts:16"]
    argv += ["batch_size:16", "policy_kwargs:dict(net_arch=[4])", "update_every:64", "warmup_timesteps:0"]
    run_cli(train_module.main, argv)
    run = tmp_path / "irlplus" / "BiasedPendulum-v0_1"
    (run / FINISHED_FILE).unlink()
    (run / "BiasedPendulum-v0.zip").unlink()
    buffer = run / "rl_model_replay_buffer_128_steps.pkl"
    buffer.unlink()
    buffer.mkdir()
    expected = f"The replay buffer {buffer} is a folder, not a replay buffer file: remove it to continue from its checkpoint"
    with pytest.raises(CLIError, match=re.escape(expected)):
        run_cli(train_module.main, [*argv, "--resume"])


def test_a_damaged_evaluations_npz_is_named_and_skipped(run: pathlib.Path, tmp_path: pathlib.Path) -> None:
    copy = _copy(run, tmp_path)
    evaluations = copy / "evaluations.npz"
    evaluations.write_bytes(evaluations.read_bytes()[:100])
    message = f"{evaluations} cannot be read (BadZipFile"
    with pytest.raises(ValueError, match=re.escape(message) + ".*delete the file to leave the run out of the curves"):
        load_evaluations(copy)
    with pytest.warns(UserWarning, match=re.escape(message) + ".* Skipped"), pytest.raises(FileNotFoundError):
        load_runs(tmp_path, ["ppolag"], ENV, skip_missing=True)  # (the only run: none left to plot)
    # Resumed, the run goes on with its evaluations afresh from the checkpoint, and says so
    (copy / FINISHED_FILE).unlink()
    argv = ["--algo", "ppolag", "--env", ENV, "-n", "32", "--seed", "0", "-f", str(tmp_path), "--exp-id", "1", "--resume"]
    with pytest.warns(UserWarning, match=re.escape(message) + ".*evaluations start afresh at step 32"):
        run_cli(train_module.main, [*argv, "--eval-freq", "16", "--eval-episodes", "1", *TRAIN_TINY[2:]])
    assert load_evaluations(copy)["timesteps"].tolist() == [32]  # written anew: no evaluation of the lost file is kept


def test_an_evaluations_npz_of_other_arrays_is_named_on_resume(run: pathlib.Path, tmp_path: pathlib.Path) -> None:
    copy = _copy(run, tmp_path)
    (copy / FINISHED_FILE).unlink()
    evaluations = copy / "evaluations.npz"
    np.savez(evaluations, foo=np.arange(3))  # an npz written by something else
    argv = ["--algo", "ppolag", "--env", ENV, "-n", "32", "--seed", "0", "-f", str(tmp_path), "--exp-id", "1", "--resume"]
    message = f"{evaluations} holds no 'timesteps' array (keys: ['foo']): it was not written by train.py."
    with pytest.warns(UserWarning, match=re.escape(message) + ".*evaluations start afresh at step 32"):
        run_cli(train_module.main, [*argv, "--eval-freq", "16", "--eval-episodes", "1", *TRAIN_TINY[2:]])
    (copy / FINISHED_FILE).unlink()
    np.savez(evaluations, timesteps=np.array([16, 32]), results=np.zeros((3, 1)))  # rows that do not match
    with pytest.warns(UserWarning, match=re.escape(f"{evaluations} has 2 timesteps, but not as many rows in ['results']")):
        run_cli(train_module.main, [*argv, "--eval-freq", "16", "--eval-episodes", "1", *TRAIN_TINY[2:]])


@pytest.mark.parametrize(
    "arrays, message",
    [
        ({"results": np.zeros((2, 1))}, "has 3 timesteps, but not as many rows in ['results']: it was not written by"),
        ({"results": np.zeros((3, 1))}, "has no 'violations' array (keys: ['results', 'timesteps']): it was not written by"),
    ],
    ids=["rows-do-not-match", "metric-missing"],
)
def test_curves_name_an_evaluations_npz_of_other_arrays(tmp_path: pathlib.Path, arrays: dict, message: str) -> None:
    folder = tmp_path / "ppolag" / f"{ENV}_1"
    folder.mkdir(parents=True)
    np.savez(folder / "evaluations.npz", timesteps=np.arange(3), **arrays)
    argv = ["curves", "-f", str(tmp_path), "--algos", "ppolag", "--env", ENV, "-o", str(tmp_path / "x.png")]
    expected = f"error: {folder / 'evaluations.npz'} {message}"
    with pytest.raises(CLIError, match=re.escape(expected) + ".*Pass --skip-missing to plot the other runs"):
        run_cli(plots_cli.main, argv)


def test_compare_names_a_damaged_finished_json(
    run: pathlib.Path, tmp_path: pathlib.Path, capsys: pytest.CaptureFixture
) -> None:
    copy = _copy(run, tmp_path)
    (copy / FINISHED_FILE).write_text('{"num_timesteps": 3')
    compare_module.check_runs([str(copy)])
    assert f"{copy}/finished.json is not a JSON mapping (cut short or overwritten)" in capsys.readouterr().err


def test_compare_names_a_wall_time_it_cannot_read(
    run: pathlib.Path, tmp_path: pathlib.Path, capsys: pytest.CaptureFixture
) -> None:
    copy = _copy(run, tmp_path)
    finished = json.loads((copy / FINISHED_FILE).read_text())
    (copy / FINISHED_FILE).write_text(json.dumps({**finished, "wall_time_s": "abc", "wall_time_total_s": "abc"}))
    compare_module.check_runs([str(copy)])
    expected = f"warning: {copy}/finished.json records wall_time_total_s as 'abc', not a number of seconds: the wall time"
    assert expected + " comes from the training monitor instead" in capsys.readouterr().err
    monitor = copy / "0.monitor.csv"
    for content, problem in [("garbage,,\n", "has no 't' column (header 'garbage,,')"), ("", "is empty")]:
        monitor.write_text(content)
        compare_module.check_runs([str(copy)])
        assert f"{monitor} {problem}: it is not an SB3 Monitor file, so the wall time shows as nan" in capsys.readouterr().err
        assert np.isnan(compare_module.training_wall_time(str(copy)))
    monitor.write_text('#{"t_start": 0.0}\nr,l,t\n1.0,5,12.5\n1.0,5,x\n')
    compare_module.check_runs([str(copy)])
    assert f"{monitor}: its last row's time 'x' is not a number (cut short or overwritten)" in capsys.readouterr().err


def _interrupted(*args: Any, **kwargs: Any) -> None:
    """A stand-in for a long call that the user stops with Ctrl-C."""
    raise KeyboardInterrupt


def test_ctrl_c_ends_compare_with_one_line(
    run: pathlib.Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    monkeypatch.setattr(compare_module, "evaluate_run", _interrupted)
    assert compare_module.main([str(run), "-n", "50"]) == 130
    errors = capsys.readouterr().err
    assert "Traceback" not in errors and errors.strip().splitlines()[-1].startswith("interrupted: no table")


@pytest.fixture(scope="module")
def suite_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[pathlib.Path, pathlib.Path]:
    """A finished suite of two tiny PPO-Lagrangian runs: its file and its log root."""
    root = tmp_path_factory.mktemp("suite")
    path = root / "partial.yml"
    path.write_text(
        f"envs: [{ENV}]\nalgos: [ppolag]\nseeds: [0, 1]\nsteps: 32\neval_episodes: 1\n"
        "train_args: {eval_freq: 16, eval_episodes: 1, save_freq: 16}\n"
        "variants: {base: {hyperparams: {n_steps: 16, batch_size: 16, policy_kwargs: 'dict(net_arch=[4])'}}}\n"
    )
    run_cli(benchmark_cli.main, ["run", str(path), "-f", str(root / "logs"), "--jobs", "1", "--no-report"])
    return path, root / "logs"


@pytest.mark.parametrize(
    "how, note",
    [
        ("finished.json cut short", "finished.json is not a JSON mapping (cut short or overwritten)"),
        ("final model cut short", f"{ENV}.zip is cut short or damaged (it has no `data` entry): the report leaves it out"),
        ("final model empty", f"{ENV}.zip is empty (0 bytes): the report leaves it out"),
        # A whole zip whose tensor entry is cut short: its CRC holds, so only the entry's own archive tells
        (
            "final model broken-tensor",
            f"{ENV}.zip is damaged (its tensor entry 'policy.pth' is cut short or is not a torch archive): the report "
            "leaves it out",
        ),
        ("final model missing", f"{ENV}.zip is missing: the report leaves it out"),
    ],
)
def test_status_and_report_name_what_is_wrong_in_a_partial_run_folder(
    suite_runs: tuple[pathlib.Path, pathlib.Path], tmp_path: pathlib.Path, capsys: pytest.CaptureFixture, how: str, note: str
) -> None:
    path, logs = suite_runs
    root = tmp_path / "logs"
    shutil.copytree(logs, root)
    broken = load_suite(str(path)).runs()[1].run_folder(str(root))
    if how == "finished.json cut short":
        (pathlib.Path(broken) / FINISHED_FILE).write_text('{"num_timesteps": 3')
    elif how == "final model missing":
        (pathlib.Path(broken) / f"{ENV}.zip").unlink()
    else:
        damage(
            pathlib.Path(broken) / f"{ENV}.zip",
            pathlib.Path(broken) / f"{ENV}.zip",
            how.split()[-1].replace("short", "truncated"),
        )
    capsys.readouterr()
    assert benchmark_cli.main(["status", str(path), "-f", str(root)]) == 0
    line = next(line for line in capsys.readouterr().out.splitlines() if "seed 1" in line)
    assert note in line and broken in line
    assert benchmark_cli.main(["report", str(path), "-f", str(root), "--no-figures"]) == 0
    out = capsys.readouterr().out
    if how == "finished.json cut short":
        assert f"{broken}/finished.json is not a JSON mapping" in out and "trains it again from its last checkpoint" in out
        assert "Not finished yet (1): base/ppolag/GridWorldWall-v0/seed 1" in out
    else:
        assert f"left out of the report, its model in {broken} could not be evaluated" in out


def _status_lines(suite: pathlib.Path, root: pathlib.Path, capsys: pytest.CaptureFixture) -> list[str]:
    capsys.readouterr()
    assert benchmark_cli.main(["status", str(suite), "-f", str(root), "-v"]) == 0
    return capsys.readouterr().out.splitlines()


def test_status_names_checkpoints_that_do_not_read(
    run: pathlib.Path, tmp_path: pathlib.Path, capsys: pytest.CaptureFixture
) -> None:
    suite = tmp_path / "s.yml"
    suite.write_text(f"envs: [{ENV}]\nalgos: [ppolag]\nseeds: [0, 1]\nsteps: 64\n")
    only_junk, one_good = (tmp_path / "logs" / "s" / "base" / "ppolag" / f"{ENV}_{seed}" for seed in (0, 1))
    for folder in (only_junk, one_good):
        folder.mkdir(parents=True)
        (folder / "rl_model_48_steps.zip").write_text("junk")  # not a zip at all
    shutil.copy(run / "rl_model_16_steps.zip", one_good)
    damage(run / "rl_model_32_steps.zip", one_good / "rl_model_32_steps.zip", "broken-tensor")
    lines = _status_lines(suite, tmp_path / "logs", capsys)
    first, second = (
        next(line for line in lines if line.endswith(f"seed {seed}") or f"seed {seed} (" in line) for seed in (0, 1)
    )
    assert first.startswith("interrupted") and " - / 64 " in first
    assert (
        f"(its checkpoint {only_junk}/rl_model_48_steps.zip is not a zip archive: no checkpoint loads, so the suite" in first
    )
    assert second.startswith("interrupted") and " 16 / 64 " in second
    assert f"(its checkpoint {one_good}/rl_model_32_steps.zip is damaged (its tensor entry 'policy.pth' is cut short" in second
    assert "(and 1 newer one): the suite resumes the run from its checkpoint at 16 steps)" in second


def test_status_names_a_log_folder_without_the_suite_and_a_file_in_place_of_a_run_folder(
    tmp_path: pathlib.Path, capsys: pytest.CaptureFixture
) -> None:
    suite = tmp_path / "s.yml"
    suite.write_text(f"envs: [{ENV}]\nalgos: [ppolag]\nseeds: [0]\nsteps: 64\n")
    missing = tmp_path / "no" / "such"
    assert _status_lines(suite, missing, capsys)[-1] == (
        f"note: -f/--log-folder {missing} does not exist: no run has started there; check -f"
    )
    (tmp_path / "ppolag").mkdir()  # train.py's runs, not a suite's
    assert _status_lines(suite, tmp_path, capsys)[-1] == (
        f"note: -f/--log-folder {tmp_path} has no folder s of this suite (it holds ppolag, s.yml): no run has started "
        "there; check -f"
    )
    file = tmp_path / "logs" / "s" / "base" / "ppolag" / f"{ENV}_0"
    file.parent.mkdir(parents=True)
    file.write_text("x")
    line = next(line for line in _status_lines(suite, tmp_path / "logs", capsys) if "seed 0" in line)
    assert line.startswith("not started")
    assert line.endswith(f"seed 0 ({file} is a file, not a run folder: move it away, or the suite cannot train the run)")


def test_ctrl_c_ends_data_generate_with_one_line(
    tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    monkeypatch.setattr(data_cli, "build_dataset", _interrupted)
    out = str(tmp_path / "demos.npz")
    assert data_cli.main(["generate", "--env", ENV, "--expert", "pilag", "--n", "1", "--out", out]) == 130
    errors = capsys.readouterr().err
    assert "Traceback" not in errors and errors.strip().splitlines()[-1].startswith("interrupted: `generate` stopped")


@pytest.mark.parametrize("content", ['{"suite": "partial"', "[1, 2]"])
def test_report_update_names_a_summary_json_that_is_cut_short_or_overwritten(
    suite_runs: tuple[pathlib.Path, pathlib.Path], tmp_path: pathlib.Path, content: str
) -> None:
    path, logs = suite_runs
    summary = tmp_path / "report" / "summary.json"
    summary.parent.mkdir()
    summary.write_text(content)
    message = f"--update: {summary} is not a report's summary (cut short or overwritten): write the report anew without"
    with pytest.raises(CLIError, match=re.escape(message)):
        run_cli(
            benchmark_cli.main, ["report", str(path), "-f", str(logs), "-o", str(summary.parent), "--no-figures", "--update"]
        )


# -------------------------------------------------------------------- importers


def _steps(n: int, bad_row: int | None = None) -> np.ndarray:
    values = np.zeros((n, 2), dtype=np.float32)
    if bad_row is not None:
        values[bad_row, 0] = np.nan
    return values


def _pickles(folder: pathlib.Path, files: dict[str, dict[str, Any]]) -> pathlib.Path:
    folder.mkdir()
    for name, content in files.items():
        (folder / name).write_bytes(pickle.dumps(content))
    return folder


LIU = "scene-1_len-5_time_out.pkl"
# (id, call(tmp_path), fragment of the DemonstrationError's message)
IMPORTER_CASES: list[tuple[str, Any, str]] = [
    ("arrays-nan-observation", lambda t: from_arrays(_steps(5, 2), _steps(5)), "episode 0: `obs` holds NaN or infinite"),
    ("arrays-inf-action", lambda t: from_arrays(_steps(5), _steps(5) + np.inf), "`acts` holds NaN or infinite values"),
    ("arrays-nan-reward", lambda t: from_arrays(_steps(5), _steps(5), rewards=_steps(5, 1)[:, 0]), "`rews` holds NaN"),
    ("arrays-nan-cost", lambda t: from_arrays(_steps(5), _steps(5), costs=_steps(5, 0)[:, 0]), "`costs` holds NaN"),
    ("arrays-negative-cost", lambda t: from_arrays(_steps(5), _steps(5), costs=-np.ones(5)), "`costs` holds negative"),
    ("arrays-single-value", lambda t: from_arrays(np.float32(1.0), _steps(5)), "`observations` must be an array with one"),
    ("arrays-single-reward", lambda t: from_arrays(_steps(5), _steps(5), rewards=1.0), "`rewards` must be an array"),
    (
        "arrays-next-observations-shape",
        lambda t: from_arrays(_steps(5), _steps(5), next_observations=np.zeros((5, 3))),
        "`next_observations` have shape (3,) per step, `observations` (2,)",
    ),
    (
        "arrays-first-step-not-an-episode-start",
        lambda t: from_arrays(_steps(5), _steps(5), episode_starts=[False, False, True, False, False]),
        "`episode_starts[0]` is False, but the first step always starts an episode (SB3's convention",
    ),
    # Each next observation is the next row inside an episode: not so when the boundaries are wrong or a row is shifted
    (
        "arrays-next-observations-disagree",
        lambda t: from_arrays(
            np.arange(6.0)[:, None], _steps(6), next_observations=np.arange(6.0)[:, None] + 5, episode_lengths=[3, 3]
        ),
        "`next_observations[0]` differs from `observations[1]` inside episode 0 (4 such steps in all): the observation",
    ),
    (
        "arrays-next-observations-across-an-unmarked-start",
        lambda t: from_arrays(np.array([[0.0], [1.0], [9.0]]), _steps(3), next_observations=np.array([[1.0], [2.0], [10.0]])),
        "`next_observations[1]` differs from `observations[2]` inside episode 0 (1 such step in all)",
    ),
    # Observations or actions of another env's shape: refused before the replay, which would fail inside MuJoCo
    (
        "arrays-observations-of-another-env",
        lambda t: from_arrays(_steps(5), _steps(5)[:, :1], env_id="sb3_icrl/BiasedPendulum-v0"),
        "from_arrays: the observations have shape (2,) per step, but sb3_icrl/BiasedPendulum-v0's are (4,)",
    ),
    (
        "arrays-actions-of-another-env",
        lambda t: from_arrays(np.zeros((5, 4)), _steps(5), env_id="sb3_icrl/BiasedPendulum-v0"),
        "from_arrays: the actions have shape (2,) per step, but sb3_icrl/BiasedPendulum-v0's are (1,)",
    ),
    # An env id that is not registered: a typo (the closest of ours named), or an env whose module was not imported
    (
        "arrays-env-not-registered",
        lambda t: from_arrays(_steps(5), _steps(5), env_id="sb3_icrl/NoSuch-v0"),
        "from_arrays: env_id 'sb3_icrl/NoSuch-v0' is not a registered gymnasium env. Give the id of the env the data was "
        "recorded on, registered first: import the module that registers it (the --gym-packages MODULE of the commands)",
    ),
    (
        "arrays-env-typo",
        lambda t: from_arrays(_steps(5), _steps(5), env_id="sb3_icrl/BiasedPendulm-v0"),
        "is not a registered gymnasium env. Did you mean 'BiasedPendulum-v0'?",
    ),
    (
        "malik-env-typo",
        lambda t: from_malik_rollouts(
            _pickles(t / "m", {"0.pkl": {"observations": _steps(5), "actions": _steps(5)}}), env_id="BlockedSwimer-v0"
        ),
        "from_malik_rollouts: env_id 'BlockedSwimer-v0' is not a registered gymnasium env. Did you mean 'BlockedSwimmer-v0'?",
    ),
    (
        "malik-nan-observation",
        lambda t: from_malik_rollouts(_pickles(t / "m", {"0.pkl": {"observations": _steps(5, 2), "actions": _steps(5)}})),
        "0.pkl: `obs` holds NaN or infinite values (1 rows, first at row 2)",
    ),
    (
        "malik-nan-return",
        lambda t: from_malik_rollouts(
            _pickles(t / "m", {"0.pkl": {"observations": _steps(5), "actions": _steps(5), "rewards": np.array([np.nan])}})
        ),
        "0.pkl: its recorded return is NaN or infinite",
    ),
    (
        "liu-reward-length",
        lambda t: from_liu_pickles(
            _pickles(t / "l", {LIU: {"original_observations": _steps(5), "actions": _steps(5), "reward": np.zeros(4)}})
        ),
        f"{LIU}: 4 rewards for 5 actions",
    ),
    (
        "liu-nan-reward",
        lambda t: from_liu_pickles(
            _pickles(t / "l", {LIU: {"original_observations": _steps(5), "actions": _steps(5), "reward": _steps(5, 1)[:, 0]}})
        ),
        f"{LIU}: `rews` holds NaN",
    ),
]


@pytest.mark.parametrize(("call", "fragment"), [case[1:] for case in IMPORTER_CASES], ids=[case[0] for case in IMPORTER_CASES])
def test_importers_refuse_broken_numbers_naming_the_source(tmp_path: pathlib.Path, call: Any, fragment: str) -> None:
    with pytest.raises(DemonstrationError) as raised:
        call(tmp_path)
    assert fragment in str(raised.value)


def test_importers_unchecked_keep_an_env_id_not_registered_here() -> None:
    imported = from_arrays(_steps(5), _steps(5), env_id="sb3_icrl/NoSuch-v0", check_replay=False)
    assert imported.metadata["env_id"] == "sb3_icrl/NoSuch-v0"


def test_an_imitation_dataset_with_nan_rewards_is_refused(tmp_path: pathlib.Path) -> None:
    datasets = pytest.importorskip("datasets")
    clean = Trajectory(_steps(3), _steps(2), None, False, np.zeros(2, np.float32), np.zeros(2, np.float32))
    save_imitation_dataset(tmp_path / "clean", [clean])
    broken = datasets.load_from_disk(str(tmp_path / "clean")).map(lambda row: {**row, "rews": [float("nan"), 0.0]})
    broken.save_to_disk(str(tmp_path / "broken"))
    with pytest.raises(DemonstrationError, match="broken trajectory 0: `rews` holds NaN or infinite values"):
        load_imitation_dataset(tmp_path / "broken", missing_costs="zeros")


@pytest.mark.parametrize("name", ["args.yml", "config.yml"])
@pytest.mark.parametrize(
    "content, problem",
    [("n_timesteps: [32\n", "is not valid YAML (expected ',' or ']', but got '<stream end>', line 2)"), ("", "is empty")],
    ids=["invalid", "empty"],
)
def test_a_damaged_run_yml_is_named(run: pathlib.Path, tmp_path: pathlib.Path, name: str, content: str, problem: str) -> None:
    copy = _copy(run, tmp_path)
    broken = copy / ENV / name
    broken.write_text(content)
    expected = f"{broken} {problem}: the run folder is damaged; restore the file from a copy, or train the run again."
    with pytest.raises(CLIError) as raised:
        run_cli(enjoy_module.main, ["--algo", "ppolag", "--env", ENV, "--run", str(copy), "--no-render", "-n", "10"])
    assert expected in str(raised.value)
    with pytest.raises(CLIError) as raised:
        run_cli(compare_module.main, [str(copy), "-n", "50"])
    assert expected in str(raised.value)


def test_damaged_statistics_and_training_state_are_named(run: pathlib.Path, tmp_path: pathlib.Path) -> None:
    copy = _copy(run, tmp_path)
    state = copy / ENV / "training_state.pkl"
    state.write_bytes(state.read_bytes()[:20])
    argv = ["--algo", "ppolag", "--env", ENV, "-n", "16", "-i", str(copy / f"{ENV}.zip"), *TRAIN_TINY]
    with pytest.raises(CLIError, match=re.escape(f"The training state {state} cannot be read (UnpicklingError")):
        run_cli(train_module.main, argv)
    state.write_bytes(pickle.dumps([1, 2]))  # a whole pickle of something else
    with pytest.raises(CLIError, match=re.escape(f"{state} is not a training state of this sb3-icrl version (format 1): it")):
        run_cli(train_module.main, argv[: argv.index("-params")])  # (-i keeps the model's own hyper-parameters)
    statistics = tmp_path / "vecnormalize.pkl"
    venv = DummyVecEnv([lambda: gym.make("Pendulum-v1")])
    VecNormalize(venv).save(str(statistics))
    statistics.write_bytes(statistics.read_bytes()[:50])
    with pytest.raises(ValueError, match=re.escape(f"The VecNormalize statistics {statistics} cannot be read")):
        load_vec_normalize(str(statistics), venv)


def test_statistics_of_something_else_or_of_another_env_are_named(tmp_path: pathlib.Path) -> None:
    venv = DummyVecEnv([lambda: gym.make("Pendulum-v1")])
    overwritten = tmp_path / "overwritten.pkl"
    overwritten.write_bytes(pickle.dumps({"obs_rms": None}))
    with pytest.raises(
        ValueError, match=re.escape(f"The VecNormalize statistics {overwritten} hold a dict, not VecNormalize")
    ):
        load_vec_normalize(str(overwritten), venv)
    other = tmp_path / "other.pkl"
    VecNormalize(DummyVecEnv([lambda: gym.make("CartPole-v1")])).save(str(other))
    with pytest.raises(ValueError, match=re.escape(f"The VecNormalize statistics {other} were saved for another env")):
        load_vec_normalize(str(other), venv)


def test_statistics_of_another_env_of_the_same_shape_are_refused(tmp_path: pathlib.Path) -> None:
    cart_pole = tmp_path / "cart_pole.pkl"  # (4,) observations, as BiasedPendulum's, but bounded where its are not
    VecNormalize(DummyVecEnv([lambda: gym.make("CartPole-v1")])).save(str(cart_pole))
    pendulum = DummyVecEnv([lambda: gym.make("sb3_icrl/BiasedPendulum-v0")])
    expected = f"The VecNormalize statistics {cart_pole} were saved for another env (observations Box([-4.8"
    with pytest.raises(ValueError, match=re.escape(expected) + ".*this env's are Box\\(-inf, inf, \\(4,\\), float64\\)"):
        load_vec_normalize(str(cart_pole), pendulum)
    # other finite bounds (an env argument moved a limit) and another float width are the same observations
    saved = tmp_path / "pendulum.pkl"
    VecNormalize(DummyVecEnv([lambda: gym.make("Pendulum-v1")])).save(str(saved))
    moved = gym.spaces.Box(-20.0, 20.0, (3,), dtype=np.float64)
    venv = DummyVecEnv([lambda: gym.wrappers.TransformObservation(gym.make("Pendulum-v1"), lambda obs: obs, moved)])
    assert load_vec_normalize(str(saved), venv).venv is venv
