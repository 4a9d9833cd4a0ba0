"""
Recover a grid-world constraint from the shipped expert demonstrations and save the learned map beside the true one.

MECL or VICRL learn the constraint with the exact PI-Lagrangian forward solver (:func:`sb3_icrl.icrl.tabular.tabular_icrl`,
as ``benchmarks/icrl_gridworld.py`` and the paper do on their grid worlds); the constraint net sees the cell only, so
its cost is a map of cells. Prints the learned map beside the true one, with precision and recall of the recovered
unsafe cells against the true ones, for cells costing more than ``--threshold`` and for cells costing more than the
dearest cell on the expert's path (what a cost-minimising planner avoids). Cells the expert never comes near are
expected among the recovered ones: nothing in the data says they are safe. ``--nominal-buffer`` keeps the planner's
trajectories of all iterations for the constraint updates (the reference code's grid-world setting); without it MECL's
regulariser keeps every cost low and only VICRL's map shows some contrast. About half a minute on 2 busy CPU cores.
``train.py --algo mecl --env GridWorldBigSquare-v0`` runs the same loop through the zoo (``forward_solver:
pi_lagrangian``)::

    python examples/recover_grid_constraint.py --algo mecl --env GridWorldBigSquare-v0 -o docs/images/grid_constraint.png
    python examples/recover_grid_constraint.py --algo vicrl --nominal-buffer 0 -o vicrl.png
"""

import argparse

import gymnasium as gym
import torch as th

from sb3_icrl.constraints import BetaFeasibilityNet, FeasibilityNet
from sb3_icrl.data import load_demonstrations
from sb3_icrl.icrl import ICRLTrainer
from sb3_icrl.icrl.tabular import tabular_icrl
from sb3_icrl.mecl import MECLTrainer
from sb3_icrl.plots.figures import grid_constraint_figure, grid_cost_map, save_figure
from sb3_icrl.vicrl import VICRLTrainer
from sb3_icrl.zoo.summary import demonstration_cells, grid_constraint_report

#: algo -> (trainer class, constraint net class)
ALGOS: dict[str, tuple[type[ICRLTrainer], type]] = {
    "mecl": (MECLTrainer, FeasibilityNet),
    "vicrl": (VICRLTrainer, BetaFeasibilityNet),
}


def main() -> None:
    """Learn the constraint, print precision and recall, save the learned-vs-true figure."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algo", default="mecl", choices=list(ALGOS))
    parser.add_argument("--env", default="GridWorldBigSquare-v0", help="a grid world with shipped demonstrations")
    parser.add_argument("--iterations", type=int, default=20, help="plan-then-update ICRL iterations")
    parser.add_argument("--nominal-buffer", type=int, default=500, help="nominal trajectories kept (0: none)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threshold", type=float, default=0.5, help="cost above which a cell is recovered unsafe")
    parser.add_argument("-o", "--output", default="grid_constraint.png", help="image file to write")
    args = parser.parse_args()
    th.set_num_threads(1)  # tiny nets: more threads only contend
    th.manual_seed(args.seed)

    trainer_class, net_class = ALGOS[args.algo]
    env = gym.make(f"sb3_icrl/{args.env}")
    demonstrations = load_demonstrations(args.env)
    net = net_class.from_spaces(
        env.observation_space, env.action_space, hidden_sizes=[64], normalize_input=False, use_action=False
    )
    tabular_icrl(
        trainer_class,
        net,
        env,
        demonstrations,
        n_iterations=args.iterations,
        constraint_learning_rate=1e-2,
        constraint_steps=10,
        nominal_buffer_size=args.nominal_buffer,
        seed=args.seed,
    )

    grid = env.unwrapped
    costs = grid_cost_map(net, grid)
    visited = demonstration_cells(demonstrations, grid.n_rows, grid.n_cols)
    # The map train.py prints at the end of a grid-world run: learned beside true, precision and recall
    report, _, _ = grid_constraint_report(
        costs, grid.unsafe_mask, grid.start_cell, grid.goal_cell, visited, threshold=args.threshold
    )
    print(f"{args.algo.upper()} on {args.env}:\n{report}")

    title = (
        f"{args.algo.upper()} on {args.env}: PI-Lagrangian solver, {args.iterations} iterations, "
        f"nominal buffer {args.nominal_buffer}, seed {args.seed}"
    )
    figure = grid_constraint_figure(costs, grid.unsafe_mask, grid.start_cell, grid.goal_cell, visited=visited, title=title)
    print(f"saved {save_figure(figure, args.output)}")


if __name__ == "__main__":
    main()
