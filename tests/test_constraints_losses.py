"""The constraint losses against values computed by hand on a fixed tiny batch, and their error messages."""

import math

import numpy as np
import pytest
import scipy.integrate
import scipy.special
import scipy.stats
import torch as th

from sb3_icrl.constraints import (
    FeasibilityNet,
    bc2l_loss,
    beta_kl_divergence,
    gacl_discriminator_loss,
    mecl_importance_weights,
    mecl_loss,
    mecl_should_stop,
    vicrl_loss,
)

EXPERT = [0.9, 0.6]
NOMINAL = [0.2, 0.5, 0.7]


def tensor(values, requires_grad: bool = False) -> th.Tensor:
    return th.tensor(values, dtype=th.float64, requires_grad=requires_grad)


def kl_beta_by_hand(a: float, b: float, a0: float, b0: float) -> float:
    return (
        scipy.special.betaln(a0, b0)
        - scipy.special.betaln(a, b)
        + (a - a0) * scipy.special.digamma(a)
        + (b - b0) * scipy.special.digamma(b)
        + (a0 - a + b0 - b) * scipy.special.digamma(a + b)
    )


@pytest.mark.parametrize("loss_fn", [bc2l_loss, gacl_discriminator_loss])
def test_binary_cross_entropy_by_hand(loss_fn):
    loss = loss_fn(tensor(EXPERT), tensor(NOMINAL), eps=0.0)
    expert = -(math.log(0.9) + math.log(0.6)) / 2
    nominal = -(math.log(0.8) + math.log(0.5) + math.log(0.3)) / 3
    assert loss.expert.item() == pytest.approx(expert, rel=1e-12)
    assert loss.nominal.item() == pytest.approx(nominal, rel=1e-12)
    assert loss.regularizer.item() == 0.0
    assert loss.total.item() == pytest.approx(expert + nominal, rel=1e-12)
    assert loss.total.item() == pytest.approx(1.0148476, abs=1e-7)  # 0.3080931 + 0.7067545


def test_binary_cross_entropy_matches_torch_bce():
    expert, nominal = tensor(EXPERT), tensor(NOMINAL)
    reference = th.nn.functional.binary_cross_entropy(expert, th.ones(2, dtype=th.float64))
    reference = reference + th.nn.functional.binary_cross_entropy(nominal, th.zeros(3, dtype=th.float64))
    assert bc2l_loss(expert, nominal, eps=0.0).total.item() == pytest.approx(reference.item(), rel=1e-12)


def test_eps_keeps_the_loss_finite_and_the_gradient_alive():
    expert = tensor([0.0, 1.0], requires_grad=True)
    nominal = tensor([1.0, 0.0], requires_grad=True)
    loss = bc2l_loss(expert, nominal, eps=1e-5)
    loss.total.backward()
    assert math.isfinite(loss.total.item())
    assert loss.total.item() == pytest.approx(-(math.log(1e-5) + math.log(1 + 1e-5)), rel=1e-9)
    assert expert.grad[0] < 0 and nominal.grad[0] > 0  # pushes expert up, nominal down, even when saturated


def test_mecl_loss_without_weights_by_hand():
    loss = mecl_loss(tensor(EXPERT), tensor(NOMINAL), regularizer_coef=0.5, eps=0.0)
    expert = -(math.log(0.9) + math.log(0.6)) / 2
    nominal = (math.log(0.2) + math.log(0.5) + math.log(0.7)) / 3
    regularizer = 0.5 * ((0.1 + 0.4) / 2 + (0.8 + 0.5 + 0.3) / 3)
    assert loss.expert.item() == pytest.approx(expert, rel=1e-12)
    assert loss.nominal.item() == pytest.approx(nominal, rel=1e-12)
    assert loss.regularizer.item() == pytest.approx(regularizer, rel=1e-12)
    assert loss.total.item() == pytest.approx(expert + nominal + regularizer, rel=1e-12)
    assert loss.total.item() == pytest.approx(-0.1866603, abs=1e-7)  # 0.3080931 - 0.8864200 + 0.3916667


def test_mecl_loss_with_weights_by_hand_and_weights_get_no_gradient():
    weights = tensor([2.0, 0.5, 0.5], requires_grad=True)
    nominal = tensor(NOMINAL, requires_grad=True)
    loss = mecl_loss(tensor(EXPERT), nominal, nominal_weights=weights, eps=0.0)
    expected_nominal = (2.0 * math.log(0.2) + 0.5 * math.log(0.5) + 0.5 * math.log(0.7)) / 3
    assert loss.nominal.item() == pytest.approx(expected_nominal, rel=1e-12)
    loss.total.backward()
    assert weights.grad is None
    assert nominal.grad[0].item() == pytest.approx(2.0 / 3 / 0.2, rel=1e-12)  # d/dphi of mean(w log phi)


def test_importance_weights_by_hand():
    old = tensor([0.5, 0.5, 0.5])
    new = tensor([0.25, 0.5, 1.0])  # step ratios 0.5, 1, 2
    result = mecl_importance_weights(old, new, episode_lengths=[2, 1], eps=0.0)
    # trajectory products rho = [0.5, 2]; weights n * rho / sum(rho) = [0.4, 1.6], repeated over the steps
    np.testing.assert_allclose(result.weights.numpy(), [0.4, 0.4, 1.6], rtol=1e-12)
    assert result.kl_old_new.item() == pytest.approx(-(math.log(0.5) + math.log(2.0)) / 2, abs=1e-12)  # = 0
    assert result.kl_new_old.item() == pytest.approx(((0.4 - 1) * math.log(0.5) + (1.6 - 1) * math.log(2.0)) / 2, rel=1e-12)
    assert result.kl_new_old.item() == pytest.approx(0.6 * math.log(2.0), rel=1e-12)

    per_step = mecl_importance_weights(old, new, episode_lengths=[2, 1], per_step=True, eps=0.0)
    np.testing.assert_allclose(per_step.weights.numpy(), np.array([0.5, 1.0, 2.0]) / (3.5 / 3), rtol=1e-12)
    assert per_step.kl_new_old.item() == pytest.approx(result.kl_new_old.item())


def test_importance_weights_are_one_for_an_unchanged_model_and_normalised_otherwise():
    rng = np.random.default_rng(0)
    old = tensor(rng.uniform(0.05, 0.95, size=60))
    unchanged = mecl_importance_weights(old, old.clone(), episode_lengths=[20, 30, 10])
    np.testing.assert_allclose(unchanged.weights.numpy(), 1.0, rtol=1e-12)
    assert unchanged.kl_old_new.item() == pytest.approx(0.0, abs=1e-12)
    assert unchanged.kl_new_old.item() == pytest.approx(0.0, abs=1e-12)

    lengths = [20, 30, 10]
    moved = mecl_importance_weights(old, tensor(rng.uniform(0.05, 0.95, size=60)), episode_lengths=lengths)
    starts = np.cumsum([0, *lengths[:-1]])
    assert moved.weights.numpy()[starts].mean() == pytest.approx(1.0, rel=1e-12)  # one weight per trajectory, mean 1
    assert moved.kl_new_old.item() > 0.0


def test_importance_weights_do_not_overflow_on_long_episodes():
    old = tensor(np.full(2000, 0.1))
    new = tensor(np.full(2000, 0.9))  # a ratio of 9 per step: 9**1000 overflows float64
    result = mecl_importance_weights(old, new, episode_lengths=[1000, 1000])
    assert th.all(th.isfinite(result.weights))
    np.testing.assert_allclose(result.weights.numpy(), 1.0, rtol=1e-9)


def test_should_stop_compares_each_bound_and_none_disables_it():
    old = tensor([0.5, 0.5, 0.5])
    importance = mecl_importance_weights(old, tensor([0.25, 0.5, 1.0]), episode_lengths=[2, 1], eps=0.0)
    kl_new_old = 0.6 * math.log(2.0)  # ~0.416, kl_old_new = 0
    assert not mecl_should_stop(importance)
    assert mecl_should_stop(importance, target_kl_new_old=kl_new_old - 0.01)
    assert not mecl_should_stop(importance, target_kl_new_old=kl_new_old + 0.01)
    assert not mecl_should_stop(importance, target_kl_old_new=0.01)
    with pytest.raises(ValueError, match="target_kl_old_new"):
        mecl_should_stop(importance, target_kl_old_new=-1)


def test_early_stopping_halts_the_constraint_updates_once_the_model_has_moved():
    th.manual_seed(0)
    rng = np.random.default_rng(0)
    expert_obs, nominal_obs = rng.normal(-1.0, 0.3, size=(40, 1)), rng.normal(1.0, 0.3, size=(40, 1))
    lengths = [10, 10, 10, 10]

    def updates_until_stop(target: float | None, max_updates: int = 30) -> int:
        net = FeasibilityNet(1, 1, hidden_sizes=(8,), use_action=False)
        net.fit_normalizer(np.concatenate([expert_obs, nominal_obs]), None)
        optimizer = th.optim.SGD(net.parameters(), lr=0.5)
        with th.no_grad():
            start = net.feasibility(nominal_obs, None)
        for update in range(max_updates):
            importance = mecl_importance_weights(start, net.feasibility(nominal_obs, None).detach(), lengths)
            if mecl_should_stop(importance, target_kl_new_old=target):
                return update
            loss = mecl_loss(net.feasibility(expert_obs, None), net.feasibility(nominal_obs, None), importance.weights)
            optimizer.zero_grad()
            loss.total.backward()
            optimizer.step()
        return max_updates

    stopped_at = updates_until_stop(target=0.05)
    assert 1 <= stopped_at < 30
    assert updates_until_stop(target=None) == 30


def test_importance_weights_errors():
    old = tensor([0.5, 0.5, 0.5])
    with pytest.raises(ValueError, match=r"sum to 2 but there are 3 nominal samples"):
        mecl_importance_weights(old, old, episode_lengths=[1, 1])
    with pytest.raises(ValueError, match="positive integers"):
        mecl_importance_weights(old, old, episode_lengths=[3.0])
    with pytest.raises(ValueError, match=r"same shape.*\(3,\) and \(2,\)"):
        mecl_importance_weights(old, tensor([0.5, 0.5]), episode_lengths=[3])


@pytest.mark.parametrize(
    "alpha,beta,prior",
    [(2.0, 3.0, (0.9, 0.1)), (0.5, 0.7, (0.9, 0.1)), (5.0, 1.2, (2.0, 2.0)), (1.0, 1.0, (3.0, 0.5))],
)
def test_beta_kl_matches_a_numerical_integral(alpha, beta, prior):
    posterior, prior_dist = scipy.stats.beta(alpha, beta), scipy.stats.beta(*prior)

    def integrand(x: float) -> float:
        return posterior.pdf(x) * (posterior.logpdf(x) - prior_dist.logpdf(x))

    numerical, _ = scipy.integrate.quad(integrand, 0.0, 1.0, limit=200, points=[0.5])
    closed_form = beta_kl_divergence(tensor([alpha]), tensor([beta]), *prior).item()
    assert closed_form == pytest.approx(numerical, rel=1e-6, abs=1e-8)
    assert closed_form == pytest.approx(kl_beta_by_hand(alpha, beta, *prior), rel=1e-10)


def test_beta_kl_is_zero_at_the_prior_and_checks_the_prior():
    assert beta_kl_divergence(tensor([0.9]), tensor([0.1]), 0.9, 0.1).item() == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError, match=r"alpha0 > 0 and beta0 > 0, got \(0.0, 1.0\)"):
        beta_kl_divergence(tensor([1.0]), tensor([1.0]), 0.0, 1.0)


def test_vicrl_loss_by_hand():
    expert_alpha, expert_beta, expert_sample = [4.0, 2.0], [1.0, 0.5], [0.9, 0.6]
    nominal_alpha, nominal_beta, nominal_sample = [1.0, 2.0, 0.5], [3.0, 2.0, 0.5], [0.2, 0.5, 0.7]
    weights = [1.5, 0.75, 0.75]
    loss = vicrl_loss(
        tensor(expert_alpha),
        tensor(expert_beta),
        tensor(expert_sample),
        tensor(nominal_alpha),
        tensor(nominal_beta),
        tensor(nominal_sample),
        nominal_weights=tensor(weights),
        kl_coef=0.3,
        prior=(0.9, 0.1),
        eps=0.0,
    )
    expert = -(math.log(0.9) + math.log(0.6)) / 2
    nominal = (1.5 * math.log(0.2) + 0.75 * math.log(0.5) + 0.75 * math.log(0.7)) / 3
    kl_expert = np.mean([kl_beta_by_hand(a, b, 0.9, 0.1) for a, b in zip(expert_alpha, expert_beta, strict=True)])
    kl_nominal = np.mean([kl_beta_by_hand(a, b, 0.9, 0.1) for a, b in zip(nominal_alpha, nominal_beta, strict=True)])
    assert loss.expert.item() == pytest.approx(expert, rel=1e-12)
    assert loss.nominal.item() == pytest.approx(nominal, rel=1e-12)
    assert loss.regularizer.item() == pytest.approx(0.3 * (kl_expert + kl_nominal), rel=1e-10)
    assert loss.total.item() == pytest.approx(expert + nominal + 0.3 * (kl_expert + kl_nominal), rel=1e-10)


def test_vicrl_gradient_reaches_alpha_and_beta_through_the_sample():
    alpha, beta = tensor([2.0, 3.0], requires_grad=True), tensor([1.0, 1.0], requires_grad=True)
    sample = th.distributions.Beta(alpha, beta).rsample()
    loss = vicrl_loss(alpha, beta, sample, alpha, beta, sample, kl_coef=0.0)
    loss.total.backward()
    assert alpha.grad is not None and beta.grad is not None


@pytest.mark.parametrize(
    "call,message",
    [
        (
            lambda: bc2l_loss(tensor([[0.5], [0.5]]), tensor(NOMINAL)),
            r"`expert_probability` must be a non-empty 1-D.*\(2, 1\)",
        ),
        (lambda: mecl_loss(tensor([]), tensor(NOMINAL)), r"`expert_feasibility` must be a non-empty 1-D"),
        (lambda: mecl_loss([0.5], tensor(NOMINAL)), "must be a torch.Tensor, got list"),
        (
            lambda: mecl_loss(tensor(EXPERT), tensor(NOMINAL), nominal_weights=tensor([1.0, 1.0])),
            r"`nominal_weights` and `nominal_feasibility` must have the same shape",
        ),
        (lambda: mecl_loss(tensor(EXPERT), tensor(NOMINAL), regularizer_coef=-0.1), "delta"),
        (
            lambda: vicrl_loss(*[tensor(EXPERT)] * 2, tensor(NOMINAL), *[tensor(NOMINAL)] * 3),
            r"`expert_alpha` and `expert_feasibility_sample` must have the same shape",
        ),
        (lambda: vicrl_loss(*[tensor(EXPERT)] * 3, *[tensor(NOMINAL)] * 3, kl_coef=-1.0), "kl_coef"),
    ],
)
def test_clear_errors_on_bad_inputs(call, message):
    with pytest.raises((ValueError, TypeError), match=message):
        call()
