"""
Losses of the constraint models of BC2L, GACL, MECL, VICRL and IRL-Plus, as pure functions of tensors.

Notation: ``phi`` is the feasibility of a state-action pair (1: allowed, 0: forbidden), so the learned cost is
``1 - phi``. ``E`` is the expert batch, ``N`` the nominal batch (the learner's own rollouts), ``mean_E`` / ``mean_N``
the averages over them. Every loss is to be *minimised* and returns a :class:`ConstraintLoss` whose ``total`` is the
sum of its other three fields, so the parts can be logged.

Logarithms take ``log(p + eps)`` as in the reference code: a probability that reaches 0 in float32 costs
``log(eps)`` instead of ``-inf``, and, unlike clamping, the gradient still flows when a sigmoid saturates.

Sources: the paper "Benchmarking Constraint Inference in Inverse Reinforcement Learning" (Liu et al., ICLR 2023),
sections 2.2 (maximum-entropy likelihood) and 3.2 (baselines), and its public code
(``constraint_models/constraint_net/constraint_net.py``, ``variational_constraint_net.py``, ``gail_net.py`` and
``utils/model_utils.py`` in Guiliang/ICRL-benchmarks-public), which follows Malik et al. (2021) for MECL.
"""

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import torch as th

#: Smallest feasibility the losses take the log of
DEFAULT_LOG_EPS = 1e-5


class ConstraintLoss(NamedTuple):
    """
    A constraint-model loss and its parts, with ``total == expert + nominal + regularizer``.

    :param total: The loss to minimise
    :param expert: The expert term (as it enters ``total``)
    :param nominal: The nominal term (as it enters ``total``)
    :param regularizer: The regulariser term, already multiplied by its coefficient (0 when there is none)
    """

    total: th.Tensor
    expert: th.Tensor
    nominal: th.Tensor
    regularizer: th.Tensor


class ImportanceWeights(NamedTuple):
    """
    MECL's importance weights of the nominal samples and the two KL estimates used for early stopping.

    :param weights: One weight per nominal sample, shape ``(n_samples,)``, mean 1 (normalised)
    :param kl_old_new: Estimate of KL(old || new) between the trajectory distributions of the old and the new
        feasibility: ``mean_traj[-log rho]``
    :param kl_new_old: Estimate of KL(new || old): ``mean_traj[(rho / mean(rho) - 1) * log rho]``
    """

    weights: th.Tensor
    kl_old_new: th.Tensor
    kl_new_old: th.Tensor


def _check_batch(name: str, values: th.Tensor) -> None:
    if not isinstance(values, th.Tensor):
        raise TypeError(f"`{name}` must be a torch.Tensor, got {type(values).__name__}.")
    if values.ndim != 1 or values.shape[0] == 0:
        raise ValueError(
            f"`{name}` must be a non-empty 1-D tensor (one value per state-action pair), got shape {tuple(values.shape)}. "
            "Flatten a (batch, 1) output with `.reshape(-1)`."
        )


def _check_same_length(name_a: str, a: th.Tensor, name_b: str, b: th.Tensor) -> None:
    if a.shape != b.shape:
        raise ValueError(
            f"`{name_a}` and `{name_b}` must have the same shape (one value per pair of the same batch), "
            f"got {tuple(a.shape)} and {tuple(b.shape)}."
        )


def _safe_log(values: th.Tensor, eps: float) -> th.Tensor:
    return th.log(values + eps)


def _weighted_nominal_log_feasibility(
    nominal_feasibility: th.Tensor, nominal_weights: th.Tensor | None, eps: float
) -> th.Tensor:
    """``mean_N[w * log phi]`` with ``w = 1`` when no weights are given; the weights are treated as constants."""
    log_phi = _safe_log(nominal_feasibility, eps)
    if nominal_weights is None:
        return log_phi.mean()
    _check_batch("nominal_weights", nominal_weights)
    _check_same_length("nominal_weights", nominal_weights, "nominal_feasibility", nominal_feasibility)
    # The weights re-weight samples drawn under the old constraint; no gradient flows into them
    return (nominal_weights.detach() * log_phi).mean()


def _expert_vs_nominal_bce(expert_probability: th.Tensor, nominal_probability: th.Tensor, eps: float) -> ConstraintLoss:
    _check_batch("expert_probability", expert_probability)
    _check_batch("nominal_probability", nominal_probability)
    expert_term = -_safe_log(expert_probability, eps).mean()
    nominal_term = -_safe_log(1.0 - nominal_probability, eps).mean()
    zero = th.zeros((), dtype=expert_term.dtype, device=expert_term.device)
    return ConstraintLoss(expert_term + nominal_term, expert_term, nominal_term, zero)


def bc2l_loss(expert_feasibility: th.Tensor, nominal_feasibility: th.Tensor, eps: float = DEFAULT_LOG_EPS) -> ConstraintLoss:
    """
    BC2L: binary cross-entropy of a feasibility classifier, expert pairs labelled 1 (feasible), nominal pairs 0::

        L = -mean_E[log phi(s, a)] - mean_N[log(1 - phi(s, a))]

    Each class is averaged on its own and the two are summed, as two ``BCELoss`` terms in the reference code
    (``constraint_net.py`` with ``train_gail_lambda``). No importance weights, no regulariser (paper, section 3.2).

    :param expert_feasibility: ``phi`` on expert pairs, shape ``(n_expert,)``
    :param nominal_feasibility: ``phi`` on nominal pairs, shape ``(n_nominal,)``
    :param eps: Added inside the logs: ``log(p + eps)``
    :return: The loss and its parts
    """
    return _expert_vs_nominal_bce(expert_feasibility, nominal_feasibility, eps)


def _check_episode_lengths(lengths: Sequence[int] | np.ndarray, n_samples: int, what: str) -> np.ndarray:
    """The lengths of the trajectories whose samples are stored one after the other, checked against their count."""
    array = np.asarray(lengths)
    if array.ndim != 1 or array.size == 0 or not np.issubdtype(array.dtype, np.integer) or np.any(array < 1):
        raise ValueError(f"`episode_lengths` must be a non-empty list of positive integers, got {lengths!r}.")
    if int(array.sum()) != n_samples:
        raise ValueError(
            f"`episode_lengths` sum to {int(array.sum())} but there are {n_samples} {what}; pass the length of every "
            "trajectory, in the order the samples are stored."
        )
    return array


def _trajectory_log_feasibility(feasibility: th.Tensor, lengths: Sequence[int] | np.ndarray, eps: float) -> th.Tensor:
    """``log prod_t phi_t`` of each trajectory, the pairs stored trajectory after trajectory."""
    lengths = _check_episode_lengths(lengths, feasibility.shape[0], "pairs")
    index = th.repeat_interleave(
        th.arange(len(lengths), device=feasibility.device), th.as_tensor(lengths, device=feasibility.device)
    )
    log_phi = _safe_log(feasibility, eps)
    return th.zeros(len(lengths), dtype=log_phi.dtype, device=log_phi.device).index_add(0, index, log_phi)


def bc2l_trajectory_loss(
    expert_feasibility: th.Tensor,
    expert_lengths: Sequence[int] | np.ndarray,
    nominal_feasibility: th.Tensor,
    nominal_lengths: Sequence[int] | np.ndarray,
    eps: float = DEFAULT_LOG_EPS,
) -> ConstraintLoss:
    """
    BC2L with trajectories as the samples: a trajectory is feasible when all its pairs are, ``Phi(tau) = prod_t phi``,
    and the binary cross-entropy labels expert trajectories 1 and nominal trajectories 0::

        L = -mean_E-traj[log Phi(tau)] - mean_N-traj[log(1 - Phi(tau))]

    This is the reference code's grid-world update (``ConstraintNet.train_traj_nn`` with ``train_gail_lambda``: BCE of
    the product of the predictions of one game). The label of a nominal trajectory says only that *some* of its pairs
    are infeasible, so the pairs it shares with the expert are not pushed to 0, unlike the per-pair
    :func:`bc2l_loss`, whose optimum on a pair both sides visit equally often is ``phi = 1/2``. Still a plain
    classifier: no importance weights, no regulariser.

    :param expert_feasibility: ``phi`` on the expert pairs, trajectory after trajectory, shape ``(n_expert_pairs,)``
    :param expert_lengths: Length of each expert trajectory (summing to ``n_expert_pairs``)
    :param nominal_feasibility: ``phi`` on the nominal pairs, trajectory after trajectory
    :param nominal_lengths: Length of each nominal trajectory
    :param eps: Added inside the logs: ``log(phi + eps)`` and ``log(1 - Phi + eps)``
    :return: The loss and its parts (per-trajectory means)
    """
    _check_batch("expert_feasibility", expert_feasibility)
    _check_batch("nominal_feasibility", nominal_feasibility)
    expert_term = -_trajectory_log_feasibility(expert_feasibility, expert_lengths, eps).mean()
    nominal_trajectory_feasibility = th.exp(_trajectory_log_feasibility(nominal_feasibility, nominal_lengths, eps))
    nominal_term = -_safe_log(1.0 - nominal_trajectory_feasibility, eps).mean()
    zero = th.zeros((), dtype=expert_term.dtype, device=expert_term.device)
    return ConstraintLoss(expert_term + nominal_term, expert_term, nominal_term, zero)


def gacl_discriminator_loss(
    expert_probability: th.Tensor, nominal_probability: th.Tensor, eps: float = DEFAULT_LOG_EPS
) -> ConstraintLoss:
    """
    GACL: the GAIL discriminator's binary cross-entropy, ``D(s, a)`` is 1 on expert pairs and 0 on nominal ones::

        L = -mean_E[log D(s, a)] - mean_N[log(1 - D(s, a))]

    The same form as :func:`bc2l_loss` (reference: ``gail_net.py``); what differs is the use: GACL feeds
    ``log D`` into the reward (see ``GACLRewardWrapper``) instead of ``1 - D`` into a cost.

    :param expert_probability: ``D`` on expert pairs, shape ``(n_expert,)``
    :param nominal_probability: ``D`` on nominal pairs, shape ``(n_nominal,)``
    :param eps: Added inside the logs: ``log(p + eps)``
    :return: The loss and its parts
    """
    return _expert_vs_nominal_bce(expert_probability, nominal_probability, eps)


def mecl_loss(
    expert_feasibility: th.Tensor,
    nominal_feasibility: th.Tensor,
    nominal_weights: th.Tensor | None = None,
    regularizer_coef: float = 0.0,
    eps: float = DEFAULT_LOG_EPS,
) -> ConstraintLoss:
    """
    MECL (Malik et al. 2021): the negative maximum-entropy log-likelihood of the expert data with the ``delta``
    regulariser that favours the least constraining constraint::

        L = -mean_E[log phi] + mean_N[w * log phi] + delta * (mean_E[1 - phi] + mean_N[1 - phi])

    This is the paper's likelihood gradient (section 2.2: ``sum_E log phi - N * E_nominal[log phi]``) with both
    sums turned into means, the nominal expectation estimated on samples of the old policy with normalised importance weights
    ``w`` (:func:`mecl_importance_weights`), and the regulariser over both batches as in the reference code
    (``constraint_net.py``, ``regularizer_coeff``).

    :param expert_feasibility: ``phi`` on expert pairs, shape ``(n_expert,)``
    :param nominal_feasibility: ``phi`` on nominal pairs, shape ``(n_nominal,)``
    :param nominal_weights: Importance weights of the nominal pairs, shape ``(n_nominal,)``, treated as constants;
        ``None``: all 1 (no importance sampling)
    :param regularizer_coef: ``delta >= 0``
    :param eps: Added inside the logs: ``log(phi + eps)``
    :return: The loss and its parts
    """
    _check_batch("expert_feasibility", expert_feasibility)
    _check_batch("nominal_feasibility", nominal_feasibility)
    if regularizer_coef < 0:
        raise ValueError(f"`regularizer_coef` (delta) must be >= 0, got {regularizer_coef}.")
    expert_term = -_safe_log(expert_feasibility, eps).mean()
    nominal_term = _weighted_nominal_log_feasibility(nominal_feasibility, nominal_weights, eps)
    regularizer = regularizer_coef * ((1.0 - expert_feasibility).mean() + (1.0 - nominal_feasibility).mean())
    return ConstraintLoss(expert_term + nominal_term + regularizer, expert_term, nominal_term, regularizer)


def mecl_importance_weights(
    old_feasibility: th.Tensor,
    new_feasibility: th.Tensor,
    episode_lengths: Sequence[int] | np.ndarray,
    per_step: bool = False,
    eps: float = DEFAULT_LOG_EPS,
) -> ImportanceWeights:
    """
    MECL's importance weights for nominal samples drawn under the *old* feasibility while the constraint model
    moves to the *new* one, and KL estimates between the two for early stopping (reference:
    ``ConstraintNet.compute_is_weights``).

    With ``r_t = (phi_new(s_t, a_t) + eps) / (phi_old(s_t, a_t) + eps)`` and, for each nominal trajectory ``j``,
    ``rho_j = prod_{t in j} r_t``::

        trajectory weights (default): w_t = n_traj * rho_j / sum_k rho_k   for every step t of trajectory j
        per-step weights:             w_t = r_t / mean(r)
        kl_old_new = mean_j[-log rho_j]
        kl_new_old = mean_j[(rho_j / mean(rho) - 1) * log rho_j]

    Both weightings have mean 1 over trajectories (trajectory weights) or steps (per-step weights). The products
    are formed in log space, so long episodes do not overflow. The samples must be ordered trajectory by
    trajectory, as ``episode_lengths`` lists them.

    :param old_feasibility: ``phi_old`` on the nominal pairs (before this round of constraint updates), ``(n,)``
    :param new_feasibility: ``phi_new`` on the same pairs (current model), ``(n,)``
    :param episode_lengths: Length of each nominal trajectory; they must sum to ``n``
    :param per_step: Use per-step ratios instead of trajectory products for the weights (the KLs stay per trajectory)
    :param eps: Added to both feasibilities in the ratio
    :return: The weights (no gradient) and the two KL estimates
    """
    _check_batch("old_feasibility", old_feasibility)
    _check_batch("new_feasibility", new_feasibility)
    _check_same_length("old_feasibility", old_feasibility, "new_feasibility", new_feasibility)
    lengths = _check_episode_lengths(episode_lengths, old_feasibility.shape[0], "nominal samples")
    with th.no_grad():
        log_ratio = th.log(new_feasibility + eps) - th.log(old_feasibility + eps)
        trajectory_index = th.repeat_interleave(
            th.arange(len(lengths), device=log_ratio.device), th.as_tensor(lengths, device=log_ratio.device)
        )
        log_rho = th.zeros(len(lengths), dtype=log_ratio.dtype, device=log_ratio.device)
        log_rho.index_add_(0, trajectory_index, log_ratio)
        # rho_j / mean(rho), computed as n_traj * softmax(log rho) to stay finite
        normalised_rho = len(lengths) * th.softmax(log_rho, dim=0)
        if per_step:
            ratio = th.exp(log_ratio)
            weights = ratio / ratio.mean()
        else:
            weights = normalised_rho[trajectory_index]
        kl_old_new = (-log_rho).mean()
        kl_new_old = ((normalised_rho - 1.0) * log_rho).mean()
    return ImportanceWeights(weights, kl_old_new, kl_new_old)


def mecl_should_stop(
    importance: ImportanceWeights, target_kl_old_new: float | None = None, target_kl_new_old: float | None = None
) -> bool:
    """
    Early stop of MECL's constraint updates: stop once either KL estimate exceeds its bound, since the importance
    weights are then no longer reliable (reference: ``target_kl_old_new`` / ``target_kl_new_old``; ``-1`` there,
    ``None`` here, disables a bound). The check is meant to run before each pass over the data.

    :param importance: The output of :func:`mecl_importance_weights` for the current model
    :param target_kl_old_new: Bound on KL(old || new), or ``None``
    :param target_kl_new_old: Bound on KL(new || old), or ``None``
    :return: Whether to stop updating the constraint model in this round
    """
    for name, bound in (("target_kl_old_new", target_kl_old_new), ("target_kl_new_old", target_kl_new_old)):
        if bound is not None and bound < 0:
            raise ValueError(f"`{name}` must be >= 0 or None (no bound), got {bound}.")
    return (target_kl_old_new is not None and float(importance.kl_old_new) > target_kl_old_new) or (
        target_kl_new_old is not None and float(importance.kl_new_old) > target_kl_new_old
    )


def beta_kl_divergence(alpha: th.Tensor, beta: th.Tensor, prior_alpha: float, prior_beta: float) -> th.Tensor:
    """
    Closed-form ``KL(Beta(alpha, beta) || Beta(alpha0, beta0))``, elementwise (paper, section 3.2, the Dirichlet-VAE
    formula of Joo et al. 2020 for two categories)::

        KL = ln B(alpha0, beta0) - ln B(alpha, beta)
             + (alpha - alpha0) psi(alpha) + (beta - beta0) psi(beta) + (alpha0 - alpha + beta0 - beta) psi(alpha + beta)

    with ``ln B(a, b) = lgamma(a) + lgamma(b) - lgamma(a + b)`` and ``psi`` the digamma function.

    :param alpha: Posterior ``alpha > 0``, any shape
    :param beta: Posterior ``beta > 0``, same shape
    :param prior_alpha: Prior ``alpha0 > 0``
    :param prior_beta: Prior ``beta0 > 0``
    :return: The KL divergence, same shape as ``alpha``
    """
    _check_same_length("alpha", alpha, "beta", beta)
    if not (prior_alpha > 0 and prior_beta > 0):
        raise ValueError(f"The Beta prior needs alpha0 > 0 and beta0 > 0, got ({prior_alpha}, {prior_beta}).")
    prior_a = th.as_tensor(prior_alpha, dtype=alpha.dtype, device=alpha.device)
    prior_b = th.as_tensor(prior_beta, dtype=alpha.dtype, device=alpha.device)
    log_beta_fn_prior = th.lgamma(prior_a) + th.lgamma(prior_b) - th.lgamma(prior_a + prior_b)
    log_beta_fn = th.lgamma(alpha) + th.lgamma(beta) - th.lgamma(alpha + beta)
    return (
        log_beta_fn_prior
        - log_beta_fn
        + (alpha - prior_a) * th.digamma(alpha)
        + (beta - prior_b) * th.digamma(beta)
        + (prior_a - alpha + prior_b - beta) * th.digamma(alpha + beta)
    )


def vicrl_loss(
    expert_alpha: th.Tensor,
    expert_beta: th.Tensor,
    expert_feasibility_sample: th.Tensor,
    nominal_alpha: th.Tensor,
    nominal_beta: th.Tensor,
    nominal_feasibility_sample: th.Tensor,
    nominal_weights: th.Tensor | None = None,
    kl_coef: float = 1.0,
    prior: tuple[float, float] = (0.9, 0.1),
    eps: float = DEFAULT_LOG_EPS,
) -> ConstraintLoss:
    """
    VICRL: the negative ELBO of the paper (section 3.2), ``-(E_q[log p(D_e | phi)] - KL(q(phi | D) || p(phi)))``, with
    ``q(phi | s, a) = Beta(alpha, beta)`` and the KL over the data approximated by the per-pair KLs::

        L = -mean_E[log phi~] + mean_N[w * log phi~]
            + kl_coef * (mean_E[KL(Beta(alpha, beta) || Beta(alpha0, beta0))] + mean_N[KL(...)])

    where ``phi~ ~ Beta(alpha, beta)`` is one reparameterised sample per pair
    (``BetaFeasibilityNet.distribution(obs, acts).rsample()``), so ``E_q[log p(D_e | phi)]`` is estimated as in
    MECL's likelihood (section 2.2) with the feasibility sampled; the KL is :func:`beta_kl_divergence`. As in the
    reference code (``variational_constraint_net.py``), the KL of both the expert and the nominal pairs is
    averaged, its weight is the config's regulariser coefficient, and importance weights are off by default.
    The default prior ``Beta(0.9, 0.1)`` has mean 0.9 (most pairs feasible).

    :param expert_alpha: ``alpha`` on expert pairs, ``(n_expert,)``
    :param expert_beta: ``beta`` on expert pairs, ``(n_expert,)``
    :param expert_feasibility_sample: ``phi~`` on expert pairs (reparameterised, so gradients reach alpha and beta)
    :param nominal_alpha: ``alpha`` on nominal pairs, ``(n_nominal,)``
    :param nominal_beta: ``beta`` on nominal pairs, ``(n_nominal,)``
    :param nominal_feasibility_sample: ``phi~`` on nominal pairs
    :param nominal_weights: Importance weights of the nominal pairs (constants), or ``None`` for none
    :param kl_coef: Weight of the KL term, ``>= 0``
    :param prior: ``(alpha0, beta0)`` of the Beta prior
    :param eps: Added inside the logs: ``log(phi~ + eps)``
    :return: The loss and its parts (``regularizer`` is the weighted KL)
    """
    for name, values in (
        ("expert_alpha", expert_alpha),
        ("expert_beta", expert_beta),
        ("expert_feasibility_sample", expert_feasibility_sample),
        ("nominal_alpha", nominal_alpha),
        ("nominal_beta", nominal_beta),
        ("nominal_feasibility_sample", nominal_feasibility_sample),
    ):
        _check_batch(name, values)
    _check_same_length("expert_alpha", expert_alpha, "expert_feasibility_sample", expert_feasibility_sample)
    _check_same_length("nominal_alpha", nominal_alpha, "nominal_feasibility_sample", nominal_feasibility_sample)
    if kl_coef < 0:
        raise ValueError(f"`kl_coef` must be >= 0, got {kl_coef}.")
    expert_term = -_safe_log(expert_feasibility_sample, eps).mean()
    nominal_term = _weighted_nominal_log_feasibility(nominal_feasibility_sample, nominal_weights, eps)
    kl = (
        beta_kl_divergence(expert_alpha, expert_beta, *prior).mean()
        + beta_kl_divergence(nominal_alpha, nominal_beta, *prior).mean()
    )
    regularizer = kl_coef * kl
    return ConstraintLoss(expert_term + nominal_term + regularizer, expert_term, nominal_term, regularizer)


def irl_plus_loss(expert_cost: th.Tensor, nominal_cost: th.Tensor, l2_coef: float = 0.1) -> ConstraintLoss:
    """
    IRL-Plus's cost loss (Hugessen et al., NeurIPS 2024), an inverse-RL loss on a cost seen as a negative reward:
    ``mean_E[c] - mean_N[c] + l2_coef * mean_E[c^2]``. Minimising it makes the cost low where the expert goes and
    high where the learner goes; the L2 term keeps the expert's costs near 0, so the costs cannot all drift upward
    together. Here ``c`` is a cost (:class:`~sb3_icrl.constraints.CostNet`), not ``1 - phi``.

    :param expert_cost: ``c`` on the expert batch, shape ``(n_expert,)``
    :param nominal_cost: ``c`` on the nominal batch, shape ``(n_nominal,)``
    :param l2_coef: Weight of the penalty on the expert's squared costs (reference: 0.1; 0: the plain IRL loss)
    :return: The loss and its parts (the penalty as ``regularizer``)
    """
    _check_batch("expert_cost", expert_cost)
    _check_batch("nominal_cost", nominal_cost)
    if not l2_coef >= 0:  # NaN too
        raise ValueError(f"`l2_coef` must be >= 0 (0: no penalty), got {l2_coef}.")
    expert = expert_cost.mean()
    nominal = -nominal_cost.mean()
    regularizer = l2_coef * (expert_cost**2).mean()
    return ConstraintLoss(expert + nominal + regularizer, expert, nominal, regularizer)
