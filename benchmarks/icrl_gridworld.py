"""
Constraint recovery on the grid world: BC2L, MECL, VICRL and IRL-Plus, each from the shipped expert demonstrations. Prints,
per algorithm, the recovered map next to the true one, its precision and recall against the true unsafe cells, and
the violation and goal-reaching rates of the final policy (deterministic, against the true cost: evaluation only),
with the wall time::

    python benchmarks/icrl_gridworld.py                                   # PI-Lagrangian forward solver, wall map
    python benchmarks/icrl_gridworld.py --map GridWorldZigzag-v0 --iterations 30
    python benchmarks/icrl_gridworld.py --solver ppo --timesteps 40000    # the algorithm classes, PPO-Lagrangian

Forward solver: ``pilag`` (default) plans exactly on the learned cost table with PI-Lagrangian, as the paper does for
its grid worlds (:func:`sb3_icrl.icrl.tabular.tabular_icrl`); ``ppo`` runs the ``BC2L``/``MECL``/``VICRL`` classes
(PPO-Lagrangian on the learned cost). Both update the same constraint model with the same trainers. The constraint
net sees the cell only (``use_action=False``), so its cost is a map of cells.

IRL-Plus learns a cost as a negative reward (a :class:`~sb3_icrl.constraints.CostNet`, no upper bound, L2 penalty 0.1
on the expert's costs) and holds the multiplier at 1 (``IRLPlusPPO``; the planner holds it too), with the same loop
settings as the others (iterations, nominal episodes, passes, learning rate, net).

BC2L classifies whole trajectories (a trajectory is feasible when all its pairs are; expert trajectories 1, nominal
ones 0), as the reference code does on its grid worlds (``train_traj_nn``); ``--bc2l-per-pair`` gives the per-pair
classifier instead, which fails here: once the planner walks the expert's path, the pairs both sides visit get
``phi = 1/2``, a cost of about 0.5 per safe step, and a cost-minimising planner then cuts through a cell or two of
cost 1 to save several such steps (BigSquare, Zigzag).

A cell counts as recovered unsafe when its learned cost is above ``--threshold`` ("absolute"), or above the largest
cost of the cells the expert walks through ("relative": what a cost-minimising planner avoids). Cells the expert
never comes near are expected among them: nothing in the data says they are safe, so a recovered map is a superset of
the least constraining one (the paper's appendix makes the same observation).
"""

import argparse
import time
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_icrl.bc2l import BC2L, BC2LTrainer
from sb3_icrl.common.evaluation import evaluate_constraint
from sb3_icrl.constraints import BetaFeasibilityNet, CostNet, FeasibilityNet
from sb3_icrl.data import load_demonstrations
from sb3_icrl.envs.grid_world import GridWorldEnv
from sb3_icrl.icrl import ICRLTrainer, LagrangianICRL
from sb3_icrl.icrl.tabular import cost_table, held_planner_kwargs, precision_recall, tabular_icrl
from sb3_icrl.irlplus import IRLPlusPPO, IRLPlusTrainer
from sb3_icrl.irlplus.irlplus import IRLPLUS_LAGRANGE_KWARGS
from sb3_icrl.mecl import MECL, MECLTrainer
from sb3_icrl.vicrl import VICRL, VICRLTrainer

#: algo -> (algorithm class for PPO, trainer class for PI-Lag, constraint net class)
ALGOS: dict[str, tuple[type[LagrangianICRL], type[ICRLTrainer], type]] = {
    "bc2l": (BC2L, BC2LTrainer, FeasibilityNet),
    "mecl": (MECL, MECLTrainer, FeasibilityNet),
    "vicrl": (VICRL, VICRLTrainer, BetaFeasibilityNet),
    "irlplus": (IRLPlusPPO, IRLPlusTrainer, CostNet),
}
#: The constraint net of every run: the cell only, one small hidden layer
NET_KWARGS: dict[str, Any] = dict(hidden_sizes=[64], normalize_input=False, use_action=False)
CONSTRAINT_LEARNING_RATE = 1e-2
CONSTRAINT_STEPS = 10
#: PPO-Lagrangian settings of ``--solver ppo`` (small nets, short rollouts, a constraint update per rollout)
PPO_KWARGS: dict[str, Any] = dict(
    n_steps=512,
    batch_size=128,
    n_epochs=4,
    learning_rate=3e-4,
    ent_coef=0.05,
    policy_kwargs=dict(net_arch=[64]),
    update_every=512,
    lagrange_kwargs=dict(init=0.5, lr=0.5, optimizer="sgd"),
)


def make_env(env_id: str) -> DummyVecEnv:
    """
    :param env_id: A grid world id without the namespace, e.g. ``"GridWorldWall-v0"``
    :return: One monitored env in a ``DummyVecEnv``
    """
    return DummyVecEnv([lambda: Monitor(gym.make(f"sb3_icrl/{env_id}"))])


def trainer_kwargs(algo: str, env_id: str, bc2l_per_pair: bool = False) -> dict[str, Any]:
    """
    Trainer arguments of one algorithm on the grid world: BC2L labels whole trajectories unless ``bc2l_per_pair``.

    :param algo: ``"bc2l"``, ``"mecl"``, ``"vicrl"`` or ``"irlplus"``
    :param env_id: The grid world (its shipped demonstrations give the expert episode lengths)
    :param bc2l_per_pair: Whether BC2L classifies pairs instead of trajectories
    :return: Keyword arguments for the trainer
    """
    if algo == "irlplus":
        return dict(l2_coef=0.1)
    if algo != "bc2l" or bc2l_per_pair:
        return {}
    return dict(expert_episode_lengths=[len(trajectory) for trajectory in load_demonstrations(env_id)])


def run(algo: str, env_id: str, solver: str, budget: int, seed: int, bc2l_per_pair: bool = False) -> dict[str, Any]:
    """
    Learn the constraint with one algorithm and forward solver, then evaluate the final policy against the true cost.

    :param algo: ``"bc2l"``, ``"mecl"``, ``"vicrl"`` or ``"irlplus"``
    :param env_id: The grid world, e.g. ``"GridWorldZigzag-v0"``
    :param solver: ``"pilag"`` or ``"ppo"``
    :param budget: PI-Lag iterations (``pilag``) or policy timesteps (``ppo``)
    :param seed: Seed of the constraint net, the solver and the evaluation
    :param bc2l_per_pair: BC2L classifies pairs instead of trajectories
    :return: The grid, the learned cell costs, the policy's evaluation and the wall time
    """
    algo_class, trainer_class, net_class = ALGOS[algo]
    kwargs = trainer_kwargs(algo, env_id, bc2l_per_pair)
    th.manual_seed(seed)
    grid = GridWorldEnv(map_name=gym.spec(f"sb3_icrl/{env_id}").kwargs["map_name"])
    start = time.perf_counter()
    if solver == "pilag":
        env = gym.make(f"sb3_icrl/{env_id}")
        net = net_class.from_spaces(env.observation_space, env.action_space, **NET_KWARGS)
        result = tabular_icrl(
            trainer_class,
            net,
            env,
            load_demonstrations(env_id),
            n_iterations=budget,
            constraint_learning_rate=CONSTRAINT_LEARNING_RATE,
            constraint_steps=CONSTRAINT_STEPS,
            trainer_kwargs=kwargs,
            # IRL-Plus weighs its cost as a negative reward: the multiplier it holds, not one that adapts
            planner_kwargs=held_planner_multiplier(algo),
            seed=seed,
        )
        policy: Any = result.planner
    else:
        policy = algo_class(
            "MlpPolicy",
            make_env(env_id),
            env_id,
            seed=seed,
            constraint_net_kwargs=NET_KWARGS,
            constraint_learning_rate=CONSTRAINT_LEARNING_RATE,
            constraint_steps=CONSTRAINT_STEPS,
            trainer_kwargs=kwargs,
            **{**PPO_KWARGS, **({"lagrange_kwargs": IRLPLUS_LAGRANGE_KWARGS} if algo == "irlplus" else {})},
        )
        policy.learn(budget)
        net = policy.constraint_net
    wall_time = time.perf_counter() - start
    # The net sees the cell only: the cost of any action in a cell is the cell's cost
    costs = cost_table(net, grid.n_states, grid.n_actions)[:, 0].reshape(grid.n_rows, grid.n_cols)
    # Deterministic env and policy: the 10 episodes are identical, kept for the metrics' definitions
    evaluation = evaluate_constraint(policy, make_env(env_id), n_eval_episodes=10, deterministic=True, seed=seed)
    return dict(algo=algo, env_id=env_id, solver=solver, grid=grid, costs=costs, evaluation=evaluation, wall_time=wall_time)


def held_planner_multiplier(algo: str) -> dict[str, float] | None:
    """
    :param algo: The algorithm
    :return: The PI-Lagrangian arguments that hold the multiplier at IRL-Plus's 1 (``None``: the planner's defaults)
    """
    if algo != "irlplus":
        return None
    return held_planner_kwargs(IRLPLUS_LAGRANGE_KWARGS["init"])


def expert_cells(env_id: str, grid: GridWorldEnv) -> np.ndarray:
    """
    Boolean map of the cells the expert demonstrations walk through (goal excluded).

    :param env_id: The grid world whose shipped demonstrations to read
    :param grid: The grid world (for its shape)
    :return: ``(n_rows, n_cols)`` booleans
    """
    visited = np.zeros(grid.n_states, dtype=bool)
    visited[np.concatenate([t.obs[:-1] for t in load_demonstrations(env_id)]).astype(int)] = True
    return visited.reshape(grid.n_rows, grid.n_cols)


def render(grid: GridWorldEnv, unsafe: np.ndarray) -> list[str]:
    """
    :param grid: The grid world (start and goal cells)
    :param unsafe: Boolean map of the cells to mark ``X``
    :return: One string per row over ``S G X .``
    """
    rows = []
    for row in range(grid.n_rows):
        cells = ""
        for col in range(grid.n_cols):
            cell = (row, col)
            cells += "S" if cell == grid.start_cell else "G" if cell == grid.goal_cell else "X" if unsafe[row, col] else "."
        rows.append(cells)
    return rows


def report(result: dict[str, Any], threshold: float) -> dict[str, float]:
    """
    Print the true and recovered maps, the learned costs, precision and recall, violation and goal-reaching rates.

    :param result: The output of :func:`run`
    :param threshold: Cost above which a cell counts as recovered unsafe ("absolute")
    :return: Violation rate, reach rate, absolute precision and recall
    """
    grid, costs, evaluation = result["grid"], result["costs"], result["evaluation"]
    endpoints = np.zeros_like(grid.unsafe_mask)
    endpoints[grid.start_cell] = endpoints[grid.goal_cell] = True
    absolute = (costs > threshold) & ~endpoints
    relative = (costs > costs[expert_cells(result["env_id"], grid)].max()) & ~endpoints
    abs_precision, abs_recall = precision_recall(absolute, grid.unsafe_mask)
    rel_precision, rel_recall = precision_recall(relative, grid.unsafe_mask)
    reach_rate = float(np.mean(evaluation.episode_rewards > 0))
    print(f"== {result['algo'].upper()} on {result['env_id']} ({result['solver']} forward solver)")
    print(f"   true      >{threshold:g}       relative   learned cost of each cell")
    maps = zip(render(grid, grid.unsafe_mask), render(grid, absolute), render(grid, relative), costs, strict=True)
    for true_row, abs_row, rel_row, cost_row in maps:
        print(f"   {true_row}   {abs_row}    {rel_row}    " + " ".join(f"{c:.2f}" for c in cost_row))
    print(
        f"   absolute: precision {abs_precision:.2f} recall {abs_recall:.2f} | relative: precision {rel_precision:.2f} "
        f"recall {rel_recall:.2f} | violation rate {evaluation.violation_rate:.2f} reach rate {reach_rate:.2f} "
        f"episode length {np.mean(evaluation.episode_lengths):.0f} | wall time {result['wall_time']:.0f} s"
    )
    return dict(violation_rate=evaluation.violation_rate, reach_rate=reach_rate, precision=abs_precision, recall=abs_recall)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algos", nargs="+", default=list(ALGOS), choices=list(ALGOS))
    parser.add_argument("--map", default="GridWorldWall-v0", help="a grid world with shipped demonstrations")
    parser.add_argument("--solver", default="pilag", choices=["pilag", "ppo"])
    parser.add_argument("--iterations", type=int, default=20, help="ICRL iterations (pilag)")
    parser.add_argument("--timesteps", type=int, default=40_000, help="policy timesteps (ppo)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threshold", type=float, default=0.5)
    parser.add_argument("--bc2l-per-pair", action="store_true", help="BC2L classifies pairs, not trajectories")
    args = parser.parse_args()
    th.set_num_threads(1)  # tiny nets: more threads only contend
    budget = args.iterations if args.solver == "pilag" else args.timesteps
    for algo in args.algos:
        report(run(algo, args.map, args.solver, budget, args.seed, args.bc2l_per_pair), args.threshold)


if __name__ == "__main__":
    main()
