"""
Lagrange multipliers for constrained RL: one lambda_i >= 0 per constraint, updated on (J_c,i - budget_i).

Two update rules, as in OmniSafe's ``common/lagrange.py`` and ``common/pid_lagrange.py``:

- :class:`GradientLagrangeMultiplier`: gradient ascent on the Lagrangian dual,
  ``lambda <- clip(lambda + lr * (J_c - budget), 0, max)`` (SGD) or the same direction through Adam.
- :class:`PIDLagrangeMultiplier`: the PID controller of Stooke et al. (2020), "Responsive Safety in
  Reinforcement Learning by PID Lagrangian Methods", which damps the oscillations of gradient ascent.
"""

from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch as th


def _as_vector(value: float | Sequence[float] | np.ndarray, n_constraints: int, name: str) -> np.ndarray:
    vector = np.asarray(value, dtype=np.float64)
    if vector.ndim == 0:
        return np.full(n_constraints, float(vector))
    if vector.shape != (n_constraints,):
        raise ValueError(
            f"`{name}` has shape {vector.shape}, expected a float or {n_constraints} floats (one per constraint)."
        )
    return vector.copy()


class LagrangeMultiplier(ABC):
    """
    One Lagrange multiplier per constraint, kept in ``[0, upper_bound]``.

    :param cost_budget: Budget ``d_i`` per constraint (a float applies to every constraint)
    :param n_constraints: Number of constraints
    :param upper_bound: Optional upper bound on each multiplier (``None``: unbounded)
    """

    def __init__(self, cost_budget: float | Sequence[float], n_constraints: int = 1, upper_bound: float | None = None):
        if n_constraints < 1:
            raise ValueError(f"`n_constraints` must be >= 1, got {n_constraints}.")
        if upper_bound is not None and not upper_bound >= 0:  # NaN too
            raise ValueError(f"`upper_bound` must be >= 0 or None, got {upper_bound}.")
        self.n_constraints = n_constraints
        self.cost_budget = _as_vector(cost_budget, n_constraints, "cost_budget")
        self.upper_bound = upper_bound

    @property
    @abstractmethod
    def value(self) -> np.ndarray:
        """The current multipliers, shape ``(n_constraints,)``."""

    @abstractmethod
    def update(self, constraint_values: np.ndarray) -> np.ndarray:
        """
        Update the multipliers from the latest constraint estimates.

        :param constraint_values: ``J_c,i`` per constraint, same statistic as the budget
        :return: The new multipliers
        """

    def _initial_multipliers(self, init: float | Sequence[float]) -> np.ndarray:
        init_vector = _as_vector(init, self.n_constraints, "init")
        if not np.all(init_vector >= 0):  # NaN too
            raise ValueError(f"Initial multipliers must be >= 0, got {init_vector.tolist()}.")
        if self.upper_bound is not None and np.any(init_vector > self.upper_bound):
            raise ValueError(
                f"Initial multipliers {init_vector.tolist()} exceed `upper_bound` {self.upper_bound}: lower `init` or raise "
                "the bound."
            )
        return init_vector

    def _check(self, constraint_values: np.ndarray | Sequence[float]) -> np.ndarray:
        values = np.asarray(constraint_values, dtype=np.float64).reshape(-1)
        if values.shape != (self.n_constraints,) or not np.all(np.isfinite(values)):
            raise ValueError(
                f"Expected {self.n_constraints} finite constraint value(s) (one per constraint), got {constraint_values!r}."
            )
        return values

    def _clip(self, value: np.ndarray) -> np.ndarray:
        return np.clip(value, 0.0, np.inf if self.upper_bound is None else self.upper_bound)


class GradientLagrangeMultiplier(LagrangeMultiplier):
    """
    Gradient ascent on the dual: minimise ``-sum_i lambda_i (J_c,i - d_i)`` w.r.t. lambda, then project on ``[0, max]``.

    :param cost_budget: Budget ``d_i`` per constraint
    :param n_constraints: Number of constraints
    :param init: Initial multiplier value(s)
    :param lr: Learning rate of the multiplier
    :param optimizer: ``"sgd"`` (step ``lr * (J_c - d)``) or ``"adam"`` (scale-free steps of about ``lr``)
    :param upper_bound: Optional upper bound on each multiplier
    """

    optimizer_classes: dict[str, type[th.optim.Optimizer]] = {"sgd": th.optim.SGD, "adam": th.optim.Adam}

    def __init__(
        self,
        cost_budget: float | Sequence[float],
        n_constraints: int = 1,
        init: float | Sequence[float] = 1.0,
        lr: float = 0.035,
        optimizer: str = "adam",
        upper_bound: float | None = None,
    ):
        super().__init__(cost_budget, n_constraints, upper_bound)
        if optimizer not in self.optimizer_classes:
            raise ValueError(f"Unknown multiplier optimizer {optimizer!r}: use one of {sorted(self.optimizer_classes)}.")
        if not lr >= 0:  # NaN too
            raise ValueError(f"The multiplier learning rate must be >= 0, got {lr}.")
        init_vector = self._initial_multipliers(init)
        self.lr = lr
        self.optimizer_name = optimizer
        self._multiplier = th.nn.Parameter(th.as_tensor(self._clip(init_vector), dtype=th.float32))
        self._optimizer = self._make_optimizer()

    @property
    def value(self) -> np.ndarray:
        return self._multiplier.detach().numpy().astype(np.float64)

    def update(self, constraint_values: np.ndarray) -> np.ndarray:
        violation = th.as_tensor(self._check(constraint_values) - self.cost_budget, dtype=th.float32)
        self._optimizer.zero_grad()
        dual_loss = -(self._multiplier * violation).sum()
        dual_loss.backward()
        self._optimizer.step()
        with th.no_grad():
            self._multiplier.copy_(th.as_tensor(self._clip(self.value), dtype=th.float32))
        return self.value

    def __getstate__(self) -> dict[str, Any]:
        # Torch parameters and optimizers are stored as plain state so that models pickle and load anywhere
        state = self.__dict__.copy()
        state["_multiplier"] = self.value
        state["_optimizer"] = self._optimizer.state_dict()
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        optimizer_state = state.pop("_optimizer")
        self.__dict__.update(state)
        self._multiplier = th.nn.Parameter(th.as_tensor(state["_multiplier"], dtype=th.float32))
        self._optimizer = self._make_optimizer()
        self._optimizer.load_state_dict(optimizer_state)

    def _make_optimizer(self) -> th.optim.Optimizer:
        return self.optimizer_classes[self.optimizer_name]([self._multiplier], lr=self.lr)  # type: ignore[call-arg]


class PIDLagrangeMultiplier(LagrangeMultiplier):
    """
    PID Lagrangian (Stooke et al., 2020, Algorithm 2), per constraint::

        delta = J_c - d
        I <- max(0, I + Ki * delta)
        P <- EMA_{alpha_p}(delta)
        D = max(0, EMA_{alpha_d}(J_c) now - the same EMA ``d_delay`` updates ago)
        lambda = clip(Kp * P + I + Kd * D, 0, max)

    :param cost_budget: Budget ``d_i`` per constraint
    :param n_constraints: Number of constraints
    :param init: Initial multiplier value(s); it seeds the integral term
    :param kp: Proportional gain
    :param ki: Integral gain
    :param kd: Derivative gain
    :param d_delay: Number of updates between the two cost values whose difference is the derivative
    :param delta_p_ema_alpha: EMA smoothing of the proportional term (0: none)
    :param delta_d_ema_alpha: EMA smoothing of the cost used by the derivative term (0: none)
    :param upper_bound: Optional upper bound on each multiplier
    """

    def __init__(
        self,
        cost_budget: float | Sequence[float],
        n_constraints: int = 1,
        init: float | Sequence[float] = 0.0,
        kp: float = 0.1,
        ki: float = 0.01,
        kd: float = 0.01,
        d_delay: int = 10,
        delta_p_ema_alpha: float = 0.95,
        delta_d_ema_alpha: float = 0.95,
        upper_bound: float | None = None,
    ):
        super().__init__(cost_budget, n_constraints, upper_bound)
        if not all(gain >= 0 for gain in (kp, ki, kd)):  # NaN too
            raise ValueError(f"PID gains must be >= 0, got kp={kp}, ki={ki}, kd={kd}.")
        if d_delay < 1:
            raise ValueError(f"`d_delay` must be >= 1, got {d_delay}.")
        if not (0.0 <= delta_p_ema_alpha < 1.0 and 0.0 <= delta_d_ema_alpha < 1.0):
            raise ValueError("EMA alphas must be in [0, 1).")
        init_vector = self._initial_multipliers(init)
        self.kp, self.ki, self.kd = kp, ki, kd
        self.d_delay = d_delay
        self.delta_p_ema_alpha = delta_p_ema_alpha
        self.delta_d_ema_alpha = delta_d_ema_alpha
        self.integral = init_vector.copy()
        self.delta_p = np.zeros(n_constraints)
        self.cost_d = np.zeros(n_constraints)
        self.cost_d_history: deque[np.ndarray] = deque([np.zeros(n_constraints)], maxlen=d_delay)
        self._value = self._clip(init_vector)

    @property
    def value(self) -> np.ndarray:
        return self._value.copy()

    def update(self, constraint_values: np.ndarray) -> np.ndarray:
        costs = self._check(constraint_values)
        delta = costs - self.cost_budget
        self.integral = np.maximum(0.0, self.integral + self.ki * delta)
        alpha_p, alpha_d = self.delta_p_ema_alpha, self.delta_d_ema_alpha
        self.delta_p = alpha_p * self.delta_p + (1.0 - alpha_p) * delta
        self.cost_d = alpha_d * self.cost_d + (1.0 - alpha_d) * costs
        derivative = np.maximum(0.0, self.cost_d - self.cost_d_history[0])
        self._value = self._clip(self.kp * self.delta_p + self.integral + self.kd * derivative)
        self.cost_d_history.append(self.cost_d.copy())
        return self.value


LAGRANGE_MULTIPLIERS: dict[str, type[LagrangeMultiplier]] = {
    "gradient": GradientLagrangeMultiplier,
    "pid": PIDLagrangeMultiplier,
}


def make_lagrange_multiplier(
    kind: str, cost_budget: float | Sequence[float], n_constraints: int, **kwargs: Any
) -> LagrangeMultiplier:
    """
    Build a multiplier by name.

    :param kind: ``"gradient"`` or ``"pid"``
    :param cost_budget: Budget per constraint
    :param n_constraints: Number of constraints
    :param kwargs: Passed to the multiplier's constructor
    :return: The multiplier
    """
    if kind not in LAGRANGE_MULTIPLIERS:
        raise ValueError(f"Unknown Lagrange multiplier update {kind!r}: use one of {sorted(LAGRANGE_MULTIPLIERS)}.")
    try:
        return LAGRANGE_MULTIPLIERS[kind](cost_budget, n_constraints, **kwargs)
    except TypeError as error:
        raise TypeError(f"Bad `lagrange_kwargs` for the {kind!r} multiplier: {error}") from error
