"""The binding variants: the source env's spaces and true constraint, a reward that grows toward the forbidden side."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gymnasium_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from sb3_icrl.envs import BINDING_ENV_SPECS, BINDING_VARIANTS, get_constraint_spec

# variant -> (a safe x next to the line, an unsafe x beyond it)
LINE = {
    "BlockedHalfCheetahReach-v0": (-2.9, -3.1),
    "BlockedAntReach-v0": (-2.9, -3.1),
    "BlockedWalkerReach-v0": (-2.9, -3.1),
}


def make(name: str, **kwargs) -> gym.Env:
    return gym.make(f"sb3_icrl/{name}", **kwargs)


def place(env: gym.Env, x: float) -> None:
    """Put the robot at ``x`` in its initial pose, at rest."""
    base = env.unwrapped
    qpos, qvel = base.init_qpos.copy(), np.zeros_like(base.init_qvel)
    qpos[0] = x
    base.set_state(qpos, qvel)


def test_every_variant_keeps_its_source_envs_spaces_length_and_constraint():
    assert set(BINDING_VARIANTS.values()) == set(BINDING_ENV_SPECS)
    for source, variant in BINDING_VARIANTS.items():
        source_env, variant_env = make(source), make(variant)
        assert variant_env.observation_space == source_env.observation_space
        assert variant_env.action_space == source_env.action_space
        assert variant_env.spec.max_episode_steps == source_env.spec.max_episode_steps
        assert get_constraint_spec(variant_env) == get_constraint_spec(source_env)


@pytest.mark.filterwarnings("ignore:.*(infinity|symmetric and normalized).*:UserWarning")
@pytest.mark.parametrize("name", sorted(BINDING_ENV_SPECS))
def test_env_checkers(name):
    env = make(name)
    gymnasium_check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env)


@pytest.mark.parametrize("name", sorted(LINE))
def test_the_position_pays_and_the_line_costs(name):
    safe_x, unsafe_x = LINE[name]
    env = make(name)
    action = np.zeros(env.action_space.shape)
    steps = {}
    for x in (0.0, safe_x, unsafe_x):
        env.reset(seed=0)
        place(env, x)
        _, reward, _, _, info = env.step(action)
        steps[x] = (reward, info)
    for x, (reward, info) in steps.items():
        # The reach term is the position after the step, negated; the rest is the source env's (control, health)
        assert info["reward_reach"] == pytest.approx(-info["x_position"])
        others = sum(value for key, value in info.items() if key.startswith("reward_") and key != "reward_reach")
        assert reward == pytest.approx(info["reward_reach"] + others)
        assert info["cost"] == float(x == unsafe_x)
    # Nearer the line pays more, beyond it more still: what pulls an unconstrained learner across
    assert steps[0.0][0] < steps[safe_x][0] < steps[unsafe_x][0]


def test_pendulum_variant_pays_in_full_only_well_beyond_the_wall():
    source, variant = make("BiasedPendulum-v0").unwrapped, make("BiasedPendulumReach-v0").unwrapped
    assert variant.cost_threshold == source.cost_threshold == -0.015
    # The source pays in full from x = -0.01, before its wall: nothing pulls across it. The variant's reward keeps
    # growing to x = -0.05, beyond the wall
    assert source.biased_reward(-0.012) == source.high_reward
    assert variant.biased_reward(-0.014) < variant.biased_reward(-0.03) < variant.biased_reward(-0.05) == variant.high_reward


def test_the_ant_is_paid_only_half_a_metre_past_its_line():
    env = make("BlockedAntReach-v0")
    action = np.zeros(env.action_space.shape)
    reaches = {}
    for x in (-3.4, -3.6, -6.0):
        env.reset(seed=0)
        place(env, x)
        _, _, _, _, info = env.step(action)
        reaches[x] = info["reward_reach"]
        assert info["cost"] == 1.0
    # Up to 0.5 m past the line the position pays as elsewhere; beyond, the pull stops at 3.5
    assert reaches[-3.4] == pytest.approx(3.4, abs=0.05)  # the step moves the ant a little
    assert reaches[-3.6] == reaches[-6.0] == pytest.approx(3.5)
    with pytest.raises(ValueError, match="paid_beyond_line"):
        gym.make("sb3_icrl/BlockedAntReach-v0", paid_beyond_line=-1.0)


def test_the_ant_ends_its_episode_at_the_line_only_when_asked():
    ended, running = make("BlockedAntReach-v0", end_at_line=True), make("BlockedAntReach-v0")
    action = np.zeros(ended.action_space.shape)
    for env in (ended, running):
        env.reset(seed=0)
        _, _, terminated, _, info = env.step(action)
        assert info["cost"] == 0.0 and not terminated  # on the allowed side nothing ends
    for env, should_end in ((ended, True), (running, False)):
        place(env, -3.2)
        _, _, terminated, truncated, info = env.step(action)
        assert info["cost"] == 1.0 and terminated is should_end and not truncated
    with pytest.raises(TypeError, match="end_at_line"):
        gym.make("sb3_icrl/BlockedAntReach-v0", end_at_line="yes")
