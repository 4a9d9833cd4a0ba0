import copy
import csv
import os

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import configure
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.save_util import load_from_zip_file
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_icrl import PPOLagrangian
from sb3_icrl.common.callbacks import EpisodeCostRecorder
from sb3_icrl.common.envs import ConstrainedCorridorEnv
from sb3_icrl.common.policies import CostActorCriticPolicy, clip_grad_norms_
from sb3_icrl.data.registry import EXPERTS_DIR
from sb3_icrl.ppo_lagrangian.ppo_lagrangian import merge_cost_optimizer

TINY = dict(n_steps=32, batch_size=16, n_epochs=2, policy_kwargs=dict(net_arch=[16]))


class PendulumWithCost(gym.Wrapper):
    """Continuous actions and time-limit truncations (200 steps); cost 1 when the pendulum is left of vertical."""

    def __init__(self) -> None:
        super().__init__(gym.make("Pendulum-v1"))

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        info["cost"] = float(obs[1] < 0.0)
        return obs, reward, terminated, truncated, info


def zero_multiplier_model(env_fn, **kwargs) -> PPOLagrangian:
    return PPOLagrangian("MlpPolicy", env_fn(), lagrange_kwargs=dict(init=0.0, lr=0.0), **kwargs)


@pytest.mark.parametrize("env_fn", [PendulumWithCost, ConstrainedCorridorEnv])
def test_zero_multiplier_update_equals_ppo_update(env_fn):
    """
    Same seed, same rollout buffer content: one PPOLagrangian update with lambda = 0 is PPO's update, bit for bit, when
    PPO uses the fused Adam that PPOLagrangian's policy picks by default.
    """
    kwargs = dict(n_steps=64, batch_size=16, n_epochs=3, seed=7)
    ppo = PPO("MlpPolicy", env_fn(), policy_kwargs=dict(optimizer_kwargs=dict(eps=1e-5, fused=True)), **kwargs)
    lag = zero_multiplier_model(env_fn, **kwargs)
    ppo_params, lag_params = ppo.policy.state_dict(), lag.policy.state_dict()
    for key in ppo_params:
        assert th.equal(ppo_params[key], lag_params[key]), f"initial {key} differs from PPO's at the same seed"

    lag.learn(64)  # fills the buffer (and updates once)
    ppo.policy.load_state_dict({key: value for key, value in lag.policy.state_dict().items() if key in ppo_params})
    # PPOLagrangian's one optimizer holds the actor-critic's parameters first, then the cost critic's: PPO takes the
    # first part (deepcopy: load_state_dict would share the Adam moment tensors between the two optimizers)
    lag_optimizer = copy.deepcopy(lag.policy.optimizer.state_dict())
    n_actor_critic = len(ppo.policy.optimizer.param_groups[0]["params"])
    assert len(lag_optimizer["param_groups"][0]["params"]) == n_actor_critic + len(lag.policy.cost_critic_parameters())
    ppo.policy.optimizer.load_state_dict(
        {
            "state": {index: value for index, value in lag_optimizer["state"].items() if index < n_actor_critic},
            "param_groups": [{**lag_optimizer["param_groups"][0], "params": list(range(n_actor_critic))}],
        }
    )
    ppo._logger, ppo._current_progress_remaining = lag.logger, lag._current_progress_remaining
    ppo.rollout_buffer = copy.deepcopy(lag.rollout_buffer)  # a CostRolloutBuffer is a RolloutBuffer
    state = np.random.get_state()
    ppo.train()
    np.random.set_state(state)
    lag.train()
    for key, value in ppo.policy.state_dict().items():
        assert th.equal(value, lag.policy.state_dict()[key]), f"{key} differs after one update"


def test_zero_multiplier_training_matches_ppo_end_to_end():
    """
    Whole runs agree up to float rounding (PPOLagrangian computes the rollout's values in one batch, and its Adam is
    fused where PPO's default loops over the tensors).
    """
    kwargs = dict(n_steps=64, batch_size=16, n_epochs=2, seed=3)
    ppo = PPO("MlpPolicy", PendulumWithCost(), **kwargs).learn(256)
    lag = zero_multiplier_model(PendulumWithCost, **kwargs).learn(256)
    for key, value in ppo.policy.state_dict().items():
        np.testing.assert_allclose(value.numpy(), lag.policy.state_dict()[key].numpy(), atol=1e-5)
    np.testing.assert_allclose(ppo.rollout_buffer.returns, lag.rollout_buffer.returns, rtol=1e-4, atol=1e-4)


def test_zero_multiplier_training_matches_ppo_at_the_throughput_shape():
    """
    The throughput recipes' shape (several envs per VecEnv, minibatches of a large share of the rollout, few epochs):
    whole runs still agree with PPO up to float rounding.
    """

    def vec_env() -> DummyVecEnv:
        return DummyVecEnv([PendulumWithCost] * 4)

    kwargs = dict(n_steps=32, batch_size=64, n_epochs=2, seed=5)
    ppo = PPO("MlpPolicy", vec_env(), **kwargs).learn(512)
    lag = zero_multiplier_model(vec_env, **kwargs).learn(512)
    for key, value in ppo.policy.state_dict().items():
        np.testing.assert_allclose(value.numpy(), lag.policy.state_dict()[key].numpy(), atol=1e-5)
    np.testing.assert_allclose(ppo.rollout_buffer.returns, lag.rollout_buffer.returns, rtol=1e-4, atol=1e-4)


def test_truncation_bootstraps_reward_and_cost():
    """At a time-limit truncation the stored reward and cost get gamma * V(final obs) and cost_gamma * V_c(final obs)."""

    class CheckTruncation(BaseCallback):
        def _on_step(self) -> bool:
            if self.locals["dones"][0]:
                info = self.locals["infos"][0]
                assert info["TimeLimit.truncated"]
                self.final_obs = th.as_tensor(info["terminal_observation"][None])
                self.raw_reward, self.raw_cost = float(self.locals["rewards"][0]), float(self.locals["costs"][0, 0])
            return True

        def _on_rollout_end(self) -> None:
            buffer = self.model.rollout_buffer
            with th.no_grad():
                value = self.model.policy.predict_values(self.final_obs).item()
                cost_value = self.model.policy.predict_cost_values(self.final_obs).item()
            assert abs(cost_value) > 1e-4
            np.testing.assert_allclose(buffer.rewards[-1, 0], self.raw_reward + 0.99 * value, rtol=1e-5)
            np.testing.assert_allclose(buffer.costs[-1, 0, 0], self.raw_cost + 0.9 * cost_value, rtol=1e-5)
            assert set(np.unique(buffer.costs[:-1])) <= {0.0, 1.0}, "other steps keep their raw costs"
            self.checked = True

    callback = CheckTruncation()
    model = PPOLagrangian("MlpPolicy", PendulumWithCost(), n_steps=200, batch_size=50, n_epochs=1, seed=0, cost_gamma=0.9)
    model.learn(200, callback=callback)
    assert callback.checked


def test_multiplier_grows_while_over_budget_and_logs(tmp_path):
    model = PPOLagrangian(
        "MlpPolicy",
        ConstrainedCorridorEnv(safe_limit=0),
        cost_budget=0.0,
        budget_statistic="step",
        lagrange_kwargs=dict(init=0.0, lr=0.1, optimizer="sgd"),
        seed=0,
        **TINY,
    )
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(32 * 4)
    # SGD on the mean per-step cost of each rollout: lambda is the sum of 0.1 * those means
    assert model.lagrange_multiplier.value[0] > 0.0
    with open(os.path.join(tmp_path, "progress.csv")) as handle:
        rows = list(csv.DictReader(handle))
    keys = set(rows[-1])
    for key in (
        "rollout/ep_cost_mean",
        "train/lagrange_multiplier",
        "train/cost_value_loss",
        "train/cost_explained_variance",
        "train/constraint_value",
        "rollout/ep_rew_mean",
        "train/value_loss",
    ):
        assert key in keys, f"{key} not logged"
    step_costs = [float(row["train/constraint_value"]) for row in rows if row["train/constraint_value"]]
    multipliers = [float(row["train/lagrange_multiplier"]) for row in rows if row["train/lagrange_multiplier"]]
    np.testing.assert_allclose(multipliers, 0.1 * np.cumsum(step_costs), rtol=1e-5)


def test_several_constraints_have_one_multiplier_each(tmp_path):
    class TwoCosts(ConstrainedCorridorEnv):
        def step(self, action):
            obs, reward, terminated, truncated, info = super().step(action)
            info["cost"] = [info["cost"], 1.0]  # the second constraint is always broken
            return obs, reward, terminated, truncated, info

    model = PPOLagrangian(
        "MlpPolicy", TwoCosts(), cost_budget=[100.0, 0.0], lagrange_kwargs=dict(init=0.5, lr=0.3), seed=0, **TINY
    )
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(32 * 3)
    first, second = model.lagrange_multiplier.value
    assert first == 0.0 and second > 0.5
    assert model.policy.predict_cost_values(th.zeros(3, 2)).shape == (3, 2)
    with open(os.path.join(tmp_path, "progress.csv")) as handle:
        header = handle.readline()
    assert "train/lagrange_multiplier_0" in header and "train/lagrange_multiplier_1" in header


@pytest.mark.parametrize("lagrange_update", ["gradient", "pid"])
def test_save_load_round_trip_restores_everything(tmp_path, lagrange_update):
    env = DummyVecEnv([PendulumWithCost])
    model = PPOLagrangian("MlpPolicy", env, cost_budget=1.0, lagrange_update=lagrange_update, seed=0, **TINY)
    model.learn(32 * 3)
    path = str(tmp_path / "model.zip")
    model.save(path)
    loaded = PPOLagrangian.load(path, env=DummyVecEnv([PendulumWithCost]))

    np.testing.assert_array_equal(loaded.lagrange_multiplier.value, model.lagrange_multiplier.value)
    if lagrange_update == "pid":
        for attribute in ("integral", "delta_p", "cost_d"):
            np.testing.assert_array_equal(
                getattr(loaded.lagrange_multiplier, attribute), getattr(model.lagrange_multiplier, attribute)
            )
        assert list(map(list, loaded.lagrange_multiplier.cost_d_history)) == list(
            map(list, model.lagrange_multiplier.cost_d_history)
        )
    observations = np.random.default_rng(0).normal(size=(5, 3)).astype(np.float32)
    np.testing.assert_array_equal(
        loaded.predict(observations, deterministic=True)[0], model.predict(observations, deterministic=True)[0]
    )
    obs_tensor = th.as_tensor(observations)
    assert th.equal(loaded.policy.predict_cost_values(obs_tensor), model.policy.predict_cost_values(obs_tensor))
    for key, value in model.policy.optimizer.state_dict()["state"].items():
        assert th.equal(loaded.policy.optimizer.state_dict()["state"][key]["exp_avg"], value["exp_avg"])

    # Both multipliers continue identically on the same data, and training resumes
    np.testing.assert_array_equal(
        loaded.lagrange_multiplier.update(np.array([3.0])), model.lagrange_multiplier.update(np.array([3.0]))
    )
    loaded.learn(32 * 2, reset_num_timesteps=False)
    assert loaded.num_timesteps == 32 * 5


def test_plain_ppo_breaks_the_constraint_ppolag_respects_the_budget():
    """On the corridor (20 steps, cost 1 per step right of cell 6), budget 2 per episode."""
    budget = 2.0
    kwargs = dict(n_steps=256, batch_size=64, policy_kwargs=dict(net_arch=[32, 32]), learning_rate=3e-3, seed=0)
    ppo = PPO("MlpPolicy", ConstrainedCorridorEnv(), **kwargs).learn(10_000)
    lag = PPOLagrangian(
        "MlpPolicy", ConstrainedCorridorEnv(), cost_budget=budget, lagrange_kwargs=dict(init=0.0, lr=0.1), **kwargs
    ).learn(10_000)

    def episode_cost(model) -> float:
        env, total = ConstrainedCorridorEnv(), 0.0
        obs, _ = env.reset()
        for _ in range(env.max_steps):
            obs, _, _, _, info = env.step(int(model.predict(obs, deterministic=True)[0]))
            total += info["cost"]
        return total

    assert episode_cost(ppo) > 3 * budget
    assert episode_cost(lag) <= 1.1 * budget
    assert np.mean(list(lag.ep_cost_buffer)[-20:]) <= 1.1 * budget, "training episodes must end within budget too"


def test_bad_arguments():
    env = ConstrainedCorridorEnv()
    with pytest.raises(ValueError, match="Unknown `budget_statistic`"):
        PPOLagrangian("MlpPolicy", env, budget_statistic="trajectory")
    with pytest.raises(ValueError, match="Unknown Lagrange multiplier update"):
        PPOLagrangian("MlpPolicy", env, lagrange_update="newton")
    with pytest.raises(ValueError, match="finite float or a non-empty sequence"):
        PPOLagrangian("MlpPolicy", env, cost_budget=[])
    with pytest.raises(ValueError, match=r"policy_kwargs\['n_costs'\]=2 disagrees"):
        PPOLagrangian("MlpPolicy", env, policy_kwargs=dict(n_costs=2))
    with pytest.raises(TypeError, match="needs a CostActorCriticPolicy"):
        PPOLagrangian(ActorCriticPolicy, env)
    with pytest.raises(NotImplementedError, match="Dict observation"):
        PPOLagrangian(CostActorCriticPolicy, DictObsCorridor())


class DictObsCorridor(ConstrainedCorridorEnv):
    def __init__(self):
        super().__init__()
        self.observation_space = gym.spaces.Dict({"x": gym.spaces.Box(0, 1, shape=(2,))})


def test_policy_loss_uses_the_lagrangian_advantage():
    """First minibatch of an update (ratio = 1): the policy loss is -mean((A_r - lambda A_c) / (1 + lambda))."""
    model = PPOLagrangian(
        "MlpPolicy",
        ConstrainedCorridorEnv(safe_limit=0),
        n_steps=64,
        batch_size=64,
        n_epochs=1,
        normalize_advantage=False,
        lagrange_kwargs=dict(init=2.0, lr=0.0),
        seed=0,
    )
    model.learn(64)
    buffer = model.rollout_buffer  # flattened by the update
    expected = -np.mean((buffer.advantages - 2.0 * buffer.cost_advantages[:, 0]) / 3.0)
    assert np.abs(buffer.cost_advantages).max() > 0.1, "the test needs non-trivial cost advantages"
    assert model.logger.name_to_value["train/policy_gradient_loss"] == pytest.approx(expected, rel=1e-5, abs=1e-7)


def test_episode_statistic_uses_the_episodes_ended_since_the_last_update():
    """Budget 0, SGD lr 1: each update adds the mean cost of the episodes that ended during the rollout."""
    recorder = EpisodeCostRecorder()
    model = PPOLagrangian(
        "MlpPolicy",
        ConstrainedCorridorEnv(safe_limit=0),
        cost_budget=0.0,
        budget_statistic="episode",
        lagrange_kwargs=dict(init=0.0, lr=1.0, optimizer="sgd"),
        seed=0,
        n_steps=30,  # 20-step episodes end at steps 20 | 40, 60 | 80: one, two, one per rollout
        batch_size=30,
        n_epochs=1,
    )
    model.learn(90, callback=recorder)
    costs = recorder.recent(10)[:, 2]
    assert len(costs) == 4
    expected = costs[0] + np.mean(costs[1:3]) + costs[3]
    assert model.lagrange_multiplier.value[0] == pytest.approx(expected)


def test_the_episode_costs_kept_for_the_multiplier_do_not_grow(tmp_path):
    """Under "step" the multiplier reads the rollout's mean: no episode is kept (nor saved); under "episode" only those
    that ended since the last update are."""
    for statistic, most in (("step", 0), ("episode", 1)):
        model = PPOLagrangian(
            "MlpPolicy", ConstrainedCorridorEnv(safe_limit=0), budget_statistic=statistic, seed=0, n_steps=30, batch_size=30
        )
        model.learn(150)  # 20-step episodes: seven of them ended
        assert len(model.ep_cost_buffer) == 7
        assert len(model._episode_costs_since_update) <= most, statistic
        model.save(tmp_path / statistic)
        assert len(PPOLagrangian.load(tmp_path / statistic)._episode_costs_since_update) <= most


def test_optimizers_fused_by_default_with_sb3_adam_settings():
    """The optimiser takes torch's fused Adam with SB3's eps; a caller's own choice (foreach, other kwargs) is kept."""
    model = PPOLagrangian("MlpPolicy", PendulumWithCost(), n_steps=64, batch_size=16)
    assert model.policy.optimizer.defaults["fused"] is True
    assert model.policy.optimizer.defaults["eps"] == 1e-5
    own = PPOLagrangian(
        "MlpPolicy", PendulumWithCost(), n_steps=64, batch_size=16, policy_kwargs=dict(optimizer_kwargs=dict(foreach=True))
    )
    assert own.policy.optimizer.defaults["foreach"] is True and not own.policy.optimizer.defaults["fused"]
    assert own.policy.optimizer.defaults["eps"] == 1e-8  # torch's default: the caller gave kwargs, as in SB3
    rmsprop = PPOLagrangian(
        "MlpPolicy", PendulumWithCost(), n_steps=64, batch_size=16, policy_kwargs=dict(optimizer_class=th.optim.RMSprop)
    )
    assert "fused" not in rmsprop.policy.optimizer_kwargs  # torch's RMSprop has no fused CPU kernel in this list


def test_clip_grad_norms_matches_torch_per_group() -> None:
    """One pass over two groups gives, bit for bit, torch's clip_grad_norm_ applied to each group on its own."""
    generator = th.Generator().manual_seed(0)
    shapes = [[(4, 3), (3,)], [(2, 5), (5,), (1,)]]
    for scale in (1e-3, 10.0):  # below the bound (left as is) and above it (scaled down)
        groups = [[th.nn.Parameter(th.zeros(shape)) for shape in group] for group in shapes]
        twins = [[th.nn.Parameter(th.zeros(shape)) for shape in group] for group in shapes]
        for group, twin in zip(groups, twins, strict=True):
            for param, other in zip(group, twin, strict=True):
                param.grad = th.randn(param.shape, generator=generator) * scale
                other.grad = param.grad.clone()
        totals = clip_grad_norms_(groups, max_norm=0.5)
        expected = th.stack([th.nn.utils.clip_grad_norm_(twin, 0.5, foreach=True) for twin in twins])
        assert th.equal(totals, expected)
        for group, twin in zip(groups, twins, strict=True):
            assert all(th.equal(param.grad, other.grad) for param, other in zip(group, twin, strict=True))
        norms = [th.linalg.vector_norm(th.cat([param.grad.flatten() for param in group])) for group in groups]
        if scale > 1:
            assert all(abs(float(norm) - 0.5) < 1e-5 for norm in norms)  # each group by its own norm
    # A group without gradients is left alone (norm 0), as torch does
    frozen, trained = th.nn.Parameter(th.zeros(2)), th.nn.Parameter(th.zeros(2))
    trained.grad = th.full((2,), 3.0)
    assert clip_grad_norms_([[frozen], [trained]], 0.5).tolist() == [0.0, pytest.approx(18**0.5)]
    assert frozen.grad is None and abs(float(th.linalg.vector_norm(trained.grad)) - 0.5) < 1e-6
    # Groups of different dtypes: torch per group, each coefficient in its group's dtype
    single, double = th.nn.Parameter(th.zeros(3)), th.nn.Parameter(th.zeros(3, dtype=th.float64))
    single.grad, double.grad = th.randn(3, generator=generator), th.randn(3, generator=generator, dtype=th.float64)
    single_twin, double_twin = single.grad.clone(), double.grad.clone()
    clip_grad_norms_([[single], [double]], 0.5)
    single_expected, double_expected = th.nn.Parameter(th.zeros(3)), th.nn.Parameter(th.zeros(3, dtype=th.float64))
    single_expected.grad, double_expected.grad = single_twin, double_twin
    th.nn.utils.clip_grad_norm_([single_expected], 0.5, foreach=True)
    th.nn.utils.clip_grad_norm_([double_expected], 0.5, foreach=True)
    assert th.equal(single.grad, single_expected.grad) and th.equal(double.grad, double_expected.grad)


def test_train_clips_the_actor_critic_and_the_cost_critic_apart(monkeypatch) -> None:
    """Each minibatch: one clip over two groups, the actor-critic's parameters and the cost critic's, never joined."""
    import sb3_icrl.ppo_lagrangian.ppo_lagrangian as module

    calls = []

    def spy(groups, max_norm):
        calls.append(([list(group) for group in groups], max_norm))
        return clip_grad_norms_(groups, max_norm)

    monkeypatch.setattr(module, "clip_grad_norms_", spy)
    model = PPOLagrangian("MlpPolicy", ConstrainedCorridorEnv(), n_steps=32, batch_size=16, n_epochs=2, max_grad_norm=0.3)
    model.learn(32)
    assert len(calls) == 4  # 2 epochs x 2 minibatches
    # The one optimizer holds the actor-critic's parameters, then the cost critic's
    optimized = [id(param) for group in model.policy.optimizer.param_groups for param in group["params"]]
    cost_critic = [id(param) for param in model.policy.cost_critic_parameters()]
    assert len(cost_critic) == 6 and optimized[-6:] == cost_critic
    for groups, max_norm in calls:
        assert max_norm == 0.3 and len(groups) == 2
        assert [id(p) for p in groups[0]] == optimized[:-6]
        assert [id(p) for p in groups[1]] == cost_critic


def test_distribution_validation_comes_back_after_nested_overlapping_and_failing_blocks():
    """Off inside (a NaN mean builds a Normal), torch's setting back after the last block, even after an error."""
    import threading

    from torch.distributions import Distribution, Normal

    from sb3_icrl.common.policies import no_distribution_validation

    nan = th.tensor([float("nan")])
    previous = Distribution._validate_args
    Distribution.set_default_validate_args(True)
    try:
        with pytest.raises(RuntimeError, match="inside"), no_distribution_validation():
            with no_distribution_validation():
                Normal(nan, th.ones(1))
            Normal(nan, th.ones(1))  # still off after the inner block
            raise RuntimeError("inside")
        with pytest.raises(ValueError):
            Normal(nan, th.ones(1))
        # Two threads whose blocks overlap (A enters, B enters, A leaves, B leaves): the checks come back on
        entered, a_left = threading.Event(), threading.Event()
        seen = []

        def thread_b() -> None:
            with no_distribution_validation():
                entered.set()
                a_left.wait()
                seen.append(Distribution._validate_args)

        with no_distribution_validation():
            other = threading.Thread(target=thread_b)
            other.start()
            entered.wait()
        a_left.set()
        other.join()
        assert seen == [False] and Distribution._validate_args is True
    finally:
        Distribution.set_default_validate_args(previous)


def test_diverged_policy_fails_clearly_in_rollouts():
    """torch's distribution checks are off in rollouts: NaN actions must still stop training with a clear error."""
    from torch.distributions import Distribution

    model = PPOLagrangian("MlpPolicy", PendulumWithCost(), seed=0, **TINY)
    with th.no_grad():
        model.policy.action_net.weight.fill_(float("nan"))
    previous = Distribution._validate_args
    with pytest.raises(FloatingPointError, match=r"The policy.s actions are not finite.*Lower the learning rate"):
        model.learn(32)
    assert Distribution._validate_args == previous


def test_diverged_critic_fails_clearly_in_the_update():
    """A NaN value turns the advantages and losses NaN: the update says so instead of training on."""
    from torch.distributions import Distribution

    model = PPOLagrangian("MlpPolicy", PendulumWithCost(), seed=0, **TINY)
    with th.no_grad():
        model.policy.value_net.weight.fill_(float("nan"))
    previous = Distribution._validate_args
    message = r"The losses of the update at step 32 \(means: .*value_loss.: nan.*are not finite"
    with pytest.raises(FloatingPointError, match=message):
        model.learn(32)
    assert Distribution._validate_args == previous


def test_callbacks_keep_torchs_distribution_checks():
    """Only the policy's own distributions skip torch's checks: user code in callbacks runs with torch's setting."""
    from torch.distributions import Distribution

    class RecordSetting(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.settings: set[bool] = set()

        def _on_step(self) -> bool:
            self.settings.add(Distribution._validate_args)
            return True

        def _on_rollout_end(self) -> None:
            self.settings.add(Distribution._validate_args)

    previous = Distribution._validate_args
    Distribution.set_default_validate_args(True)  # torch's default, also under python -O
    try:
        callback = RecordSetting()
        model = PPOLagrangian("MlpPolicy", PendulumWithCost(), seed=0, **TINY)
        # ... while the policy's own distributions, in rollouts and in the update, skip them
        in_policy = set()
        get_distribution = model.policy._get_action_dist_from_latent

        def recording(*args, **kwargs):
            in_policy.add(Distribution._validate_args)
            return get_distribution(*args, **kwargs)

        model.policy._get_action_dist_from_latent = recording
        model.learn(64, callback=callback)
        assert callback.settings == {True} and in_policy == {False}
    finally:
        Distribution.set_default_validate_args(previous)


def test_target_kl_stop_on_a_non_finite_minibatch_is_not_divergence():
    """A minibatch that target_kl stops before its step is not applied: its losses do not count as divergence."""
    model = PPOLagrangian("MlpPolicy", PendulumWithCost(), seed=0, target_kl=0.01, **TINY)
    model.learn(32)
    # The old log-probabilities far below the new ones: the ratio overflows to inf, the KL too, and training stops
    model.rollout_buffer.log_probs[:] = -1e6
    model.rollout_buffer._sampling_tensors = None  # (made again from the fields)
    model.train()  # no FloatingPointError
    assert model.logger.name_to_value["train/policy_gradient_loss"] == float("inf")  # the stopped minibatch's loss


@pytest.mark.parametrize("batch", [1, 3])
@pytest.mark.parametrize("deterministic", [False, True])
def test_act_computes_what_sb3s_gaussian_distribution_computes(batch: int, deterministic: bool) -> None:
    # The rollouts' actor skips SB3's distribution objects for a diagonal Gaussian: same actions, log-probabilities
    # and draws from the random generator, bit for bit
    env = gym.make("sb3_icrl/BlockedAnt-v0")  # 8-d actions
    policy = PPOLagrangian("MlpPolicy", env, seed=0, **TINY).policy
    with th.no_grad():
        policy.log_std.fill_(-0.7)
    obs = th.as_tensor(np.stack([env.observation_space.sample() for _ in range(batch)]), dtype=th.float32)

    def sb3_act() -> tuple[th.Tensor, th.Tensor]:
        features = super(ActorCriticPolicy, policy).extract_features(obs, policy.pi_features_extractor)
        distribution = policy._get_action_dist_from_latent(policy.mlp_extractor.forward_actor(features))
        actions = distribution.get_actions(deterministic=deterministic)
        return actions, distribution.log_prob(actions)

    with th.no_grad():
        th.manual_seed(3)
        expected = [sb3_act() for _ in range(3)], th.rand(4)
        th.manual_seed(3)
        lean = policy._diag_gaussian_act
        calls = []
        policy._diag_gaussian_act = lambda *args: calls.append(1) or lean(*args)  # the lean path is the one taken
        got = [policy.act(obs, deterministic=deterministic) for _ in range(3)], th.rand(4)
    assert len(calls) == 3
    for (actions, log_prob), (want_actions, want_log_prob) in zip(got[0], expected[0], strict=True):
        assert actions.shape == (batch, 8) and log_prob.shape == (batch,)
        assert th.equal(actions, want_actions) and th.equal(log_prob, want_log_prob)
    assert th.equal(got[1], expected[1])  # the generator is where SB3's path leaves it
    assert deterministic or not th.equal(got[0][0][0], got[0][1][0])  # samples, not the mean


def test_lean_actor_trains_exactly_as_sb3s_distribution_path(monkeypatch) -> None:
    def via_distribution(policy: CostActorCriticPolicy, mean: th.Tensor, deterministic: bool):
        distribution = policy.action_dist.proba_distribution(mean, policy.log_std)
        actions = distribution.get_actions(deterministic=deterministic)
        return actions, distribution.log_prob(actions)

    def run() -> list[th.Tensor]:
        model = PPOLagrangian("MlpPolicy", PendulumWithCost(), n_steps=64, batch_size=16, n_epochs=2, seed=3)
        return [param.detach().clone() for param in model.learn(256).policy.parameters()]

    lean = run()
    monkeypatch.setattr(CostActorCriticPolicy, "_diag_gaussian_act", via_distribution)
    reference = run()
    assert all(th.equal(mine, theirs) for mine, theirs in zip(lean, reference, strict=True))


def test_a_policy_that_builds_its_own_distribution_keeps_it_in_rollouts() -> None:
    # A subclass that changes the distribution in _get_action_dist_from_latent: rollouts must sample from it, so that
    # the stored log-probabilities are those the update computes again
    class ClampedStd(CostActorCriticPolicy):
        def _get_action_dist_from_latent(self, latent_pi: th.Tensor):
            return self.action_dist.proba_distribution(self.action_net(latent_pi), self.log_std.clamp(min=-1.0))

    space = gym.spaces.Box(-1.0, 1.0, (4,))
    policy = ClampedStd(space, gym.spaces.Box(-1.0, 1.0, (2,)), lambda _: 1e-3, log_std_init=-3.0)
    obs = th.as_tensor(np.stack([space.sample() for _ in range(3)]))
    with th.no_grad():
        actions, log_prob = policy.act(obs)
        _, expected, _ = policy.evaluate_actions(obs, actions)
    th.testing.assert_close(log_prob, expected)
    assert not policy._plain_diag_gaussian()


def test_load_merges_the_cost_optimizer_of_a_model_saved_with_two_optimizers():
    """
    A zip saved when the cost critic had an optimizer of its own (the shipped experts) loads into the one optimizer:
    every Adam state lands on its own parameter, and the model saves back in the one-optimizer format.
    """
    path = EXPERTS_DIR / "BiasedPendulum-v0.zip"
    _, saved, _ = load_from_zip_file(path, load_data=False)
    assert "policy.cost_optimizer" in saved  # the older format, or this test proves nothing
    model = PPOLagrangian.load(path)
    params = model.policy.optimizer.param_groups[0]["params"]
    state = model.policy.optimizer.state_dict()["state"]
    n_actor_critic = len(saved["policy.optimizer"]["param_groups"][0]["params"])
    assert len(params) == n_actor_critic + len(model.policy.cost_critic_parameters())
    for offset, name in ((0, "policy.optimizer"), (n_actor_critic, "policy.cost_optimizer")):
        assert saved[name]["state"]
        for index, value in saved[name]["state"].items():
            assert th.equal(state[offset + index]["exp_avg_sq"], value["exp_avg_sq"])
            assert state[offset + index]["exp_avg"].shape == params[offset + index].shape
    merged = merge_cost_optimizer(saved)
    assert "policy.cost_optimizer" in saved and "policy.cost_optimizer" not in merged  # the caller's dict is kept
    assert set(model.get_parameters()) == {"policy", "policy.optimizer"}


def test_merge_cost_optimizer_refuses_several_parameter_groups():
    group = {"lr": 1e-3, "params": [0]}
    params = {"policy.optimizer": {"state": {}, "param_groups": [group, {**group, "params": [1]}]}}
    assert merge_cost_optimizer(params) is params  # nothing to merge
    with pytest.raises(ValueError, match="one parameter group"):
        merge_cost_optimizer({**params, "policy.cost_optimizer": {"state": {}, "param_groups": [group]}})
    with pytest.raises(ValueError, match="without the actor-critic's"):
        merge_cost_optimizer({"policy.cost_optimizer": {"state": {}, "param_groups": [group]}})
