"""TrueConstraintLogger: one row per finished episode, from the true cost, on several envs at once."""

from types import SimpleNamespace

import numpy as np
import pytest

from sb3_icrl.icrl.callbacks import TrueConstraintLogger


def run_steps(steps, **kwargs):
    logger = TrueConstraintLogger(**kwargs)
    venv = SimpleNamespace(num_envs=3)
    logger.model = SimpleNamespace(_vec_normalize_env=None, num_timesteps=0, get_env=lambda: venv)
    logger._on_training_start()
    for timesteps, (infos, rewards, dones) in enumerate(steps, start=1):
        logger.model.num_timesteps = 3 * timesteps
        logger.update_locals({"infos": infos, "rewards": np.array(rewards), "dones": np.array(dones)})
        logger.on_step()
    return logger


def test_rows_hold_violation_feasible_reward_and_cost_per_env():
    steps = [
        # env 0: feasible, then a violation; env 1 reports no true cost; env 2: a cost per constraint, env_reward kept
        ([{"true_cost": 0.0}, {}, {"true_cost": np.zeros(2), "env_reward": 5.0}], [1.0, 7.0, -1.0], [False, False, False]),
        ([{"true_cost": 1.0}, {}, {"true_cost": np.zeros(2), "env_reward": 5.0}], [2.0, 7.0, -1.0], [False, True, True]),
        (
            [{"true_cost": 0.5}, {}, {"true_cost": np.array([0.0, 2.0]), "env_reward": 4.0}],
            [3.0, 7.0, -1.0],
            [True, False, False],
        ),
        ([{"true_cost": 0.0}, {}, {"true_cost": np.zeros(2), "env_reward": 4.0}], [4.0, 7.0, -1.0], [False, False, True]),
    ]
    logger = run_steps(steps)
    # (timesteps, violated, feasible reward until the first violation, episode cost), in the order episodes ended
    assert logger.episodes == [(6, False, 10.0, 0.0), (9, True, 1.0, 1.5), (12, True, 0.0, 2.0)]


@pytest.mark.parametrize("cost", [0.0, 0, np.float32(0.0)])
def test_a_zero_cost_of_any_number_type_is_no_violation(cost):
    logger = run_steps([([{"true_cost": cost}] * 3, [1.0, 1.0, 1.0], [True, True, True])])
    assert [row[1:] for row in logger.episodes] == [(False, 1.0, 0.0)] * 3


def test_only_the_most_recent_episodes_are_kept_and_a_rollout_logs_its_own():
    logger = run_steps([([{"true_cost": 0.0}] * 3, [1.0, 1.0, 1.0], [True, True, True])] * 3, max_episodes=4)
    assert len(logger.episodes) == 9  # trimmed at a rollout's start, never during one
    logger._on_rollout_start()
    assert [row[0] for row in logger.episodes] == [6, 9, 9, 9]
    records = {}
    logger.model.logger = SimpleNamespace(record=lambda key, value: records.__setitem__(key, value))
    logger.update_locals({"infos": [{"true_cost": 1.0}] * 3, "rewards": np.ones(3), "dones": np.array([True] * 3)})
    logger.on_step()
    logger._on_rollout_end()
    assert records["true/violation_rate"] == 1.0  # the three episodes of this rollout, not the kept ones before it


def test_max_episodes_below_one_is_refused():
    with pytest.raises(ValueError, match="max_episodes must be at least 1"):
        TrueConstraintLogger(max_episodes=0)
