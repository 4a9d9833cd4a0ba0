"""Policy iteration with a Lagrange multiplier (PI-Lag, Algorithm 2 of Liu et al., ICLR 2023) for tabular CMDPs."""

import io
import json
import pathlib
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.env_util import is_wrapped
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv

from sb3_icrl.common.utils import atomic_write_bytes, read_npz

# Two action values closer than this are a tie: keeps the policy from flipping between equal actions
_TIE_TOLERANCE = 1e-10
#: The arrays :meth:`PILagrangian.save` writes besides its ``params`` and ``state``
PILAGRANGIAN_ARRAYS = ("policy_table", "q_values", "values", "transitions", "rewards", "cost_table")


class PILagrangian:
    """
    Policy iteration on the Lagrangian ``R - lambda * C`` of a tabular CMDP, with gradient ascent on
    ``lambda >= 0`` (Liu et al., ICLR 2023, Algorithm 2).

    Each iteration of :meth:`learn` (1) runs policy iteration to convergence for the current
    multiplier (exact policy evaluation by a linear solve, greedy improvement), (2) computes the
    policy's expected cost per episode ``J_c`` exactly from the tables over the episode's horizon,
    (3) updates ``lambda <- clip(lambda + lagrange_lr * (J_c - cost_budget), 0, lagrange_upper_bound)``.
    It stops when the policy and the multiplier no longer change.

    Plain policy iteration is ``lagrange_init=0.0, lagrange_lr=0.0`` (multiplier fixed at 0).

    The environment must expose the tables of :class:`~sb3_icrl.envs.GridWorldEnv`: ``P[s, a, s']``,
    ``R[s, a]``, ``C[s, a]`` (true expected cost) and ``start_state``. To plan with a learned cost instead
    of the true one (ICRL), pass ``cost_table`` or call :meth:`set_cost_table`.

    :param env: The environment (a gymnasium env, a VecEnv, or a registered id such as ``"sb3_icrl/GridWorld-v0"``)
    :param gamma: Discount factor, in [0, 1)
    :param cost_budget: Budget on the expected (undiscounted) number of costly steps per episode
    :param lagrange_init: Initial multiplier
    :param lagrange_lr: Step size of the multiplier's gradient ascent (0: multiplier fixed)
    :param lagrange_upper_bound: Optional upper bound on the multiplier
    :param cost_table: Cost ``C[s, a]`` to plan with; ``None``: the environment's true cost table
    :param horizon: Episode length used for ``J_c``; ``None``: the environment's ``max_episode_steps``
    :param max_policy_iterations: Cap on the policy-iteration sweeps per multiplier value
    :param seed: Seed of the tie-breaking in ``predict(deterministic=False)``
    :param verbose: 1 to print each multiplier update
    """

    def __init__(
        self,
        env: gym.Env | VecEnv | str,
        gamma: float = 0.99,
        cost_budget: float = 0.0,
        lagrange_init: float = 1.0,
        lagrange_lr: float = 0.01,
        lagrange_upper_bound: float | None = None,
        cost_table: np.ndarray | None = None,
        horizon: int | None = None,
        max_policy_iterations: int = 1000,
        seed: int | None = None,
        verbose: int = 0,
    ):
        if not 0.0 <= gamma < 1.0:
            raise ValueError(f"`gamma` must be in [0, 1) for policy evaluation to be well posed, got {gamma}.")
        for name, value in (("cost_budget", cost_budget), ("lagrange_init", lagrange_init), ("lagrange_lr", lagrange_lr)):
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"`{name}` must be a finite float >= 0, got {value!r}.")
        if lagrange_upper_bound is not None and not lagrange_upper_bound >= lagrange_init:
            raise ValueError(f"`lagrange_upper_bound` ({lagrange_upper_bound}) must be >= `lagrange_init` ({lagrange_init}).")
        if max_policy_iterations < 1:
            raise ValueError(f"`max_policy_iterations` must be >= 1, got {max_policy_iterations}.")
        self.gamma = float(gamma)
        self.cost_budget = float(cost_budget)
        self.lagrange_init = float(lagrange_init)
        self.lagrange_lr = float(lagrange_lr)
        self.lagrange_upper_bound = None if lagrange_upper_bound is None else float(lagrange_upper_bound)
        self.max_policy_iterations = int(max_policy_iterations)
        self.seed = seed
        self.verbose = verbose

        self.env: VecEnv | None = None
        self.transitions = np.zeros((0, 0, 0))
        self.rewards = np.zeros((0, 0))
        self.cost_table = np.zeros((0, 0))
        self.start_state = 0
        self.horizon = 0
        self.set_env(env, horizon=horizon)
        if cost_table is not None:
            self.set_cost_table(cost_table)

        self.lagrange_multiplier = self.lagrange_init
        n_states, n_actions = self.rewards.shape
        self.policy_table = np.zeros(n_states, dtype=np.int64)
        self.q_values = np.zeros((n_states, n_actions))
        self.values = np.zeros(n_states)
        self.num_iterations = 0
        #: One dict per multiplier update: iteration, lagrange_multiplier (used), episode_cost, episode_reward
        self.history: list[dict[str, float]] = []
        self._rng = np.random.default_rng(seed)

    # ------------------------------------------------------------------ environment and tables

    def set_env(self, env: gym.Env | VecEnv | str, horizon: int | None = None) -> None:
        """
        Set the environment and read its tables (the cost table too, unless one was set by hand).

        :param env: A gymnasium env, a VecEnv, or a registered id
        :param horizon: Episode length for ``J_c``; ``None``: the environment's ``max_episode_steps``
        """
        if isinstance(env, str):
            env = gym.make(env)
        if not isinstance(env, VecEnv):
            monitored = env if is_wrapped(env, Monitor) else Monitor(env)
            env = DummyVecEnv([lambda: monitored])
        tables: dict[str, Any] = {}
        for name in ("P", "R", "C", "start_state"):
            try:
                tables[name] = env.get_attr(name, indices=0)[0]
            except AttributeError as error:
                raise TypeError(
                    f"PILagrangian plans on tables: the environment must expose `{name}` "
                    "(like sb3_icrl.envs.GridWorldEnv: P[s, a, s'], R[s, a], C[s, a], start_state)."
                ) from error
        transitions = np.asarray(tables["P"], dtype=np.float64)
        rewards = np.asarray(tables["R"], dtype=np.float64)
        n_states, n_actions = rewards.shape
        if transitions.shape != (n_states, n_actions, n_states):
            raise ValueError(f"The environment's P has shape {transitions.shape}, expected {(n_states, n_actions, n_states)}.")
        if self.rewards.size > 0 and self.rewards.shape != rewards.shape:
            raise ValueError(f"The new environment has {rewards.shape} (states, actions), the model {self.rewards.shape}.")
        if horizon is None:
            spec = env.get_attr("spec", indices=0)[0]
            horizon = getattr(spec, "max_episode_steps", None) or self.horizon
        if horizon is None or horizon < 1:
            raise ValueError("Give `horizon` (episode length): the environment has no `max_episode_steps`.")
        keep_cost = getattr(self, "_custom_cost", False)
        self.env = env
        self.transitions, self.rewards = transitions, rewards
        self.start_state = int(tables["start_state"])
        self.horizon = int(horizon)
        if not keep_cost:
            self.cost_table = np.asarray(tables["C"], dtype=np.float64)
            self._custom_cost = False

    def get_env(self) -> VecEnv | None:
        """
        :return: The environment (a VecEnv), ``None`` for a model loaded without one
        """
        return self.env

    def set_cost_table(self, cost_table: np.ndarray) -> None:
        """
        Plan with this cost instead of the environment's true cost (e.g. a learned constraint).

        :param cost_table: Expected cost of each state-action pair, shape ``(n_states, n_actions)``
        """
        cost_table = np.asarray(cost_table, dtype=np.float64)
        if cost_table.shape != self.rewards.shape or not np.all(np.isfinite(cost_table)):
            raise ValueError(f"`cost_table` must be a finite array of shape {self.rewards.shape}, got {cost_table.shape}.")
        self.cost_table = cost_table
        self._custom_cost = True

    # ------------------------------------------------------------------ planning

    def _policy_matrices(self, policy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        states = np.arange(len(policy))
        return (
            self.transitions[states, policy],
            self.rewards[states, policy],
            self.cost_table[states, policy],
            states,
        )

    def _evaluate(self, policy: np.ndarray, multiplier: float) -> np.ndarray:
        # Exact policy evaluation: V = (I - gamma P_pi)^-1 (r_pi - lambda c_pi)
        p_pi, r_pi, c_pi, states = self._policy_matrices(policy)
        return np.linalg.solve(np.eye(len(states)) - self.gamma * p_pi, r_pi - multiplier * c_pi)

    def _policy_iteration(self, multiplier: float) -> None:
        policy = self.policy_table.copy()
        lagrangian_reward = self.rewards - multiplier * self.cost_table
        for _ in range(self.max_policy_iterations):
            values = self._evaluate(policy, multiplier)
            q_values = lagrangian_reward + self.gamma * self.transitions @ values
            best = q_values.max(axis=1)
            # Keep the current action unless another one is strictly better
            keep = q_values[np.arange(len(policy)), policy] >= best - _TIE_TOLERANCE
            new_policy = np.where(keep, policy, q_values.argmax(axis=1))
            stable = np.array_equal(new_policy, policy)
            policy = new_policy
            if stable:
                break
        self.policy_table, self.values, self.q_values = policy, values, q_values

    def episode_returns(self, policy: np.ndarray | None = None) -> tuple[float, float]:
        """
        Expected undiscounted reward and cost of one episode from the start state, computed from the tables.

        :param policy: Deterministic policy (action per state); ``None``: the current one
        :return: ``(episode_reward, episode_cost)`` over :attr:`horizon` steps (the cost is that of the planning table)
        """
        p_pi, r_pi, c_pi, _ = self._policy_matrices(self.policy_table if policy is None else policy)
        distribution = np.zeros(len(r_pi))
        distribution[self.start_state] = 1.0
        episode_reward = episode_cost = 0.0
        for _ in range(self.horizon):
            episode_reward += distribution @ r_pi
            episode_cost += distribution @ c_pi
            distribution = distribution @ p_pi
        return float(episode_reward), float(episode_cost)

    def learn(self, total_iterations: int = 1000, tol: float = 1e-8) -> "PILagrangian":
        """
        Alternate policy iteration and multiplier updates.

        :param total_iterations: Maximum number of multiplier updates
        :param tol: Stop once the policy is unchanged and the multiplier moved by less than this
        :return: The trained model
        """
        if self.env is None:
            raise ValueError("This model has no environment: call `set_env(env)` before `learn()`.")
        if isinstance(total_iterations, bool) or not isinstance(total_iterations, (int, np.integer)) or total_iterations < 1:
            raise ValueError(f"`total_iterations` must be an integer >= 1 (multiplier updates), got {total_iterations!r}.")
        if not tol >= 0:  # NaN too
            raise ValueError(f"`tol` must be >= 0, got {tol!r}.")
        for _ in range(total_iterations):
            old_policy = self.policy_table.copy()
            self._policy_iteration(self.lagrange_multiplier)
            episode_reward, episode_cost = self.episode_returns()
            multiplier = self.lagrange_multiplier + self.lagrange_lr * (episode_cost - self.cost_budget)
            upper = np.inf if self.lagrange_upper_bound is None else self.lagrange_upper_bound
            new_multiplier = float(np.clip(multiplier, 0.0, upper))
            self.history.append(
                {
                    "iteration": self.num_iterations,
                    "lagrange_multiplier": self.lagrange_multiplier,
                    "episode_cost": episode_cost,
                    "episode_reward": episode_reward,
                }
            )
            if self.verbose >= 1:
                print(f"PI-Lag {self.num_iterations}: {self.history[-1]}")
            self.num_iterations += 1
            converged = np.array_equal(old_policy, self.policy_table) and abs(new_multiplier - self.lagrange_multiplier) <= tol
            self.lagrange_multiplier = new_multiplier
            if converged:
                break
        return self

    # ------------------------------------------------------------------ acting

    def predict(
        self,
        observation: int | np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """
        Actions for a state index or a batch of them (SB3's signature; ``state`` and ``episode_start`` are unused).

        :param observation: State index, or an array of them (one per environment)
        :param state: Unused (no recurrent state)
        :param episode_start: Unused
        :param deterministic: ``True``: the policy's action; ``False``: uniform among the optimal (tied) actions
        :return: The actions, with the observation's shape, and ``None``
        """
        obs = np.asarray(observation)
        n_states, _ = self.q_values.shape
        if not np.issubdtype(obs.dtype, np.integer) and not (
            np.issubdtype(obs.dtype, np.floating) and np.all(obs == np.round(obs))
        ):
            raise ValueError(f"PILagrangian expects state indices (integers in 0..{n_states - 1}), got {observation!r}.")
        states = obs.astype(np.int64)
        if np.any(states < 0) or np.any(states >= n_states):
            raise ValueError(f"State indices must be in 0..{n_states - 1}, got {observation!r}.")
        if deterministic:
            return np.asarray(self.policy_table[states]), state
        q_values = self.q_values[states.reshape(-1)]
        optimal = q_values >= q_values.max(axis=1, keepdims=True) - _TIE_TOLERANCE
        # Random tie-break: the optimal action with the largest uniform key
        keys = np.where(optimal, self._rng.random(optimal.shape), -1.0)
        return keys.argmax(axis=1).reshape(states.shape), state

    # ------------------------------------------------------------------ persistence

    def _params(self) -> dict[str, Any]:
        return {
            "gamma": self.gamma,
            "cost_budget": self.cost_budget,
            "lagrange_init": self.lagrange_init,
            "lagrange_lr": self.lagrange_lr,
            "lagrange_upper_bound": self.lagrange_upper_bound,
            "horizon": self.horizon,
            "max_policy_iterations": self.max_policy_iterations,
            "seed": self.seed,
            "verbose": self.verbose,
        }

    def save(self, path: str | pathlib.Path) -> None:
        """
        Save the model to a ``.npz`` archive, atomically (a temporary file replaced into place).

        :param path: Where to write (used as given, no suffix added)
        """
        path = pathlib.Path(path)
        state = {
            "lagrange_multiplier": self.lagrange_multiplier,
            "num_iterations": self.num_iterations,
            "start_state": self.start_state,
            "custom_cost": self._custom_cost,
            "history": self.history,
        }
        buffer = io.BytesIO()
        np.savez(
            buffer,
            params=np.array(json.dumps(self._params())),
            state=np.array(json.dumps(state)),
            policy_table=self.policy_table,
            q_values=self.q_values,
            values=self.values,
            transitions=self.transitions,
            rewards=self.rewards,
            cost_table=self.cost_table,
        )
        atomic_write_bytes(path, buffer.getvalue())

    @classmethod
    def load(cls, path: str | pathlib.Path, env: gym.Env | VecEnv | str | None = None) -> "PILagrangian":
        """
        Load a model written by :meth:`save`.

        :param path: The saved file
        :param env: Optional environment to continue training on (must have the same numbers of states and actions)
        :return: The model
        :raises ValueError: When the file is cut short, damaged or not one that :meth:`save` wrote
        """
        # numpy's errors on a damaged file name neither the file nor what it was read as
        arrays = read_npz(path)  # (a ValueError naming the file when it is cut short)
        missing = [key for key in ("params", "state", *PILAGRANGIAN_ARRAYS) if key not in arrays]
        if missing:
            raise ValueError(f"{path} is not a model saved by PILagrangian.save: it lacks {missing}.")
        try:
            params = json.loads(str(arrays.pop("params")))
            state = json.loads(str(arrays.pop("state")))
        except ValueError as error:
            raise ValueError(f"{path} is damaged: its params or state is not JSON ({error}).") from error
        model = cls.__new__(cls)
        for key, value in params.items():
            setattr(model, key, value)
        model.env = None
        model.transitions, model.rewards, model.cost_table = arrays["transitions"], arrays["rewards"], arrays["cost_table"]
        model.policy_table, model.q_values, model.values = arrays["policy_table"], arrays["q_values"], arrays["values"]
        model.lagrange_multiplier = float(state["lagrange_multiplier"])
        model.num_iterations = int(state["num_iterations"])
        model.start_state = int(state["start_state"])
        model.history = state["history"]
        model._custom_cost = bool(state["custom_cost"])
        model._rng = np.random.default_rng(model.seed)
        if env is not None:
            model.set_env(env, horizon=model.horizon)
        return model
