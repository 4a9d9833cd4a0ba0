"""
ICRL on a tabular env (the grid world) with PI-Lagrangian as the forward solver, as the paper does for its grid
worlds ("we replace the policy gradient algorithm in the baseline algorithms with policy iteration"): the constraint
model is the same and is updated by the same :class:`~sb3_icrl.icrl.ICRLTrainer` as with PPO-Lagrangian; only the
policy step is exact planning on the learned cost table.

:func:`tabular_icrl` runs the loop on its own; :func:`learn_with_planner` runs it for a built ICRL model of the zoo
(``forward_solver: pi_lagrangian`` in ``zoo_hyperparams/<algo>.yml``), with SB3's callbacks, so ``train.py`` writes its
usual run folder (evaluations, checkpoints, the model whose policy acts as planned).
"""

import functools
import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th

from sb3_icrl.constraints.networks import BetaFeasibilityNet, CostNet, _ConstraintNet
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
    The learned cost of every state-action pair (VICRL: of the Beta's mean, a planning table must be deterministic;
    IRL-Plus: floored at 0).

    :param constraint_net: A constraint model for ``Discrete`` observations and actions
    :param n_states: Number of states
    :param n_actions: Number of actions
    :return: ``C[s, a]``, shape ``(n_states, n_actions)``
    """
    state_grid, action_grid = np.meshgrid(np.arange(n_states), np.arange(n_actions), indexing="ij")
    states, actions = state_grid.ravel(), action_grid.ravel()
    if isinstance(constraint_net, BetaFeasibilityNet):
        costs = 1.0 - constraint_net.predict_feasibility(states, actions, cost_mode="mean")
    elif isinstance(constraint_net, CostNet):  # IRL-Plus: the cost its forward learner is charged, as IRLPlusPPO's
        costs = constraint_net.paid_cost(states, actions)
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


def mix_with_buffer(trajectories: list, buffer: list, buffer_size: int, n_nominal: int, rng: np.random.Generator) -> list:
    """
    Add new trajectories to a bounded buffer of earlier ones (a random one makes room once it is full) and draw the
    update's nominal data from the whole buffer, with replacement.

    :param trajectories: The newest trajectories
    :param buffer: The buffer, changed in place
    :param buffer_size: Most trajectories the buffer keeps
    :param n_nominal: Trajectories drawn for the update
    :param rng: Random generator of the buffer
    :return: The drawn trajectories
    """
    for trajectory in trajectories:
        if len(buffer) >= buffer_size:
            buffer.pop(int(rng.integers(len(buffer))))
        buffer.append(trajectory)
    return [buffer[index] for index in rng.integers(0, len(buffer), size=n_nominal)]


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
            trajectories = mix_with_buffer(trajectories, buffer, nominal_buffer_size, n_nominal, buffer_rng)
        stats = trainer.update(NominalData.from_trajectories(trajectories))
        history.append({"iteration": iteration, "planned_reward": episode_reward, "planned_cost": episode_cost, **stats})
    planner.set_cost_table(planning_costs())
    planner.learn()
    return TabularICRLResult(planner, constraint_net, trainer, history)


# ---------------------------------------------------------------------- the zoo's forward solver for tabular envs

#: ``forward_solver`` values of the zoo's hyper-parameter files: the algorithm's own policy-gradient learner, or exact
#: planning on the learned cost (tabular envs only)
FORWARD_SOLVERS = ("policy_gradient", "pi_lagrangian")
#: Keys of ``planner_kwargs`` read by :func:`learn_with_planner` itself; the others go to :class:`PILagrangian`
PLANNER_LOOP_KEYS = ("nominal_buffer_size", "label_trajectories", "distill_steps", "planner_iterations")


def learned_planning_costs(model: Any, n_states: int, n_actions: int) -> np.ndarray:
    """
    The cost table a planner minimises for an ICRL model: the learned cost ``1 - phi`` (BC2L, MECL, VICRL), or for
    GACL ``-log D``, so that planning on ``R - 1 * C`` is planning on GACL's reward ``r + log D``.

    :param model: An ICRL model (its ``constraint_net``; GACL's ``log_d_eps``)
    :param n_states: Number of states
    :param n_actions: Number of actions
    :return: ``C[s, a]``, shape ``(n_states, n_actions)``
    """
    costs = cost_table(model.constraint_net, n_states, n_actions)
    if hasattr(model, "log_d_eps"):  # GACL: D is the feasibility, its reward adds log D
        return -np.log(np.clip(1.0 - costs, model.log_d_eps, 1.0))
    return costs


def absorbing_states(planner: PILagrangian) -> np.ndarray:
    """
    :param planner: A planner with its transition table
    :return: Boolean mask of the states no action leaves (the goal): a learned cost there is never paid
    """
    n_states = planner.rewards.shape[0]
    return np.all(planner.transitions[np.arange(n_states), :, np.arange(n_states)] == 1.0, axis=1)


def distill_planner(policy: Any, planner: PILagrangian, max_steps: int = 2000, learning_rate: float = 1e-2) -> int:
    """
    Teach an SB3 policy over ``Discrete`` states to act as the planner: cross-entropy on every state's planned action,
    until the policy's deterministic action is the planner's in every state (the saved model then acts as planned, in
    ``enjoy`` and ``compare``). Only the actor (shared layers and action head) moves.

    :param policy: An SB3 ``ActorCriticPolicy`` for the planner's env
    :param planner: The planner
    :param max_steps: Most gradient steps
    :param learning_rate: Adam learning rate
    :return: The gradient steps taken
    :raises RuntimeError: When the policy still disagrees with the planner after ``max_steps``
    """
    n_states = planner.rewards.shape[0]
    states = th.as_tensor(np.arange(n_states), device=policy.device)
    targets = th.as_tensor(planner.policy_table, dtype=th.long, device=policy.device)
    parameters = [p for name, p in policy.named_parameters() if not name.startswith(("value_net", "cost_value_net"))]
    optimizer = th.optim.Adam(parameters, lr=learning_rate)
    for step in range(max_steps + 1):
        distribution = policy.get_distribution(policy.obs_to_tensor(states.cpu().numpy())[0])
        logits = distribution.distribution.logits
        # A margin keeps float noise from flipping a nearly tied action after saving and loading
        top2 = logits.topk(2, dim=1).values
        chosen = logits.gather(1, targets[:, None])[:, 0]
        if bool((chosen >= top2[:, 0]).all()) and bool((chosen - top2[:, 1] > 1.0).all()):
            return step
        if step == max_steps:
            break
        loss = th.nn.functional.cross_entropy(logits, targets)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    raise RuntimeError(f"The policy did not learn the planner's actions in {max_steps} steps: give it more capacity.")


def learn_with_planner(
    model: Any,
    total_timesteps: int,
    callback: Any = None,
    planner_kwargs: dict[str, Any] | None = None,
    tb_log_name: str = "run",
    reset_num_timesteps: bool = True,
    progress_bar: bool = False,
) -> PILagrangian:
    """
    Train an ICRL model of the zoo (BC2L, MECL, VICRL, GACL, IRL-Plus on PPO) with exact planning as its forward
    solver, on a tabular env: the paper's grid-world setting, driven like SB3's ``learn`` (steps counted in the env,
    callbacks called at every step, so evaluation, checkpoints and the progress bar work as usual).

    Each iteration plans with :class:`~sb3_icrl.PILagrangian` on the learned cost (GACL: on ``r + log D``, a cost
    ``-log D`` with the multiplier fixed at 1), runs the plan in the model's env (random tie-breaks) until
    ``n_nominal_trajectories`` episodes have ended, and updates the constraint model with the model's own trainer
    class and settings on expert vs those trajectories (none before the trainer's ``warmup_timesteps``, if it has
    one). A model that holds its multiplier fixed (:func:`held_multiplier`) plans with it held. The learner reads
    nothing but the raw states and actions of its episodes. After each planning, the model's policy is taught the
    planned actions (:func:`distill_planner`), so evaluations and the saved model act as planned; the multiplier of a
    Lagrangian model is set to the planner's.

    :param model: A built ICRL model with its env and demonstrations
    :param total_timesteps: Env steps to run
    :param callback: SB3 callback(s), as for ``learn``
    :param planner_kwargs: :class:`~sb3_icrl.PILagrangian` arguments (``gamma``, ``cost_budget``, ``lagrange_init``,
        ``lagrange_lr``...), plus ``nominal_buffer_size`` (as in :func:`tabular_icrl`; default 0),
        ``label_trajectories`` (BC2L and GACL classify whole trajectories, as the reference code on its grid worlds;
        default ``False``), ``planner_iterations`` (most multiplier updates per planning, ``PILagrangian.learn``'s
        ``total_iterations``; the planner and its multiplier carry over from one planning to the next; default 1000)
        and ``distill_steps`` (most steps of :func:`distill_planner`; default 2000)
    :param tb_log_name: TensorBoard run name
    :param reset_num_timesteps: Whether to reset the step count (``False``: a resumed run)
    :param progress_bar: Display a progress bar
    :return: The planner on the final learned cost
    """
    if model.demonstrations is None or model.constraint_net is None or model.constraint_optimizer is None:
        raise ValueError(f"{type(model).__name__} needs its demonstrations and constraint model to learn.")
    env = model.get_env()
    if env is None:
        raise ValueError("This model has no env: call `set_env(env)` first.")
    options = dict(planner_kwargs or {})
    loop = {key: options.pop(key) for key in PLANNER_LOOP_KEYS if key in options}
    buffer_size = int(loop.get("nominal_buffer_size", 0))
    if buffer_size < 0:
        raise ValueError(f"`nominal_buffer_size` must be >= 0 (0: no buffer), got {buffer_size}.")
    try:
        planner = PILagrangian(env, seed=model.seed, **options)
    except TypeError as error:
        raise ValueError(
            f"planner_kwargs: {error}. PILagrangian takes gamma, cost_budget, lagrange_init, lagrange_lr, "
            f"lagrange_upper_bound, horizon, max_policy_iterations; the loop takes {', '.join(PLANNER_LOOP_KEYS)}."
        ) from error
    n_states, n_actions = planner.rewards.shape
    absorbing = absorbing_states(planner)
    trainer_kwargs = {key: value for key, value in model.trainer_kwargs.items() if key != "budget_from_expert"}
    if loop.get("label_trajectories", False):
        if not _takes_episode_lengths(model.trainer_class):
            raise ValueError(f"label_trajectories is for BC2L and GACL, not {model.trainer_class.__name__}.")
        trainer_kwargs["expert_episode_lengths"] = [len(trajectory) for trajectory in model.demonstrations]
    n_nominal = model.n_nominal_trajectories or len(model.demonstrations)
    trainer = model.trainer_class(
        model.constraint_net,
        model.constraint_optimizer,
        model.expert_obs,
        model.expert_acts,
        None,
        None,
        update_every=1,
        constraint_steps=model.constraint_steps,
        batch_size=model.constraint_batch_size,
        n_nominal_trajectories=n_nominal,
        seed=model.seed,
        **trainer_kwargs,
    )
    trainer.n_updates = int(getattr(model, "n_constraint_updates", 0))

    total_timesteps, callback = model._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)
    callback.on_training_start(locals(), globals())
    recorder = model.recorder
    recorder.pop_trajectories()  # nothing from before this run
    buffer: list[NominalTrajectory] = []
    buffer_rng = np.random.default_rng(model.seed)
    # The planner reads no cost from the env: step below the learned-cost wrapper when nothing else sits above it
    stepper = recorder if model.env is model.constraint_wrapper else env
    planner_iterations = int(loop.get("planner_iterations", 1000))
    held = held_multiplier(model)
    if held is not None:  # GACL's r + log D, IRL-Plus's cost as a negative reward: no multiplier to learn
        planner.lagrange_multiplier, planner.lagrange_lr = held, 0.0
    # A trainer with a warm-up (IRL-Plus) leaves the cost at its start until then: the planner follows the reward alone
    warmup_timesteps = int(getattr(trainer, "warmup_timesteps", 0))
    observations = model._last_obs
    distilled: np.ndarray | None = None
    keep_going = True
    while keep_going and model.num_timesteps < total_timesteps:
        costs = learned_planning_costs(model, n_states, n_actions)
        costs[absorbing] = 0.0
        if trainer.n_updates == 0:
            # Before any update the learner is the nominal (unconstrained) planner: every shortest path ties, and the
            # random tie-breaks spread its first trajectories over all of them, not over the one an untrained net favours
            costs[:] = 0.0
        planner.set_cost_table(costs)
        planner.learn(total_iterations=planner_iterations)
        if distilled is None or not np.array_equal(distilled, planner.policy_table):
            distill_planner(model.policy, planner, max_steps=int(loop.get("distill_steps", 2000)))
            distilled = planner.policy_table.copy()
        _set_multiplier(model, planner.lagrange_multiplier)
        callback.on_rollout_start()
        finished = 0
        while finished < n_nominal and model.num_timesteps < total_timesteps:
            actions = planner.predict(np.asarray(observations).reshape(-1), deterministic=False)[0]
            observations, rewards, dones, infos = stepper.step(actions)
            model.num_timesteps += env.num_envs
            finished += int(np.sum(dones))
            callback.update_locals(locals())
            if not callback.on_step():
                keep_going = False
                break
        model._last_obs = observations
        trajectories = recorder.pop_trajectories(n_nominal)
        warmed_up = model.num_timesteps >= warmup_timesteps
        if keep_going and trajectories and warmed_up and model.num_timesteps <= total_timesteps:
            if buffer_size > 0:
                trajectories = mix_with_buffer(trajectories, buffer, buffer_size, n_nominal, buffer_rng)
            stats = trainer.update(NominalData.from_trajectories(trajectories))
            model.n_constraint_updates = trainer.n_updates
            planned_reward, planned_cost = planner.episode_returns()
            stats.update(
                planned_reward=planned_reward, planned_cost=planned_cost, planner_multiplier=planner.lagrange_multiplier
            )
            for key, value in stats.items():
                model.logger.record(f"constraint/{key}", value)
        callback.on_rollout_end()
        model.logger.record("time/total_timesteps", model.num_timesteps, exclude="tensorboard")
        model.logger.dump(model.num_timesteps)
    # The returned planner and the saved policy act on the final learned cost
    costs = learned_planning_costs(model, n_states, n_actions)
    costs[absorbing] = 0.0
    planner.set_cost_table(costs)
    planner.learn(total_iterations=planner_iterations)
    if distilled is None or not np.array_equal(distilled, planner.policy_table):
        distill_planner(model.policy, planner, max_steps=int(loop.get("distill_steps", 2000)))
    _set_multiplier(model, planner.lagrange_multiplier)
    callback.on_training_end()
    return planner


def held_multiplier(model: Any) -> float | None:
    """
    The multiplier a model holds fixed instead of learning it, which its planner must hold too: GACL's 1 (it plans on
    ``r + log D``), or the ``init`` of a model whose ``lagrange_kwargs`` has ``lr`` 0 (IRL-Plus: the cost as a negative
    reward).

    :param model: An ICRL model of the zoo
    :return: The value, or ``None`` when the model learns its multiplier
    """
    if hasattr(model, "log_d_eps"):
        return 1.0
    lagrange_kwargs = getattr(model, "lagrange_kwargs", None) or {}
    if "lr" in lagrange_kwargs and float(lagrange_kwargs["lr"]) == 0.0:
        return float(lagrange_kwargs.get("init", 1.0))
    return None


def held_planner_kwargs(multiplier: float) -> dict[str, float]:
    """
    The planner's arguments for a model that holds its multiplier (a planner learns its own from the budget otherwise).

    :param multiplier: The multiplier a planner must hold (see :func:`held_multiplier`)
    :return: The :class:`~sb3_icrl.PILagrangian` arguments that start it there and never move it
    """
    return dict(lagrange_init=float(multiplier), lagrange_lr=0.0)


def _set_multiplier(model: Any, value: float) -> None:
    """Give a Lagrangian model the planner's multiplier (both price a whole episode's cost against a budget of 0)."""
    multiplier = getattr(model, "lagrange_multiplier", None)
    if multiplier is None:
        return
    parameter = getattr(multiplier, "_multiplier", None)
    if isinstance(parameter, th.nn.Parameter):
        with th.no_grad():
            parameter.fill_(float(value))
    elif hasattr(multiplier, "_value"):
        multiplier._value = np.full_like(multiplier._value, float(value))


def _takes_episode_lengths(trainer_class: type) -> bool:
    """Whether a trainer labels whole trajectories when given the expert's episode lengths (BC2L's and GACL's do)."""
    return any(
        "expert_episode_lengths" in inspect.signature(vars(klass)["__init__"]).parameters
        for klass in trainer_class.__mro__
        if "__init__" in vars(klass)
    )


def learn_function(model: Any, solver: str, planner_kwargs: dict[str, Any] | None = None) -> Callable[..., Any]:
    """
    The ``learn`` a zoo run calls: the model's own, or :func:`learn_with_planner` bound to it.

    :param model: The model
    :param solver: One of :data:`FORWARD_SOLVERS` (see :func:`forward_solver`)
    :param planner_kwargs: The planner's settings (``pi_lagrangian`` only)
    :return: A function with ``learn``'s arguments
    """
    if solver == "pi_lagrangian":
        return functools.partial(learn_with_planner, model, planner_kwargs=planner_kwargs)
    return model.learn
