"""Feasibility nets: input handling, normaliser, Beta cost modes, save/load and error messages."""

import copy

import numpy as np
import pytest
import scipy.integrate
import scipy.stats
import torch as th
from gymnasium import spaces
from torch import nn

from sb3_icrl.constraints import BetaFeasibilityNet, FeasibilityNet, InputNormalizer, beta_tail_feasibility
from sb3_icrl.constraints.networks import NUMPY_MAX_BATCH

RNG = np.random.default_rng(0)
OBS = RNG.normal(3.0, 2.0, size=(32, 4)).astype(np.float32)
ACTS = RNG.uniform(-1.0, 1.0, size=(32, 2)).astype(np.float32)


def make_net(cls=FeasibilityNet, **kwargs) -> FeasibilityNet | BetaFeasibilityNet:
    th.manual_seed(0)
    net = cls(4, 2, hidden_sizes=(8,), **kwargs)
    if net.normalize_input:
        net.fit_normalizer(OBS, ACTS)
    return net


def test_feasibility_in_unit_interval_and_cost_is_one_minus_phi():
    net = make_net()
    phi = net.predict_feasibility(OBS, ACTS)
    assert phi.shape == (32,) and phi.dtype == np.float32
    assert np.all((phi > 0.0) & (phi < 1.0))
    np.testing.assert_allclose(net.cost(OBS, ACTS), 1.0 - phi, rtol=1e-6)
    assert net.feasibility(OBS, ACTS).requires_grad


def test_normaliser_standardises_the_expert_inputs_and_clips():
    net = make_net(clip_input=3.0)
    inputs = net.preprocess(OBS, ACTS)
    np.testing.assert_allclose(inputs.mean(dim=0).numpy(), 0.0, atol=1e-5)
    np.testing.assert_allclose(inputs.std(dim=0, unbiased=False).numpy(), 1.0, atol=1e-4)
    far = net.preprocess(OBS[:1] + 1e3, ACTS[:1])
    assert far[0, :4].tolist() == [3.0] * 4


def test_constant_expert_feature_stays_finite():
    normalizer = InputNormalizer(2)
    normalizer.fit(th.tensor([[1.0, 5.0], [2.0, 5.0]]))
    out = normalizer(th.tensor([[1.5, 6.0]]))
    assert th.all(th.isfinite(out)) and out[0, 1].item() == 10.0  # clipped, not inf


def test_unfitted_normaliser_refuses_to_run():
    net = FeasibilityNet(4, 2, hidden_sizes=(8,))
    with pytest.raises(RuntimeError, match=r"not been fitted: call `fit_normalizer\(expert_obs, expert_acts\)`"):
        net.cost(OBS, ACTS)
    raw = FeasibilityNet(4, 2, hidden_sizes=(8,), normalize_input=False)
    assert raw.cost(OBS, ACTS).shape == (32,)


def test_obs_select_dim_and_use_action_decide_the_inputs():
    net = make_net(obs_select_dim=[0, 2], use_action=False)
    assert net.input_dim == 2
    changed = OBS.copy()
    changed[:, [1, 3]] += 5.0
    np.testing.assert_array_equal(net.predict_feasibility(OBS, ACTS), net.predict_feasibility(changed, -ACTS))
    np.testing.assert_array_equal(net.predict_feasibility(OBS, ACTS), net.predict_feasibility(OBS, None))
    moved = OBS.copy()
    moved[:, 0] += 5.0
    assert not np.allclose(net.predict_feasibility(OBS, None), net.predict_feasibility(moved, None))
    with_action = make_net(obs_select_dim=[])
    assert with_action.input_dim == 2
    assert not np.allclose(with_action.predict_feasibility(OBS, ACTS), with_action.predict_feasibility(OBS, -ACTS))


def test_discrete_spaces_are_one_hot_encoded():
    net = FeasibilityNet.from_spaces(spaces.Discrete(5), spaces.Discrete(3), hidden_sizes=(8,), normalize_input=False)
    assert (net.obs_dim, net.action_dim, net.input_dim) == (5, 3, 8)
    inputs = net.preprocess(np.array([4, 0]), np.array([[2], [1]]))
    np.testing.assert_array_equal(inputs.numpy(), [[0, 0, 0, 0, 1, 0, 0, 1], [1, 0, 0, 0, 0, 0, 1, 0]])
    with pytest.raises(ValueError, match=r"Discrete actions must be integers in \[0, 2\], got \[3, 1\]"):
        net.preprocess(np.array([4, 0]), np.array([3, 1]))
    box = FeasibilityNet.from_spaces(spaces.Box(-1, 1, (6,)), spaces.Box(-1, 1, (1,)), normalize_input=False)
    assert (box.obs_dim, box.action_dim, box.discrete_obs) == (6, 1, False)
    assert box.cost(np.zeros((3, 6)), np.zeros(3)).shape == (3,)  # (batch,) actions of a 1-D Box are accepted


@pytest.mark.parametrize(
    "call,message",
    [
        (lambda net: net.cost(OBS[:, :3], ACTS), r"shape \(batch, 4\), got \(32, 3\).*built for 4 observation features"),
        (lambda net: net.cost(OBS[0], ACTS[:1]), r"got \(4,\)\. Pass a single observation as obs\[None\]"),
        (lambda net: net.cost(OBS, ACTS[:, :1]), r"Actions must be a batch of shape \(batch, 2\), got \(32, 1\)"),
        (lambda net: net.cost(OBS, ACTS[:5]), "Got 32 observations but 5 actions"),
        (lambda net: net.cost(OBS, None), "takes the action as input"),
        (lambda net: net.fit_normalizer(OBS[:0], ACTS[:0]), r"non-empty batch of shape \(n_samples, 6\), got \(0, 6\)"),
    ],
)
def test_clear_errors_on_bad_inputs(call, message):
    with pytest.raises(ValueError, match=message):
        call(make_net())


def test_constructor_errors():
    with pytest.raises(ValueError, match=r"indices \[4\] outside the 4 observation features"):
        FeasibilityNet(4, 2, obs_select_dim=[0, 4])
    with pytest.raises(ValueError, match="no input"):
        FeasibilityNet(4, 2, obs_select_dim=[], use_action=False)
    with pytest.raises(ValueError, match="flat Box or a Discrete observation space"):
        FeasibilityNet.from_spaces(spaces.Box(0, 1, (2, 2)), spaces.Discrete(2))
    with pytest.raises(ValueError, match=r"class from torch\.nn"):
        FeasibilityNet(4, 2, activation_fn=lambda: nn.ReLU())
    with pytest.raises(ValueError, match="Unknown cost mode 'median'"):
        BetaFeasibilityNet(4, 2, cost_mode="median")
    with pytest.raises(ValueError, match=r"`confidence` must be in \(0, 1\), got 1.0"):
        BetaFeasibilityNet(4, 2, confidence=1.0)
    # A misspelt argument from a recipe's constraint_net_kwargs: named, with the closest argument the net takes
    with pytest.raises(
        TypeError, match=r"BetaFeasibilityNet takes no argument 'hiden_sizes' \(did you mean 'hidden_sizes'\?\)"
    ):
        BetaFeasibilityNet.from_spaces(spaces.Box(0, 1, (4,)), spaces.Discrete(2), hiden_sizes=[8])
    with pytest.raises(TypeError, match="takes no argument 'width': its arguments are activation_fn, clip_input, hidden"):
        FeasibilityNet.from_spaces(spaces.Box(0, 1, (4,)), spaces.Discrete(2), width=8)


@pytest.mark.parametrize("cls,extra", [(FeasibilityNet, {}), (BetaFeasibilityNet, dict(cost_mode="VaR", confidence=0.8))])
def test_save_and_load_round_trip(tmp_path, cls, extra):
    net = make_net(cls, obs_select_dim=[1, 3], activation_fn=nn.Tanh, **extra)
    path = str(tmp_path / "constraint.pt")
    net.save(path)
    loaded = cls.load(path)
    assert loaded.constructor_kwargs == net.constructor_kwargs
    assert loaded.activation_fn is nn.Tanh
    np.testing.assert_array_equal(loaded.preprocess(OBS, ACTS).numpy(), net.preprocess(OBS, ACTS).numpy())
    if cls is FeasibilityNet:
        np.testing.assert_array_equal(loaded.cost(OBS, ACTS), net.cost(OBS, ACTS))
    else:
        assert loaded.cost_mode == "var" and loaded.confidence == 0.8
        np.testing.assert_array_equal(loaded.cost(OBS, ACTS), net.cost(OBS, ACTS))
    other = BetaFeasibilityNet if cls is FeasibilityNet else FeasibilityNet
    with pytest.raises(ValueError, match=f"holds a '{cls.__name__}', not a {other.__name__}"):
        other.load(path)


def test_beta_parameters_stay_positive_for_extreme_inputs():
    net = make_net(BetaFeasibilityNet)
    with th.no_grad():
        net.network[-1].bias.fill_(-1e4)  # softplus underflows to 0 here
    alpha, beta = net.alpha_beta(OBS, ACTS)
    assert th.all(alpha > 0) and th.all(beta > 0)
    assert th.all(th.isfinite(net.distribution(OBS, ACTS).log_prob(th.full((32,), 0.5))))


def test_beta_cost_modes():
    net = make_net(BetaFeasibilityNet)
    alpha, beta = (value.detach().numpy().astype(np.float64) for value in net.alpha_beta(OBS, ACTS))
    mean = net.predict_feasibility(OBS, ACTS, cost_mode="mean")
    np.testing.assert_allclose(mean, alpha / (alpha + beta), rtol=1e-6)

    value_at_risk = net.predict_feasibility(OBS, ACTS, cost_mode="var", confidence=0.9)
    # The low-feasibility tail: P(phi <= VaR) = 1 - confidence
    np.testing.assert_allclose(scipy.stats.beta.cdf(value_at_risk, alpha, beta), 0.1, atol=1e-5)
    cvar = net.predict_feasibility(OBS, ACTS, cost_mode="cvar", confidence=0.9)
    assert np.all(cvar <= value_at_risk + 1e-7) and np.all(value_at_risk < mean)
    # Higher confidence, larger (more risk-averse) cost
    assert np.all(net.cost(OBS, ACTS) >= 0) and np.all(
        1 - net.predict_feasibility(OBS, ACTS, cost_mode="var", confidence=0.95) > 1 - value_at_risk
    )

    th.manual_seed(1)
    samples = np.stack([net.predict_feasibility(OBS, ACTS, cost_mode="sample") for _ in range(200)])
    assert np.all((samples >= 0) & (samples <= 1))
    np.testing.assert_allclose(samples.mean(axis=0), mean, atol=0.1)

    net.cost_mode = "mean"
    np.testing.assert_allclose(net.cost(OBS, ACTS), 1 - mean, rtol=1e-6)


@pytest.mark.parametrize("alpha,beta,confidence", [(2.0, 5.0, 0.9), (0.9, 0.1, 0.5), (8.0, 1.5, 0.95)])
def test_cvar_matches_the_tail_mean_by_integration(alpha, beta, confidence):
    value_at_risk = beta_tail_feasibility(np.array([alpha]), np.array([beta]), confidence, "var")[0]
    tail_mean, _ = scipy.integrate.quad(lambda x: x * scipy.stats.beta.pdf(x, alpha, beta), 0.0, value_at_risk)
    tail_mean /= 1.0 - confidence
    cvar = beta_tail_feasibility(np.array([alpha]), np.array([beta]), confidence, "cvar")[0]
    assert cvar == pytest.approx(tail_mean, rel=1e-6)


@pytest.mark.parametrize("obs_select_dim", [[0, 3], [3, 0], None, [0, 1, 2, 3, 4]])
@pytest.mark.parametrize("activation_fn", [nn.ReLU, nn.Tanh, nn.LeakyReLU, nn.ELU, nn.Sigmoid])
@pytest.mark.parametrize("net_class", [FeasibilityNet, BetaFeasibilityNet])
def test_numpy_cost_equals_torch_forward(net_class, activation_fn, obs_select_dim):
    """The per-step NumPy path gives the torch forward pass's feasibility, for every activation and feature choice."""
    rng = np.random.default_rng(0)
    net = net_class(5, 2, hidden_sizes=[16, 8], activation_fn=activation_fn, obs_select_dim=obs_select_dim, clip_input=2.0)
    expert_obs, expert_acts = rng.normal(size=(200, 5)), rng.normal(size=(200, 2))
    net.fit_normalizer(expert_obs, expert_acts)
    obs, acts = 3 * rng.normal(size=(4, 5)), rng.normal(size=(4, 2))  # some inputs clipped by the normaliser
    assert net._numpy_forward(obs, acts) is not None
    with th.no_grad():
        if net_class is FeasibilityNet:
            expected = net.feasibility(obs, acts).numpy()
        else:
            alpha, beta = net.alpha_beta(obs, acts)
            expected = (alpha / (alpha + beta)).numpy()
    kwargs = {} if net_class is FeasibilityNet else {"cost_mode": "mean"}
    np.testing.assert_allclose(net.predict_feasibility(obs, acts, **kwargs), expected, rtol=1e-5, atol=1e-6)
    # A batch above NUMPY_MAX_BATCH goes through torch: the same values for the same pairs
    big_obs, big_acts = np.repeat(obs, NUMPY_MAX_BATCH, axis=0), np.repeat(acts, NUMPY_MAX_BATCH, axis=0)
    assert net._numpy_forward(big_obs, big_acts) is None
    np.testing.assert_allclose(
        net.predict_feasibility(big_obs, big_acts, **kwargs)[::NUMPY_MAX_BATCH], expected, rtol=1e-5, atol=1e-6
    )


def test_numpy_cost_follows_every_weight_change():
    """An optimiser step, load_state_dict and a new normaliser fit all reach the per-step cost at once."""
    rng = np.random.default_rng(1)
    net = FeasibilityNet(3, 1, hidden_sizes=[8])
    net.fit_normalizer(rng.normal(size=(50, 3)), rng.normal(size=(50, 1)))
    obs, acts = rng.normal(size=(2, 3)), rng.normal(size=(2, 1))
    before = net.cost(obs, acts)
    snapshot = copy.deepcopy(net.state_dict())
    optimizer = th.optim.Adam(net.parameters(), lr=0.5)
    net.feasibility(obs, acts).sum().backward()
    optimizer.step()
    stepped = net.cost(obs, acts)
    assert not np.allclose(stepped, before)
    with th.no_grad():
        np.testing.assert_allclose(stepped, 1 - net.feasibility(obs, acts).numpy(), rtol=1e-5)
    net.load_state_dict(snapshot)
    np.testing.assert_array_equal(net.cost(obs, acts), before)
    net.fit_normalizer(rng.normal(loc=3.0, size=(50, 3)), rng.normal(size=(50, 1)))
    with th.no_grad():
        np.testing.assert_allclose(net.cost(obs, acts), 1 - net.feasibility(obs, acts).numpy(), rtol=1e-5)


def test_numpy_path_left_to_torch_where_it_does_not_apply():
    """Discrete spaces, torch inputs, unknown activations and malformed batches take the torch path (and its errors)."""
    rng = np.random.default_rng(2)
    discrete = FeasibilityNet(4, 3, discrete_obs=True, discrete_actions=True, normalize_input=False)
    assert discrete._numpy_forward(np.array([0, 1]), np.array([2, 0])) is None
    net = FeasibilityNet(3, 1, hidden_sizes=[8], normalize_input=False, activation_fn=nn.GELU)
    assert net._numpy_forward(rng.normal(size=(2, 3)), rng.normal(size=(2, 1))) is None
    relu = FeasibilityNet(3, 1, hidden_sizes=[8], normalize_input=False)
    assert relu._numpy_forward(th.zeros(2, 3), th.zeros(2, 1)) is None
    with pytest.raises(ValueError, match="batch of shape"):
        relu.cost(rng.normal(size=3), rng.normal(size=(1, 1)))
