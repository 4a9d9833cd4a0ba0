"""
Constraint recovery on the four grid worlds from the shipped demonstrations (slow: about a minute in all).

BC2L, MECL, VICRL and IRL-Plus each alternate PI-Lagrangian planning on the learned cost with constraint updates, with the
settings of ``benchmarks/icrl_gridworld.py``; the final policy must reach the goal and break the true constraint in
at most 10% of the episodes. The true constraint is used for this evaluation only.
"""

import gymnasium as gym
import numpy as np
import pytest
import torch as th

from sb3_icrl.bc2l import BC2LTrainer
from sb3_icrl.common.evaluation import evaluate_constraint
from sb3_icrl.constraints import BetaFeasibilityNet, CostNet, FeasibilityNet
from sb3_icrl.data import load_demonstrations
from sb3_icrl.icrl import ICRLTrainer
from sb3_icrl.icrl.tabular import held_planner_kwargs, tabular_icrl
from sb3_icrl.irlplus import IRLPlusTrainer
from sb3_icrl.irlplus.irlplus import IRLPLUS_LAGRANGE_KWARGS
from sb3_icrl.mecl import MECLTrainer
from sb3_icrl.vicrl import VICRLTrainer

MAPS = ["GridWorldWall-v0", "GridWorldSquare-v0", "GridWorldBigSquare-v0", "GridWorldZigzag-v0"]
ALGOS: dict[str, tuple[type[ICRLTrainer], type[FeasibilityNet] | type[BetaFeasibilityNet] | type[CostNet]]] = {
    "bc2l": (BC2LTrainer, FeasibilityNet),
    "mecl": (MECLTrainer, FeasibilityNet),
    "vicrl": (VICRLTrainer, BetaFeasibilityNet),
    # Its cost as a negative reward: the planner holds the multiplier at 1, as IRLPlusPPO does
    "irlplus": (IRLPlusTrainer, CostNet),
}


@pytest.mark.slow
@pytest.mark.parametrize("env_id", MAPS)
@pytest.mark.parametrize("algo", list(ALGOS))
def test_grid_world_recovery_reaches_the_goal_safely(algo: str, env_id: str) -> None:
    th.set_num_threads(1)
    th.manual_seed(0)
    trainer_class, net_class = ALGOS[algo]
    demonstrations = load_demonstrations(env_id)
    env = gym.make(f"sb3_icrl/{env_id}")
    net = net_class.from_spaces(
        env.observation_space, env.action_space, hidden_sizes=[64], normalize_input=False, use_action=False
    )
    trainer_kwargs: dict = {}
    planner_kwargs = None
    if algo == "bc2l":  # BC2L labels whole trajectories, as the reference code does on its grid worlds
        trainer_kwargs = dict(expert_episode_lengths=[len(t) for t in demonstrations])
    elif algo == "irlplus":
        trainer_kwargs, planner_kwargs = dict(l2_coef=0.1), held_planner_kwargs(IRLPLUS_LAGRANGE_KWARGS["init"])
    result = tabular_icrl(
        trainer_class,
        net,
        env,
        demonstrations,
        n_iterations=20,
        constraint_learning_rate=1e-2,
        constraint_steps=10,
        trainer_kwargs=trainer_kwargs,
        planner_kwargs=planner_kwargs,
        seed=0,
    )
    evaluation = evaluate_constraint(result.planner, gym.make(f"sb3_icrl/{env_id}"), n_eval_episodes=10, seed=0)
    assert evaluation.violation_rate <= 0.1
    assert np.all(evaluation.episode_rewards > 0)  # every episode reaches the goal
