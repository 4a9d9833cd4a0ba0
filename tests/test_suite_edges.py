"""Suite mistakes caught before any run, with file and line; run folders that only look finished."""

import json
import os
import pathlib
import pickle
import signal
import subprocess
import sys
import textwrap
import time

import pytest
import torch as th
from model_files import write_whole_zip

from sb3_icrl.benchmark import load_suite
from sb3_icrl.benchmark.cli import main as benchmark_main
from sb3_icrl.benchmark.suite import SuiteError
from sb3_icrl.zoo.runs import FINISHED_FILE, is_finished, latest_checkpoint

HEAD = "envs: [GridWorldWall-v0]\nalgos: [bc2l]\nseeds: [0]\n"


def write(tmp_path, text: str) -> str:
    path = tmp_path / "suite.yml"
    path.write_text(textwrap.dedent(text))
    return str(path)


@pytest.mark.parametrize(
    "text, line, message",
    [
        (HEAD + "seeds: [1]\n", 4, r"`seeds` is given twice \(first on line 3\)"),
        (
            HEAD + "variants:\n  a: {transition_noise: 0.1, transition_noise: 0.2}\n",
            5,
            "`variants.a.transition_noise` is given twice",
        ),
        (HEAD + "variants:\n  imperfect: {violating_fraction: 1.5}\n", 5, r"within \[0, 1\], got 1.5"),
        (
            HEAD + "variants:\n  noisy: {transition_noise: 0.1, transition_noise_model: scalar}\n",
            5,
            "`transition_noise_model` is one of component, shared .*got 'scalar'",
        ),
        (
            HEAD + "variants:\n  quiet: {transition_noise: 0, transition_noise_model: shared}\n",
            5,
            "`transition_noise_model` says how the noise of `transition_noise` is drawn, and the variant has none",
        ),
        (HEAD + "train_args: {eval_episodes: -1}\n", 4, "`eval_episodes` is at least 1"),
        (
            "envs: [GridWorld-v0]\nalgos: [bc2l]\nseeds: [0]\n",
            1,
            "none are shipped for GridWorld-v0 .*give the variant `demonstrations: PATH.npz`",
        ),
        (
            "envs: [HighwayVelocity-v0]\nalgos: [mecl]\nseeds: [0]\nvariants:\n  imperfect: {violating_fraction: 0.2}\n",
            1,
            r"none are shipped for HighwayVelocity-v0 with violating_fraction 0.2 \(shipped fractions: \[0.0\]\)",
        ),
        (HEAD + "variants:\n  mine: {demonstrations: no/such/file.npz}\n", 5, "no demonstrations file 'no/such/file.npz'"),
        (
            HEAD + "variants:\n  a:\n    hyperparams:\n      n_steps: 16\n      n_stepz: 16\n",
            8,
            r"`n_stepz` is not a hyper-parameter of bc2l \(did you mean 'n_steps'\?\)",
        ),
        (
            "envs: [GridWorldWall-v0]\nalgos: [ppo, bc2l]\nseeds: [0]\nvariants:\n  a: {hyperparams: {constraint_steps: 2}}\n",
            5,
            "`constraint_steps` is not a hyper-parameter of ppo: every run of variant 'a' would stop",
        ),
        ("envs: [CartPole-v1]\nalgos: [ppolag]\nseeds: [0]\n", 1, r"CartPole-v1 reports no true cost \(its step's info"),
        (HEAD + "eval_episodes: -1\n", 4, "`eval_episodes` must be an integer >= 1, got -1"),
        (HEAD + "description: [MECL, VICRL]\n", 4, r"`description` is one line of text .*got \['MECL', 'VICRL'\]"),
        (HEAD + "train_args: {device: tpu9}\n", 4, "`device` 'tpu9' is not a torch device: use auto, cpu, cuda or cuda:N"),
        # The env as each run makes it: its keywords and values, and whether noise can be added to its states
        (
            HEAD + "variants:\n  a: {env_kwargs: {map_nam: wall}}\n",
            5,
            "variant 'a': GridWorldWall-v0 cannot be made with these env_kwargs .*unexpected keyword argument 'map_nam'",
        ),
        (
            HEAD + "variants:\n  a: {transition_noise: 0.1}\n",
            5,
            "variant 'a' cannot run on GridWorldWall-v0: TransitionNoiseWrapper adds Gaussian noise to continuous states",
        ),
        # Values only the algorithm refuses: the checker makes each run's model (a dry build) to find them
        (
            HEAD + "variants:\n  a:\n    hyperparams:\n      n_steps: 128\n      cost_budget: -1\n",
            8,
            "variant 'a' stops every bc2l run on GridWorldWall-v0 at its start, at `cost_budget`: ValueError: "
            r"`cost_budget` must be >= 0 \(costs are non-negative, so no policy could meet it\), got -1",
        ),
        (
            "envs: [GridWorldWall-v0]\nalgos: [ppo, gacl]\nseeds: [0]\nvariants:\n  a: {hyperparams: {n_steps: abc}}\n",
            5,
            r"variant 'a' stops every ppo run on GridWorldWall-v0 at its start, at `n_steps`: .*n_steps='abc' is text, "
            r"but PPO expects int \(default 2048\): give a Python value, e.g. n_steps: 2048",
        ),
        (
            HEAD + "variants:\n  base: {}\n  wide:\n    hyperparams:\n      n_steps: 128\n"
            '      constraint_net_kwargs: "dict(hiden_sizes=[64])"\n',
            9,
            "variant 'wide' stops every bc2l run on GridWorldWall-v0 at its start, at `constraint_net_kwargs`: "
            r"TypeError: FeasibilityNet takes no argument 'hiden_sizes' \(did you mean 'hidden_sizes'\?\)",
        ),
    ],
)
def test_mistakes_are_caught_before_any_run(tmp_path, text, line, message):
    with pytest.raises(SuiteError, match=f"line {line}: .*{message}"):
        load_suite(write(tmp_path, text))


def test_run_refuses_a_variant_its_algorithm_refuses_before_any_run_starts(tmp_path, capsys):
    path = write(tmp_path, HEAD + "variants:\n  a: {hyperparams: {cost_budget: -1}}\n")
    root = tmp_path / "logs"
    assert benchmark_main(["run", path, "-f", str(root), "--jobs", "1", "--no-report"]) == 2
    assert "line 5: variant 'a' stops every bc2l run on GridWorldWall-v0 at its start" in capsys.readouterr().err
    assert not root.exists()  # no run folder, no log
    # status and report start no run: they read the folders without making models
    assert benchmark_main(["status", path, "-f", str(root)]) == 0


def test_a_dry_build_keeps_the_random_state_and_passes_good_values(tmp_path):
    # 3e-4 is a string to yml and a float to the run's train.py: the check takes it as the run does
    text = HEAD + "variants:\n  small:\n    hyperparams:\n      n_steps: 64\n      learning_rate: 3e-4\n"
    text += "      constraint_net_kwargs: 'dict(hidden_sizes=[8])'\n"
    th.manual_seed(0)
    state, threads = th.get_rng_state(), th.get_num_threads()
    suite = load_suite(write(tmp_path, text))
    assert th.equal(th.get_rng_state(), state)  # the models made to check the suite drew no random number of the caller
    assert th.get_num_threads() == threads  # (they are made on one thread)
    assert [run.variant for run in suite.runs()] == ["small"]


def test_a_build_that_fails_without_the_variant_s_values_too_is_left_to_the_run(tmp_path):
    # IRL+ (SAC) takes Box actions only: the grid's runs stop whatever the variant sets, and say so in their logs
    text = "envs: [GridWorldWall-v0]\nalgos: [irlplus]\nseeds: [0]\nvariants:\n  a: {hyperparams: {learning_starts: 10}}\n"
    assert [run.name for run in load_suite(write(tmp_path, text)).runs()] == ["a/irlplus/GridWorldWall-v0/seed 0"]


def test_reference_rows_need_no_demonstrations(tmp_path):
    assert load_suite(write(tmp_path, "envs: [GridWorld-v0]\nalgos: [ppo, ppolag]\nseeds: [0]\n")).runs()


def test_an_env_written_module_colon_id_makes_every_run_import_its_module(tmp_path):
    suite = load_suite(write(tmp_path, "envs: ['sb3_icrl.envs:sb3_icrl/GridWorldWall-v0']\nalgos: [bc2l]\nseeds: [0]\n"))
    assert suite.gym_packages == ("sb3_icrl.envs",)
    argv = suite.runs()[0].train_argv("logs")
    assert argv[argv.index("--gym-packages") + 1] == "sb3_icrl.envs"


def test_a_finished_json_that_is_not_a_json_mapping_is_no_finished_run(tmp_path):
    for text, finished in (("", False), ('{"num_timesteps": 5', False), ("[1, 2]", False), ('{"num_timesteps": 5}', True)):
        (tmp_path / FINISHED_FILE).write_text(text)
        assert is_finished(str(tmp_path)) is finished, text
    os.remove(tmp_path / FINISHED_FILE)
    assert not is_finished(str(tmp_path)) and json.dumps({}) == "{}"


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _sigint_as_a_terminal_leaves_it() -> None:
    # At its default and not blocked, as an interactive shell starts a command, whatever this test process inherited
    # or was left with by the tests before it (a child inherits both the disposition and the blocked set)
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def _start_training_suite(tmp_path: pathlib.Path, in_background: bool = False) -> tuple[subprocess.Popen, str]:
    """
    A one-run suite started in its own session, returned once its run has logged a training step (its log file);
    ``in_background``: with SIGINT ignored, as a shell starts ``nohup ... &`` (its runs inherit that).
    """
    path = write(tmp_path, HEAD + "steps: 100000\ntrain_args: {eval_freq: 50000, save_freq: 0}\n")
    root = str(tmp_path / "logs")
    command = [sys.executable, "-m", "sb3_icrl.benchmark", "run", path, "-f", root, "--jobs", "1", "--no-report"]
    process = subprocess.Popen(
        command,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=_ignore_sigint if in_background else _sigint_as_a_terminal_leaves_it,
        # A SIGABRT then prints where every thread of the engine and its run stands (see _end_of)
        env={**os.environ, "PYTHONFAULTHANDLER": "1"},
    )
    log = load_suite(path).runs()[0].log_file(root)
    deadline = time.time() + 60
    while not (os.path.isfile(log) and "step" in pathlib.Path(log).read_text()) and time.time() < deadline:
        time.sleep(0.2)
    return process, log


def _end_of(process: subprocess.Popen, log: str, timeout: float = 60.0) -> str:
    """The engine's stderr once it has ended; one still running after ``timeout`` seconds fails the test with where
    its threads and its run's stood, and the end of the run's log."""
    try:
        return process.communicate(timeout=timeout)[1]
    except subprocess.TimeoutExpired:
        pass
    masks = "\n".join(_signal_masks(process.pid))
    os.killpg(process.pid, signal.SIGABRT)
    errors = process.communicate(timeout=30)[1]
    log_text = pathlib.Path(log).read_text() if os.path.isfile(log) else "(no log)"
    # Before the run's own stack dump, and without its list of extension modules
    log_end = "\n".join(line for line in log_text.splitlines()[-80:] if not line.startswith("Extension modules"))
    pytest.fail(
        f"the engine still ran {timeout:.0f} s after the signal.\nSignal masks (pid, command, pending/blocked/ignored/"
        f"caught):\n{masks}\nIts stderr:\n{errors}\nIts run's log:\n{log_end}"
    )


def _signal_masks(group: int) -> list[str]:
    """Per process of a process group, its signal masks from ``/proc`` (Linux): was SIGINT pending, blocked, ignored?"""
    lines = []
    for status in pathlib.Path("/proc").glob("[0-9]*/stat"):
        try:
            if int(status.read_text().rsplit(")", 1)[1].split()[2]) != group:
                continue
            fields = dict(
                line.split(":", 1) for line in (status.parent / "status").read_text().splitlines() if line.startswith("Sig")
            )
            command = (status.parent / "cmdline").read_bytes().replace(b"\0", b" ").decode()[:90]
        except (OSError, ValueError, IndexError):
            continue  # ended meanwhile
        masks = " ".join(fields.get(name, "?").strip() for name in ("SigPnd", "SigBlk", "SigIgn", "SigCgt"))
        lines.append(f"{status.parent.name} {command}: {masks} (SIGINT is bit 0x2)")
    return lines


def test_ctrl_c_ends_a_suite_with_one_line(tmp_path):
    process, log = _start_training_suite(tmp_path)
    # As a terminal's Ctrl-C does: SIGINT to the whole process group, the engine and its run
    os.killpg(process.pid, signal.SIGINT)
    errors = _end_of(process, log)
    assert process.returncode == 130
    assert "Traceback" not in errors and errors.strip().splitlines()[-1].startswith("interrupted: the runs resume")


@pytest.mark.parametrize(
    ("stop", "in_background"),
    [
        # As `kill -INT` sends it: the engine's process only, which passes it on to its runs
        (signal.SIGINT, False),
        # As `kill PID` on `nohup sb3-icrl benchmark run ... &` does, or a job scheduler's time limit: SIGINT is
        # ignored there
        (signal.SIGTERM, True),
    ],
    ids=["sigint", "sigterm-in-background"],
)
def test_a_signal_to_the_engine_alone_stops_its_runs_which_save_and_ends_with_one_line(tmp_path, stop, in_background):
    process, log = _start_training_suite(tmp_path, in_background=in_background)
    os.kill(process.pid, stop)
    errors = _end_of(process, log)
    assert process.returncode == 130
    assert "Traceback" not in errors and errors.strip().splitlines()[-1].startswith("interrupted: the runs resume")
    assert "Interrupted: saving the model" in pathlib.Path(log).read_text()


def test_status_into_a_pipe_closed_early_ends_quietly(tmp_path):
    # As `sb3-icrl benchmark status SUITE | head -1` does once head has its line
    command = [sys.executable, "-m", "sb3_icrl.benchmark", "status", "smoke", "-f", str(tmp_path)]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    process.stdout.close()  # before the command writes anything
    errors = process.stderr.read()
    assert process.wait(timeout=60) == 0 and errors == ""


def test_a_broken_model_leaves_its_seed_out_of_the_report_and_names_its_folder(tmp_path, capsys):
    path = write(
        tmp_path,
        HEAD.replace("seeds: [0]", "seeds: [0, 1]") + "steps: 256\neval_episodes: 2\n"
        "train_args: {eval_freq: 128, eval_episodes: 1, save_freq: 0}\n"
        "variants: {base: {hyperparams: {forward_solver: policy_gradient, n_steps: 128}}}\n",
    )
    root = str(tmp_path / "logs")
    assert benchmark_main(["run", path, "-f", root, "--jobs", "1", "--no-report"]) == 0
    broken = load_suite(path).runs()[1].run_folder(root)
    model = pathlib.Path(broken) / "GridWorldWall-v0.zip"
    model.write_bytes(model.read_bytes()[:100])  # a copy cut short
    capsys.readouterr()
    assert benchmark_main(["report", path, "-f", root, "--no-figures"]) == 0
    out = capsys.readouterr().out
    assert f"left out of the report, its model in {broken} could not be evaluated" in out
    summary = json.loads((pathlib.Path(root) / "suite" / "report" / "summary.json").read_text())
    assert [cell["n_seeds"] for cell in summary["cells"]] == [1]


def test_resume_falls_back_past_a_checkpoint_whose_pickles_are_broken(tmp_path):
    for steps in (100, 200):
        write_whole_zip(str(tmp_path / f"rl_model_{steps}_steps.zip"))
        for kind in ("vecnormalize", "training_state"):
            (tmp_path / f"rl_model_{kind}_{steps}_steps.pkl").write_bytes(pickle.dumps({"steps": steps}))
    assert latest_checkpoint(str(tmp_path)).endswith("rl_model_200_steps.zip")
    broken = tmp_path / "rl_model_training_state_200_steps.pkl"
    broken.write_bytes(broken.read_bytes()[:5])  # cut short
    with pytest.warns(UserWarning, match=f"{broken} cannot be read: resuming from an earlier checkpoint"):
        assert latest_checkpoint(str(tmp_path)).endswith("rl_model_100_steps.zip")


def test_only_that_matches_nothing_names_the_suites_values() -> None:
    suite = load_suite("table3", dry_build=False)
    with pytest.raises(SuiteError, match=r"it has seed: 1000, 1001, 1002, 1003, 1004; algo: .*mecl") as error:
        suite.select({"seed": ["7"], "algo": ["mecll"]})
    assert "env:" not in str(error.value)  # only the keys filtered on
