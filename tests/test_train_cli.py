"""train.py / sb3_icrl.zoo: the rl-zoo style command line, its hyper-parameter files and its run folders."""

import os
import pathlib
import shutil
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import yaml
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from sb3_icrl.data.registry import DEMONSTRATIONS_DIR
from sb3_icrl.zoo import ALGOS, ICRL_ALGOS, main, resolve_env_id
from sb3_icrl.zoo.callbacks import (
    ConstraintEvalCallback,
    RecordedEpisode,
    learned_episode_stats,
    learned_penalised_rewards,
    learned_selection_score,
    rescore_episodes,
)
from sb3_icrl.zoo.hyperparams import (
    DEFAULT_HYPERPARAMS_DIR,
    HyperparameterError,
    algo_kwargs,
    load_hyperparams,
    preprocess_hyperparams,
    read_hyperparams_file,
)

ROOT = pathlib.Path(__file__).resolve().parents[1]
#: The algorithms that act in discrete action spaces too (the grid worlds, the corridor): SAC-based ones need Box actions
DISCRETE_ACTION_ALGOS = [algo for algo in ALGOS if not issubclass(ALGOS[algo], OffPolicyAlgorithm)]
#: Those with grid-world recipes: IRL-Plus holds its multiplier at 1, where the grid recipes plan with one that adapts
GRID_ALGOS = [algo for algo in DISCRETE_ACTION_ALGOS if algo != "irlplusppo"]
# The policy-gradient forward solver everywhere (the grid recipes plan instead): its rollouts fix checkpoints and updates
FAST = ["-n", "256", "-params", "n_steps:128", "batch_size:32", "forward_solver:policy_gradient", "--eval-freq", "128"]
FAST += ["--eval-episodes", "2", "--seed", "1"]


@pytest.mark.parametrize("algo", GRID_ALGOS)
def test_train_subprocess_writes_zoo_run_folder(algo: str, tmp_path: pathlib.Path) -> None:
    """The root ``train.py`` trains each algo on the grid world (shipped demonstrations) and leaves rl-zoo's layout."""
    command = [sys.executable, str(ROOT / "train.py"), "--algo", algo, "--env", "GridWorldWall-v0", *FAST]
    command += ["--save-freq", "128", "-f", "logs", "-tb", "tb", "--verbose", "0"]
    result = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-3000:]

    run = tmp_path / "logs" / algo / "GridWorldWall-v0_1"
    for name in ("GridWorldWall-v0.zip", "best_model.zip", "rl_model_128_steps.zip", "rl_model_256_steps.zip"):
        assert (run / name).is_file(), name
    assert (run / "0.monitor.csv").is_file() and (run / "eval" / "0.monitor.csv").is_file()
    assert "--algo" in (run / "command.txt").read_text()

    config = yaml.safe_load((run / "GridWorldWall-v0" / "config.yml").read_text())
    assert config["n_steps"] == 128 and config["batch_size"] == 32 and config["n_timesteps"] == 256
    args = yaml.safe_load((run / "GridWorldWall-v0" / "args.yml").read_text())
    assert args["env"] == "sb3_icrl/GridWorldWall-v0" and args["seed"] == 1 and args["algo"] == algo
    versions = yaml.safe_load((run / "GridWorldWall-v0" / "versions.yml").read_text())
    assert {"sb3_icrl", "stable_baselines3", "gymnasium", "torch", "git_revision"} <= set(versions)

    evaluations = np.load(run / "evaluations.npz")
    assert evaluations["timesteps"].tolist() == [128, 256]
    # SB3's layout: every array but timesteps holds one row per evaluation and one column per episode
    per_episode = ("results", "ep_lengths", "feasible_rewards", "violations", "episode_costs", "learned_feasible_rewards")
    per_episode += ("learned_episode_costs", "learned_penalised_rewards")
    shapes = {key: evaluations[key].shape for key in evaluations.files if key != "timesteps"}
    assert shapes == dict.fromkeys(per_episode, (2, 2))
    learned = evaluations["learned_feasible_rewards"]
    assert np.isfinite(learned).all() == (algo in ICRL_ALGOS)  # NaN for the algos without a learned constraint
    assert np.isfinite(evaluations["learned_episode_costs"]).all() == (algo in ICRL_ALGOS)
    penalised = evaluations["learned_penalised_rewards"]  # only the Lagrangian learners price their learned cost
    assert np.isfinite(penalised).all() == (algo in ("bc2l", "mecl", "vicrl"))
    selection = np.load(run / "model_selection.npz")  # one value per evaluation
    assert {key: selection[key].shape for key in selection.files} == {
        key: (2,) for key in ("timesteps", "selection_score", "best_model_rescored", "lagrange_multiplier")
    }
    assert selection["timesteps"].tolist() == [128, 256]
    expected_score = penalised if algo in ("bc2l", "mecl", "vicrl") else learned if algo == "gacl" else None
    if expected_score is not None:
        np.testing.assert_allclose(selection["selection_score"], expected_score.mean(axis=1))
    assert np.isfinite(selection["lagrange_multiplier"]).all() == (algo not in ("ppo", "gacl"))
    # from the second evaluation on, the best model so far is priced again under the current constraint
    rescored = selection["best_model_rescored"]
    assert np.isnan(rescored[0]) and np.isfinite(rescored[1]) == (algo in ICRL_ALGOS)
    events = list(tmp_path.glob("tb/GridWorldWall-v0/*/events.out.tfevents.*"))
    assert events
    # ICRL runs draw the recovered constraint map into TensorBoard at each evaluation
    accumulator = EventAccumulator(str(events[0].parent), size_guidance={"images": 0}).Reload()
    images = accumulator.Tags()["images"]
    assert images == (["constraint/map"] if algo in ICRL_ALGOS else []), images
    if algo in ICRL_ALGOS:
        assert [event.step for event in accumulator.Images("constraint/map")] == [128, 256]


def test_normalize_noise_and_run_ids(tmp_path: pathlib.Path) -> None:
    """VecNormalize statistics are saved, transition noise reaches the env, and a second run gets the next id."""
    fast = [*FAST[:5], "normalize:True", *FAST[5:]]  # -n 256 -params n_steps:128 batch_size:32 normalize:True ...
    args = ["--algo", "ppolag", "--env", "ConstrainedCorridor-v0", *fast, "--transition-noise", "0.01", "--env-kwargs"]
    args += ["max_steps:8"]
    args += ["-f", str(tmp_path), "--verbose", "0"]
    assert main(args) == 0
    assert main(args) == 0
    first, second = tmp_path / "ppolag" / "ConstrainedCorridor-v0_1", tmp_path / "ppolag" / "ConstrainedCorridor-v0_2"
    assert (first / "ConstrainedCorridor-v0" / "vecnormalize.pkl").is_file() and second.is_dir()
    assert yaml.safe_load((first / "ConstrainedCorridor-v0" / "args.yml").read_text())["transition_noise"] == 0.01
    assert (np.load(first / "evaluations.npz")["ep_lengths"] == 8).all()  # --env-kwargs reached the envs


def test_a_run_trained_in_process_closes_its_envs(tmp_path: pathlib.Path) -> None:
    """Training from Python (a notebook, a worker that trains several runs) leaves no monitor file open behind it."""
    import gc
    import warnings

    args = ["--algo", "mecl", "--env", "GridWorldWall-v0", *FAST, "-f", str(tmp_path), "--verbose", "0"]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ResourceWarning)
        assert main(args) == 0
        gc.collect()  # an env nobody closed warns when it is collected
    unclosed = [str(warning.message) for warning in caught if issubclass(warning.category, ResourceWarning)]
    assert not [message for message in unclosed if "monitor.csv" in message], unclosed


def test_a_drawn_seed_is_printed_and_saved(tmp_path: pathlib.Path, capsys) -> None:
    """Without --seed the run draws one: the closing line names it, as args.yml records it, so the run can be repeated."""
    assert main(["--algo", "bc2l", "--env", "GridWorldWall-v0", *FAST, "-f", str(tmp_path), "--verbose", "0"]) == 0
    saved = yaml.safe_load((tmp_path / "bc2l" / "GridWorldWall-v0_1" / "GridWorldWall-v0" / "args.yml").read_text())
    assert f" s, seed {saved['seed']})" in capsys.readouterr().out


def test_violating_fraction_picks_the_shipped_variant(tmp_path: pathlib.Path) -> None:
    args = ["--algo", "bc2l", "--env", "GridWorldWall-v0", *FAST, "--violating-fraction", "0.2", "-f", str(tmp_path)]
    assert main([*args, "--verbose", "0"]) == 0
    assert yaml.safe_load((tmp_path / "bc2l" / "GridWorldWall-v0_1" / "GridWorldWall-v0" / "args.yml").read_text())[
        "violating_fraction"
    ] == pytest.approx(0.2)
    assert main(["--algo", "bc2l", "--env", "GridWorldWall-v0", "--violating-fraction", "0.3", "-f", str(tmp_path)]) == 2


@pytest.mark.parametrize(
    "args, message",
    [
        (["--algo", "ppo", "--env", "GridWorldWal-v0"], "Did you mean 'GridWorldWall-v0'"),
        (["--algo", "ppo", "--env", "GridWorldWall-v0", "-params", "bogus:1"], "rejects the hyper-parameters"),
        (["--algo", "mecl", "--env", "ConstrainedCorridor-v0"], "--demonstrations"),  # none shipped for it
        (["--algo", "ppo", "--env", "GridWorldWall-v0", "--demonstrations", "GridWorldWall-v0"], "ICRL algorithms"),
        (["--algo", "ppolag", "--env", "GridWorldWall-v0", "--violating-fraction", "0.2"], "ICRL algorithms"),
    ],
)
def test_clear_errors_leave_no_run_folder(args: list[str], message: str, tmp_path, capsys) -> None:
    assert main([*args, "-n", "64", "-f", str(tmp_path)]) == 2
    assert message in capsys.readouterr().err
    assert not any(path.is_dir() for path in tmp_path.glob("*/*_*"))


def test_malformed_params_exit_with_usage(tmp_path: pathlib.Path) -> None:
    with pytest.raises(SystemExit):
        main(["--algo", "ppo", "--env", "GridWorldWall-v0", "-params", "no_colon", "-f", str(tmp_path)])


def test_short_and_full_env_ids() -> None:
    assert resolve_env_id("BlockedHalfCheetah-v0") == "sb3_icrl/BlockedHalfCheetah-v0"
    assert resolve_env_id("sb3_icrl/GridWorldWall-v0") == "sb3_icrl/GridWorldWall-v0"
    assert resolve_env_id("CartPole-v1") == "CartPole-v1"
    with pytest.raises(ValueError, match="BlockedAnt-v0"):
        resolve_env_id("Nope-v0")


def test_rl_zoo_string_conventions() -> None:
    raw = {
        "n_timesteps": "1e3",
        "policy_kwargs": "dict(net_arch=[8], activation_fn=nn.Tanh)",
        "learning_rate": "lin_1e-3",
        "normalize": "{'norm_obs': True, 'norm_reward': False}",
        "env_wrapper": [{"sb3_icrl.envs.wrappers.TransitionNoiseWrapper": {"sigma": 0.1}}],
    }
    params = preprocess_hyperparams(raw)
    assert params["n_timesteps"] == 1000 and params["normalize"] is True
    assert params["normalize_kwargs"] == {"norm_obs": True, "norm_reward": False}
    assert params["learning_rate"](0.5) == pytest.approx(5e-4)
    assert params["policy_kwargs"]["activation_fn"].__name__ == "Tanh"
    assert params["env_wrapper"][0][1] == {"sigma": 0.1}
    assert set(algo_kwargs(params)) == {"policy_kwargs", "learning_rate"}
    with pytest.raises(HyperparameterError, match="policy_kwargs"):
        preprocess_hyperparams({"n_timesteps": 1, "policy_kwargs": "dict(("})
    with pytest.raises(HyperparameterError, match="Unknown algo"):
        load_hyperparams("sac", "GridWorldWall-v0")


def _entries() -> list[tuple[str, str]]:
    return [(algo, key) for algo in ALGOS for key in read_hyperparams_file(algo)]


def test_every_benchmark_env_has_an_entry() -> None:
    mujoco = ["BlockedHalfCheetah-v0", "BlockedAnt-v0", "BiasedPendulum-v0", "BlockedWalker-v0", "BlockedSwimmer-v0"]
    for algo in ALGOS:
        assert (DEFAULT_HYPERPARAMS_DIR / f"{algo}.yml").is_file()
        grid = {"GridWorldWall-v0"} if algo in GRID_ALGOS else set()
        assert {"default", *grid, *mujoco} <= set(read_hyperparams_file(algo)), algo
    highway = {"HighwayVelocity-v0", "HighwayDistance-v0", "HighwayVelocityDistance-v0"}
    for algo in ALGOS:
        assert highway <= set(read_hyperparams_file(algo)), algo
        if algo in ("gacl", "bc2l", "mecl", "vicrl"):  # the paper's methods share the driving recipes' constraint side
            params = preprocess_hyperparams(load_hyperparams(algo, "HighwayDistance-v0")[0])
            assert (params["n_timesteps"], params["update_every"], params["constraint_steps"]) == (2_000_000, 50_000, 5)
            assert params["constraint_net_kwargs"] == {"hidden_sizes": [64, 64]} and params["normalize"]


def test_hyperparameter_files_are_package_data() -> None:
    """One copy, inside the package (so a wheel carries it); the root ``zoo_hyperparams`` (rl-zoo's place) links to it."""
    import configparser

    import sb3_icrl

    package = pathlib.Path(sb3_icrl.__file__).resolve().parent
    assert package / "zoo_hyperparams" == DEFAULT_HYPERPARAMS_DIR
    assert (ROOT / "zoo_hyperparams").is_symlink() and (ROOT / "zoo_hyperparams").resolve() == DEFAULT_HYPERPARAMS_DIR
    config = configparser.ConfigParser()
    config.read(ROOT / "setup.cfg")
    assert "zoo_hyperparams/*.yml" in [item.strip() for item in config["options.package_data"]["sb3_icrl"].split(",")]


@pytest.mark.slow
def test_wheel_ships_the_hyperparameter_files(tmp_path: pathlib.Path) -> None:
    """A non-editable install finds the yml files: they are in the wheel, where DEFAULT_HYPERPARAMS_DIR points."""
    import shutil
    import zipfile

    source = tmp_path / "src"
    ignore = shutil.ignore_patterns(".git", ".venv", "logs", "runs", "build", "dist", "*.egg-info", "__pycache__", "tests")
    shutil.copytree(ROOT, source, symlinks=True, ignore=ignore)
    command = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(tmp_path / "w"), "."]
    result = subprocess.run(command, cwd=source, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    (wheel,) = (tmp_path / "w").glob("*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {f"sb3_icrl/zoo_hyperparams/{algo}.yml" for algo in ALGOS} <= names


# The reference ICRL code's constraint settings per env: net, learning rate, steps per update, delta, VICRL's prior
# (HalfCheetah, whose recipe departs from them where RESULTS.md says why, has a test of its own)
REFERENCE_CONSTRAINT = {
    "BlockedAnt-v0": ([40, 40], 5e-3, 5, 0.6, (0.9, 0.1)),
    "BiasedPendulum-v0": ([20], 1e-3, 5, 0.6, (0.09, 0.01)),
    "BlockedWalker-v0": ([64, 64], 1e-3, 5, 0.6, (0.009, 0.001)),
    "BlockedSwimmer-v0": ([20], 1e-3, 5, 0.6, (0.9, 0.1)),
}
# Where one algorithm's reference settings differ from the env's: (algo, env) -> (net, learning rate)
REFERENCE_EXCEPTIONS = {
    ("vicrl", "BiasedPendulum-v0"): ([20], 1e-4),
    ("bc2l", "BlockedWalker-v0"): ([20], 1e-3),
    ("gacl", "BiasedPendulum-v0"): ([40, 40], 1e-5),  # GACL: the reference's discriminator settings
    ("gacl", "BlockedWalker-v0"): ([64, 64], 3e-3),
    ("gacl", "BlockedSwimmer-v0"): ([30], 3e-3),
}
TABLE3_ENVS = ["BlockedHalfCheetah-v0", *REFERENCE_CONSTRAINT, "HighwayVelocity-v0", "HighwayDistance-v0"]
# What the forward learner of an ICRL recipe shares with the expert's ppolag.yml entry
FORWARD_LEARNER_KEYS = ("n_envs", "n_steps", "batch_size", "learning_rate", "gamma", "n_epochs", "policy_kwargs", "normalize")


#: Recipes whose forward learner departs from the expert's by a study (benchmarks/RESULTS.md): the faster HalfCheetah
#: recipe, four envs of 128 steps (the same rollout) and 10 epochs at twice the expert's learning rate (MECL's and
#: VICRL's study; GACL and BC2L take it too, so that every method of the env learns on the same forward learner)
FASTER_FORWARD_LEARNER = {(algo, "BlockedHalfCheetah-v0") for algo in ("gacl", "bc2l", "mecl", "vicrl")}
#: Envs whose ICRL recipes take the throughput family (docs/guide/speed.md: 16 envs x 256 steps, SB3's PPO defaults and
#: nets, learning rate 3e-4) instead of the expert's forward learner: minibatch, epochs and the run's length
THROUGHPUT_FAMILY = {
    "BlockedAnt-v0": (512, 10, 5_000_000),
    "BiasedPendulum-v0": (512, 10, 3_000_000),
    "BlockedWalker-v0": (512, 10, 7_500_000),
    "HighwayVelocity-v0": (512, 10, 2_000_000),
    "HighwayDistance-v0": (1024, 5, 2_000_000),
}
#: Recipes whose constraint inputs are normalised on the expert data by a study (benchmarks/RESULTS.md)
NORMALISED_INPUTS = {("vicrl", "BlockedSwimmer-v0")}

#: Envs whose BC2L, MECL and VICRL recipes charge terminated episodes the per-step budget
TERMINATION_BUDGET_ENVS = ("BiasedPendulum-v0", "BlockedWalker-v0", "HighwayVelocity-v0", "HighwayDistance-v0")


@pytest.mark.parametrize("env_id", TABLE3_ENVS)
@pytest.mark.parametrize("algo", ["gacl", "bc2l", "mecl", "vicrl"])
def test_benchmark_recipes(algo: str, env_id: str) -> None:
    """
    Every table3 recipe: the throughput family's member at its run length (THROUGHPUT_FAMILY), else the expert's
    forward learner (the env's ppolag.yml entry) for at most 1M steps; the reference's constraint settings on MuJoCo,
    the expert's cost as the budget with the PID multiplier (not GACL), and at least 5 constraint updates.
    """
    params = preprocess_hyperparams(load_hyperparams(algo, env_id)[0])
    if env_id in THROUGHPUT_FAMILY:
        batch_size, n_epochs, n_timesteps = THROUGHPUT_FAMILY[env_id]
        forward = dict(n_envs=16, n_steps=256, batch_size=batch_size, n_epochs=n_epochs, learning_rate=3e-4, gamma=0.99)
        forward.update(policy_kwargs={}, normalize=True)
        assert params["n_timesteps"] == n_timesteps
    else:
        forward = preprocess_hyperparams(load_hyperparams("ppolag", env_id)[0])
        if (algo, env_id) in FASTER_FORWARD_LEARNER:
            forward = {
                **forward,
                "n_envs": 4 * forward["n_envs"],
                "n_steps": forward["n_steps"] // 4,
                "n_epochs": forward["n_epochs"] // 2,
                "learning_rate": 2 * forward["learning_rate"],
            }
        assert params["n_timesteps"] <= 10**6
    for key in FORWARD_LEARNER_KEYS:
        wanted = pytest.approx(forward[key]) if key == "learning_rate" else forward.get(key)
        assert params.get(key) == wanted, key
    assert params["n_timesteps"] // params["update_every"] >= 5
    if env_id in REFERENCE_CONSTRAINT:
        hidden, learning_rate, steps, delta, prior = REFERENCE_CONSTRAINT[env_id]
        hidden, learning_rate = REFERENCE_EXCEPTIONS.get((algo, env_id), (hidden, learning_rate))
        # Raw inputs, as the reference, except the Pendulum's cart position (std 0.003 m in the demonstrations)
        raw = {"normalize_input": False} if env_id != "BiasedPendulum-v0" else {}
        raw = {"normalize_input": True} if (algo, env_id) in NORMALISED_INPUTS else raw
        assert params["constraint_net_kwargs"] == {"hidden_sizes": hidden, **raw}
        assert (params["constraint_learning_rate"], params["constraint_steps"]) == (learning_rate, steps)
        if algo == "mecl":
            assert params["regularizer_coef"] == delta
        if algo == "vicrl":
            assert params["kl_coef"] == delta and params["prior"] == prior
    if algo == "gacl":
        assert "cost_budget" not in params
    else:
        assert params["cost_budget"] == "expert" and params["lagrange_update"] == "pid"
        assert params["lagrange_kwargs"] == {"init": 1.0, "kp": 5.0, "ki": 0.005, "kd": 0.0}
        # Decided by the early-termination studies (benchmarks/RESULTS.md)
        assert params.get("termination_cost", "zero") == ("budget" if env_id in TERMINATION_BUDGET_ENVS else "zero")


def test_halfcheetah_entries_are_the_recipe_of_the_results() -> None:
    """
    HalfCheetah departs from the reference (benchmarks/RESULTS.md): expert budget, PID multiplier, rollouts of 512
    steps (four envs of 128), 1M steps; it keeps the reference's raw constraint inputs, and VICRL its KL weight and
    full-batch updates.
    """
    for algo in ("mecl", "vicrl"):
        params = preprocess_hyperparams(load_hyperparams(algo, "BlockedHalfCheetah-v0")[0])
        assert params["constraint_net_kwargs"] == {"hidden_sizes": [20], "normalize_input": False}
        if algo == "vicrl":
            assert params["kl_coef"] == 0.5  # the reference's cn_reg_coeff
        assert params["cost_budget"] == "expert" and params["lagrange_update"] == "pid"
        assert params["lagrange_kwargs"] == {"init": 1.0, "kp": 5.0, "ki": 0.005, "kd": 0.0}
        assert (params["update_every"], params["n_envs"] * params["n_steps"], params["n_timesteps"]) == (100_000, 512, 10**6)
        # The faster recipe: four envs of 128 steps, 10 epochs at twice rl-zoo's learning rate; VICRL skips an update
        # while its learner is within 0.05 of the expert's feasibility
        assert (params["n_envs"], params["n_epochs"], params["learning_rate"]) == (4, 10, pytest.approx(2 * 2.0633e-05))
        assert params.get("trainer_kwargs") == ({"match_tolerance": 0.05} if algo == "vicrl" else None)
        # MECL's KL bound stops its updates early; VICRL takes the reference's full-batch steps
        assert params["constraint_batch_size"] == {"mecl": 1000, "vicrl": None}[algo]


@pytest.mark.parametrize("algo, key", _entries())
def test_every_entry_builds_its_model(algo: str, key: str) -> None:
    """Each yml entry's arguments are accepted by its algorithm (env: the entry's own, the corridor for `default`)."""
    default_env = "ConstrainedCorridor-v0" if algo in DISCRETE_ACTION_ALGOS else "BiasedPendulum-v0"
    env_id = resolve_env_id(default_env if key == "default" else key)
    params = preprocess_hyperparams(load_hyperparams(algo, env_id)[0])
    env = gym.make(env_id)
    try:
        model = ALGOS[algo](params["policy"], env, device="cpu", **algo_kwargs(params))
        assert model.n_steps == params.get("n_steps", 1)  # (off-policy: SAC's one-step returns)
    finally:
        env.close()


class _Model:
    def __init__(self, **attributes):
        self.__dict__.update(attributes)


def test_best_model_selection_never_reads_the_true_constraint() -> None:
    """Learned-constraint models are ranked by learned scores; only PPO-Lag (trained on it) uses the true cost."""
    metrics = {"mean_reward": 10.0, "feasible_reward": 1.0, "violation_rate": 1.0, "learned_feasible_reward": 7.0}
    callback = ConstraintEvalCallback.__new__(ConstraintEvalCallback)
    callback.model = _Model(constraint_net=object(), cost_fn=None)
    assert callback._selection_score(metrics) == 7.0
    assert callback._selection_score({**metrics, "learned_penalised_reward": 4.0}) == 4.0
    callback.model = _Model(cost_fn=None)
    assert callback._selection_score({k: v for k, v in metrics.items() if k != "learned_feasible_reward"}) == 1.0
    callback.model = _Model()
    assert callback._selection_score({"mean_reward": 10.0, "feasible_reward": 1.0}) == 10.0


class _Multiplier:
    value = np.array([2.0])


@pytest.mark.parametrize("statistic", ["step", "episode"])
def test_learned_penalised_reward_prices_only_the_cost_beyond_the_budget(statistic: str) -> None:
    """reward - lambda * max(0, learned cost - budget), the budget per step scaled by the episode length."""
    model = _Model(lagrange_multiplier=_Multiplier(), cost_budget=np.array([0.1]), budget_statistic=statistic)
    # rows: (reward, learned feasible reward, learned cost, length)
    episodes = np.array([[100.0, 0.0, 30.0, 200.0], [50.0, 50.0, 5.0, 100.0]])
    expected = [100.0 - 2.0 * (30.0 - 20.0), 50.0] if statistic == "step" else [100.0 - 2.0 * 29.9, 50.0 - 2.0 * 4.9]
    np.testing.assert_allclose(learned_penalised_rewards(model, episodes), expected)
    assert learned_selection_score(model, episodes) == pytest.approx(np.mean(expected))
    gacl = _Model(cost_budget=np.array([0.1]), budget_statistic=statistic)  # no multiplier: the learned feasible reward
    assert learned_penalised_rewards(gacl, episodes) is None
    assert learned_selection_score(gacl, episodes) == 25.0


def test_learned_penalised_reward_of_a_signed_cost_is_not_floored() -> None:
    """IRL-Plus charges its learned cost signed while it trains; selection prices it the same way, below 0 included."""
    model = _Model(lagrange_multiplier=_Multiplier(), cost_budget=np.array([0.0]), budget_statistic="step", signed_costs=True)
    episodes = np.array([[100.0, 0.0, 30.0, 200.0], [50.0, 50.0, -5.0, 100.0]])
    np.testing.assert_allclose(learned_penalised_rewards(model, episodes), [100.0 - 2.0 * 30.0, 50.0 + 2.0 * 5.0])
    floored = _Model(lagrange_multiplier=_Multiplier(), cost_budget=np.array([0.0]), budget_statistic="step")
    np.testing.assert_allclose(learned_penalised_rewards(floored, episodes), [100.0 - 2.0 * 30.0, 50.0])


def test_learned_episode_stats_price_recorded_episodes() -> None:
    """(reward, reward before the first step whose learned cost exceeds 0.5, summed learned cost, length) per episode."""
    episodes = [
        RecordedEpisode(np.arange(4.0).reshape(4, 1), np.zeros((4, 1)), np.array([1.0, 2.0, 3.0, 4.0])),
        RecordedEpisode(np.zeros((2, 1)), np.zeros((2, 1)), np.array([5.0, 6.0])),
    ]

    def cost_fn(observations: np.ndarray, actions: np.ndarray) -> np.ndarray:
        return 0.3 * observations[:, 0]  # 0, 0.3, 0.6, 0.9: the third step is the first infeasible one

    np.testing.assert_allclose(learned_episode_stats(episodes, cost_fn), [[10.0, 3.0, 1.8, 4.0], [11.0, 11.0, 0.0, 2.0]])
    with pytest.raises(ValueError):  # a cost per pair, not per episode
        learned_episode_stats(episodes, lambda observations, actions: np.zeros(1))


def test_best_model_is_priced_again_with_the_current_constraint() -> None:
    """A best model whose episodes a later constraint finds costly loses its score (and its place) under that constraint."""
    model = _Model(lagrange_multiplier=_Multiplier(), cost_budget=np.array([0.1]), budget_statistic="step")
    assert rescore_episodes(model, [], lambda observations, actions: np.zeros(len(observations))) is None
    best = [RecordedEpisode(np.zeros((10, 1)), np.zeros((10, 1)), np.full(10, 3.0))]
    assert rescore_episodes(model, best, lambda observations, actions: np.zeros(len(observations))) == 30.0
    # a cost of 0.6 per step: 6 in all against a budget of 0.1 * 10, priced at lambda = 2
    assert rescore_episodes(model, best, lambda observations, actions: np.full(len(observations), 0.6)) == 30.0 - 2.0 * 5.0


def test_console_entry_point() -> None:
    from sb3_icrl.zoo.train import cli

    assert cli([]) == 2
    assert os.path.isfile(ROOT / "train.py")


def _safe_corridor_demonstrations(path: pathlib.Path) -> None:
    """Scripted expert: run right to the last safe cell and stay there (never breaks the constraint)."""
    from sb3_icrl.data.serialize import save
    from sb3_icrl.data.types import Trajectory

    trajectories = []
    for _ in range(2):
        env = gym.make("sb3_icrl/ConstrainedCorridor-v0")
        obs, _ = env.reset()
        observations, actions, rewards, costs = [obs], [], [], []
        done = False
        while not done:
            action = 2 if env.unwrapped.position < env.unwrapped.safe_limit else 1
            obs, reward, terminated, truncated, info = env.step(action)
            observations.append(obs), actions.append(action), rewards.append(reward), costs.append(info["cost"])
            done = terminated or truncated
        trajectories.append(
            Trajectory(np.array(observations), np.array(actions), None, terminated, np.array(rewards), np.array(costs))
        )
    save(path, trajectories, {"env_id": "sb3_icrl/ConstrainedCorridor-v0"})


@pytest.mark.parametrize("algo", [algo for algo in ICRL_ALGOS if algo in DISCRETE_ACTION_ALGOS])
def test_icrl_with_vecnormalize_and_demonstration_path(algo: str, tmp_path: pathlib.Path) -> None:
    """ICRL models wrap their training env further than the eval env: normalisation statistics must still reach it."""
    demos = tmp_path / "demos.npz"
    _safe_corridor_demonstrations(demos)
    fast = [*FAST[:5], "normalize:True", *FAST[5:]]
    args = ["--algo", algo, "--env", "ConstrainedCorridor-v0", *fast, "--demonstrations", str(demos), "-f", str(tmp_path)]
    assert main([*args, "--verbose", "0"]) == 0
    run = tmp_path / algo / "ConstrainedCorridor-v0_1"
    assert (run / "ConstrainedCorridor-v0" / "vecnormalize.pkl").is_file()
    evaluations = np.load(run / "evaluations.npz")
    assert evaluations["timesteps"].tolist() == [128, 256]
    learned = evaluations["learned_feasible_rewards"]  # per episode
    assert np.isfinite(learned).all() and learned.shape == (2, 2)


def test_conf_file_replaces_the_shipped_yml(tmp_path: pathlib.Path) -> None:
    conf = tmp_path / "mine.yml"
    conf.write_text("default:\n  n_timesteps: 128\n  n_steps: 64\n  batch_size: 16\n")
    entry, source = load_hyperparams("ppo", "sb3_icrl/GridWorldWall-v0", {"batch_size": 32}, conf_file=str(conf))
    assert source == "default" and entry == {"n_timesteps": 128, "n_steps": 64, "batch_size": 32}
    args = ["--algo", "ppo", "--env", "GridWorldWall-v0", "-conf", str(conf), "--eval-freq", "-1", "-f", str(tmp_path)]
    assert main([*args, "--verbose", "0"]) == 0
    config = yaml.safe_load((tmp_path / "ppo" / "GridWorldWall-v0_1" / "GridWorldWall-v0" / "config.yml").read_text())
    assert config == {"n_timesteps": 128, "n_steps": 64, "batch_size": 16}


def _resume_args(algo: str, tmp_path: pathlib.Path) -> list[str]:
    fast = [*FAST[:5], "normalize:True", *FAST[5:]]  # -n 256 -params n_steps:128 batch_size:32 normalize:True ...
    args = ["--algo", algo, "--env", "ConstrainedCorridor-v0", *fast, "--save-freq", "128", "-f", str(tmp_path)]
    args += ["--verbose", "0", "--env-kwargs", "safe_limit:0"]  # every step right costs: the multiplier moves at once
    if algo in ICRL_ALGOS:
        _safe_corridor_demonstrations(tmp_path / "demos.npz")
        args += ["--demonstrations", str(tmp_path / "demos.npz")]
    return args


@pytest.mark.parametrize("algo", ["ppolag", "mecl"])
def test_resume_from_a_checkpoint(algo: str, tmp_path: pathlib.Path) -> None:
    """-i: the checkpoint's multiplier, constraint net and VecNormalize statistics go on, and so does the step count."""
    import torch as th
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from sb3_icrl.zoo.train import _setup, get_parser

    args = _resume_args(algo, tmp_path)
    assert main([*args, "-n", "384"]) == 0
    first = tmp_path / algo / "ConstrainedCorridor-v0_1"
    # Saved at the start of the third rollout (256 steps), after two updates: one multiplier update behind the end
    checkpoint = first / "rl_model_256_steps.zip"
    assert all((first / f"rl_model_vecnormalize_{steps}_steps.pkl").is_file() for steps in (128, 256, 384))
    assert not list(first.glob("*replay_buffer*"))  # on-policy: no replay buffer to save

    # The model the resumed run starts from, built by the command line's own set-up
    resume = get_parser().parse_args([*args, "-i", str(checkpoint)])
    env_id = resolve_env_id(resume.env)
    params = preprocess_hyperparams(load_hyperparams(algo, env_id, resume.hyperparams)[0])
    model, _ = _setup(resume, env_id, params, algo_kwargs(params), str(tmp_path / "probe"))
    saved, final = ALGOS[algo].load(checkpoint), ALGOS[algo].load(first / "ConstrainedCorridor-v0.zip")
    assert model.num_timesteps == 256 and final.num_timesteps == 384
    assert not np.allclose(saved.lagrange_multiplier.value, 0.1)  # it moved from its initial value: a real check
    np.testing.assert_array_equal(model.lagrange_multiplier.value, saved.lagrange_multiplier.value)
    assert not np.array_equal(final.lagrange_multiplier.value, saved.lagrange_multiplier.value)
    if algo in ICRL_ALGOS:
        resumed_net, saved_net = model.constraint_net.state_dict(), saved.constraint_net.state_dict()
        assert resumed_net.keys() == saved_net.keys()
        assert all(th.equal(resumed_net[key].cpu(), value.cpu()) for key, value in saved_net.items())
        final_net = final.constraint_net.state_dict()
        assert not all(th.equal(final_net[key].cpu(), value.cpu()) for key, value in saved_net.items())
    stats = VecNormalize.load(str(first / "rl_model_vecnormalize_256_steps.pkl"), DummyVecEnv([lambda: gym.make(env_id)]))
    end_stats = VecNormalize.load(str(first / "ConstrainedCorridor-v0" / "vecnormalize.pkl"), stats.venv)
    normalize = model.get_vec_normalize_env()
    assert normalize is not None and normalize.training
    np.testing.assert_array_equal(normalize.obs_rms.mean, stats.obs_rms.mean)
    assert normalize.obs_rms.count == stats.obs_rms.count != end_stats.obs_rms.count

    with pytest.warns(UserWarning, match=r"overrides \['batch_size', 'n_steps'\] are not used"):  # the zip's are kept
        # An earlier checkpoint of a run that went on: it branches into a new run folder
        assert main([*args, "-n", "256", "-i", str(checkpoint), "--new-folder"]) == 0
    second = tmp_path / algo / "ConstrainedCorridor-v0_2"
    assert (second / "rl_model_384_steps.zip").is_file() and (second / "rl_model_512_steps.zip").is_file()
    assert np.load(second / "evaluations.npz")["timesteps"].tolist() == [384, 512]
    assert ALGOS[algo].load(second / "ConstrainedCorridor-v0.zip").num_timesteps == 512
    recorded = yaml.safe_load((second / "ConstrainedCorridor-v0" / "args.yml").read_text())
    assert recorded["trained_agent"] == str(checkpoint)


def test_a_resumed_run_counts_the_wall_and_cpu_time_of_its_earlier_segments(tmp_path: pathlib.Path) -> None:
    """finished.json's wall_time_total_s and cpu_time_total_s: the times saved with the checkpoint resumed from, plus
    the new segment's."""
    import json
    import pickle

    from sb3_icrl.zoo.callbacks import training_state_cpu_time, training_state_wall_time

    args = [*_resume_args("ppolag", tmp_path), "-n", "384", "--exp-id", "1", "--resume"]
    assert main(args) == 0
    run = tmp_path / "ppolag" / "ConstrainedCorridor-v0_1"
    states = [str(run / f"rl_model_training_state_{steps}_steps.pkl") for steps in (128, 256, 384)]
    saved = [training_state_wall_time(path) for path in states]
    saved_cpu = [training_state_cpu_time(path) for path in states]
    assert 0 < saved[0] < saved[1] < saved[2]  # each checkpoint carries the run's time so far
    # Interrupted after the 256-step checkpoint: the later files never were
    for path in [run / "ConstrainedCorridor-v0.zip", run / "finished.json", *run.glob("rl_model*_384_steps.*")]:
        path.unlink()
    assert main(args) == 0
    finished = json.loads((run / "finished.json").read_text())
    assert finished["resumed_from"].endswith("rl_model_256_steps.zip")
    assert finished["wall_time_total_s"] == pytest.approx(saved[1] + finished["wall_time_s"], abs=0.5)
    assert finished["wall_time_total_s"] > finished["wall_time_s"]
    # The attempt record `benchmark status` reads: the resumed attempt's clock started with the checkpoint's time
    attempt = json.loads((run / "attempt.json").read_text())
    assert attempt["resumed_wall_time_s"] == pytest.approx(saved[1])
    assert attempt["started"] + finished["wall_time_s"] == pytest.approx(os.path.getmtime(run / "finished.json"), abs=2.0)
    # CPU time the same way
    assert 0 < saved_cpu[0] < saved_cpu[1] < saved_cpu[2]
    assert finished["cpu_time_total_s"] == pytest.approx(saved_cpu[1] + finished["cpu_time_s"], abs=0.5)
    # A checkpoint that recorded no CPU time (an earlier version's): the whole run's is unknown, not undercounted
    state_path = run / "rl_model_training_state_256_steps.pkl"
    state = pickle.loads(state_path.read_bytes())
    del state["cpu_time_s"]
    state_path.write_bytes(pickle.dumps(state))
    for path in [run / "ConstrainedCorridor-v0.zip", run / "finished.json", *run.glob("rl_model*_384_steps.*")]:
        path.unlink()
    assert main(args) == 0
    finished = json.loads((run / "finished.json").read_text())
    assert finished["cpu_time_total_s"] is None and finished["cpu_time_s"] > 0


def test_a_run_does_not_resume_with_another_recipe(tmp_path: pathlib.Path, capsys) -> None:
    """--resume after the recipe changed (the yml, -params, -n) stops with the changed keys; the run folder is kept."""
    args = [*_resume_args("ppolag", tmp_path), "--exp-id", "1", "--resume"]
    assert main([*args, "-n", "384"]) == 0
    run = tmp_path / "ppolag" / "ConstrainedCorridor-v0_1"
    for path in [run / "ConstrainedCorridor-v0.zip", run / "finished.json", *run.glob("rl_model*_384_steps.*")]:
        path.unlink()
    before = sorted(path.name for path in run.iterdir())
    assert main([*args, "-n", "512"]) == 2
    error = capsys.readouterr().err
    assert "hyper-parameters changed since it started (n_timesteps: 384 then, 512 now)" in error
    assert main([*args, "-n", "384", "-params", "gamma:0.5"]) == 2
    assert "gamma: (not set) then, 0.5 now" in capsys.readouterr().err
    assert sorted(path.name for path in run.iterdir()) == before
    (run / "failed.json").write_text("{}")  # a failed attempt stays marked failed when the resume is refused
    assert main([*args, "-n", "512"]) == 2 and (run / "failed.json").is_file()
    capsys.readouterr()
    (run / "failed.json").unlink()
    assert main([*args, "-n", "384"]) == 0 and (run / "finished.json").is_file()
    # A finished run is not passed as done for another recipe either
    assert main([*args, "-n", "384", "-params", "gamma:0.5"]) == 2
    assert "gamma: (not set) then, 0.5 now" in capsys.readouterr().err
    assert main([*args, "-n", "384"]) == 0  # same recipe: nothing to do


def test_resume_errors_are_clear(tmp_path: pathlib.Path, capsys) -> None:
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    env = gym.make("sb3_icrl/ConstrainedCorridor-v0")
    PPO("MlpPolicy", env, n_steps=64, device="cpu").save(tmp_path / "agent" / "ppo_agent")
    (tmp_path / "not_a_model.zip").write_text("nope")
    base = ["--env", "ConstrainedCorridor-v0", "-n", "64", "-f", str(tmp_path / "logs"), "--verbose", "0"]
    cases = [
        (["--algo", "ppo", "-i", str(tmp_path / "missing.zip")], "does not exist"),
        (["--algo", "ppo", "-i", str(tmp_path / "not_a_model.zip")], "is not a zip archive"),
        (["--algo", "mecl", "-i", str(tmp_path / "agent" / "ppo_agent.zip")], "holds a ppo model, not a mecl one"),
    ]
    for args, message in cases:
        assert main([*base, *args]) == 2
        assert message in capsys.readouterr().err
    VecNormalize(DummyVecEnv([lambda: env])).save(str(tmp_path / "agent" / "vecnormalize.pkl"))
    assert main([*base, "--algo", "ppo", "-i", str(tmp_path / "agent" / "ppo_agent.zip")]) == 2
    assert "pass -params normalize:True" in capsys.readouterr().err
    assert not any(path.is_dir() for path in tmp_path.glob("logs/*/*_*"))


def test_exp_id_and_resume_errors_are_clear(tmp_path: pathlib.Path, capsys) -> None:
    base = ["--algo", "ppo", "--env", "ConstrainedCorridor-v0", "-n", "64", "-f", str(tmp_path), "--verbose", "0"]
    base += ["--eval-freq", "-1", "-params", "n_steps:64", "batch_size:32"]
    assert main([*base, "--resume"]) == 2
    assert "pass --exp-id N as well" in capsys.readouterr().err
    assert main([*base, "--exp-id", "7"]) == 0
    assert (tmp_path / "ppo" / "ConstrainedCorridor-v0_7" / "finished.json").is_file()
    assert main([*base, "--exp-id", "7"]) == 2
    assert "pass --resume to continue it" in capsys.readouterr().err
    assert main([*base, "--exp-id", "7", "--resume", "--verbose", "1"]) == 0
    assert "has finished: nothing to do" in capsys.readouterr().out
    assert main([*base, "--exp-id", "7", "--resume", "-i", "x.zip"]) == 2
    assert "leave out -i" in capsys.readouterr().err


def test_icrl_run_too_short_for_a_constraint_update_says_so(tmp_path: pathlib.Path) -> None:
    args = ["--algo", "bc2l", "--env", "GridWorldWall-v0", "-n", "128", "-f", str(tmp_path), "--verbose", "0"]
    args += ["--eval-freq", "-1", "-params", "n_steps:64", "batch_size:32", "update_every:1000"]
    with pytest.warns(UserWarning, match="it will make no constraint update"):
        assert main(args) == 0


def test_a_relative_demonstrations_path_is_recorded_absolute(tmp_path, monkeypatch):
    shutil.copy(DEMONSTRATIONS_DIR / "GridWorldWall-v0.npz", tmp_path / "mine.npz")
    shutil.copy(DEMONSTRATIONS_DIR / "GridWorldWall-v0.json", tmp_path / "mine.json")
    monkeypatch.chdir(tmp_path)
    args = ["--algo", "bc2l", "--env", "GridWorldWall-v0", "-n", "256", "--seed", "0", "-f", "logs", "--eval-freq", "-1"]
    assert main([*args, "--demonstrations", "mine.npz"]) == 0
    run = tmp_path / "logs" / "bc2l" / "GridWorldWall-v0_1"
    recorded = yaml.safe_load((run / "GridWorldWall-v0" / "args.yml").read_text())
    assert recorded["demonstrations"] == str(tmp_path / "mine.npz")  # plots and reports run elsewhere still find it


def test_noise_model_is_recorded_and_resume_keeps_it(tmp_path: pathlib.Path) -> None:
    """The run's args.yml carries the noise model its envs drew with; resuming with another one is refused."""
    from sb3_icrl.envs.wrappers import TransitionNoiseWrapper, recorded_transition_noise
    from sb3_icrl.zoo.train import create_env

    args = ["--algo", "ppolag", "--env", "ConstrainedCorridor-v0", *FAST, "--transition-noise", "0.01"]
    args += ["--env-kwargs", "max_steps:8", "-f", str(tmp_path), "--verbose", "0", "--exp-id", "1"]
    assert main([*args, "--transition-noise-model", "shared"]) == 0
    recorded = yaml.safe_load(
        (tmp_path / "ppolag" / "ConstrainedCorridor-v0_1" / "ConstrainedCorridor-v0" / "args.yml").read_text()
    )
    assert recorded_transition_noise(recorded) == (0.01, "shared")
    # An env rebuilt from the record (as evaluation and enjoy build it) draws the same way
    sigma, noise_model = recorded_transition_noise(recorded)
    params = preprocess_hyperparams(load_hyperparams("ppolag", resolve_env_id("ConstrainedCorridor-v0"))[0])
    venv, _ = create_env(
        resolve_env_id("ConstrainedCorridor-v0"),
        params,
        1,
        0,
        {},
        sigma,
        None,
        eval_env=True,
        transition_noise_model=noise_model,
    )
    noise_wrappers = [env for env in _wrapper_chain(venv.unwrapped.envs[0]) if isinstance(env, TransitionNoiseWrapper)]
    assert [(env.sigma, env.model) for env in noise_wrappers] == [(0.01, "shared")]
    venv.close()
    assert main([*args, "--resume", "--transition-noise-model", "component"]) == 2
    assert main([*args, "--resume", "--transition-noise-model", "shared"]) == 0  # finished: nothing to do
    with pytest.raises(SystemExit, match="2"):
        main([*args, "--transition-noise-model", "scalar"])


def _wrapper_chain(env: gym.Env) -> list[gym.Env]:
    chain = [env]
    while isinstance(chain[-1], gym.Wrapper):
        chain.append(chain[-1].env)
    return chain
