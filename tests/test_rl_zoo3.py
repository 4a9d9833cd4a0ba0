"""sb3-icrl's algorithms inside rl_zoo3 (skipped where rl_zoo3 is not installed, except the parts that do not need it)."""

import os

import numpy as np
import pytest
import yaml
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize

from sb3_icrl import GACL, MECL, PPOLagrangian
from sb3_icrl.zoo.rl_zoo3 import (
    RL_ZOO3_ALGOS,
    ZooGACL,
    ZooMECL,
    ZooPPOLagrangian,
    export_rl_zoo3_config,
    main,
    register_rl_zoo3,
    rl_zoo3_hyperparams,
    shipped_demonstrations_for,
)


def test_exported_config_has_full_env_ids(tmp_path):
    entries = rl_zoo3_hyperparams("mecl")
    assert entries["sb3_icrl/BlockedHalfCheetah-v0"] == entries["BlockedHalfCheetah-v0"]
    assert "default" in entries and "sb3_icrl/default" not in entries
    path = export_rl_zoo3_config("gacl", tmp_path / "gacl.yml")
    with open(path) as file:
        written = yaml.safe_load(file)
    assert (
        written["sb3_icrl/GridWorldWall-v0"] == written["GridWorldWall-v0"] == rl_zoo3_hyperparams("gacl")["GridWorldWall-v0"]
    )
    with pytest.raises(FileNotFoundError, match="No hyper-parameter file"):
        rl_zoo3_hyperparams("dqn")


def test_zoo_classes_evaluate_strings_and_default_to_shipped_data():
    env = make_vec_env("sb3_icrl/GridWorldWall-v0", n_envs=1)
    assert shipped_demonstrations_for(env) == "GridWorldWall-v0"
    model = ZooGACL("MlpPolicy", env, n_steps=64, batch_size=32, constraint_net_kwargs="dict(hidden_sizes=[8])")
    assert isinstance(model, GACL) and model.demonstrations_source == "GridWorldWall-v0"
    assert model.demonstrations is not None and len(model.demonstrations) > 0
    lagrangian = ZooPPOLagrangian("MlpPolicy", env, n_steps=64, batch_size=32, lagrange_kwargs="dict(init=0.5)")
    assert isinstance(lagrangian, PPOLagrangian)
    assert float(np.asarray(lagrangian.lagrange_multiplier.value).reshape(-1)[0]) == pytest.approx(0.5)
    corridor = make_vec_env("sb3_icrl/ConstrainedCorridor-v0", n_envs=1)
    assert shipped_demonstrations_for(corridor) is None
    with pytest.raises(ValueError, match="--hyperparams demonstrations"):
        ZooMECL("MlpPolicy", corridor, n_steps=64, batch_size=32)


def test_models_the_bridge_saves_are_the_algorithms_own(tmp_path):
    # sb3-icrl compare and enjoy load a bridge-trained model with the algorithm's class, rl_zoo3 with the adapter
    from sb3_icrl.common.saved import SAVED_ALGORITHM_KEY, library_algorithm, saved_algorithm

    assert library_algorithm(ZooGACL) == "GACL" and library_algorithm(ZooPPOLagrangian) == "PPOLagrangian"
    assert saved_algorithm({SAVED_ALGORITHM_KEY: "ZooMECL"}) == "MECL"  # as zips saved by the bridge recorded it
    env = make_vec_env("sb3_icrl/GridWorldWall-v0", n_envs=1)
    ZooGACL("MlpPolicy", env, n_steps=64, batch_size=32).save(tmp_path / "model.zip")
    assert type(GACL.load(tmp_path / "model.zip", demonstrations_source=None)) is GACL
    assert type(ZooGACL.load(tmp_path / "model.zip", demonstrations_source=None)) is ZooGACL


def test_plain_eval_callback_gets_the_normalization_statistics():
    # SB3's EvalCallback cannot sync VecNormalize through the ICRL algorithms' extra wrappers; the zoo classes can
    env = VecNormalize(make_vec_env("sb3_icrl/BlockedHalfCheetah-v0", n_envs=1))
    eval_env = VecNormalize(make_vec_env("sb3_icrl/BlockedHalfCheetah-v0", n_envs=1), training=False)
    model = ZooMECL("MlpPolicy", env, n_steps=64, batch_size=32, update_every=128, constraint_batch_size=64)
    callback = EvalCallback(eval_env, eval_freq=64, n_eval_episodes=1, warn=False)
    model.learn(128, callback=[callback])
    assert isinstance(callback, EvalCallback) and callback.n_calls == 128
    np.testing.assert_allclose(eval_env.obs_rms.mean, env.obs_rms.mean)
    assert eval_env.obs_rms.count == env.obs_rms.count > 1


def test_register_adds_algorithms_to_rl_zoo3():
    rl_zoo3_utils = pytest.importorskip("rl_zoo3.utils")
    algos = register_rl_zoo3()
    assert algos is rl_zoo3_utils.ALGOS
    assert algos["mecl"] is ZooMECL and issubclass(algos["mecl"], MECL)
    assert algos["ppo"] is not None and set(RL_ZOO3_ALGOS) <= set(algos)
    assert register_rl_zoo3() is algos  # idempotent


def test_rl_zoo3_trains_and_saves_an_icrl_model(tmp_path, monkeypatch):
    pytest.importorskip("rl_zoo3.train")
    monkeypatch.chdir(tmp_path)
    main(
        [
            "train",
            "--algo",
            "gacl",
            "--env",
            "sb3_icrl/GridWorldWall-v0",
            "--gym-packages",
            "sb3_icrl",
            "-n",
            "128",
            "--eval-freq",
            "-1",
            "--seed",
            "0",
            "-f",
            str(tmp_path / "logs"),
            "--hyperparams",
            "n_steps:64",
            "batch_size:32",
        ]
    )
    run = tmp_path / "logs" / "gacl" / "sb3_icrl-GridWorldWall-v0_1"
    saved = run / "sb3_icrl-GridWorldWall-v0.zip"
    assert saved.is_file()
    with open(run / "sb3_icrl-GridWorldWall-v0" / "config.yml") as file:
        config = dict(yaml.unsafe_load(file))
    entry = rl_zoo3_hyperparams("gacl")["GridWorldWall-v0"]
    assert config["constraint_net_kwargs"] == entry["constraint_net_kwargs"]  # the GridWorldWall-v0 entry was used
    model = ZooGACL.load(os.fspath(saved))
    assert model.demonstrations_source == "GridWorldWall-v0"
    assert model.forward_solver == entry.get("forward_solver", "policy_gradient")


@pytest.mark.parametrize("flag", ["-optimize", "--optimize-hyperparameters"])
def test_rl_zoo3_hyperparameter_search_is_refused_for_our_algorithms(flag):
    # Refused before rl_zoo3 is imported: its samplers have no search space for these algorithms
    with pytest.raises(SystemExit, match=f"{flag} is rl_zoo3's Optuna search.*no search space for mecl"):
        main(["train", "--algo", "mecl", "--env", "sb3_icrl/BlockedHalfCheetah-v0", flag, "--n-trials", "2"])
