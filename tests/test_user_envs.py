"""A user's own env, registered in the user's own module, works with every command (--gym-packages, MODULE:EnvId)."""

import os
import subprocess
import sys
import textwrap

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
    with pytest.raises(ValueError, match="cannot import 'no_such_module_xyz'"):
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
