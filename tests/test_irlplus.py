"""IRL-Plus and the off-policy ICRL machinery: its loss, SAC-Lagrangian, what the learner sees, resets, saving."""

import itertools

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3 import SAC
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_icrl import IRLPlus, IRLPlusPPO, SACLagrangian
from sb3_icrl.common.costs import CostError
from sb3_icrl.constraints import CostNet, FeasibilityNet, LearnedCostVecEnvWrapper, irl_plus_loss
from sb3_icrl.data import Demonstrations, Trajectory
from sb3_icrl.icrl import TrajectoryRecorderVecEnvWrapper
from sb3_icrl.icrl.trainer import Minibatch
from sb3_icrl.irlplus import IRLPlusTrainer
from sb3_icrl.sac_lagrangian import CostReplayBuffer

EPISODE = 8
TRUE_COST = 1000.0  # far from any learned cost: a leak cannot go unnoticed


class Line(gym.Env):
    """A point on a line, moved by a Box action; reward for going right; info["cost"] is always TRUE_COST."""

    def __init__(self):
        self.observation_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.x, self.t = 0.0, 0

    def _obs(self) -> np.ndarray:
        return np.array([self.x, self.t / EPISODE], dtype=np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x, self.t = 0.0, 0
        return self._obs(), {}

    def step(self, action):
        self.x = float(np.clip(self.x + 0.25 * float(np.asarray(action).reshape(-1)[0]), -1.0, 1.0))
        self.t += 1
        return self._obs(), self.x, False, self.t >= EPISODE, {"cost": TRUE_COST}


def line_demonstrations(n_trajectories: int = 2) -> Demonstrations:
    """An expert that goes right to x = 0.5 and stays."""
    trajectories = []
    for _ in range(n_trajectories):
        env = Line()
        obs, _ = env.reset()
        observations, actions, rewards = [obs], [], []
        for _ in range(EPISODE):
            action = np.array([1.0 if env.x < 0.5 else 0.0], dtype=np.float32)
            obs, reward, _, _, _ = env.step(action)
            observations.append(obs)
            actions.append(action)
            rewards.append(reward)
        trajectories.append(
            Trajectory(np.array(observations), np.array(actions), None, False, np.array(rewards), np.zeros(EPISODE))
        )
    return Demonstrations(trajectories, {})


def make_env() -> DummyVecEnv:
    return DummyVecEnv([lambda: Monitor(Line())])


def make_irlplus(**kwargs) -> IRLPlus:
    kwargs = {
        "learning_starts": 16,
        "batch_size": 16,
        "buffer_size": 500,
        "update_every": 16,
        "seed": 0,
        "policy_kwargs": {"net_arch": [8]},
        "constraint_net_kwargs": {"hidden_sizes": [8]},
        **kwargs,
    }
    return IRLPlus("MlpPolicy", make_env(), line_demonstrations(), **kwargs)


# ---------------------------------------------------------------------------------------------------- the loss


def test_irl_plus_loss_matches_a_hand_computed_value() -> None:
    loss = irl_plus_loss(th.tensor([0.5, 1.0]), th.tensor([2.0, 0.0, 1.0]), l2_coef=0.1)
    # mean_E c = 0.75, mean_N c = 1, 0.1 * mean_E c^2 = 0.1 * (0.25 + 1) / 2 = 0.0625
    assert loss.total.item() == pytest.approx(0.75 - 1.0 + 0.0625)
    assert (loss.expert.item(), loss.nominal.item(), loss.regularizer.item()) == pytest.approx((0.75, -1.0, 0.0625))
    assert irl_plus_loss(th.tensor([0.5, 1.0]), th.tensor([2.0]), l2_coef=0.0).total.item() == pytest.approx(-1.25)
    with pytest.raises(ValueError, match="l2_coef"):
        irl_plus_loss(th.tensor([0.5]), th.tensor([1.0]), l2_coef=-1.0)


def test_trainer_loss_on_a_tiny_fixed_batch() -> None:
    """The trainer's loss through a CostNet set by hand: c = LeakyReLU(x), on raw inputs."""
    net = CostNet(1, 1, hidden_sizes=[], use_action=False, normalize_input=False)
    assert np.all(net.cost(np.array([[3.0], [-2.0]]), None) == 0.0)  # the output layer starts at 0
    with th.no_grad():
        net.network[0].weight.fill_(1.0)
    expert_obs, nominal_obs = np.array([[0.5], [1.0]]), np.array([[2.0], [-1.0]])
    trainer = IRLPlusTrainer(net, th.optim.SGD(net.parameters(), lr=0.1), expert_obs, np.zeros((2, 1)), None, None, 1)
    batch = Minibatch(expert_obs, np.zeros((2, 1)), nominal_obs, np.zeros((2, 1)), np.arange(2))
    loss, parts = trainer.loss(batch)
    # expert costs 0.5 and 1 (mean 0.75, squares 0.625); nominal 2 and -0.01 (LeakyReLU), mean 0.995
    assert loss.item() == pytest.approx(0.75 - 0.995 + 0.1 * 0.625, abs=1e-6)
    assert parts == pytest.approx({"expert_cost": 0.75, "nominal_cost": 0.995, "l2_penalty": 0.0625})
    np.testing.assert_allclose(net.cost(nominal_obs, None), [2.0, -0.01], rtol=1e-6)
    np.testing.assert_allclose(net.predict_feasibility(expert_obs, None), np.exp([-0.5, -1.0]), rtol=1e-6)


def test_an_update_lowers_the_expert_cost_relative_to_the_learner() -> None:
    net = CostNet(1, 1, hidden_sizes=[4], use_action=False, normalize_input=False)
    expert_obs, nominal_obs = np.full((8, 1), -1.0), np.full((8, 1), 1.0)
    trainer = IRLPlusTrainer(net, th.optim.Adam(net.parameters(), lr=0.05), expert_obs, np.zeros((8, 1)), None, None, 1)
    trainer.constraint_steps = 20
    from sb3_icrl.icrl import NominalData, NominalTrajectory

    trainer.update(NominalData.from_trajectories([NominalTrajectory(nominal_obs, np.zeros((8, 1)))]))
    assert net.cost(nominal_obs, None).mean() > net.cost(expert_obs, None).mean() + 0.1


# ---------------------------------------------------------------------------------------------------- SAC-Lagrangian


class CostInfoPendulum(gym.Wrapper):
    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        info["cost"] = float(abs(obs[0]))
        return obs, reward, terminated, truncated, info


def test_sac_lagrangian_with_a_zero_multiplier_is_sac() -> None:
    kwargs = dict(learning_starts=20, batch_size=16, buffer_size=200, policy_kwargs=dict(net_arch=[8]), seed=0)
    sac = SAC("MlpPolicy", "Pendulum-v1", **kwargs).learn(60)
    lagrangian = SACLagrangian(
        "MlpPolicy", CostInfoPendulum(gym.make("Pendulum-v1")), lagrange_kwargs={"init": 0.0, "lr": 0.0}, **kwargs
    ).learn(60)
    extended = lagrangian.policy.state_dict()
    for name, value in sac.policy.state_dict().items():  # the actor, the reward critics and their targets
        assert th.equal(value, extended[name]), name
    # ...while the cost critic learned the costs
    assert lagrangian.logger.name_to_value["train/cost_critic_loss"] > 0


def test_sac_lagrangian_multiplier_rises_over_budget_and_costs_are_stored() -> None:
    env = DummyVecEnv([lambda: CostInfoPendulum(gym.make("Pendulum-v1", max_episode_steps=20))])
    model = SACLagrangian(
        "MlpPolicy", env, budget_statistic="episode", learning_starts=10, batch_size=8, buffer_size=100, seed=0
    )
    model.learn(60)
    assert isinstance(model.replay_buffer, CostReplayBuffer)
    assert np.all(model.replay_buffer.costs[:60] > 0)  # |cos| is never 0 here
    assert model.lagrange_multiplier.value[0] > 1.0  # default init 1, each 20-step episode costs far more than 0
    assert len(model.ep_cost_buffer) == 3
    assert len(model._episode_costs_since_update) <= 1  # the multiplier empties it at each update


def test_sac_lagrangian_on_its_critic_keeps_no_episode_costs() -> None:
    # The multiplier reads the cost critic: a list of the episodes' costs would only grow (into every checkpoint)
    env = DummyVecEnv([lambda: CostInfoPendulum(gym.make("Pendulum-v1", max_episode_steps=20))])
    model = SACLagrangian(
        "MlpPolicy", env, budget_statistic="critic", learning_starts=10, batch_size=8, buffer_size=100, seed=0
    ).learn(60)
    assert len(model.ep_cost_buffer) == 3
    assert model._episode_costs_since_update == []


def test_sac_lagrangian_clear_errors() -> None:
    env = CostInfoPendulum(gym.make("Pendulum-v1"))
    with pytest.raises(ValueError, match="cost_budget"):
        SACLagrangian("MlpPolicy", env, cost_budget=-1.0)
    with pytest.raises(ValueError, match="budget_statistic"):
        SACLagrangian("MlpPolicy", env, budget_statistic="step")
    with pytest.raises(ValueError, match="critic"):
        SACLagrangian("MlpPolicy", env, cost_fn=lambda obs, acts: np.zeros(len(obs)))
    with pytest.raises(ValueError, match="n_steps"):
        SACLagrangian("MlpPolicy", env, n_steps=3)
    with pytest.raises(TypeError, match="CostSACPolicy"):
        SACLagrangian(SAC.policy_aliases["MlpPolicy"], env)
    model = SACLagrangian("MlpPolicy", gym.make("Pendulum-v1"), learning_starts=5, batch_size=4, buffer_size=50)
    with pytest.raises(CostError, match="cost"):
        model.learn(10)


def test_sac_lagrangian_cost_fn_is_computed_on_sampled_batches() -> None:
    calls = []

    def cost_fn(observations, actions):
        calls.append((observations.shape, actions.shape))
        return np.ones(len(observations))

    model = SACLagrangian(
        "MlpPolicy", gym.make("Pendulum-v1"), cost_fn=cost_fn, budget_statistic="critic", learning_starts=10, batch_size=8
    )
    model.learn(20)
    assert calls and set(calls) == {((8, 3), (8, 1))}  # once per gradient step, on the batch, never per env step
    assert model.logger.name_to_value["train/batch_cost"] == 1.0


# ---------------------------------------------------------------------------------------------------- IRL-Plus


def test_the_learner_never_sees_the_true_cost() -> None:
    model = make_irlplus()
    wrapper = model.env
    assert isinstance(wrapper, LearnedCostVecEnvWrapper) and isinstance(wrapper.venv, TrajectoryRecorderVecEnvWrapper)
    seen = []
    model.set_cost_fn(lambda obs, acts: (seen.append(model.constraint_cost(obs, acts)), seen[-1])[1])
    model.learn(48)
    assert model.replay_buffer.cost_info_key is None and np.all(model.replay_buffer.costs == 0)
    assert seen and max(float(np.max(np.abs(costs))) for costs in seen) < TRUE_COST / 10
    assert model.n_constraint_updates >= 2
    assert isinstance(model.constraint_net, CostNet)


def test_resets_draw_new_output_layers_and_keep_the_reward_critic() -> None:
    model = make_irlplus()
    reward_critic = {k: v.clone() for k, v in model.critic.state_dict().items()}
    mu, cost_last = model.actor.mu.weight.clone(), model.cost_critic.q_networks[0][-1].weight.clone()
    model.reset_policy_layers()
    assert not th.equal(mu, model.actor.mu.weight) and not th.equal(cost_last, model.cost_critic.q_networks[0][-1].weight)
    assert all(th.equal(value, model.critic.state_dict()[key]) for key, value in reward_critic.items())

    counts = []
    model.reset_policy_layers = lambda: counts.append(model.num_timesteps)  # type: ignore[method-assign]
    model.learn(64)
    assert counts and all(b - a >= 16 for a, b in itertools.pairwise(counts))
    model = make_irlplus(policy_resets=False)
    model.reset_policy_layers = lambda: counts.append(-1)  # type: ignore[method-assign]
    model.learn(64)
    assert -1 not in counts


def test_without_separate_critics_the_cost_joins_the_reward_critic() -> None:
    model = make_irlplus(separate_critics=False)
    cost_critic = {k: v.clone() for k, v in model.cost_critic.state_dict().items()}
    model.learn(48)
    assert all(th.equal(value, model.cost_critic.state_dict()[key]) for key, value in cost_critic.items())
    assert "train/cost_critic_loss" not in model.logger.name_to_value
    assert not model.separate_critics


def test_warmup_postpones_the_cost_updates() -> None:
    model = make_irlplus(warmup_timesteps=40)
    model.learn(32)
    assert model.n_constraint_updates == 0 and np.all(model.constraint_cost(np.zeros((3, 2)), np.zeros((3, 1))) == 0)
    model.learn(32, reset_num_timesteps=False)
    assert model.n_constraint_updates >= 1


def test_irlplus_save_load_round_trip(tmp_path) -> None:
    model = make_irlplus()
    model.learn(48)
    model.save(tmp_path / "irlplus.zip")
    loaded = IRLPlus.load(tmp_path / "irlplus.zip", env=make_env(), demonstrations=line_demonstrations())
    for name in ("policy", "constraint_net"):
        saved, restored = getattr(model, name).state_dict(), getattr(loaded, name).state_dict()
        assert saved.keys() == restored.keys()
        assert all(th.equal(value, restored[key]) for key, value in saved.items()), name
    for name in ("constraint_optimizer", "cost_critic"):
        assert str(getattr(model, name).state_dict()) == str(getattr(loaded, name).state_dict())
    assert loaded.n_constraint_updates == model.n_constraint_updates and loaded.l2_coef == 0.1
    np.testing.assert_array_equal(loaded.lagrange_multiplier.value, [1.0])
    obs = np.array([[0.3, 0.5], [-0.2, 0.1]], dtype=np.float32)
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    assert loaded.cost_fn == loaded.constraint_cost  # the learner computes the loaded model's cost
    loaded.learn(32)
    with pytest.raises(ValueError, match="IRLPlus"):
        SACLagrangian.load(tmp_path / "irlplus.zip")


def test_irlplus_clear_errors() -> None:
    with pytest.raises(ValueError, match="cost_fn"):
        make_irlplus(cost_fn=lambda obs, acts: np.zeros(len(obs)))
    with pytest.raises(ValueError, match="reset_every"):
        make_irlplus(reset_every=0)
    with pytest.raises(TypeError, match="CostNet"):
        make_irlplus(constraint_net=FeasibilityNet(2, 1), constraint_net_kwargs=None)
    with pytest.raises(ValueError, match="budget_statistic"):
        make_irlplus(budget_statistic="episode")


def test_only_irlplusppo_is_charged_negative_costs() -> None:
    """Plain PPOLagrangian still refuses a cost_fn below 0; IRLPlusPPO refuses a budget read from its signed cost."""
    from sb3_icrl import PPOLagrangian

    model = PPOLagrangian("MlpPolicy", make_env(), cost_fn=lambda obs, acts: -np.ones(len(obs)), n_steps=16, batch_size=16)
    with pytest.raises(CostError, match="negative costs"):
        model.learn(16)
    with pytest.raises(ValueError, match="cost_budget='expert'"):
        IRLPlusPPO("MlpPolicy", make_env(), line_demonstrations(), cost_budget="expert")


def test_irlplus_on_ppo_learns_and_round_trips(tmp_path) -> None:
    kwargs = dict(n_steps=16, batch_size=16, n_epochs=1, seed=0, policy_kwargs={"net_arch": [8]}, reset_every=16)
    model = IRLPlusPPO("MlpPolicy", make_env(), line_demonstrations(), constraint_net_kwargs={"hidden_sizes": [8]}, **kwargs)
    action_net = model.policy.action_net.weight.clone()
    model.learn(48)
    assert model.n_constraint_updates >= 2 and isinstance(model.constraint_net, CostNet)
    assert not th.equal(action_net, model.policy.action_net.weight)
    np.testing.assert_array_equal(model.lagrange_multiplier.value, [1.0])
    model.save(tmp_path / "ppo.zip")
    loaded = IRLPlusPPO.load(tmp_path / "ppo.zip", env=make_env(), demonstrations=line_demonstrations())
    assert all(th.equal(v, loaded.constraint_net.state_dict()[k]) for k, v in model.constraint_net.state_dict().items())


# ---------------------------------------------------------------------------------------------------- recovery (slow)


class WallWorld(gym.Env):
    """
    The wall grid world (``GridWorldWall-v0``'s unsafe row 3, columns 0-4, on a 7x7 grid) with continuous moves, as SAC
    needs Box actions: the position ``(row, column)`` moves by the action (at most one cell per axis and step). Reward:
    the rows gained, -0.1 per step, 1 on reaching the bottom row (which ends the episode); 20 steps at most. Straight
    down through the wall is the shortest way, a detour right of column 5 the safe one.
    """

    def __init__(self):
        self.observation_space = spaces.Box(0.0, 1.0, (2,), np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.position, self.t = np.array([0.5, 0.5]), 0

    def _obs(self) -> np.ndarray:
        return (self.position / 7.0).astype(np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.position, self.t = np.array([0.5, 0.5]), 0
        return self._obs(), {}

    def step(self, action):
        row_before = self.position[0]
        self.position = np.clip(self.position + np.clip(action, -1.0, 1.0), 0.0, 6.999)
        self.t += 1
        at_goal = bool(self.position[0] >= 6.0)
        unsafe = bool(3.0 <= self.position[0] < 4.0 and self.position[1] < 5.0)
        reward = self.position[0] - row_before - 0.1 + float(at_goal)
        return self._obs(), float(reward), at_goal, self.t >= 20, {"cost": float(unsafe)}


def wall_world_expert() -> Trajectory:
    """The safe detour: diagonally to (2.5, 2.5), right to column 5.5, down to the bottom row (9 steps)."""
    env = WallWorld()
    obs, _ = env.reset()
    observations, actions, rewards = [obs], [], []
    for waypoint in ([2.5, 2.5], [2.5, 5.5], [6.5, 5.5]):
        while np.linalg.norm(env.position - waypoint) > 1e-6:
            action = np.clip(np.array(waypoint) - env.position, -1.0, 1.0).astype(np.float32)
            obs, reward, _, _, info = env.step(action)
            assert info["cost"] == 0.0
            observations.append(obs)
            actions.append(action)
            rewards.append(reward)
    return Trajectory(np.array(observations), np.array(actions), None, True, np.array(rewards), np.zeros(len(actions)))


@pytest.mark.slow
def test_irlplus_recovers_the_wall_and_detours() -> None:
    """IRL-Plus on SAC learns the wall from the expert's detour: the final policy reaches the goal and never crosses it."""
    from sb3_icrl.common.evaluation import evaluate_constraint

    model = IRLPlus(
        "MlpPolicy",
        WallWorld(),
        Demonstrations([wall_world_expert() for _ in range(5)], {}),
        update_every=500,
        warmup_timesteps=2000,
        constraint_steps=10,
        constraint_learning_rate=3e-3,
        constraint_net_kwargs={"hidden_sizes": [32], "use_action": False},
        learning_starts=500,
        batch_size=128,
        learning_rate=1e-3,
        train_freq=2,
        policy_kwargs={"net_arch": [64, 64]},
        seed=0,
    )
    model.learn(10_000)
    evaluation = evaluate_constraint(model, WallWorld(), n_eval_episodes=10, seed=0)
    assert evaluation.violation_rate <= 0.1
    assert np.all(evaluation.episode_rewards > 5.0)  # every episode reaches the bottom row (6 rows + 1, less the steps)
    cells = np.array([[row + 0.5, col + 0.5] for row in range(7) for col in range(7)]) / 7.0
    costs = model.constraint_cost(cells, np.zeros((49, 2))).reshape(7, 7)
    assert costs[3, :3].mean() > 0.5 > costs[:3, 5:].max()  # the wall costs, the expert's way does not


def test_train_cli_runs_irlplus_on_blocked_half_cheetah(tmp_path) -> None:
    """``train.py --algo irlplus --env BlockedHalfCheetah-v0`` trains on the shipped recipe and demonstrations."""
    from sb3_icrl.zoo import main

    params = ["warmup_timesteps:0", "update_every:500", "learning_starts:100", "batch_size:32", "buffer_size:2000"]
    params += ["policy_kwargs:dict(net_arch=[16])", "constraint_net_kwargs:dict(hidden_sizes=[8], normalize_input=False)"]
    args = ["--algo", "irlplus", "--env", "BlockedHalfCheetah-v0", "-n", "1200", "-params", *params]
    assert main([*args, "--eval-freq", "1200", "--eval-episodes", "1", "-f", str(tmp_path), "--verbose", "0"]) == 0
    run = tmp_path / "irlplus" / "BlockedHalfCheetah-v0_1"
    model = IRLPlus.load(run / "BlockedHalfCheetah-v0.zip", device="cpu")
    assert model.num_timesteps == 1200 and model.n_constraint_updates >= 1
    assert isinstance(model.constraint_net, CostNet) and model.warmup_timesteps == 0


def test_irlplus_on_ppo_learns_with_costs_charged_as_learned() -> None:
    """IRLPlusPPO on BlockedHalfCheetah: the cost net's LeakyReLU dips below 0, and PPOLagrangian is charged the dip."""
    model = IRLPlusPPO(
        "MlpPolicy",
        "sb3_icrl/BlockedHalfCheetah-v0",
        demonstrations="BlockedHalfCheetah-v0",
        n_steps=256,
        batch_size=64,
        reset_every=512,
        policy_kwargs=dict(net_arch=[16]),
        constraint_net_kwargs=dict(hidden_sizes=[8], normalize_input=False),
        seed=0,
    )
    model.learn(2048)  # HalfCheetah's episodes end at 1000 steps: the cost updates start once one has
    assert model.n_constraint_updates >= 1 and model.l2_coef == 0.1
    pairs = np.random.default_rng(0).normal(size=(64, model.observation_space.shape[0])), np.zeros((64, 6))
    with th.no_grad():
        model.constraint_net.network[-1].bias.fill_(-1.0)  # a net whose output sits below 0 ...
    learned = model.constraint_net.cost(*pairs)
    assert (learned < 0).all()
    np.testing.assert_array_equal(model.constraint_cost(*pairs), learned)  # ... charged as it is, ranking and all
    model.learn(256, reset_num_timesteps=False)  # PPOLagrangian takes such a cost (it refuses negative env costs)
    assert model.rollout_buffer.costs.min() < 0


def test_irlplus_on_sac_charges_the_cost_as_learned() -> None:
    """IRLPlus (SAC) charges the net's cost as the reference does, its dip below 0 included (so does IRLPlusPPO)."""
    model = make_irlplus()
    with th.no_grad():
        model.constraint_net.network[-1].bias.fill_(-1.0)  # the output layer alone decides: a cost of -0.01 or so
        model.constraint_net.network[-1].weight.zero_()
    pairs = np.zeros((4, 2), dtype=np.float32), np.zeros((4, 1), dtype=np.float32)
    learned = model.constraint_net.cost(*pairs)
    assert (learned < 0).all()
    np.testing.assert_array_equal(model.constraint_cost(*pairs), learned)
    np.testing.assert_array_equal(model.cost_fn(*pairs), learned)


def test_irlplusppo_recipes_learn_on_mecl_s_forward_learner() -> None:
    """Each irlplusppo.yml entry has MECL's PPO settings for its env (equal footing) and the reference's cost side."""
    import yaml

    from sb3_icrl.registry import hyperparams_file

    irlplusppo = yaml.safe_load(hyperparams_file("irlplusppo").read_text())
    mecl = yaml.safe_load(hyperparams_file("mecl").read_text())
    forward_keys = ("n_timesteps", "n_envs", "policy", "normalize", "n_steps", "batch_size", "n_epochs", "gamma")
    forward_keys += ("gae_lambda", "learning_rate", "ent_coef", "clip_range", "max_grad_norm", "vf_coef", "policy_kwargs")
    forward_keys += ("forward_solver", "planner_kwargs")
    assert "BlockedHalfCheetah-v0" in irlplusppo and "GridWorldWall-v0" in irlplusppo
    for env, entry in irlplusppo.items():
        assert {key: entry.get(key) for key in forward_keys} == {key: mecl[env].get(key) for key in forward_keys}, env
        # The grid worlds update on the sizes of the loop the other methods share there (decided on tuning seeds)
        grid = entry.get("forward_solver") == "pi_lagrangian"
        assert (entry["constraint_steps"], entry["n_nominal_trajectories"]) == ((10, 50) if grid else (1, 5)), env
        assert entry["l2_coef"] == 0.1, env
        assert entry["warmup_timesteps"] == int(float(entry["n_timesteps"])) // 20, env
    assert irlplusppo["BlockedHalfCheetah-v0"]["constraint_learning_rate"] == 1e-4
    assert irlplusppo["BlockedSwimmer-v0"]["constraint_learning_rate"] == 1e-3
    # The grid worlds: the other methods' cell-only cost net and learning rate, nothing to reset under a planner
    for env in ("GridWorld-v0", "GridWorldWall-v0", "GridWorldSquare-v0", "GridWorldBigSquare-v0", "GridWorldZigzag-v0"):
        grid = irlplusppo[env]
        assert grid["forward_solver"] == "pi_lagrangian" and grid["policy_resets"] is False, env
        assert (grid["constraint_net_kwargs"], grid["constraint_learning_rate"]) == (
            mecl[env]["constraint_net_kwargs"],
            mecl[env]["constraint_learning_rate"],
        ), env


def test_held_multiplier_of_the_planner() -> None:
    """GACL and a model that holds its multiplier (IRL-Plus) plan with it held; a learning multiplier is the planner's."""
    from types import SimpleNamespace

    from sb3_icrl.icrl.tabular import held_multiplier, held_planner_kwargs
    from sb3_icrl.pi_lagrangian import PILagrangian

    assert held_multiplier(SimpleNamespace(log_d_eps=1e-5)) == 1.0
    assert held_multiplier(SimpleNamespace(lagrange_kwargs={"init": 2.0, "lr": 0.0})) == 2.0
    assert held_multiplier(SimpleNamespace(lagrange_kwargs={"init": 0.1, "lr": 0.05})) is None
    assert held_multiplier(SimpleNamespace(lagrange_kwargs={})) is None
    # Held at 0, the planner walks through the wall and keeps the multiplier there all the same (a learning one rises)
    planner = PILagrangian(gym.make("sb3_icrl/GridWorldWall-v0"), **held_planner_kwargs(0.0)).learn(total_iterations=5)
    assert planner.lagrange_multiplier == 0.0 and planner.history[-1]["episode_cost"] > 0


def test_a_planner_is_never_paid_by_an_irlplus_cost() -> None:
    """The cost net's LeakyReLU dips below 0; the planning table floors it at 0, as PPO-Lagrangian gets it."""
    from sb3_icrl.icrl.tabular import cost_table

    env = gym.make("sb3_icrl/GridWorldWall-v0")
    net = CostNet.from_spaces(env.observation_space, env.action_space, hidden_sizes=[8], normalize_input=False)
    output = [module for module in net.modules() if isinstance(module, th.nn.Linear)][-1]
    with th.no_grad():
        output.weight.zero_()
        output.bias.fill_(-3.0)  # a cost of -0.03 everywhere before the floor
    assert np.all(net.cost(np.arange(3), np.zeros(3, dtype=int)) < 0)
    np.testing.assert_array_equal(cost_table(net, 49, 8), np.zeros((49, 8)))
    np.testing.assert_array_equal(net.paid_cost(np.arange(3), np.zeros(3, dtype=int)), np.zeros(3))
    with th.no_grad():
        output.bias.fill_(0.5)  # above 0 the charged cost is the cost itself
    np.testing.assert_allclose(net.paid_cost(np.arange(3), np.zeros(3, dtype=int)), np.full(3, 0.5))


def grid_irlplus(**kwargs) -> IRLPlusPPO:
    """IRL-Plus on PPO on GridWorldWall, small, for the planner (``learn_with_planner``)."""
    return IRLPlusPPO(
        "MlpPolicy",
        "sb3_icrl/GridWorldWall-v0",
        demonstrations="GridWorldWall-v0",
        n_steps=64,
        batch_size=32,
        policy_resets=False,
        constraint_net_kwargs=dict(hidden_sizes=[8], normalize_input=False, use_action=False),
        seed=0,
        device="cpu",
        **kwargs,
    )


@pytest.mark.parametrize("warmup, updated", [(10**6, False), (0, True)])
def test_irlplus_on_the_grid_plans_with_the_multiplier_at_1_after_its_warmup(warmup: int, updated: bool) -> None:
    """On a grid world the planner holds IRL-Plus's multiplier at 1 and makes no cost update before the warm-up ends."""
    from sb3_icrl.icrl.tabular import learn_with_planner

    model = grid_irlplus(n_nominal_trajectories=5, warmup_timesteps=warmup)
    planner = learn_with_planner(model, 400, planner_kwargs=dict(planner_iterations=20))
    assert (model.n_constraint_updates > 0) == updated
    assert planner.lagrange_multiplier == 1.0 and model.lagrange_multiplier.value == 1.0


def test_train_cli_runs_irlplusppo_on_blocked_half_cheetah(tmp_path) -> None:
    """``train.py --algo irlplusppo`` trains IRL-Plus on PPO-Lagrangian from its shipped recipe and demonstrations."""
    from sb3_icrl.zoo import main

    params = ["warmup_timesteps:0", "update_every:512", "n_steps:256", "n_envs:2", "policy_kwargs:dict(net_arch=[16])"]
    args = ["--algo", "irlplusppo", "--env", "BlockedHalfCheetah-v0", "-n", "2048", "-params", *params]
    assert main([*args, "--eval-freq", "2048", "--eval-episodes", "1", "-f", str(tmp_path), "--verbose", "0"]) == 0
    model = IRLPlusPPO.load(tmp_path / "irlplusppo" / "BlockedHalfCheetah-v0_1" / "BlockedHalfCheetah-v0.zip", device="cpu")
    assert model.num_timesteps == 2048 and model.n_constraint_updates >= 1 and model.l2_coef == 0.1
    assert model.lagrange_multiplier.value == 1.0  # held at 1, as the reference


def test_the_planner_holds_the_multiplier_even_with_no_step_to_run() -> None:
    """A run resumed at its last step plans once on the final cost: with the multiplier held, not learned from it."""
    from sb3_icrl.icrl.tabular import learn_with_planner

    model = grid_irlplus()
    output = [module for module in model.constraint_net.modules() if isinstance(module, th.nn.Linear)][-1]
    with th.no_grad():
        output.weight.zero_()
        output.bias.fill_(0.5)  # a cost of 0.5 everywhere: a learned multiplier would rise above 1
    planner = learn_with_planner(model, 0, planner_kwargs=dict(planner_iterations=50))
    assert planner.lagrange_multiplier == 1.0 and model.lagrange_multiplier.value == 1.0
