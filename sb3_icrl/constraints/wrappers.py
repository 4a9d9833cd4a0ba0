"""
VecEnv wrappers that rewrite what an ICRL learner sees: the learned cost in place of the true one, or GACL's
reward ``r + log D(s, a)``. The env's own (true) cost is moved to another info key, kept for evaluation only.

Both judge the pair ``(s, a)``: the raw observation the env returned *before* the step and the action sent to it.
They must therefore sit below any ``VecNormalize`` (``VecNormalize(LearnedCostVecEnvWrapper(venv, cost_fn))``).
"""

from collections.abc import Callable
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper, VecNormalize, unwrap_vec_wrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs, VecEnvStepReturn

from sb3_icrl.common.costs import CostFn, as_cost_array

#: ``discriminator(observations, actions) -> D``: ``D(s, a) in [0, 1]`` for each env, shape ``(n_envs,)``
DiscriminatorFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


def _copy_obs(obs: VecEnvObs) -> VecEnvObs:
    if isinstance(obs, dict):
        return {key: np.array(value, copy=True) for key, value in obs.items()}
    if isinstance(obs, tuple):
        return tuple(np.array(value, copy=True) for value in obs)
    return np.array(obs, copy=True)


class _StateActionVecEnvWrapper(VecEnvWrapper):
    """
    Keeps the raw observation before each step and the actions of that step, and moves the env's own cost from
    ``info[cost_info_key]`` to ``info[true_cost_info_key]``.

    :param venv: The env to wrap (without ``VecNormalize`` inside)
    :param cost_info_key: Info key of the env's own per-step cost
    :param true_cost_info_key: Info key where that cost is moved
    """

    def __init__(self, venv: VecEnv, cost_info_key: str = "cost", true_cost_info_key: str = "true_cost"):
        if unwrap_vec_wrapper(venv, VecNormalize) is not None:
            raise ValueError(
                f"{type(self).__name__} must judge the raw observations, but the env it wraps contains a VecNormalize. "
                f"Wrap the raw env first and put VecNormalize on top: VecNormalize({type(self).__name__}(venv, ...))."
            )
        if cost_info_key == true_cost_info_key:
            raise ValueError(f"`cost_info_key` and `true_cost_info_key` must differ, both are {cost_info_key!r}.")
        super().__init__(venv)
        self.cost_info_key = cost_info_key
        self.true_cost_info_key = true_cost_info_key
        self._obs_before_step: VecEnvObs | None = None
        self._step_actions: np.ndarray | None = None

    def reset(self) -> VecEnvObs:
        obs = self.venv.reset()
        self._obs_before_step = _copy_obs(obs)
        return obs

    def _remember_actions(self, actions: np.ndarray) -> None:
        if self._obs_before_step is None:
            raise RuntimeError(f"Call reset() on the {type(self).__name__} before step().")
        self._step_actions = np.array(actions, copy=True)

    def _hide_true_cost(self, infos: list[dict[str, Any]]) -> None:
        for env_idx, info in enumerate(infos):
            if self.cost_info_key in info:
                if self.true_cost_info_key in info:
                    raise ValueError(
                        f"Env index {env_idx} already reports info[{self.true_cost_info_key!r}]; moving its "
                        f"info[{self.cost_info_key!r}] there would overwrite it. Pass another `true_cost_info_key`."
                    )
                info[self.true_cost_info_key] = info.pop(self.cost_info_key)

    def _advance(self, obs: VecEnvObs) -> None:
        # After an auto-reset the returned obs is the new episode's first one: the next step starts from it
        self._obs_before_step = _copy_obs(obs)
        self._step_actions = None


class LearnedCostVecEnvWrapper(_StateActionVecEnvWrapper):
    """
    Replaces the env's cost with a learned one: at each step ``cost_fn(obs_before_step, actions)`` is computed once,
    batched over all envs, and written to ``info[cost_info_key]``; the env's own cost, if any, is moved to
    ``info[true_cost_info_key]`` (for evaluation; a learner reading ``cost_info_key`` never sees it).

    The cost is computed right after the actions are sent, so with a ``SubprocVecEnv`` it overlaps the env step.
    With ``cost_fn=None`` the wrapper only moves the env's cost away, for a learner that computes the learned cost
    itself (``PPOLagrangian``'s ``cost_fn``, one batch per rollout, as the ICRL algorithms do: faster than one call
    per step).

    :param venv: The env to wrap (without ``VecNormalize`` inside)
    :param cost_fn: ``cost_fn(observations, actions) -> costs`` (e.g. ``FeasibilityNet.cost``), observations as the
        env returned them, costs of shape ``(n_envs,)`` or ``(n_envs, n_costs)``; ``None``: write no cost
    :param n_costs: Number of learned costs per step
    :param cost_info_key: Info key of the cost the learner reads
    :param true_cost_info_key: Info key where the env's own cost is moved
    """

    def __init__(
        self,
        venv: VecEnv,
        cost_fn: CostFn | None,
        n_costs: int = 1,
        cost_info_key: str = "cost",
        true_cost_info_key: str = "true_cost",
    ):
        super().__init__(venv, cost_info_key=cost_info_key, true_cost_info_key=true_cost_info_key)
        if n_costs < 1:
            raise ValueError(f"`n_costs` must be >= 1, got {n_costs}.")
        self.n_costs = n_costs
        self.cost_fn: CostFn | None
        self.set_cost_fn(cost_fn)
        self._step_costs: np.ndarray | None = None

    def set_cost_fn(self, cost_fn: CostFn | None) -> None:
        """
        Use another learned cost from the next step on.

        :param cost_fn: The new cost function (``None``: write no cost, only move the env's own)
        """
        if cost_fn is not None and not callable(cost_fn):
            raise TypeError(f"`cost_fn` must be callable as cost_fn(observations, actions) -> costs, got {cost_fn!r}.")
        self.cost_fn = cost_fn

    def step_async(self, actions: np.ndarray) -> None:
        if self.cost_fn is None:
            if self._obs_before_step is None:
                raise RuntimeError(f"Call reset() on the {type(self).__name__} before step().")
            self.venv.step_async(actions)
            return
        self._remember_actions(actions)
        self.venv.step_async(actions)
        self._step_costs = as_cost_array(
            self.cost_fn(self._obs_before_step, self._step_actions),  # type: ignore[arg-type]
            self.num_envs,
            self.n_costs,
            "cost_fn",
        )

    def step_wait(self) -> VecEnvStepReturn:
        obs, rewards, dones, infos = self.venv.step_wait()
        self._hide_true_cost(infos)
        if self.cost_fn is None:
            self._advance(obs)
            return obs, rewards, dones, infos
        assert self._step_costs is not None, "step_wait() called without step_async()"
        for info, cost in zip(infos, self._step_costs, strict=True):
            info[self.cost_info_key] = float(cost[0]) if self.n_costs == 1 else cost.copy()
        self._step_costs = None
        self._advance(obs)
        return obs, rewards, dones, infos


class GACLRewardWrapper(_StateActionVecEnvWrapper):
    """
    GACL's reward ``r'(s, a) = r + log(clip(D(s, a), eps, 1))``, with ``D`` the discriminator (1: expert-like,
    0: not), evaluated once per step, batched over all envs, on the raw observation before the step and the action.
    The clip bounds the penalty at ``log(eps)`` where the paper's ``log D`` would be ``-inf``. The env's reward is
    kept in ``info[env_reward_info_key]``; its own cost, if any, is moved to ``info[true_cost_info_key]``.

    Since ``log D <= 0``, every step costs the learner something and an episode that ends early stops paying: a
    learner can prefer to end its episodes (fall, drive off the road). With ``termination_gamma`` set, the last step
    of a terminated (not time-limit truncated) episode also earns ``gamma / (1 - gamma) * log D`` of its own pair: as
    if the episode stayed in its final situation for ever, so ending it is worth what staying there would be.

    :param venv: The env to wrap (without ``VecNormalize`` inside)
    :param discriminator: ``discriminator(observations, actions) -> D`` of shape ``(n_envs,)``, values in [0, 1]
        (e.g. ``FeasibilityNet.predict_feasibility``)
    :param eps: Smallest ``D`` inside the log
    :param env_reward_info_key: Info key where the env's own reward is kept
    :param cost_info_key: Info key of the env's own cost
    :param true_cost_info_key: Info key where that cost is moved
    :param termination_gamma: The learner's discount factor, to charge terminated episodes as above; ``None``: no
        charge (the paper's GACL)
    """

    def __init__(
        self,
        venv: VecEnv,
        discriminator: DiscriminatorFn,
        eps: float = 1e-5,
        env_reward_info_key: str = "env_reward",
        cost_info_key: str = "cost",
        true_cost_info_key: str = "true_cost",
        termination_gamma: float | None = None,
    ):
        super().__init__(venv, cost_info_key=cost_info_key, true_cost_info_key=true_cost_info_key)
        self.termination_gamma = termination_gamma
        self.eps = eps
        self.env_reward_info_key = env_reward_info_key
        self.discriminator: DiscriminatorFn
        self.set_discriminator(discriminator)
        self._log_discriminator: np.ndarray | None = None

    @property
    def eps(self) -> float:
        """Smallest ``D`` inside the log, in (0, 1) (checked on every assignment)."""
        return self._eps

    @eps.setter
    def eps(self, eps: float) -> None:
        if not 0.0 < eps < 1.0:
            raise ValueError(f"`eps` must be in (0, 1), got {eps}: it is the smallest D inside log D.")
        self._eps = float(eps)

    @property
    def termination_gamma(self) -> float | None:
        """The discount that charges terminated episodes, in [0, 1), or ``None`` (checked on every assignment)."""
        return self._termination_gamma

    @termination_gamma.setter
    def termination_gamma(self, termination_gamma: float | None) -> None:
        if termination_gamma is not None and not 0.0 <= termination_gamma < 1.0:
            raise ValueError(f"`termination_gamma` must be in [0, 1) or None, got {termination_gamma}.")
        self._termination_gamma = termination_gamma

    def set_discriminator(self, discriminator: DiscriminatorFn) -> None:
        """
        Use another discriminator from the next step on.

        :param discriminator: The new discriminator
        """
        if not callable(discriminator):
            raise TypeError(
                f"`discriminator` must be callable as discriminator(observations, actions) -> D, got {discriminator!r}."
            )
        self.discriminator = discriminator

    def step_async(self, actions: np.ndarray) -> None:
        self._remember_actions(actions)
        self.venv.step_async(actions)
        values = np.asarray(self.discriminator(self._obs_before_step, self._step_actions), dtype=np.float32)  # type: ignore[arg-type]
        if values.shape not in ((self.num_envs,), (self.num_envs, 1)):
            raise ValueError(
                f"The discriminator returned shape {values.shape}, expected ({self.num_envs},): one D(s, a) per env."
            )
        values = values.reshape(self.num_envs)
        if not np.all((values >= 0.0) & (values <= 1.0)):
            raise ValueError(f"The discriminator must return probabilities in [0, 1], got {values.tolist()}.")
        self._log_discriminator = np.log(np.clip(values, self.eps, 1.0))

    def step_wait(self) -> VecEnvStepReturn:
        obs, rewards, dones, infos = self.venv.step_wait()
        assert self._log_discriminator is not None, "step_wait() called without step_async()"
        self._hide_true_cost(infos)
        for info, reward in zip(infos, rewards, strict=True):
            info[self.env_reward_info_key] = float(reward)
        log_discriminator = self._log_discriminator
        if self.termination_gamma is not None:
            terminated = np.array(
                [bool(done) and not info.get("TimeLimit.truncated", False) for done, info in zip(dones, infos, strict=True)]
            )
            log_discriminator = log_discriminator * np.where(terminated, 1.0 / (1.0 - self.termination_gamma), 1.0)
        new_rewards = (rewards + log_discriminator).astype(np.asarray(rewards).dtype, copy=False)
        self._log_discriminator = None
        self._advance(obs)
        return obs, new_rewards, dones, infos
