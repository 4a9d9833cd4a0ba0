"""Actor-critic policies with an extra cost critic (one output per constraint)."""

import contextlib
import functools
import math
import threading
from collections.abc import Callable, Iterator, Sequence
from functools import partial
from typing import Any, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.distributions import DiagGaussianDistribution
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, NatureCNN, create_mlp
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from torch import nn
from torch.distributions import Distribution

FUSED_OPTIMIZERS = (th.optim.Adam, th.optim.AdamW, th.optim.SGD)


def fused_optimizer_kwargs(
    optimizer_class: type[th.optim.Optimizer], optimizer_kwargs: dict[str, Any] | None
) -> dict[str, Any]:
    """
    The optimiser's keyword arguments with ``fused=True`` added where torch offers it and the caller chose neither
    ``fused`` nor ``foreach``. A fused step does the same arithmetic as the default per-tensor loop in one kernel:
    about 2.5x cheaper for PPO's small networks on a CPU, and PPO's update is mostly optimiser steps and small matmuls.

    :param optimizer_class: The optimiser class
    :param optimizer_kwargs: The caller's keyword arguments (``None``: SB3's defaults, ``eps=1e-5`` for Adam)
    :return: A new dict
    """
    if optimizer_kwargs is None:
        # SB3's ActorCriticPolicy default, which it only applies when given no kwargs at all
        optimizer_kwargs = {"eps": 1e-5} if optimizer_class is th.optim.Adam else {}
    kwargs = dict(optimizer_kwargs)
    if optimizer_class in FUSED_OPTIMIZERS and not {"fused", "foreach"} & set(kwargs):
        kwargs["fused"] = True
    return kwargs


@th.no_grad()
def clip_grad_norms_(parameter_groups: Sequence[Sequence[th.Tensor]], max_norm: float) -> th.Tensor:
    """
    ``th.nn.utils.clip_grad_norm_(group, max_norm, foreach=True)`` for each group, each by its own total norm, with
    the same results. When every gradient has one device and dtype (PPOLagrangian's case), it takes one
    ``_foreach_norm`` over all of them instead of one per group; otherwise it calls torch per group. PPOLagrangian
    clips the actor-critic and the cost critic apart, once per minibatch.

    :param parameter_groups: Lists of parameters (those without a gradient are left out, as torch does; a group
        with none is left alone, its norm 0)
    :param max_norm: The largest total L2 norm of each group's gradients
    :return: The total norm of each group before clipping, shape ``(n_groups,)``
    """
    grads = [[param.grad for param in group if param.grad is not None] for group in parameter_groups]
    every = [grad for group in grads for grad in group]
    if not every or len({(grad.device, grad.dtype) for grad in every}) > 1:
        totals = [th.nn.utils.clip_grad_norm_(list(group), max_norm, foreach=True) for group in parameter_groups]
        return th.stack([th.as_tensor(total, dtype=th.float32).cpu() for total in totals])
    norms = th._foreach_norm(every)
    totals = []
    start = 0
    for group in grads:
        if not group:
            totals.append(th.zeros((), dtype=every[0].dtype, device=every[0].device))
            continue
        total = th.linalg.vector_norm(th.stack(norms[start : start + len(group)]))
        start += len(group)
        th._foreach_mul_(group, th.clamp(max_norm / (total + 1e-6), max=1.0))
        totals.append(total)
    return th.stack(totals)


#: Guards the process-wide setting below: how many blocks have turned the checks off, and the setting before the first
_validation_lock = threading.Lock()
_validation_off_depth = 0
_validation_before: bool | None = None


@contextlib.contextmanager
def no_distribution_validation() -> Iterator[None]:
    """
    Turn off torch's argument checks of ``torch.distributions`` inside the block (torch's default: on unless Python
    runs with ``-O``). The checks test every new distribution's parameters and every value given to ``log_prob`` (NaN,
    support) with several small tensor operations, and they change no value: without them (and with its gradients reset
    directly) PPOLagrangian trained 2-7% faster on BlockedHalfCheetah at the same settings (``benchmarks/icrl_speed.py``).

    The setting is process-wide: blocks may nest and overlap across threads, and the setting from before the first of
    them comes back when the last one ends (other threads run without the checks meanwhile).
    """
    global _validation_off_depth, _validation_before
    with _validation_lock:
        if _validation_off_depth == 0:
            _validation_before = Distribution._validate_args
            Distribution.set_default_validate_args(False)
        _validation_off_depth += 1
    try:
        yield
    finally:
        with _validation_lock:
            _validation_off_depth -= 1
            if _validation_off_depth == 0:
                assert _validation_before is not None
                Distribution.set_default_validate_args(_validation_before)


Method = TypeVar("Method", bound=Callable[..., Any])


def without_distribution_validation(method: Method) -> Method:
    """
    Run ``method`` inside :func:`no_distribution_validation`. A method decorated with it checks instead what the
    checks would catch (:func:`check_finite`).

    :param method: An update method (one that runs no user code: callbacks keep torch's setting)
    :return: The wrapped method
    """

    @functools.wraps(method)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with no_distribution_validation():
            return method(*args, **kwargs)

    return wrapper  # type: ignore[return-value]


def diverged_error(what: str) -> FloatingPointError:
    """
    The error that says training has diverged (what torch's distribution checks would otherwise report, less clearly,
    when the policy's outputs turn NaN).

    :param what: What is not finite ("The policy's actions", ...)
    :return: The error, to raise
    """
    return FloatingPointError(
        f"{what} are not finite (NaN or inf): training has diverged. Lower the learning rate or `max_grad_norm`, "
        "normalise the observations and rewards (VecNormalize), or check the env for NaN observations or rewards."
    )


def check_finite(values: np.ndarray | th.Tensor, what: str) -> None:
    """
    Raise :func:`diverged_error` unless every value is finite.

    :param values: Actions or losses
    :param what: What they are, for the message ("The policy's actions", ...)
    """
    finite = th.isfinite(values).all() if isinstance(values, th.Tensor) else np.isfinite(values).all()
    if not finite:
        raise diverged_error(what)


class CostActorCriticPolicy(ActorCriticPolicy):
    """
    SB3's ``ActorCriticPolicy`` plus a cost critic ``V_c(s)`` with one output per constraint.

    The cost critic is a network of its own (own features extractor and MLP): its loss never changes the actor or
    the reward critic, so with a zero Lagrange multiplier the actor-critic update is exactly PPO's. It is built after
    the actor and critic, under a forked random state, so that those get the same initial weights as in SB3 at the
    same seed. One optimizer (``optimizer``) updates the actor-critic and the cost critic: Adam treats every parameter
    alone, so this is the update of two optimizers in one ``step()`` call, which saves the second call's Python
    overhead (about 0.1 ms per minibatch). It is fused where torch offers it (:func:`fused_optimizer_kwargs`), which
    more than pays for the extra critic.

    :param observation_space: Observation space
    :param action_space: Action space
    :param lr_schedule: Learning rate schedule
    :param n_costs: Number of constraints (outputs of the cost critic)
    :param cost_net_arch: Hidden layers of the cost critic (default: those of the reward critic)
    :param kwargs: Every other argument of ``ActorCriticPolicy`` (``net_arch``, ``activation_fn``, ``ortho_init``, ...)
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule,
        n_costs: int = 1,
        cost_net_arch: list[int] | None = None,
        **kwargs: Any,
    ):
        if n_costs < 1:
            raise ValueError(f"`n_costs` must be >= 1, got {n_costs}.")
        self.n_costs = n_costs
        self.cost_net_arch = cost_net_arch
        optimizer_class = kwargs.get("optimizer_class", th.optim.Adam)
        kwargs["optimizer_kwargs"] = fused_optimizer_kwargs(optimizer_class, kwargs.get("optimizer_kwargs"))
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def _reward_critic_arch(self) -> list[int]:
        if isinstance(self.net_arch, dict):
            return list(self.net_arch.get("vf", []))
        return list(self.net_arch)

    def _build(self, lr_schedule: Schedule) -> None:
        super()._build(lr_schedule)
        # Fork the RNG: the actor/critic weights and the actions sampled later stay those of PPO at the same seed
        with th.random.fork_rng(devices=[]):
            self.cost_features_extractor = self.make_features_extractor()
            hidden = self.cost_net_arch if self.cost_net_arch is not None else self._reward_critic_arch()
            self.cost_mlp = nn.Sequential(
                *create_mlp(self.cost_features_extractor.features_dim, -1, hidden, self.activation_fn)
            )
            latent_dim = hidden[-1] if hidden else self.cost_features_extractor.features_dim
            self.cost_value_net = nn.Linear(latent_dim, self.n_costs)
            if self.ortho_init:
                for module, gain in (
                    (self.cost_features_extractor, np.sqrt(2)),
                    (self.cost_mlp, np.sqrt(2)),
                    (self.cost_value_net, 1.0),
                ):
                    module.apply(partial(self.init_weights, gain=gain))
        # SB3's optimizer, rebuilt over the cost critic's parameters too (after the actor-critic's, in one group)
        self.optimizer = self.optimizer_class(  # type: ignore[call-arg]
            [*self.actor_critic_parameters(), *self.cost_critic_parameters()], lr=lr_schedule(1), **self.optimizer_kwargs
        )

    def cost_critic_parameters(self) -> list[nn.Parameter]:
        """The parameters of the cost critic."""
        return [*self.cost_features_extractor.parameters(), *self.cost_mlp.parameters(), *self.cost_value_net.parameters()]

    def actor_critic_parameters(self) -> list[nn.Parameter]:
        """The parameters of the actor and the reward critic (every parameter but the cost critic's), in SB3's order."""
        cost_critic = {id(param) for param in self.cost_critic_parameters()}
        return [param for param in self.parameters() if id(param) not in cost_critic]

    def act(self, obs: PyTorchObs, deterministic: bool = False) -> tuple[th.Tensor, th.Tensor]:
        """
        The actor half of ``forward``: sample actions and their log-probabilities without running the critics
        (rollouts compute the values of all their observations in one batch afterwards). Consumes the random
        generator exactly as ``forward`` does. A plain diagonal Gaussian is computed without distribution objects
        (:meth:`_diag_gaussian_act`), so torch's argument checks do not run there: the caller checks the actions
        (PPOLagrangian's rollouts do).

        :param obs: Observation batch
        :param deterministic: Whether to use deterministic actions
        :return: Actions and their log-probabilities
        """
        features = super(ActorCriticPolicy, self).extract_features(obs, self.pi_features_extractor)
        latent = self.mlp_extractor.forward_actor(features)
        if self._plain_diag_gaussian():
            actions, log_prob = self._diag_gaussian_act(self.action_net(latent), deterministic)
        else:
            distribution = self._get_action_dist_from_latent(latent)
            actions = distribution.get_actions(deterministic=deterministic)
            log_prob = distribution.log_prob(actions)
        return actions.reshape((-1, *self.action_space.shape)), log_prob  # type: ignore[misc]

    def _plain_diag_gaussian(self) -> bool:
        """
        Whether the actor is SB3's diagonal Gaussian as SB3 builds it: the distribution class itself (not gSDE or a
        squashed one), and ``_get_action_dist_from_latent`` not replaced by a subclass or on the instance (a policy
        that changes its distribution there must keep its own way in rollouts too).
        """
        return (
            type(self.action_dist) is DiagGaussianDistribution
            and type(self)._get_action_dist_from_latent is ActorCriticPolicy._get_action_dist_from_latent
            and "_get_action_dist_from_latent" not in vars(self)
        )

    def _diag_gaussian_act(self, mean: th.Tensor, deterministic: bool) -> tuple[th.Tensor, th.Tensor]:
        """
        What SB3's ``DiagGaussianDistribution`` computes for ``get_actions`` and ``log_prob``, operation for operation
        (the same values and the same draws from the random generator), without building its distribution objects:
        at a rollout's batch of one or a few observations, building them costs more than the actor's matmuls.

        :param mean: The action means, ``(batch, action_dim)``
        :param deterministic: Whether to return the means instead of samples
        :return: Actions and their log-probabilities (summed over action dimensions)
        """
        std = th.ones_like(mean) * self.log_std.exp()
        if deterministic:
            actions = mean
        else:
            # torch's Normal.rsample: loc + eps * scale, eps from empty(shape).normal_()
            actions = mean + th.empty(mean.shape, dtype=mean.dtype, device=mean.device).normal_() * std
        # torch's Normal.log_prob, summed over the action dimensions as SB3's sum_independent_dims does
        log_prob = -((actions - mean) ** 2) / (2 * std**2) - std.log() - math.log(math.sqrt(2 * math.pi))
        return actions, log_prob.sum(dim=1) if log_prob.dim() > 1 else log_prob.sum()

    def predict_all_values(self, obs: PyTorchObs) -> tuple[th.Tensor, th.Tensor]:
        """
        :param obs: Observation batch
        :return: Reward values ``(batch, 1)`` and cost values ``(batch, n_costs)``
        """
        return self.predict_values(obs), self.predict_cost_values(obs)

    def predict_cost_values(self, obs: PyTorchObs) -> th.Tensor:
        """
        :param obs: Observation batch
        :return: Estimated discounted cost-to-go per constraint, shape ``(batch, n_costs)``
        """
        features = super(ActorCriticPolicy, self).extract_features(obs, self.cost_features_extractor)
        return self.cost_value_net(self.cost_mlp(features))

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(n_costs=self.n_costs, cost_net_arch=self.cost_net_arch)
        return data


class CostActorCriticCnnPolicy(CostActorCriticPolicy):
    """:class:`CostActorCriticPolicy` with SB3's ``NatureCNN`` features extractor, for image observations."""

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule,
        features_extractor_class: type[BaseFeaturesExtractor] = NatureCNN,
        **kwargs: Any,
    ):
        super().__init__(
            observation_space, action_space, lr_schedule, features_extractor_class=features_extractor_class, **kwargs
        )
