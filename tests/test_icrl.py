"""The ICRL algorithms (BC2L, GACL, MECL, VICRL): set-up, what the learner sees, constraint updates, logging, saving."""

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import KVWriter, Logger
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

from sb3_icrl import BC2L, GACL, MECL, VICRL
from sb3_icrl.bc2l import BC2LTrainer
from sb3_icrl.common.envs import ConstrainedCorridorEnv
from sb3_icrl.common.evaluation import evaluate_constraint
from sb3_icrl.constraints import BetaFeasibilityNet, FeasibilityNet, GACLRewardWrapper, LearnedCostVecEnvWrapper
from sb3_icrl.data import DemonstrationError, Demonstrations, Trajectory, load_demonstrations
from sb3_icrl.icrl import ICRLTrainer, NominalData, NominalTrajectory, TrajectoryRecorderVecEnvWrapper
from sb3_icrl.icrl.tabular import cost_table, precision_recall, tabular_icrl
from sb3_icrl.mecl import MECLTrainer
from sb3_icrl.pi_lagrangian import PILagrangian
from sb3_icrl.vicrl import VICRLTrainer

ALGORITHMS = (BC2L, GACL, MECL, VICRL)
LAGRANGIAN = (BC2L, MECL, VICRL)
TRUE_COST = 1000.0  # far from any learned cost in [0, 1]: a leak cannot go unnoticed
EPISODE = 8


class TrueCostCorridor(ConstrainedCorridorEnv):
    """The corridor with 8-step episodes whose info["cost"] is always TRUE_COST."""

    def __init__(self):
        super().__init__(max_steps=EPISODE)

    def step(self, action):
        obs, reward, terminated, truncated, info = super().step(action)
        info["cost"] = TRUE_COST
        return obs, reward, terminated, truncated, info


def make_env(n_envs: int = 1) -> DummyVecEnv:
    return DummyVecEnv([lambda: Monitor(TrueCostCorridor()) for _ in range(n_envs)])


def corridor_demonstrations(n_trajectories: int = 4) -> Demonstrations:
    """An expert that walks right to the last safe cell (6) and stays there."""
    env = ConstrainedCorridorEnv(max_steps=EPISODE)
    trajectories = []
    for _ in range(n_trajectories):
        obs, _ = env.reset()
        observations, actions, rewards = [obs], [], []
        for _ in range(EPISODE):
            action = 2 if env.position < env.safe_limit else 1
            obs, reward, _, _, _ = env.step(action)
            observations.append(obs)
            actions.append(action)
            rewards.append(reward)
        trajectories.append(
            Trajectory(
                obs=np.array(observations),
                acts=np.array(actions),
                infos=None,
                terminal=False,
                rews=np.array(rewards),
                costs=np.zeros(EPISODE),
            )
        )
    return Demonstrations(trajectories, {"env_id": "corridor"})


def make_model(cls, env=None, **kwargs):
    kwargs = {
        "n_steps": 32,
        "batch_size": 32,
        "n_epochs": 1,
        "seed": 0,
        "policy_kwargs": {"net_arch": [8]},
        "constraint_net_kwargs": {"hidden_sizes": [8]},
        **kwargs,
    }
    return cls("MlpPolicy", make_env() if env is None else env, corridor_demonstrations(), **kwargs)


class CapturingWriter(KVWriter):
    """Keeps every key that was dumped."""

    def __init__(self):
        self.keys: set[str] = set()
        self.values: dict[str, list[float]] = {}

    def write(self, key_values, key_excluded, step=0):
        for key, value in key_values.items():
            self.keys.add(key)
            self.values.setdefault(key, []).append(value)


@pytest.mark.parametrize("cls", ALGORITHMS)
def test_env_is_wrapped_at_the_bottom_below_vec_normalize(cls):
    model = make_model(cls, env=VecNormalize(make_env()))
    assert isinstance(model.env, VecNormalize)
    wrapper = model.env.venv
    assert isinstance(wrapper, GACLRewardWrapper if cls is GACL else LearnedCostVecEnvWrapper)
    assert isinstance(wrapper.venv, TrajectoryRecorderVecEnvWrapper)
    assert isinstance(wrapper.venv.venv, DummyVecEnv)
    assert model.get_env() is model.env


@pytest.mark.parametrize("cls", LAGRANGIAN)
def test_the_learner_reads_the_learned_cost_never_the_true_one(cls):
    model = make_model(cls)

    class Check(BaseCallback):
        def _on_step(self) -> bool:
            for info in self.locals["infos"]:
                assert info["true_cost"] == TRUE_COST and "cost" not in info
            return True

    model.learn(96, callback=Check())
    # PPOLagrangian computes the learned cost itself, once per rollout; the true cost never reaches it
    assert model.cost_fn == model.constraint_cost
    # (an episode's last step also holds the cost critic's bootstrap of the time-limit truncation)
    assert np.all(np.delete(model.rollout_buffer.costs.ravel(), slice(EPISODE - 1, None, EPISODE)) <= 1.0)
    assert len(model.ep_cost_buffer) == 96 // EPISODE and np.max(model.ep_cost_buffer) <= EPISODE


def test_learned_cost_is_the_constraint_net_on_the_raw_pairs():
    # No constraint update (update_every beyond the run), so the net is the same at every step
    model = make_model(BC2L, env=VecNormalize(make_env()), update_every=10**6)
    model.learn(32)
    trajectories = model.recorder.pop_trajectories()
    assert len(trajectories) == 32 // EPISODE
    obs = np.concatenate([t.obs for t in trajectories])
    acts = np.concatenate([t.acts for t in trajectories])
    # Raw observations (the corridor's lie in [0, 1] on a grid of 1/10 and 1/8; VecNormalize's would not)
    np.testing.assert_allclose(obs[:, 1] * EPISODE, np.round(obs[:, 1] * EPISODE), atol=1e-6)
    # The buffer's last step of each episode also holds the bootstrap of its time-limit truncation
    not_last = np.arange(len(obs)) % EPISODE != EPISODE - 1
    costs = model.constraint_cost(obs, acts)
    np.testing.assert_allclose(model.rollout_buffer.costs[not_last, 0, 0], costs[not_last], rtol=1e-6)
    episode_costs = costs.reshape(-1, EPISODE).sum(axis=1)
    np.testing.assert_allclose(np.ravel(model.ep_cost_buffer), episode_costs, rtol=1e-5)


def test_gacl_reward_is_env_reward_plus_log_d_and_hides_the_true_cost():
    model = make_model(GACL)

    class Check(BaseCallback):
        def _on_step(self) -> bool:
            for info, reward in zip(self.locals["infos"], self.locals["rewards"], strict=True):
                assert "cost" not in info and info["true_cost"] == TRUE_COST
                assert reward <= info["env_reward"] + 1e-6  # log D <= 0
            return True

    model.learn(64, callback=Check())


@pytest.mark.parametrize("cls", ALGORITHMS)
def test_constraint_updates_and_logged_keys(cls):
    writer = CapturingWriter()
    model = make_model(cls, n_steps=64, batch_size=64)
    model.set_logger(Logger(folder=None, output_formats=[writer]))
    before = [p.detach().clone() for p in model.constraint_net.parameters()]
    model.learn(256)
    assert model.icrl_trainer.n_updates == 4  # one per rollout of 64 steps (8 finished episodes each)
    assert any(not th.equal(a, b) for a, b in zip(before, model.constraint_net.parameters(), strict=True))
    expected = {
        "constraint/loss",
        "constraint/expert_feasibility",
        "constraint/nominal_feasibility",
        "true/violation_rate",
        "true/feasible_reward",
    }
    if cls is VICRL:
        expected |= {"constraint/kl"}
    if cls is MECL:
        expected |= {"constraint/is_weight_min", "constraint/is_weight_max", "constraint/kl_old_new", "constraint/kl_new_old"}
    assert expected <= writer.keys
    assert all(0.0 <= v <= 1.0 for v in writer.values["true/violation_rate"])
    if cls in LAGRANGIAN:  # the learner's episode costs are learned ones (at most 1 per step), not TRUE_COST
        assert all(v <= EPISODE for v in writer.values["rollout/ep_cost_mean"])


def test_bc2l_separates_expert_from_nominal_pairs():
    model = make_model(BC2L, n_steps=64, batch_size=64, constraint_learning_rate=1e-2, constraint_steps=20)
    writer = CapturingWriter()
    model.set_logger(Logger(folder=None, output_formats=[writer]))
    model.learn(512)
    # Mean feasibility after the last update, on all expert pairs and on that update's nominal pairs
    expert, nominal = writer.values["constraint/expert_feasibility"][-1], writer.values["constraint/nominal_feasibility"][-1]
    assert expert > 0.8 and nominal < expert - 0.2


def test_mecl_kl_early_stop():
    passes = {}
    for name, bound in (("tight", 0.0), ("loose", None)):
        writer = CapturingWriter()
        model = make_model(
            MECL, constraint_learning_rate=0.05, constraint_steps=10, target_kl_old_new=bound, target_kl_new_old=bound
        )
        model.set_logger(Logger(folder=None, output_formats=[writer]))
        model.learn(32)
        passes[name] = writer.values["constraint/n_passes"]
    # The first pass always runs (old == new feasibility); a zero bound stops the update right after it
    assert passes == {"tight": [1.0], "loose": [10.0]}


@pytest.mark.parametrize("cls", ALGORITHMS)
def test_save_load_round_trip_restores_policy_and_constraint_exactly(cls, tmp_path):
    model = make_model(cls, n_steps=64, batch_size=64, constraint_learning_rate=1e-2)
    model.learn(128)
    path = tmp_path / "model.zip"
    model.save(path)
    loaded = cls.load(path, env=make_env(), demonstrations=corridor_demonstrations())

    obs = np.random.default_rng(0).uniform(0, 1, size=(50, 2)).astype(np.float32)
    acts = np.arange(50) % 3
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    if cls is VICRL:
        # Both parameters of the Beta, hence every cost mode; a sampled cost matches under the same torch seed
        mine, theirs = model.constraint_net.alpha_beta(obs, acts), loaded.constraint_net.alpha_beta(obs, acts)
        assert th.equal(mine[0], theirs[0]) and th.equal(mine[1], theirs[1])
        th.manual_seed(3)
        sampled = model.constraint_cost(obs, acts)
        th.manual_seed(3)
        np.testing.assert_array_equal(sampled, loaded.constraint_cost(obs, acts))
        assert loaded.constraint_net.cost_mode == model.constraint_net.cost_mode
    else:
        np.testing.assert_array_equal(model.constraint_cost(obs, acts), loaded.constraint_cost(obs, acts))
    for key, value in model.constraint_optimizer.state_dict()["state"].items():
        assert th.equal(value["exp_avg"], loaded.constraint_optimizer.state_dict()["state"][key]["exp_avg"])
    assert type(loaded.constraint_net) is type(model.constraint_net)
    assert loaded.trainer_kwargs == model.trainer_kwargs or cls is VICRL
    if cls in LAGRANGIAN:
        np.testing.assert_array_equal(loaded.lagrange_multiplier.value, model.lagrange_multiplier.value)
    # The loaded model keeps learning, with its constraint wired into its new env
    assert loaded.n_constraint_updates == model.n_constraint_updates > 0
    loaded.learn(64)
    # The count goes on over the model's life (match_tolerance's warm-up is not made twice)
    assert loaded.icrl_trainer.n_updates == loaded.n_constraint_updates == model.n_constraint_updates + 1


def test_load_without_env_predicts_costs_and_asks_for_demonstrations(tmp_path):
    model = make_model(BC2L)
    model.save(tmp_path / "m.zip")
    loaded = BC2L.load(tmp_path / "m.zip")
    obs, acts = np.zeros((3, 2), dtype=np.float32), np.array([0, 1, 2])
    np.testing.assert_array_equal(model.constraint_cost(obs, acts), loaded.constraint_cost(obs, acts))
    assert loaded.demonstrations is None
    with pytest.raises(ValueError, match="no demonstrations to learn from"):
        loaded.learn(10)


def test_shipped_demonstrations_by_name_are_reloaded(tmp_path):
    env = DummyVecEnv([lambda: Monitor(gym.make("sb3_icrl/GridWorldWall-v0"))])
    model = BC2L("MlpPolicy", env, "GridWorldWall-v0", n_steps=32, batch_size=32, n_epochs=1, seed=0)
    assert len(model.demonstrations) == 50
    model.save(tmp_path / "m.zip")
    loaded = BC2L.load(tmp_path / "m.zip", env=DummyVecEnv([lambda: Monitor(gym.make("sb3_icrl/GridWorldWall-v0"))]))
    assert loaded.demonstrations_source == "GridWorldWall-v0" and len(loaded.demonstrations) == 50


@pytest.mark.parametrize("cls", ALGORITHMS)
def test_demonstrations_that_do_not_match_the_env_are_refused(cls):
    # Grid-world data (Discrete observations) on the corridor (Box(2) observations)
    with pytest.raises(DemonstrationError, match="do not match the target env"):
        cls("MlpPolicy", make_env(), "GridWorldWall-v0")
    # Actions out of the corridor's Discrete(3)
    demos = corridor_demonstrations()
    bad = [Trajectory(obs=t.obs, acts=t.acts + 5, infos=None, terminal=False, rews=t.rews, costs=t.costs) for t in demos]
    with pytest.raises(DemonstrationError, match=r"actions range over .* outside Discrete\(3\)"):
        cls("MlpPolicy", make_env(), bad)
    with pytest.raises(TypeError, match="`demonstrations` must be"):
        cls("MlpPolicy", make_env(), 42)


def test_no_demonstrations_cannot_learn():
    model = BC2L("MlpPolicy", make_env(), n_steps=32, batch_size=32)
    with pytest.raises(ValueError, match="no demonstrations"):
        model.learn(32)
    model.set_demonstrations(corridor_demonstrations())
    model.learn(32)


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="learns its cost"):
        make_model(BC2L, cost_fn=lambda obs, acts: np.zeros(len(obs)))
    with pytest.raises(ValueError, match="not both"):
        make_model(BC2L, constraint_net=FeasibilityNet(2, 3, discrete_actions=True))
    with pytest.raises(TypeError, match="subclass of ICRLTrainer"):
        make_model(BC2L, trainer_class=object)
    # VICRL needs a Beta net: the trainer says so when the model is made
    net = FeasibilityNet(2, 3, discrete_actions=True, hidden_sizes=[8])
    with pytest.raises(TypeError, match="VICRLTrainer trains a BetaFeasibilityNet"):
        VICRL("MlpPolicy", make_env(), corridor_demonstrations(), constraint_net=net, n_steps=32, batch_size=32)


@pytest.mark.parametrize("cls", (MECL, VICRL))
def test_expert_budget_follows_the_experts_learned_cost(cls):
    writer = CapturingWriter()
    model = make_model(cls, n_steps=64, batch_size=64, cost_budget="expert", constraint_net_kwargs={"hidden_sizes": [8]})
    model.set_logger(Logger(folder=None, output_formats=[writer]))
    model.learn(192)
    assert model.icrl_trainer.n_updates == 3
    expected = 1.0 - model.constraint_net.predict_feasibility(model.expert_obs, model.expert_acts, **_mean_mode(model))
    # VICRL's default cost is a Beta sample: its expert mean is within sampling noise of the mean cost
    tolerance = 0.05 if cls is VICRL else 1e-6
    assert model.cost_budget[0] == pytest.approx(expected.mean(), abs=tolerance)
    assert model.lagrange_multiplier.cost_budget[0] == model.cost_budget[0]
    assert writer.values["constraint/cost_budget"][-1] == pytest.approx(model.cost_budget[0])
    # Budgets change with the constraint model: not stuck at their first value
    assert len(set(writer.values["constraint/cost_budget"])) == 3


def _mean_mode(model):
    return {"cost_mode": "mean"} if isinstance(model.constraint_net, BetaFeasibilityNet) else {}


def test_multiplier_falls_when_the_learner_is_below_the_expert_budget():
    model = make_model(MECL, cost_budget="expert", lagrange_kwargs={"init": 1.0, "lr": 0.5, "optimizer": "sgd"})
    model.set_cost_budget(0.6)
    assert model.lagrange_multiplier.update(np.array([0.2]))[0] == pytest.approx(1.0 - 0.5 * 0.4)
    with pytest.raises(ValueError, match="finite budget"):
        model.set_cost_budget([0.1, 0.2])


def test_expert_budget_needs_a_per_step_budget():
    with pytest.raises(ValueError, match="budget_statistic='step'"):
        make_model(MECL, cost_budget="expert", budget_statistic="episode")
    with pytest.raises(ValueError, match="a float or 'expert'"):
        make_model(MECL, cost_budget="experts")
    model = make_model(GACL, trainer_kwargs={"budget_from_expert": True})
    with pytest.raises(ValueError, match="must be a PPOLagrangian"):
        model.learn(32)


def test_env_already_wrapped():
    # A model's own env can be given back to it, or to another model of the same kind
    model = make_model(BC2L)
    other = make_model(MECL, env=model.get_env())
    assert other.recorder is model.recorder and other.constraint_wrapper is model.constraint_wrapper
    other.learn(32)
    model.set_env(model.get_env())
    model.learn(32)
    with pytest.raises(ValueError, match="already contains a LearnedCostVecEnvWrapper; GACL adds its own GACLRewardWrapper"):
        make_model(GACL, env=model.get_env())
    with pytest.raises(ValueError, match="already contains a LearnedCostVecEnvWrapper"):
        make_model(BC2L, env=LearnedCostVecEnvWrapper(make_env(), lambda obs, acts: np.zeros(len(obs))))


def test_custom_constraint_net_must_fit_the_env():
    with pytest.raises(ValueError, match="takes 3 observation and 3 action features"):
        make_model(BC2L, constraint_net=FeasibilityNet(3, 3, discrete_actions=True), constraint_net_kwargs=None)


def test_custom_constraint_net_and_trainer():
    calls = []

    class CountingTrainer(BC2LTrainer):
        def update(self, nominal):
            calls.append(len(nominal))
            return super().update(nominal)

    net = FeasibilityNet(2, 3, discrete_actions=True, hidden_sizes=[4], normalize_input=False)
    model = make_model(BC2L, constraint_net=net, constraint_net_kwargs=None, trainer_class=CountingTrainer)
    assert model.constraint_net is net
    model.learn(64)
    assert calls == [32, 32]  # 4 finished 8-step episodes per 32-step rollout


def test_nominal_memory_adds_earlier_trajectories_to_each_update():
    seen = []

    class RecordingTrainer(BC2LTrainer):
        def update(self, nominal):
            seen.append(nominal)
            return super().update(nominal)

    writer = CapturingWriter()
    model = make_model(BC2L, n_nominal_trajectories=2, trainer_class=RecordingTrainer, trainer_kwargs={"nominal_memory": 3})
    model.set_logger(Logger(folder=None, output_formats=[writer]))
    model.learn(128)  # 4 updates, each with the 2 latest of the rollout's 4 finished episodes
    assert [len(nominal.episode_lengths) for nominal in seen] == [2, 4, 5, 5]
    assert writer.values["constraint/n_remembered_trajectories"] == [0, 2, 3, 3]
    # Remembered pairs are earlier updates' own, appended before the new ones
    earlier = np.concatenate([nominal.obs[-2 * EPISODE :] for nominal in seen[:3]])
    remembered = seen[3].obs[: 3 * EPISODE].reshape(3, EPISODE, -1)
    for trajectory in remembered:
        assert any(np.array_equal(trajectory, earlier[i : i + EPISODE]) for i in range(0, len(earlier), EPISODE))
    assert len(model.icrl_trainer.remembered) == 3


def test_without_nominal_memory_each_update_sees_only_its_own_trajectories():
    model = make_model(BC2L, n_nominal_trajectories=2)
    model.learn(96)
    assert model.icrl_trainer.remembered == []
    with pytest.raises(ValueError, match="`nominal_memory` must be >= 0"):
        make_model(BC2L, trainer_kwargs={"nominal_memory": -1}).learn(32)


def test_recorder_groups_raw_pairs_by_trajectory():
    venv = TrajectoryRecorderVecEnvWrapper(make_env(n_envs=2))
    obs = venv.reset()
    sent = []
    for step in range(EPISODE + 3):
        actions = np.array([step % 3, 2])
        sent.append((obs.copy(), actions))
        obs, _, _, _ = venv.step(actions)
    trajectories = venv.pop_trajectories()
    assert len(trajectories) == 2 and all(len(t) == EPISODE for t in trajectories)
    np.testing.assert_array_equal(trajectories[0].obs, np.stack([o[0] for o, _ in sent[:EPISODE]]))
    np.testing.assert_array_equal(trajectories[1].acts, np.full(EPISODE, 2))
    assert venv.pop_trajectories() == []
    data = NominalData.from_trajectories(trajectories)
    assert len(data) == 2 * EPISODE and data.episode_lengths.tolist() == [EPISODE, EPISODE]
    with pytest.raises(ValueError, match="VecNormalize"):
        TrajectoryRecorderVecEnvWrapper(VecNormalize(make_env()))


def grid_setup(net_class, seed: int = 0):
    th.manual_seed(seed)
    env = gym.make("sb3_icrl/GridWorldWall-v0")
    net = net_class.from_spaces(
        env.observation_space, env.action_space, hidden_sizes=[64], normalize_input=False, use_action=False
    )
    return env, net


def test_tabular_icrl_plans_on_the_learned_cost_and_ignores_absorbing_states():
    env, net = grid_setup(FeasibilityNet)
    result = tabular_icrl(BC2LTrainer, net, env, load_demonstrations("GridWorldWall-v0"), n_iterations=2, constraint_steps=2)
    assert len(result.history) == 2 and result.trainer.n_updates == 2
    assert {"loss", "expert_feasibility", "nominal_feasibility", "planned_cost"} <= set(result.history[0])
    table = cost_table(net, 49, 8)
    assert table.shape == (49, 8) and np.all((table >= 0) & (table <= 1))
    planned = result.planner.cost_table
    goal = env.unwrapped.goal_state
    assert np.all(planned[goal] == 0.0) and np.allclose(np.delete(planned, goal, axis=0), np.delete(table, goal, axis=0))
    with pytest.raises(DemonstrationError, match="do not match"):
        tabular_icrl(BC2LTrainer, net, gym.make("sb3_icrl/GridWorldWall-v0"), corridor_demonstrations())


@pytest.mark.slow
@pytest.mark.parametrize(
    "trainer_class, net_class",
    [(BC2LTrainer, FeasibilityNet), (MECLTrainer, FeasibilityNet), (VICRLTrainer, BetaFeasibilityNet)],
)
def test_grid_world_constraint_recovery(trainer_class, net_class):
    """From the shipped demonstrations, the policy planned on the learned cost reaches the goal and stays safe."""
    th.set_num_threads(1)
    env, net = grid_setup(net_class)
    # Without a constraint the shortest path crosses the wall: the check below can fail
    unconstrained = PILagrangian(gym.make("sb3_icrl/GridWorldWall-v0"), lagrange_init=0.0, lagrange_lr=0.0)
    unconstrained.set_cost_table(np.zeros((49, 8)))
    unconstrained.learn()
    assert evaluate_constraint(unconstrained, gym.make("sb3_icrl/GridWorldWall-v0"), n_eval_episodes=2).violation_rate == 1.0

    result = tabular_icrl(trainer_class, net, env, load_demonstrations("GridWorldWall-v0"), n_iterations=20)
    evaluation = evaluate_constraint(result.planner, gym.make("sb3_icrl/GridWorldWall-v0"), n_eval_episodes=10)
    assert evaluation.violation_rate <= 0.1
    assert np.all(evaluation.episode_rewards > 0)  # every episode reaches the goal


def test_precision_recall_of_a_recovered_map():
    true_unsafe = np.array([[True, True], [False, False]])
    assert precision_recall(np.array([[True, False], [True, True]]), true_unsafe) == (1 / 3, 1 / 2)
    assert precision_recall(np.zeros((2, 2), dtype=bool), true_unsafe) == (0.0, 0.0)


@pytest.mark.parametrize("cls", LAGRANGIAN)
def test_constraint_learning_rate_decays_per_update_and_survives_save_load(cls, tmp_path):
    """The reference's anneal_clr_by_factor: each update uses the previous rate times the decay."""
    writer = CapturingWriter()
    model = make_model(cls, constraint_learning_rate=0.01, trainer_kwargs={"learning_rate_decay": 0.5})
    model.set_logger(Logger(folder=None, output_formats=[writer]))
    model.learn(96)  # three updates, one per 32-step rollout
    np.testing.assert_allclose(writer.values["constraint/learning_rate"], [0.01, 0.005, 0.0025])
    assert model.constraint_optimizer.param_groups[0]["lr"] == pytest.approx(0.00125)
    model.save(tmp_path / "model.zip")
    loaded = cls.load(tmp_path / "model.zip", env=make_env(), demonstrations=corridor_demonstrations())
    writer = CapturingWriter()
    loaded.set_logger(Logger(folder=None, output_formats=[writer]))
    loaded.learn(32, reset_num_timesteps=False)
    np.testing.assert_allclose(writer.values["constraint/learning_rate"], [0.00125])  # goes on where it was


def test_constraint_learning_rate_decay_must_be_a_factor_in_0_1():
    for decay in (0.0, 1.5):
        with pytest.raises(ValueError, match="`learning_rate_decay` must be in"):
            make_model(BC2L, trainer_kwargs={"learning_rate_decay": decay}).learn(32)


@pytest.mark.parametrize("cls", LAGRANGIAN)
def test_match_tolerance_skips_updates_once_the_learner_matches_the_expert(cls, tmp_path, monkeypatch):
    """After the warm-up, an update is skipped when the gap measured before it is below the tolerance."""
    gaps = iter([0.5, 0.01, 0.01, 0.2, 0.04, 0.01])
    monkeypatch.setattr(ICRLTrainer, "feasibility_gap", lambda self, nominal: next(gaps))
    writer = CapturingWriter()
    model = make_model(cls, trainer_kwargs={"match_tolerance": 0.05, "match_warmup_updates": 2})
    model.set_logger(Logger(folder=None, output_formats=[writer]))
    model.learn(32 * 3)
    # The second update is made despite its small gap: the warm-up is not over
    assert writer.values["constraint/skipped"] == [0.0, 0.0, 1.0]
    np.testing.assert_allclose(writer.values["constraint/feasibility_gap"], [0.5, 0.01, 0.01])
    assert model.n_constraint_updates == 2
    frozen = [p.detach().clone() for p in model.constraint_net.parameters()]
    model.learn(32, reset_num_timesteps=False)  # gap 0.2: updated
    assert model.n_constraint_updates == 3
    assert any(not th.equal(a, b) for a, b in zip(frozen, model.constraint_net.parameters(), strict=True))

    model.save(tmp_path / "model.zip")
    loaded = cls.load(tmp_path / "model.zip", env=make_env(), demonstrations=corridor_demonstrations())
    assert loaded.n_constraint_updates == 3
    writer = CapturingWriter()
    loaded.set_logger(Logger(folder=None, output_formats=[writer]))
    frozen = [p.detach().clone() for p in loaded.constraint_net.parameters()]
    lr = loaded.constraint_optimizer.param_groups[0]["lr"]
    loaded.learn(32 * 2, reset_num_timesteps=False)  # gaps 0.04 and 0.01: no second warm-up after loading
    assert writer.values["constraint/skipped"] == [1.0, 1.0]
    assert all(th.equal(a, b) for a, b in zip(frozen, loaded.constraint_net.parameters(), strict=True))
    assert loaded.constraint_optimizer.param_groups[0]["lr"] == lr
    assert loaded.n_constraint_updates == 3


@pytest.mark.parametrize(
    "two_sided, skipped", [(False, [0.0, 0.0, 1.0, 1.0, 1.0, 0.0]), (True, [0.0, 0.0, 0.0, 1.0, 1.0, 0.0])]
)
def test_match_two_sided_updates_a_learner_that_looks_more_feasible_than_the_expert(two_sided, skipped, monkeypatch):
    """One-sided, any gap below the tolerance skips, a negative one too; two-sided, only a gap of small size does."""
    gaps = iter([0.5, 0.3, -0.2, 0.01, -0.01, 0.2])
    monkeypatch.setattr(ICRLTrainer, "feasibility_gap", lambda self, nominal: next(gaps))
    writer = CapturingWriter()
    kwargs = {"match_tolerance": 0.05, "match_two_sided": two_sided, "match_warmup_updates": 2}
    model = make_model(MECL, trainer_kwargs=kwargs)
    model.set_logger(Logger(folder=None, output_formats=[writer]))
    model.learn(32 * 6)
    assert writer.values["constraint/skipped"] == skipped
    assert model.n_constraint_updates == skipped.count(0.0)


def test_feasibility_gap_is_the_expert_mean_less_the_learner_mean():
    model = make_model(MECL)
    model.learn(32)
    trainer = model.icrl_trainer
    # The expert's first pairs with the other actions: not the expert's mean
    nominal = NominalData.from_trajectories([NominalTrajectory(trainer.expert_obs[:5], 2 - trainer.expert_acts[:5])])
    expected = np.mean(1.0 - model.constraint_cost(trainer.expert_obs, trainer.expert_acts)) - np.mean(
        1.0 - model.constraint_cost(nominal.obs, nominal.acts)
    )
    assert trainer.feasibility_gap(nominal) == pytest.approx(expected)
    expert = NominalData.from_trajectories([NominalTrajectory(trainer.expert_obs, trainer.expert_acts)])
    assert trainer.feasibility_gap(expert) == pytest.approx(0.0, abs=1e-6)


def test_match_tolerance_and_warmup_must_be_positive():
    with pytest.raises(ValueError, match="`match_tolerance` must be > 0"):
        make_model(BC2L, trainer_kwargs={"match_tolerance": 0.0}).learn(32)
    with pytest.raises(ValueError, match="`match_warmup_updates` must be >= 1"):
        make_model(BC2L, trainer_kwargs={"match_warmup_updates": 0}).learn(32)
    with pytest.raises(ValueError, match="needs a `match_tolerance`"):
        make_model(BC2L, trainer_kwargs={"match_two_sided": True}).learn(32)
    with pytest.raises(TypeError, match="`match_two_sided` must be True or False, got 'false'"):
        make_model(BC2L, trainer_kwargs={"match_tolerance": 0.05, "match_two_sided": "false"}).learn(32)


def test_a_loaded_model_samples_its_constraint_minibatches_from_its_seed(tmp_path):
    """The update count carries over a load, but a new trainer still seeds its minibatch sampling from the model."""
    model = make_model(MECL, constraint_batch_size=4)
    model.learn(64)
    model.save(tmp_path / "model.zip")
    rngs = []
    for _ in range(2):
        loaded = MECL.load(tmp_path / "model.zip", env=make_env(), demonstrations=corridor_demonstrations())
        loaded.learn(32, reset_num_timesteps=False)
        assert loaded.icrl_trainer.n_updates == model.n_constraint_updates + 1
        rngs.append(loaded.icrl_trainer._rng.integers(1 << 30, size=4))
    np.testing.assert_array_equal(rngs[0], rngs[1])


def test_gacl_settings_set_the_wrapper_also_a_reused_one_and_survive_save_load(tmp_path):
    model = GACL("MlpPolicy", make_env(), corridor_demonstrations(), n_steps=16, batch_size=16, gamma=0.95)
    assert model.termination_reward == "zero" and model.constraint_wrapper.termination_gamma is None
    repeat = GACL(
        "MlpPolicy",
        make_env(),
        corridor_demonstrations(),
        n_steps=16,
        batch_size=16,
        gamma=0.95,
        termination_reward="repeat",
        log_d_eps=1e-3,
    )
    assert repeat.constraint_wrapper.termination_gamma == 0.95 and repeat.constraint_wrapper.eps == 1e-3
    repeat.save(tmp_path / "gacl.zip")
    loaded = GACL.load(tmp_path / "gacl.zip", env=make_env(), demonstrations=corridor_demonstrations())
    assert loaded.termination_reward == "repeat" and loaded.constraint_wrapper.termination_gamma == 0.95
    assert loaded.constraint_wrapper.eps == loaded.log_d_eps == 1e-3
    with pytest.raises(ValueError, match=r"`log_d_eps` must be in \(0, 1\), got 0.0"):
        GACL.load(tmp_path / "gacl.zip", env=make_env(), demonstrations=corridor_demonstrations(), log_d_eps=0.0)
    with pytest.raises(ValueError, match=r"`eps` must be in \(0, 1\)"):
        loaded.constraint_wrapper.eps = 1.5
    model.set_env(repeat.env)  # an env wrapped by another GACL model: reused, with this model's settings
    assert model.constraint_wrapper is repeat.constraint_wrapper and model.constraint_wrapper.termination_gamma is None
    assert model.constraint_wrapper.eps == model.log_d_eps == 1e-5
    with pytest.raises(ValueError, match=r"`log_d_eps` must be in \(0, 1\), got 0"):
        GACL("MlpPolicy", make_env(), corridor_demonstrations(), log_d_eps=0.0)
    with pytest.raises(ValueError, match="`termination_reward` must be one of 'zero', 'repeat'"):
        GACL("MlpPolicy", make_env(), corridor_demonstrations(), termination_reward="budget")
