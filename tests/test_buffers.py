import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import RolloutBuffer

from sb3_icrl.common.buffers import CostRolloutBuffer

N_STEPS, N_ENVS = 7, 2
OBS_SPACE = spaces.Box(-1, 1, shape=(3,))
ACTION_SPACE = spaces.Box(-1, 1, shape=(1,))


def fill(buffer: RolloutBuffer, rng: np.random.Generator, rewards: np.ndarray, values: np.ndarray, starts: np.ndarray) -> None:
    for step in range(N_STEPS):
        buffer.add(
            rng.normal(size=(N_ENVS, 3)).astype(np.float32),
            rng.normal(size=(N_ENVS, 1)).astype(np.float32),
            rewards[step],
            starts[step],
            th.as_tensor(values[step]),
            th.zeros(N_ENVS),
        )


def hand_gae(signal, values, starts, last_values, dones, gamma, lam):
    """Textbook GAE for one env column: delta_t = c_t + gamma V_{t+1} (1 - done_{t+1}) - V_t."""
    advantages = np.zeros_like(signal)
    running = 0.0
    for t in reversed(range(len(signal))):
        non_terminal = 1.0 - (dones if t == len(signal) - 1 else starts[t + 1])
        next_value = last_values if t == len(signal) - 1 else values[t + 1]
        delta = signal[t] + gamma * next_value * non_terminal - values[t]
        running = delta + gamma * lam * non_terminal * running
        advantages[t] = running
    return advantages


def test_cost_gae_matches_hand_computation_and_reward_gae_matches_sb3():
    rng = np.random.default_rng(0)
    rewards = rng.normal(size=(N_STEPS, N_ENVS)).astype(np.float32)
    values = rng.normal(size=(N_STEPS, N_ENVS)).astype(np.float32)
    starts = (rng.random((N_STEPS, N_ENVS)) < 0.3).astype(np.float32)
    costs = (rng.random((N_STEPS, N_ENVS, 2)) < 0.5).astype(np.float32)
    cost_values = rng.normal(size=(N_STEPS, N_ENVS, 2)).astype(np.float32)
    last_values, last_cost_values = rng.normal(size=N_ENVS), rng.normal(size=(N_ENVS, 2))
    dones = np.array([True, False])

    reference = RolloutBuffer(N_STEPS, OBS_SPACE, ACTION_SPACE, gamma=0.9, gae_lambda=0.8, n_envs=N_ENVS)
    fill(reference, np.random.default_rng(1), rewards, values, starts)
    reference.compute_returns_and_advantage(th.as_tensor(last_values), dones)

    buffer = CostRolloutBuffer(
        N_STEPS,
        OBS_SPACE,
        ACTION_SPACE,
        gamma=0.9,
        gae_lambda=0.8,
        n_envs=N_ENVS,
        n_costs=2,
        cost_gamma=0.5,
        cost_gae_lambda=0.7,
    )
    fill(buffer, np.random.default_rng(1), rewards, values, starts)
    buffer.costs[:] = costs
    buffer.set_cost_values(cost_values)
    buffer.compute_returns_and_advantage(th.as_tensor(last_values), dones, last_cost_values=last_cost_values)

    np.testing.assert_array_equal(buffer.advantages, reference.advantages)
    np.testing.assert_array_equal(buffer.returns, reference.returns)
    for env_idx in range(N_ENVS):
        for cost_idx in range(2):
            expected = hand_gae(
                costs[:, env_idx, cost_idx],
                cost_values[:, env_idx, cost_idx],
                starts[:, env_idx],
                last_cost_values[env_idx, cost_idx],
                float(dones[env_idx]),
                gamma=0.5,
                lam=0.7,
            )
            np.testing.assert_allclose(buffer.cost_advantages[:, env_idx, cost_idx], expected, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(buffer.cost_returns, buffer.cost_advantages + cost_values, rtol=1e-6)


def test_samples_carry_cost_fields_aligned_with_observations():
    buffer = CostRolloutBuffer(N_STEPS, OBS_SPACE, ACTION_SPACE, n_envs=N_ENVS, n_costs=2)
    rng = np.random.default_rng(0)
    fill(buffer, rng, np.zeros((N_STEPS, N_ENVS)), np.zeros((N_STEPS, N_ENVS)), np.zeros((N_STEPS, N_ENVS)))
    # Tag each observation's first feature and cost value with the same id, to check rows stay aligned after shuffling
    ids = np.arange(N_STEPS * N_ENVS, dtype=np.float32).reshape(N_STEPS, N_ENVS)
    buffer.observations[..., 0] = ids
    buffer.set_cost_values(np.stack([ids, -ids], axis=-1))
    buffer.compute_returns_and_advantage(
        th.zeros(N_ENVS), np.zeros(N_ENVS, dtype=bool), last_cost_values=np.zeros((N_ENVS, 2))
    )
    batches = list(buffer.get(batch_size=4))
    assert sum(len(batch.observations) for batch in batches) == N_STEPS * N_ENVS
    for batch in batches:
        assert batch.old_cost_values.shape == (len(batch.observations), 2)
        np.testing.assert_array_equal(batch.old_cost_values[:, 0].numpy(), batch.observations[:, 0].numpy())
        np.testing.assert_array_equal(batch.old_cost_values[:, 1].numpy(), -batch.observations[:, 0].numpy())


def test_sampling_gives_sb3_layout_contiguous_and_equal_to_per_field_indexing():
    """get() gathers from tensors made once per rollout: the same values, shapes and order as indexing each array."""
    buffer = CostRolloutBuffer(N_STEPS, OBS_SPACE, spaces.Box(-1, 1, shape=(2,)), n_envs=N_ENVS, n_costs=2)
    rng = np.random.default_rng(3)
    for _ in range(N_STEPS):
        buffer.add(
            rng.normal(size=(N_ENVS, 3)).astype(np.float32),
            rng.normal(size=(N_ENVS, 2)).astype(np.float32),
            rng.normal(size=N_ENVS).astype(np.float32),
            np.zeros(N_ENVS),
            th.as_tensor(rng.normal(size=N_ENVS).astype(np.float32)),
            th.as_tensor(rng.normal(size=N_ENVS).astype(np.float32)),
        )
        buffer.add_costs(rng.uniform(size=(N_ENVS, 2)).astype(np.float32))
    buffer.set_cost_values(rng.normal(size=(N_STEPS, N_ENVS, 2)).astype(np.float32))
    dones = np.zeros(N_ENVS, dtype=bool)
    buffer.compute_returns_and_advantage(th.zeros(N_ENVS), dones, last_cost_values=np.zeros((N_ENVS, 2)))
    for epoch in range(2):  # the second epoch samples from the tensors made by the first
        np.random.seed(epoch)
        batches = list(buffer.get(batch_size=5))
        np.random.seed(epoch)
        indices = np.random.permutation(N_STEPS * N_ENVS)
        for start, batch in zip(range(0, N_STEPS * N_ENVS, 5), batches, strict=True):
            expected = buffer._get_samples(indices[start : start + 5])
            for name, value, reference in zip(batch._fields, batch, expected, strict=True):
                assert value.shape == reference.shape, name
                assert value.is_contiguous(), name
                assert th.equal(value, reference), name
