"""
ICRL on a tabular env (the grid world) with PI-Lagrangian as the forward solver, as the paper does for its grid
worlds ("we replace the policy gradient algorithm in the baseline algorithms with policy iteration"): the constraint
model is the same and is updated by the same :class:`~sb3_icrl.icrl.ICRLTrainer` as with PPO-Lagrangian; only the
policy step is exact planning on the learned cost table.
"""

from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th

from sb3_icrl.constraints.networks import BetaFeasibilityNet, _ConstraintNet
from sb3_icrl.data.serialize import check_spaces
from sb3_icrl.data.types import Demonstrations
from sb3_icrl.icrl.recorder import NominalData, NominalTrajectory
from sb3_icrl.icrl.trainer import ICRLTrainer
from sb3_icrl.pi_lagrangian import PILagrangian


@dataclass
class TabularICRLResult:
    """
    :param planner: The PI-Lagrangian policy planned on the last learned cost
    :param constraint_net: The learned constraint model
    :param trainer: The trainer (holds the optimizer and the number of updates)
    :param history: One dict per iteration: the trainer's statistics plus the planner's episode cost and reward
    """

    planner: PILagrangian
    constraint_net: _ConstraintNet
    trainer: ICRLTrainer
    history: list[dict[str, float]] = field(default_factory=list)


def precision_recall(recovered: np.ndarray, true_unsafe: np.ndarray) -> tuple[float, float]:
    """
    How well a recovered set of unsafe cells matches the true one (evaluation only).

    :param recovered: Boolean map of the cells recovered as unsafe
    :param true_unsafe: Boolean map of the truly unsafe cells
    :return: Precision (0 when nothing is recovered) and recall
    """
    hits = int(np.sum(recovered & true_unsafe))
    return hits / max(int(recovered.sum()), 1), hits / int(true_unsafe.sum())


def cost_table(constraint_net: _ConstraintNet, n_states: int, n_actions: int) -> np.ndarray:
    """
    The learned cost of every state-action pair (VICRL: of the Beta's mean, a planning table must be deterministic).

    :param constraint_net: A constraint model for ``Discrete`` observations and actions
    :param n_states: Number of states
    :param n_actions: Number of actions
    :return: ``C[s, a]``, shape ``(n_states, n_actions)``
    """
    state_grid, action_grid = np.meshgrid(np.arange(n_states), np.arange(n_actions), indexing="ij")
    states, actions = state_grid.ravel(), action_grid.ravel()
    if isinstance(constraint_net, BetaFeasibilityNet):
        costs = 1.0 - constraint_net.predict_feasibility(states, actions, cost_mode="mean")
    else:
        costs = constraint_net.cost(states, actions)
    return np.asarray(costs, dtype=np.float64).reshape(n_states, n_actions)


def rollout(
    planner: PILagrangian, env: gym.Env, n_trajectories: int, deterministic: bool, seed: int
) -> list[NominalTrajectory]:
    """
    Run the planner in the env and keep the raw pairs of each episode (nothing else: no reward, no true cost).

    :param planner: The policy
    :param env: The env (with its time limit)
    :param n_trajectories: Episodes to run
    :param deterministic: ``False``: random tie-breaks among equally good actions (some exploration)
    :param seed: Seed of the first reset
    :return: The trajectories
    """
    trajectories = []
    for index in range(n_trajectories):
        obs, _ = env.reset(seed=seed + index)
        observations, actions = [], []
        done = False
        while not done:
            action = int(planner.predict(np.array([obs]), deterministic=deterministic)[0][0])
            observations.append(obs)
            actions.append(action)
            obs, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
        trajectories.append(NominalTrajectory(np.array(observations), np.array(actions)))
    return trajectories


def tabular_icrl(
    trainer_class: type[ICRLTrainer],
    constraint_net: _ConstraintNet,
    env: gym.Env,
    demonstrations: Demonstrations,
    n_iterations: int = 30,
    constraint_learning_rate: float = 1e-2,
    constraint_steps: int = 10,
    n_nominal_trajectories: int | None = None,
    trainer_kwargs: dict[str, Any] | None = None,
    planner_kwargs: dict[str, Any] | None = None,
    deterministic_rollouts: bool = False,
    nominal_buffer_size: int = 0,
    seed: int = 0,
) -> TabularICRLResult:
    """
    Alternate exact planning on the learned cost (:class:`~sb3_icrl.PILagrangian`) and constraint updates on expert
    vs the planner's own trajectories.

    :param trainer_class: ``BC2LTrainer``, ``MECLTrainer``, ``VICRLTrainer`` (or any :class:`ICRLTrainer`)
    :param constraint_net: The constraint model, for the env's ``Discrete`` spaces (fitted normaliser, if any)
    :param env: A tabular env with its time limit (``gymnasium.make("sb3_icrl/GridWorldWall-v0")``)
    :param demonstrations: Expert demonstrations for that env (checked against its spaces)
    :param n_iterations: Plan-then-update iterations
    :param constraint_learning_rate: Adam learning rate of the constraint model
    :param constraint_steps: Passes over the nominal data per update
    :param n_nominal_trajectories: Planner episodes per iteration (default: the number of expert trajectories)
    :param trainer_kwargs: Further arguments of the trainer (``regularizer_coef``, ``prior``...)
    :param planner_kwargs: Arguments of ``PILagrangian`` (default: budget 0, as the reference)
    :param deterministic_rollouts: Whether the planner breaks ties deterministically in the rollouts
    :param nominal_buffer_size: 0: each update uses the planner's latest trajectories only. ``> 0``: keep up to this
        many nominal trajectories of all iterations so far (a random one is dropped when full) and update on
        ``n_nominal_trajectories`` of them drawn at random with replacement, the latest included in the draw; the
        reference code's grid-world setting (``use_buffer``, ``store_sample_rollouts``). Without it the constraint
        model only sees the planner's current path, so a cell it was taught to avoid is not labelled again
    :param seed: Seed of the planner, the rollouts and the minibatches
    :return: The planner on the final cost, the constraint model, the trainer and the per-iteration history
    """
    if n_iterations < 1:
        raise ValueError(f"`n_iterations` must be >= 1, got {n_iterations}.")
    if nominal_buffer_size < 0:
        raise ValueError(f"`nominal_buffer_size` must be >= 0 (0: no buffer), got {nominal_buffer_size}.")
    transitions = demonstrations.transitions
    check_spaces(transitions.obs, transitions.acts, env, demonstrations.metadata)
    n_nominal = len(demonstrations) if n_nominal_trajectories is None else n_nominal_trajectories
    trainer = trainer_class(
        constraint_net,
        th.optim.Adam(constraint_net.parameters(), lr=constraint_learning_rate),
        transitions.obs,
        transitions.acts,
        None,
        None,
        update_every=1,
        constraint_steps=constraint_steps,
        n_nominal_trajectories=n_nominal,
        seed=seed,
        **(trainer_kwargs or {}),
    )
    planner = PILagrangian(env, seed=seed, **(planner_kwargs or {}))
    n_states, n_actions = planner.rewards.shape
    # Absorbing states (the goal) end the real episode: a learned cost there is never paid, so it must not be planned
    absorbing = np.all(planner.transitions[np.arange(n_states), :, np.arange(n_states)] == 1.0, axis=1)

    def planning_costs() -> np.ndarray:
        costs = cost_table(constraint_net, n_states, n_actions)
        costs[absorbing] = 0.0
        return costs

    buffer: list[NominalTrajectory] = []
    buffer_rng = np.random.default_rng(seed)
    history = []
    for iteration in range(n_iterations):
        planner.set_cost_table(planning_costs())
        planner.learn()
        episode_reward, episode_cost = planner.episode_returns()
        trajectories = rollout(planner, env, n_nominal, deterministic_rollouts, seed + iteration * n_nominal)
        if nominal_buffer_size > 0:
            for trajectory in trajectories:
                if len(buffer) >= nominal_buffer_size:
                    buffer.pop(int(buffer_rng.integers(len(buffer))))
                buffer.append(trajectory)
            trajectories = [buffer[index] for index in buffer_rng.integers(0, len(buffer), size=n_nominal)]
        stats = trainer.update(NominalData.from_trajectories(trajectories))
        history.append({"iteration": iteration, "planned_reward": episode_reward, "planned_cost": episode_cost, **stats})
    planner.set_cost_table(planning_costs())
    planner.learn()
    return TabularICRLResult(planner, constraint_net, trainer, history)
