import pickle

import numpy as np
import pytest

from sb3_icrl.common.lagrange import GradientLagrangeMultiplier, PIDLagrangeMultiplier, make_lagrange_multiplier

MULTIPLIERS = [
    ("gradient", dict(init=0.5, lr=0.05, optimizer="sgd")),
    ("gradient", dict(init=0.5, lr=0.05, optimizer="adam")),
    ("pid", dict(init=0.0, kp=0.1, ki=0.01, kd=0.01, d_delay=5)),
]


@pytest.mark.parametrize("kind,kwargs", MULTIPLIERS)
def test_grows_above_budget_then_decays_to_zero_and_stays(kind, kwargs):
    multiplier = make_lagrange_multiplier(kind, cost_budget=25.0, n_constraints=1, **kwargs)
    above = [multiplier.update(np.array([40.0]))[0] for _ in range(50)]
    assert np.all(np.diff(above) > 0), "lambda must grow at every update while the cost is above budget"

    below = [multiplier.update(np.array([10.0]))[0] for _ in range(400)]
    first_zero = next(i for i, value in enumerate(below) if value == 0.0)
    assert np.all(np.array(below[first_zero:]) == 0.0), "once at 0 below budget, lambda stays at 0"


def test_sgd_step_is_lr_times_violation():
    multiplier = GradientLagrangeMultiplier(cost_budget=[1.0, 2.0], n_constraints=2, init=[0.5, 0.1], lr=0.1, optimizer="sgd")
    np.testing.assert_allclose(multiplier.update(np.array([3.0, 1.0])), [0.5 + 0.1 * 2.0, 0.0], atol=1e-6)
    # Second constraint projected on 0; first keeps growing
    np.testing.assert_allclose(multiplier.update(np.array([3.0, 1.0])), [0.9, 0.0], atol=1e-6)


def test_adam_first_step_is_lr_in_the_violation_direction():
    multiplier = GradientLagrangeMultiplier(cost_budget=0.0, init=1.0, lr=0.01, optimizer="adam")
    # Adam's first step is lr * sign(gradient), whatever the gradient's scale
    np.testing.assert_allclose(multiplier.update(np.array([123.0])), [1.01], atol=1e-6)


def test_upper_bound():
    multiplier = GradientLagrangeMultiplier(cost_budget=0.0, init=0.0, lr=1.0, optimizer="sgd", upper_bound=2.5)
    for _ in range(5):
        value = multiplier.update(np.array([1.0]))
    assert value[0] == 2.5


def test_pid_matches_hand_computation():
    pid = PIDLagrangeMultiplier(
        cost_budget=10.0, kp=1.0, ki=0.5, kd=2.0, d_delay=2, delta_p_ema_alpha=0.5, delta_d_ema_alpha=0.0
    )
    # step 1: delta 4, I = 2, P = 0.5*0 + 0.5*4 = 2, cost_d = 14, D = max(0, 14 - 0) = 14 -> lambda = 2 + 2 + 28
    assert pid.update(np.array([14.0]))[0] == pytest.approx(32.0)
    # step 2: delta 2, I = 3, P = 0.5*2 + 0.5*2 = 2, cost_d = 12, D = max(0, 12 - 0) (history [0, 14]) -> 2 + 3 + 24
    assert pid.update(np.array([12.0]))[0] == pytest.approx(29.0)
    # step 3: delta -10, I = max(0, 3 - 5) = 0, P = 0.5*2 - 5 = -4, cost_d = 0, D = max(0, 0 - 14) = 0 -> clip(-4) = 0
    assert pid.update(np.array([0.0]))[0] == 0.0


@pytest.mark.parametrize("kind,kwargs", MULTIPLIERS)
def test_pickle_round_trip_continues_identically(kind, kwargs):
    multiplier = make_lagrange_multiplier(kind, cost_budget=5.0, n_constraints=1, **kwargs)
    for cost in (9.0, 7.0, 12.0):
        multiplier.update(np.array([cost]))
    restored = pickle.loads(pickle.dumps(multiplier))
    np.testing.assert_array_equal(restored.value, multiplier.value)
    for cost in (3.0, 8.0, 1.0, 20.0):
        np.testing.assert_array_equal(restored.update(np.array([cost])), multiplier.update(np.array([cost])))


def test_bad_arguments_raise_clear_errors():
    with pytest.raises(ValueError, match="Unknown Lagrange multiplier update 'pi'"):
        make_lagrange_multiplier("pi", 0.0, 1)
    with pytest.raises(ValueError, match="Unknown multiplier optimizer"):
        GradientLagrangeMultiplier(0.0, optimizer="rmsprop")
    with pytest.raises(ValueError, match="must be >= 0"):
        GradientLagrangeMultiplier(0.0, init=-1.0)
    with pytest.raises(ValueError, match="one per constraint"):
        GradientLagrangeMultiplier([1.0, 2.0, 3.0], n_constraints=2)
    with pytest.raises(TypeError, match="Bad `lagrange_kwargs` for the 'pid' multiplier"):
        make_lagrange_multiplier("pid", 0.0, 1, lr=0.1)
    multiplier = GradientLagrangeMultiplier([1.0, 2.0], n_constraints=2)
    with pytest.raises(ValueError, match="Expected 2 finite constraint value"):
        multiplier.update(np.array([1.0]))
    with pytest.raises(ValueError, match="Expected 2 finite constraint value"):
        multiplier.update(np.array([1.0, np.nan]))
