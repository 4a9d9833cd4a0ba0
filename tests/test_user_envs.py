"""A user's own env, registered in the user's own module, works with every command (--gym-packages, MODULE:EnvId)."""

import json
import math
import os
import pathlib
import re
import shlex
import subprocess
import sys
import textwrap
import warnings

import pytest
import yaml

from sb3_icrl.zoo import main
from sb3_icrl.zoo.hyperparams import env_name, resolve_env_id

MODULE = """\
import gymnasium

gymnasium.register(id="myenvs/Corridor-v0", entry_point="sb3_icrl.common.envs:ConstrainedCorridorEnv", max_episode_steps=20)
"""
FAST = ["-n", "128", "-params", "n_steps:64", "batch_size:32", "--eval-freq", "64", "--eval-episodes", "1", "--seed", "0"]


@pytest.fixture
def user_module(tmp_path, monkeypatch):
    name = f"user_envs_{os.getpid()}_{tmp_path.name.replace('-', '_')}"
    (tmp_path / f"{name}.py").write_text(textwrap.dedent(MODULE))
    monkeypatch.syspath_prepend(str(tmp_path))
    return name


def test_unknown_env_error_says_how_to_register_one():
    with pytest.raises(ValueError, match="--gym-packages MODULE"):
        resolve_env_id("myenvs/NotRegistered-v0")
    with pytest.raises(ValueError, match="cannot import its module 'no_such_module_xyz'"):
        resolve_env_id("no_such_module_xyz:Env-v0")


def test_module_colon_env_id_imports_the_module(user_module):
    assert resolve_env_id(f"{user_module}:myenvs/Corridor-v0") == "myenvs/Corridor-v0"


def test_train_with_gym_packages_then_compare_in_a_fresh_process(user_module, tmp_path):
    logs = tmp_path / "logs"
    args = ["--algo", "ppolag", "--env", "myenvs/Corridor-v0", "--gym-packages", user_module, "-f", str(logs), *FAST]
    assert main([*args, "--verbose", "0"]) == 0
    run = logs / "ppolag" / f"{env_name('myenvs/Corridor-v0')}_1"
    assert run.name == "myenvs-Corridor-v0_1"
    saved = yaml.safe_load((run / "myenvs-Corridor-v0" / "args.yml").read_text())
    assert saved["gym_packages"] == [user_module]
    # compare learns from args.yml which module registers the env: nothing to pass
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    result = subprocess.run(
        [sys.executable, "-m", "sb3_icrl.zoo", "compare", str(run), "-n", "40"],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert "| ppolag | 0 |" in result.stdout


# ------------------------------------------------------------------------------------------------ a declared user env

DECLARED_MODULE = """\
import gymnasium

from sb3_icrl.common.envs import ConstrainedCorridorEnv
from sb3_icrl.common.constraint_spec import ConstraintSpec, FeatureConstraint


class ShortCorridorEnv(ConstrainedCorridorEnv):
    # Six steps from cell 0 never pass cell 6: any expert is safe, so a barely trained one gives demonstrations
    def __init__(self, max_steps: int = 6):
        super().__init__(length=11, safe_limit=6, max_steps=max_steps)

    @property
    def constraint_spec(self):
        return ConstraintSpec(features=(FeatureConstraint(obs_index=0, threshold=0.6, op=">", name="x"),))


gymnasium.register(id="myns/ShortCorridor-v0", entry_point=ShortCorridorEnv, max_episode_steps=6)
"""
SHORT = "myns/ShortCorridor-v0"
TINY = ["--eval-freq", "64", "--eval-episodes", "1", "--seed", "0", "--verbose", "0"]


@pytest.fixture(scope="module")
def declared_runs(tmp_path_factory):
    """An expert, its demonstrations and a MECL run on a user env, trained in this process through the CLI functions."""
    from sb3_icrl import hyperparams
    from sb3_icrl.data.__main__ import main as data_main

    root = tmp_path_factory.mktemp("declared")
    module = f"declared_envs_{os.getpid()}"
    (root / f"{module}.py").write_text(DECLARED_MODULE)
    sys.path.insert(0, str(root))
    logs = root / "logs"
    expert = ["--algo", "ppolag", "--env", f"{module}:{SHORT}", "-f", str(logs), "-n", "128", *TINY]
    assert main([*expert, "-params", "n_steps:64", "batch_size:32"]) == 0
    expert_run = logs / "ppolag" / "myns-ShortCorridor-v0_1"
    demos = root / "demos.npz"
    assert data_main(["generate", "--run", str(expert_run), "--n", "3", "--out", str(demos)]) == 0
    mecl = ["--algo", "mecl", "--env", SHORT, "--gym-packages", module, "--demonstrations", str(demos), "-f", str(logs)]
    hyperparams._ANNOUNCED_DEFAULTS.discard("mecl")  # said once per process: whatever ran before in this one
    with pytest.warns(UserWarning, match="No mecl entry"):  # an unknown env: the ICRL defaults, said once
        assert main([*mecl, "-n", "128", *TINY, "-params", '{"n_steps": 64, "batch_size": 32, "update_every": 64}']) == 0
    yield {"root": root, "module": module, "logs": logs, "expert": expert_run, "demos": demos}
    sys.path.remove(str(root))


def test_env_name_is_the_one_folder_name_of_namespaced_ids(tmp_path):
    from sb3_icrl.plots.figures import find_runs

    assert env_name("mymodule:myns/MyEnv-v0") == env_name("myns/MyEnv-v0") == "myns-MyEnv-v0"
    assert env_name("sb3_icrl/BlockedAnt-v0") == env_name("BlockedAnt-v0") == "BlockedAnt-v0"
    (tmp_path / "mecl" / "myns-MyEnv-v0_2").mkdir(parents=True)
    (tmp_path / "mecl" / "MyEnv-v0_1").mkdir()  # another env's folder: not a run of myns/MyEnv-v0
    assert [run.name for run in find_runs(tmp_path, "mecl", "mymodule:myns/MyEnv-v0")] == ["myns-MyEnv-v0_2"]


def test_unknown_env_icrl_defaults_and_json_or_yml_overrides(tmp_path, monkeypatch):
    from sb3_icrl import hyperparams
    from sb3_icrl.zoo.hyperparams import UNKNOWN_ENV_ICRL_DEFAULTS, load_hyperparams, preprocess_hyperparams
    from sb3_icrl.zoo.train import get_parser

    monkeypatch.setattr(hyperparams, "_ANNOUNCED_DEFAULTS", set())
    with pytest.warns(UserWarning, match="cost_budget=expert, budget_statistic=step, lagrange_update=pid"):
        entry, key = load_hyperparams("vicrl", "myns/Unknown-v0")
    assert key == "default" and {k: entry[k] for k in UNKNOWN_ENV_ICRL_DEFAULTS} == UNKNOWN_ENV_ICRL_DEFAULTS
    # Episodes that end early cost the budget for ever; VICRL's cost is its Beta's mean, not one draw
    assert entry["termination_cost"] == "budget" and entry["cost_mode"] == "mean"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # said once per process
        assert load_hyperparams("vicrl", "myns/Other-v0")[0]["cost_budget"] == "expert"
        assert load_hyperparams("ppolag", "myns/Other-v0")[0]["cost_budget"] == 0.0  # not an ICRL learner
        assert load_hyperparams("mecl", "GridWorldWall-v0")[0]["cost_budget"] == 0.0  # a known env keeps its recipe

    parser = get_parser()
    args = parser.parse_args(["--algo", "mecl", "--env", "E", "-params", '{"constraint_net_kwargs": {"hidden_sizes": [32]}}'])
    assert args.hyperparams == {"constraint_net_kwargs": {"hidden_sizes": [32]}}
    small = tmp_path / "small.yml"
    small.write_text("n_steps: 64\nconstraint_net_kwargs: {hidden_sizes: [8]}\n")
    assert parser.parse_args(["--algo", "mecl", "--env", "E", "-params", str(small)]).hyperparams["n_steps"] == 64
    with pytest.raises(SystemExit):
        parser.parse_args(["--algo", "mecl", "--env", "E", "-params", '{"n_steps": 64'])  # broken JSON: a clear error
    # --conf-file: a small yml or a JSON object goes over the shipped entry; -params over both
    entry, _ = load_hyperparams("mecl", "myns/Other-v0", {"n_steps": 32}, conf_file=str(small))
    assert (entry["n_steps"], entry["constraint_net_kwargs"], entry["cost_budget"]) == (32, {"hidden_sizes": [8]}, "expert")
    assert entry["constraint_steps"] == 5  # the rest of the shipped default entry
    params = preprocess_hyperparams(load_hyperparams("mecl", "GridWorldWall-v0", conf_file='{"n_steps": 128}')[0])
    assert params["n_steps"] == 128 and params["n_timesteps"] > 0
    with pytest.raises(ValueError, match="not valid JSON"):
        load_hyperparams("mecl", "GridWorldWall-v0", conf_file="{n_steps: 128")


def test_generate_from_a_run_records_a_command_that_regenerates_it(declared_runs):
    import numpy as np

    from sb3_icrl.data.__main__ import main as data_main

    sidecar = json.loads(declared_runs["demos"].with_suffix(".json").read_text())
    command = shlex.split(sidecar["command"])
    assert command[command.index("--gym-packages") + 1] == declared_runs["module"]
    assert os.path.samefile(
        command[command.index("--vecnormalize") + 1], declared_runs["expert"] / "myns-ShortCorridor-v0" / "vecnormalize.pkl"
    )
    assert sidecar["env_id"] == SHORT
    out = declared_runs["root"] / "again.npz"
    command[command.index("--out") + 1] = str(out)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(declared_runs["root"]), os.environ.get("PYTHONPATH", "")])}
    result = subprocess.run([sys.executable, *command[1:]], capture_output=True, text=True, env=env, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    with np.load(declared_runs["demos"], allow_pickle=True) as first, np.load(out, allow_pickle=True) as second:
        assert np.array_equal(first["obs"], second["obs"])
    best = declared_runs["root"] / "best.npz"
    args = ["generate", "--run", str(declared_runs["expert"]), "--model", "best", "--n", "1", "--out", str(best)]
    assert data_main(args) == 0
    assert json.loads(best.with_suffix(".json").read_text())["expert"]["path"].endswith("best_model.zip")
    assert data_main(["generate", "--run", str(declared_runs["root"]), "--n", "1", "--out", str(best)]) == 1
    assert data_main(["generate", "--n", "1", "--out", str(best)]) == 1  # neither --run nor --env/--expert


def test_plot_of_a_namespaced_run_uses_its_normalisation_statistics(declared_runs, monkeypatch, capsys):
    import sb3_icrl.plots.__main__ as plots_module
    from sb3_icrl.plots.__main__ import main as plots_main

    run = declared_runs["logs"] / "mecl" / "myns-ShortCorridor-v0_1"
    statistics = run / "myns-ShortCorridor-v0" / "vecnormalize.pkl"
    assert statistics.is_file()
    loaded = []
    original = plots_module.load_vec_normalize

    def recording_load(path, venv):
        loaded.append(os.path.abspath(path))
        return original(path, venv)

    monkeypatch.setattr(plots_module, "load_vec_normalize", recording_load)
    output = declared_runs["root"] / "constraint.png"
    assert plots_main(["constraint", str(run), "--episodes", "1", "-o", str(output)]) == 0
    assert loaded == [str(statistics)] and output.is_file()
    # an undeclared feature, with a threshold of the user's
    assert plots_main(["constraint", str(run), "--feature", "1", "--threshold", "0.5", "--op", ">=", "-o", str(output)]) == 0
    assert plots_main(["constraint", str(run), "--feature", "7", "-o", str(output)]) == 2
    assert "outside the 2 observation features" in capsys.readouterr().err
    curves = ["curves", "-f", str(declared_runs["logs"]), "--algos", "mecl", "--env", SHORT, "-o", str(output)]
    assert plots_main([*curves, "--gym-packages", declared_runs["module"]]) == 0
    statistics.rename(statistics.with_suffix(".moved"))
    try:  # a normalising run without its statistics: an error, never a silent run without them
        assert plots_main(["constraint", str(run), "--episodes", "1", "-o", str(output)]) == 2
        assert "trained with VecNormalize" in capsys.readouterr().err
    finally:
        statistics.with_suffix(".moved").rename(statistics)


def test_plot_of_an_env_without_a_declaration_asks_for_the_feature():
    from sb3_icrl.plots.__main__ import _pick_constraint

    with pytest.raises(ValueError, match="--feature INDEX"):
        _pick_constraint((), None)
    with pytest.raises(ValueError, match="go together"):
        _pick_constraint((), "0", threshold=0.5)
    chosen = _pick_constraint((), "0", threshold=0.5, op="<=")
    assert (chosen.obs_index, chosen.threshold, chosen.unsafe_side) == (0, 0.5, "below")
    assert math.isnan(_pick_constraint((), "2").threshold)  # no threshold: the figure draws none


def test_enjoy_and_compare_variants_labelled_by_folder(declared_runs, capsys):
    from sb3_icrl.zoo.compare import main as compare_main
    from sb3_icrl.zoo.compare import run_labels
    from sb3_icrl.zoo.enjoy import main as enjoy_main

    logs, module = declared_runs["logs"], declared_runs["module"]
    args = ["--algo", "mecl", "--env", SHORT, "-f", str(logs), "-n", "30", "--no-render", "--verbose", "0"]
    assert enjoy_main([*args, "--gym-packages", module]) == 0
    assert "violation rate 0.00" in capsys.readouterr().out
    # a variant: the same algorithm and seed, in another log folder
    variant_logs = declared_runs["root"] / "logs_wide"
    variant = ["--algo", "mecl", "--env", f"{module}:{SHORT}", "--demonstrations", str(declared_runs["demos"])]
    params = ["-params", "n_steps:64", "batch_size:32", "update_every:64", "constraint_net_kwargs:dict(hidden_sizes=[8])"]
    assert main([*variant, "-f", str(variant_logs), "-n", "64", *TINY, *params]) == 0
    runs = [str(logs / "mecl" / "myns-ShortCorridor-v0_1"), str(variant_logs / "mecl" / "myns-ShortCorridor-v0_1")]
    assert list(run_labels([*runs, str(declared_runs["expert"])]).values()) == ["mecl (logs)", "mecl (logs_wide)", "ppolag"]
    assert compare_main([*runs, "-n", "12", "--reference", "mecl (logs)"]) == 0
    out = capsys.readouterr().out
    assert "| mecl (logs) | 0 |" in out and "| mecl (logs_wide) | 0 |" in out
    assert compare_main([runs[0], runs[0]]) == 2  # one run twice is no variant
    assert "Two mecl runs trained with seed 0" in capsys.readouterr().err


def test_benchmark_suite_with_gym_packages(declared_runs, tmp_path):
    suite = tmp_path / "mine.yml"
    suite.write_text(
        yaml.safe_dump(
            {
                "description": "A user env",
                "envs": [SHORT],
                "algos": ["ppolag"],
                "seeds": [0],
                "steps": 64,
                "eval_episodes": 2,
                "variants": {"tiny": {"hyperparams": {"n_steps": 64, "batch_size": 32}}},
                "train_args": {"eval_freq": 64, "eval_episodes": 1},
                "gym_packages": [declared_runs["module"]],
            }
        )
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(declared_runs["root"]), os.environ.get("PYTHONPATH", "")])}
    command = [
        sys.executable,
        "-m",
        "sb3_icrl.zoo",
        "benchmark",
        "run",
        str(suite),
        "-f",
        str(tmp_path / "logs"),
        "--jobs",
        "1",
    ]
    result = subprocess.run(command, capture_output=True, text=True, env=env, timeout=600)
    assert result.returncode == 0, (result.stdout + result.stderr)[-3000:]
    assert (tmp_path / "logs" / "mine" / "tiny" / "ppolag" / "myns-ShortCorridor-v0_0" / "finished.json").is_file()


def test_benchmark_transfer_and_compare_take_gym_packages(declared_runs, tmp_path, capsys):
    import argparse

    from sb3_icrl.benchmark.cli import _load_suite
    from sb3_icrl.metrics.transfer import main as transfer_main
    from sb3_icrl.zoo.compare import main as compare_main

    suite_file = tmp_path / "mine.yml"
    suite_file.write_text(
        yaml.safe_dump({"description": "A user env", "envs": [SHORT], "algos": ["ppolag"], "seeds": [0], "steps": 64})
    )
    module = declared_runs["module"]
    suite = _load_suite(argparse.Namespace(suite=str(suite_file), gym_packages=[module]))
    assert suite.gym_packages == (module,)
    # every run of the suite imports the module before it makes the env
    argv = suite.runs()[0].train_argv("logs")
    assert argv[argv.index("--gym-packages") + 1] == module
    assert transfer_main([str(declared_runs["expert"]), "--task", "same", "--gym-packages", "no_such_module_here"]) == 2
    assert "no_such_module_here" in capsys.readouterr().err
    assert compare_main([str(declared_runs["expert"]), "--gym-packages", "no_such_module_either"]) == 2
    assert "no_such_module_either" in capsys.readouterr().err


def test_user_env_pipeline_through_the_cli_only(tmp_path):
    """A user's whole pipeline in one shell, tiny step counts: expert -> demonstrations -> MECL -> compare -> plot."""
    module = f"pipeline_envs_{os.getpid()}"
    (tmp_path / f"{module}.py").write_text(DECLARED_MODULE)
    tiny = "--eval-freq 64 --eval-episodes 1 --seed 0"
    script = f"""
    sb3-icrl train --algo ppolag --env {SHORT} --gym-packages {module} -n 128 -params n_steps:64 batch_size:32 {tiny} -f logs
    python -m sb3_icrl.data generate --run logs/ppolag/myns-ShortCorridor-v0_1 --n 3 --out demos.npz
    sb3-icrl train --algo mecl --env {SHORT} --gym-packages {module} --demonstrations demos.npz -n 128 {tiny} -f logs \\
        -params '{{"n_steps": 64, "batch_size": 32, "update_every": 64}}'
    sb3-icrl compare logs/mecl/myns-ShortCorridor-v0_1 -n 12
    python -m sb3_icrl.plots constraint logs/mecl/myns-ShortCorridor-v0_1 -o constraint.png
    """
    bin_dir = os.path.dirname(sys.executable)  # the venv's sb3-icrl
    env = {**os.environ, "PATH": os.pathsep.join([bin_dir, os.environ.get("PATH", "")]), "PYTHONPATH": str(tmp_path)}
    result = subprocess.run(
        ["bash", "-e", "-c", textwrap.dedent(script)], cwd=tmp_path, capture_output=True, text=True, env=env, timeout=600
    )
    assert result.returncode == 0, (result.stdout + result.stderr)[-3000:]
    assert (tmp_path / "logs" / "mecl" / "myns-ShortCorridor-v0_1" / "finished.json").is_file()
    assert "| mecl | 0 |" in result.stdout  # compare's table, seed 0
    assert (tmp_path / "constraint.png").stat().st_size > 0


# ------------------------------------------------------------------------------------------------ the how-to, end to end

GUIDE = pathlib.Path(__file__).resolve().parents[1] / "docs" / "guide" / "custom_env.md"


def guide_blocks() -> list[tuple[str, str]]:
    """The fenced blocks of docs/guide/custom_env.md, in order: ``(language, text)``."""
    return re.findall(r"^```(\w+)\n(.*?)^```$", GUIDE.read_text(), flags=re.MULTILINE | re.DOTALL)


@pytest.mark.slow
def test_custom_env_guide_runs_end_to_end(tmp_path):
    """
    Every file and command of the how-to, as written, in a fresh folder: expert, demonstrations, MECL, compare, plots.
    On its hopper, whose episodes end when it falls, MECL keeps the constraint without falling on purpose.
    """
    blocks = guide_blocks()
    scripts = []
    for language, text in blocks:
        first = text.splitlines()[0]
        if first.startswith("# file: "):
            (tmp_path / first.removeprefix("# file: ").strip()).write_text(text)
        elif language == "bash":
            scripts.append(["bash", "-e", "-c", text])
        elif language == "python":
            scripts.append([sys.executable, "-c", text])
    assert len(scripts) >= 6 and (tmp_path / "my_envs.py").is_file()
    bin_dir = os.path.dirname(sys.executable)  # sb3-icrl and python of this environment
    env = {**os.environ, "PYTHONPATH": str(tmp_path), "PATH": os.pathsep.join([bin_dir, os.environ.get("PATH", "")])}
    for script in scripts:
        result = subprocess.run(script, cwd=tmp_path, capture_output=True, text=True, env=env, timeout=1800)
        assert result.returncode == 0, f"{script[-1]}\n{(result.stdout + result.stderr)[-3000:]}"
    for produced in ("demos.npz", "compare.json", "constraint.png", "curves.png"):
        assert (tmp_path / produced).is_file(), produced
    runs = {run.get("label") or run["algo"]: run for run in json.loads((tmp_path / "compare.json").read_text())["runs"]}
    assert list(runs) == ["mecl (logs)", "mecl (logs_raw)", "ppolag"]
    mecl, expert = runs["mecl (logs)"], runs["ppolag"]
    assert mecl["violation_rate"] <= 0.1 and mecl["episode_length"] >= 0.5 * expert["episode_length"], (mecl, expert)
