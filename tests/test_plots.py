"""sb3_icrl.plots: headless constraint figures, their command line and the TensorBoard callback."""

import pathlib

import gymnasium as gym
import matplotlib.image
import numpy as np
import pytest
import torch as th
import yaml
from stable_baselines3 import PPO
from stable_baselines3.common.logger import Figure as LoggedFigure
from stable_baselines3.common.logger import configure
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

import sb3_icrl.envs  # noqa: F401  (registers the benchmark ids)
from sb3_icrl import BC2L
from sb3_icrl.common.envs import ConstrainedCorridorEnv
from sb3_icrl.constraints import BetaFeasibilityNet, FeasibilityNet
from sb3_icrl.data import Demonstrations, Trajectory
from sb3_icrl.data import save as save_demonstrations
from sb3_icrl.envs.grid_world import GridWorldEnv
from sb3_icrl.icrl.tabular import cost_table
from sb3_icrl.plots import (
    ConstraintFigureCallback,
    constraint_feature,
    constraint_features,
    figure_to_rgb,
    grid_constraint_figure,
    grid_cost_map,
    load_evaluations,
    partial_dependence,
    partial_dependence_figure,
    save_figure,
    seed_statistics,
    training_curves_figure,
)
from sb3_icrl.plots.__main__ import main

CORRIDOR_STEPS = 8


def n_colours(image: np.ndarray) -> int:
    return len(np.unique(image.reshape(-1, 3), axis=0))


def assert_drawn(image: np.ndarray, width: float, height: float, dpi: int = 100) -> None:
    """An RGB image of the figure's size with real content (many colours, mostly not white)."""
    assert image.dtype == np.uint8 and image.shape == (round(height * dpi), round(width * dpi), 3)
    assert n_colours(image) > 50
    assert np.mean(np.all(image == 255, axis=-1)) < 0.95


def linear_net(weights: list[float], bias: float, beta: bool = False) -> FeasibilityNet | BetaFeasibilityNet:
    """A net without hidden layer on 2 observation features and no action: phi = sigmoid(w . obs + b)."""
    cls = BetaFeasibilityNet if beta else FeasibilityNet
    net = cls(2, 1, hidden_sizes=[], use_action=False, normalize_input=False)
    layer = net.network[0]
    with th.no_grad():
        if beta:
            layer.weight.copy_(th.tensor([weights, [-w for w in weights]]))
            layer.bias.copy_(th.tensor([bias, -bias]))
        else:
            layer.weight.copy_(th.tensor([weights]))
            layer.bias.fill_(bias)
    return net


def grid_net(use_action: bool) -> FeasibilityNet:
    env = GridWorldEnv(map_name="wall")
    th.manual_seed(0)
    return FeasibilityNet.from_spaces(
        env.observation_space, env.action_space, hidden_sizes=[8], normalize_input=False, use_action=use_action
    )


# ------------------------------------------------------------------------------------------------ figures


@pytest.mark.parametrize("use_action", [False, True])
def test_grid_cost_map_averages_the_actions(use_action: bool) -> None:
    env = GridWorldEnv(map_name="wall")
    net = grid_net(use_action)
    cost_map = grid_cost_map(net, gym.make("sb3_icrl/GridWorldWall-v0"))  # wrapped env: unwrapped inside
    assert cost_map.shape == (7, 7)
    by_hand = np.array(
        [[np.mean(net.cost(np.full(8, env.cell_to_state(r, c)), np.arange(8))) for c in range(7)] for r in range(7)]
    )
    np.testing.assert_allclose(cost_map, by_hand, atol=1e-6)
    np.testing.assert_allclose(cost_map.reshape(-1), cost_table(net, 49, 8).mean(axis=1), atol=1e-12)
    if use_action:  # the actions really differ, so the mean is not just one of them
        assert not np.allclose(cost_map.reshape(-1), cost_table(net, 49, 8)[:, 0])
    with pytest.raises(TypeError, match="GridWorldEnv"):
        grid_cost_map(net, ConstrainedCorridorEnv())


def test_grid_figure_renders_headless(tmp_path: pathlib.Path) -> None:
    env = GridWorldEnv(map_name="zigzag")
    learned = np.linspace(0.0, 1.0, 49).reshape(7, 7)
    visited = np.eye(7, dtype=bool)
    figure = grid_constraint_figure(learned, env.unsafe_mask, env.start_cell, env.goal_cell, visited=visited, title="zigzag")
    assert len(figure.axes) == 3  # two maps and the colour bar
    image = figure_to_rgb(figure)
    assert_drawn(image, 9.0, 4.2)
    # The true panel is drawn from the mask: an all-safe map draws different pixels
    safe = figure_to_rgb(
        grid_constraint_figure(learned, np.zeros((7, 7), bool), env.start_cell, env.goal_cell, visited=visited, title="zigzag")
    )
    assert not np.array_equal(image, safe)

    path = save_figure(figure, tmp_path / "maps" / "grid.png")
    read = matplotlib.image.imread(path)
    assert read.shape[:2] == image.shape[:2] and read.shape[2] in (3, 4)
    assert not list(path.parent.glob(".*.tmp"))  # atomic write leaves no temporary file

    with pytest.raises(ValueError, match="same shape"):
        grid_constraint_figure(learned, np.zeros((6, 7), bool), (0, 0), (6, 6))
    with pytest.raises(ValueError, match="outside"):
        grid_constraint_figure(learned, env.unsafe_mask, (0, 0), (7, 0))


def test_partial_dependence_is_the_hand_computed_average() -> None:
    net = linear_net([2.0, -1.0], 0.5)
    observations = np.array([[10.0, 0.0], [-3.0, 1.0], [7.0, -2.0]], dtype=np.float32)
    values = np.array([-1.0, 0.0, 0.5, 2.0])
    curve = partial_dependence(net, observations, None, 0, values)

    def sigmoid(z: np.ndarray) -> np.ndarray:
        return 1.0 / (1.0 + np.exp(-z))

    # Feature 0 is replaced by each value; the samples' own feature 0 (10, -3, 7) must not matter
    by_hand = [np.mean(1.0 - sigmoid(2.0 * v - observations[:, 1] + 0.5)) for v in values]
    np.testing.assert_allclose(curve.values, values)
    np.testing.assert_allclose(curve.mean_cost, by_hand, rtol=1e-5)
    assert curve.lower is None and curve.samples is None
    # The same over the other feature
    by_hand_1 = [np.mean(1.0 - sigmoid(2.0 * observations[:, 0] - v + 0.5)) for v in values]
    np.testing.assert_allclose(partial_dependence(net, observations, None, 1, values).mean_cost, by_hand_1, rtol=1e-5)
    with pytest.raises(ValueError, match="outside"):
        partial_dependence(net, observations, None, 2, values)


def test_partial_dependence_of_a_beta_net_uses_its_mean_and_samples_the_spread() -> None:
    net = linear_net([1.0, 0.0], 0.0, beta=True)
    observations = np.zeros((4, 2), dtype=np.float32)
    values = np.array([-3.0, 0.0, 3.0])
    curve = partial_dependence(net, observations, None, 0, values, beta_samples=True, n_beta_samples=400, seed=1)
    alpha = np.log1p(np.exp(values)) + net.min_concentration  # softplus(v), softplus(-v)
    beta = np.log1p(np.exp(-values)) + net.min_concentration
    np.testing.assert_allclose(curve.mean_cost, beta / (alpha + beta), rtol=1e-5)
    assert curve.lower is not None and curve.upper is not None and curve.samples is not None
    assert np.all(curve.lower < curve.mean_cost) and np.all(curve.mean_cost < curve.upper)
    assert curve.samples.shape == (3, 5) and np.all((curve.samples >= 0) & (curve.samples <= 1))
    # Sample quantiles of 1 - phi close to the Beta's (1600 draws per value)
    rng = np.random.default_rng(0)
    for k in range(3):
        reference = np.quantile(1.0 - rng.beta(alpha[k], beta[k], 200000), [0.1, 0.9])
        np.testing.assert_allclose([curve.lower[k], curve.upper[k]], reference, atol=0.05)


@pytest.mark.parametrize("beta", [False, True])
def test_partial_dependence_figure_renders(beta: bool, tmp_path: pathlib.Path) -> None:
    net = linear_net([3.0, 0.0], 1.0, beta=beta)
    rng = np.random.default_rng(0)
    observations = rng.normal(size=(30, 2)).astype(np.float32)
    visited = {"expert": observations[:, 0], "policy": observations[:, 0] - 1.0}
    figure = partial_dependence_figure(net, observations, None, 0, -1.0, "<=", visited, beta_samples=beta, feature_name="x")
    assert_drawn(figure_to_rgb(figure), 10.0, 4.0)
    assert figure.axes[0].get_lines()[0].get_ydata().shape == (101,)
    read = matplotlib.image.imread(save_figure(figure, tmp_path / "pd.png"))
    assert read.shape[:2] == (400, 1000)
    with pytest.raises(ValueError, match="constraint side"):
        partial_dependence_figure(net, observations, None, 0, -1.0, "left", visited)


def test_constraint_feature_lookup() -> None:
    assert constraint_feature("BlockedSwimmer-v0")[1:] == (0, 0.5, ">=")
    assert constraint_feature("sb3_icrl/BlockedHalfCheetah-v0").unsafe_side == "below"
    assert constraint_feature("BlockedAnt-v0", {"cost_threshold": -2.0}).threshold == -2.0
    assert constraint_feature("ConstrainedCorridor-v0")[1:] == (0, 0.6, ">")
    both = constraint_features("HighwayVelocityDistance-v0", {"min_gap": 25.0})
    assert [(c.name, c.threshold, c.unsafe_side) for c in both] == [("ego_speed", 40.0, "above"), ("lead_gap", 25.0, "below")]
    with pytest.raises(ValueError, match="unsafe cells"):
        constraint_feature("GridWorldWall-v0")
    with pytest.raises(ValueError, match="No known feature constraint"):
        constraint_feature("CartPole-v1")


# ------------------------------------------------------------------------------------------------ training curves


def fake_evaluations(timesteps: list[int], violation_rates: list[float], feasible: list[float], n_episodes: int = 4) -> dict:
    """evaluations.npz arrays as ConstraintEvalCallback writes them, with the given per-evaluation means."""
    violations = np.array([[k < round(rate * n_episodes) for k in range(n_episodes)] for rate in violation_rates])
    return {
        "timesteps": np.array(timesteps),
        "results": np.tile(np.array(feasible)[:, None] + 1.0, (1, n_episodes)),
        "ep_lengths": np.full((len(timesteps), n_episodes), 10.0),
        "feasible_rewards": np.tile(np.array(feasible)[:, None], (1, n_episodes)),
        "violations": violations,
        "episode_costs": violations.astype(float),
    }


def write_run(folder: pathlib.Path, arrays: dict | None) -> pathlib.Path:
    folder.mkdir(parents=True)
    if arrays is not None:
        np.savez(folder / "evaluations.npz", **arrays)
    return folder


def test_seed_statistics_mean_and_std_over_seeds() -> None:
    runs = [
        fake_evaluations([100, 200, 300], [0.0, 0.5, 1.0], [1.0, 2.0, 3.0]),
        fake_evaluations([100, 200, 300], [0.5, 0.5, 0.0], [3.0, 2.0, 5.0]),
    ]
    timesteps, mean, std = seed_statistics(runs, "violation_rate")
    np.testing.assert_allclose(timesteps, [100, 200, 300])
    np.testing.assert_allclose(mean, [0.25, 0.5, 0.5])
    np.testing.assert_allclose(std, [0.25, 0.0, 0.5])
    _, mean, std = seed_statistics(runs, "feasible_reward")
    np.testing.assert_allclose(mean, [2.0, 2.0, 4.0])
    np.testing.assert_allclose(std, [1.0, 0.0, 1.0])
    # A seed that is still running: only the common range, other seeds interpolated onto its timesteps
    short = fake_evaluations([100, 250], [0.0, 0.5], [0.0, 3.0])
    timesteps, mean, _ = seed_statistics([runs[0], short], "feasible_reward")
    np.testing.assert_allclose(timesteps, [100, 200, 250])
    np.testing.assert_allclose(mean, [0.5, (2.0 + 2.0) / 2, (2.5 + 3.0) / 2])
    with pytest.raises(ValueError, match="violations"):
        seed_statistics([{"timesteps": np.array([1]), "results": np.zeros((1, 2))}], "violation_rate")


def test_training_curves_figure_renders() -> None:
    runs = {
        "MECL": [fake_evaluations([100, 200, 300], [0.0, 0.5, 1.0], [1.0, 2.0, 3.0]) for _ in range(2)],
        "VICRL": [fake_evaluations([100, 200, 300], [0.5, 0.25, 0.0], [3.0, 2.0, 5.0])],
    }
    figure = training_curves_figure(runs, title="corridor")
    assert len(figure.axes) == 2
    assert [line.get_label() for line in figure.axes[0].get_lines()] == ["MECL (2 seeds)", "VICRL (1 seed)"]
    np.testing.assert_allclose(figure.axes[0].get_lines()[1].get_ydata(), [0.5, 0.25, 0.0])
    assert_drawn(figure_to_rgb(figure), 10.0, 4.0)
    with pytest.raises(ValueError, match="Unknown metric"):
        training_curves_figure(runs, metrics=["success"])


def test_load_evaluations_errors(tmp_path: pathlib.Path) -> None:
    run = write_run(tmp_path / "mecl" / "X-v0_1", None)
    with pytest.raises(FileNotFoundError, match=r"No evaluations.npz in .*X-v0_1"):
        load_evaluations(run)
    with pytest.raises(FileNotFoundError, match="No run folder"):
        load_evaluations(tmp_path / "absent")
    np.savez(run / "evaluations.npz", results=np.zeros((1, 2)))
    with pytest.raises(ValueError, match="timesteps"):
        load_evaluations(run)


# ------------------------------------------------------------------------------------------------ command line


def test_cli_curves_writes_a_png(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture) -> None:
    logs = tmp_path / "logs"
    for algo, rates in (("mecl", [0.5, 0.25]), ("vicrl", [0.25, 0.0])):
        for seed in (1, 2):
            write_run(logs / algo / f"BlockedHalfCheetah-v0_{seed}", fake_evaluations([1000, 2000], rates, [5.0, 6.0]))
    write_run(logs / "mecl" / "BlockedAnt-v0_1", None)  # another env: ignored
    output = tmp_path / "out" / "curves.png"
    args = [
        "curves",
        "-f",
        str(logs),
        "--algos",
        "mecl",
        "vicrl",
        "--env",
        "sb3_icrl/BlockedHalfCheetah-v0",
        "-o",
        str(output),
    ]
    assert main(args) == 0
    image = matplotlib.image.imread(output)
    assert image.shape[:2] == (400, 1000) and n_colours((image[..., :3] * 255).astype(np.uint8)) > 50

    # A run without evaluations.npz: a clear error naming it, unless skipped
    write_run(logs / "vicrl" / "BlockedHalfCheetah-v0_3", None)
    assert main(args) == 2
    error = capsys.readouterr().err
    assert "No evaluations.npz" in error and "BlockedHalfCheetah-v0_3" in error and "--skip-missing" in error
    assert main([*args, "--skip-missing"]) == 0
    assert "BlockedHalfCheetah-v0_3" in capsys.readouterr().err  # named in the warning
    assert main(["curves", "-f", str(logs), "--algos", "gacl", "--env", "BlockedHalfCheetah-v0", "-o", str(output)]) == 2
    assert "No runs of 'gacl'" in capsys.readouterr().err
    assert main(["curves", "-f", str(logs), "--algos", "mecl", "--env", "BlockedWalker-v0", "-o", str(output)]) == 2
    assert "No BlockedWalker-v0_<N> runs" in capsys.readouterr().err


def write_model_run(folder: pathlib.Path, algo: str, model: object, env: str, **extra: object) -> pathlib.Path:
    """A run folder as train.py leaves it: <EnvName>.zip and <EnvName>/args.yml (no training needed)."""
    name = env.split("/")[-1]
    (folder / name).mkdir(parents=True)
    model.save(folder / f"{name}.zip")  # type: ignore[attr-defined]
    args = {"algo": algo, "env": env, "env_kwargs": None, "demonstrations": None, "violating_fraction": None}
    args.update(extra)
    (folder / name / "args.yml").write_text(yaml.safe_dump(args))
    return folder


def grid_vec_env() -> DummyVecEnv:
    return DummyVecEnv([lambda: Monitor(gym.make("sb3_icrl/GridWorldWall-v0"))])


def test_cli_constraint_draws_the_grid_map(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture) -> None:
    model = BC2L("MlpPolicy", grid_vec_env(), "GridWorldWall-v0", n_steps=32, batch_size=32, seed=0)
    run = write_model_run(tmp_path / "bc2l" / "GridWorldWall-v0_1", "bc2l", model, "sb3_icrl/GridWorldWall-v0")
    output = tmp_path / "map.png"
    assert main(["constraint", str(run), "-o", str(output)]) == 0
    image = matplotlib.image.imread(output)
    assert image.shape[:2] == (420, 900)

    ppo_run = write_model_run(
        tmp_path / "ppo" / "GridWorldWall-v0_1",
        "ppo",
        PPO("MlpPolicy", grid_vec_env(), n_steps=32, batch_size=32),
        "GridWorldWall-v0",
    )
    assert main(["constraint", str(ppo_run), "-o", str(output)]) == 2
    assert "only ICRL runs" in capsys.readouterr().err
    assert main(["constraint", str(tmp_path / "nowhere"), "-o", str(output)]) == 2
    assert "No run folder" in capsys.readouterr().err
    assert main(["constraint", str(tmp_path), "-o", str(output)]) == 2
    assert "not a train.py run folder" in capsys.readouterr().err
    assert main(["constraint", str(run), "--model", "best", "-o", str(output)]) == 2
    assert "best_model.zip" in capsys.readouterr().err


def test_cli_constraint_draws_the_partial_dependence(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture) -> None:
    demonstrations = corridor_demonstrations()
    save_demonstrations(tmp_path / "corridor.npz", list(demonstrations), {"env_id": "sb3_icrl/ConstrainedCorridor-v0"})
    env = DummyVecEnv([lambda: Monitor(gym.make("sb3_icrl/ConstrainedCorridor-v0", max_steps=CORRIDOR_STEPS))])
    model = BC2L("MlpPolicy", env, demonstrations, n_steps=32, batch_size=32, seed=0)
    run = write_model_run(
        tmp_path / "bc2l" / "ConstrainedCorridor-v0_1",
        "bc2l",
        model,
        "sb3_icrl/ConstrainedCorridor-v0",
        env_kwargs={"max_steps": CORRIDOR_STEPS},
        demonstrations=str(tmp_path / "corridor.npz"),
    )
    output = tmp_path / "pd.png"
    assert main(["constraint", str(run), "--episodes", "2", "-o", str(output)]) == 0
    assert matplotlib.image.imread(output).shape[:2] == (400, 1000)
    assert main(["constraint", str(run), "--feature", "ego_speed", "-o", str(output)]) == 2
    assert "Unknown feature 'ego_speed'" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------ callback


def corridor_demonstrations(n_trajectories: int = 2) -> Demonstrations:
    """An expert that walks right to the last safe cell and stays there."""
    env = ConstrainedCorridorEnv(max_steps=CORRIDOR_STEPS)
    trajectories = []
    for _ in range(n_trajectories):
        obs, _ = env.reset()
        observations, actions = [obs], []
        for _ in range(CORRIDOR_STEPS):
            action = 2 if env.position < env.safe_limit else 1
            obs, *_ = env.step(action)
            observations.append(obs)
            actions.append(action)
        trajectories.append(
            Trajectory(
                np.array(observations), np.array(actions), None, False, np.zeros(CORRIDOR_STEPS), np.zeros(CORRIDOR_STEPS)
            )
        )
    return Demonstrations(trajectories, {"env_id": "corridor"})


def recorded_figures(model: object, callback: ConstraintFigureCallback, tmp_path: pathlib.Path) -> list[tuple[str, object]]:
    """Train briefly with a TensorBoard logger; return what the callback recorded."""
    model.set_logger(configure(str(tmp_path / "tb"), ["tensorboard"]))  # type: ignore[attr-defined]
    records: list[tuple[str, object]] = []
    original = model.logger.record  # type: ignore[attr-defined]

    def spy(key: str, value: object, exclude: object = None) -> None:
        records.append((key, value))
        original(key, value, exclude)

    model.logger.record = spy  # type: ignore[attr-defined]
    model.learn(64, callback=[callback])  # type: ignore[attr-defined]
    return [(key, value) for key, value in records if isinstance(value, LoggedFigure)]


def test_callback_logs_the_grid_map(tmp_path: pathlib.Path) -> None:
    model = BC2L("MlpPolicy", grid_vec_env(), "GridWorldWall-v0", n_steps=32, batch_size=32, n_epochs=1, seed=0)
    figures = recorded_figures(model, ConstraintFigureCallback(eval_freq=32), tmp_path)
    assert [key for key, _ in figures] == ["constraint/map", "constraint/map"]
    assert isinstance(figures[0][1], LoggedFigure)
    assert list((tmp_path / "tb").glob("events.out.tfevents.*"))


def test_callback_logs_the_final_grid_map_of_a_run_shorter_than_eval_freq(tmp_path: pathlib.Path) -> None:
    """train.py's default --eval-freq (25000) is longer than a grid world's run: the map still reaches TensorBoard."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    model = BC2L("MlpPolicy", grid_vec_env(), "GridWorldWall-v0", n_steps=32, batch_size=32, n_epochs=1, seed=0)
    callback = ConstraintFigureCallback(eval_freq=25_000)
    figures = recorded_figures(model, callback, tmp_path)
    assert [key for key, _ in figures] == ["constraint/map"] and callback.n_figures == 1
    events = EventAccumulator(str(tmp_path / "tb"))
    events.Reload()
    assert [image.step for image in events.Images("constraint/map")] == [64]
    assert "constraint/map" not in model.logger.name_to_value  # written, not left pending


def test_callback_logs_the_partial_dependence(tmp_path: pathlib.Path) -> None:
    env = DummyVecEnv([lambda: Monitor(gym.make("sb3_icrl/ConstrainedCorridor-v0", max_steps=CORRIDOR_STEPS))])
    model = BC2L("MlpPolicy", env, corridor_demonstrations(), n_steps=32, batch_size=32, n_epochs=1, seed=0)
    callback = ConstraintFigureCallback(eval_freq=64)
    figures = recorded_figures(model, callback, tmp_path)
    assert [key for key, _ in figures] == ["constraint/partial_dependence_x_position"]
    assert callback.constraints[0].threshold == pytest.approx(0.6)
    figure = figures[0][1].figure  # type: ignore[attr-defined]
    assert_drawn(figure_to_rgb(figure), 10.0, 4.0)
    assert len(figure.axes[1].patches) > 0  # histogram bars of expert and policy values


def test_callback_refuses_a_model_without_constraint(tmp_path: pathlib.Path) -> None:
    with pytest.raises(ValueError, match="no `constraint_net`"):
        PPO("MlpPolicy", grid_vec_env(), n_steps=32, batch_size=32).learn(32, callback=[ConstraintFigureCallback(eval_freq=8)])
