"""The statistics of benchmark reports against hand-computed values and rliable's own numbers on fixed sets."""

import math

import numpy as np
import pytest

from sb3_icrl.common import statistics
from sb3_icrl.common.statistics import (
    MIN_PAIRS_FOR_WILCOXON,
    MIN_SEEDS_FOR_INTERVAL,
    iqm,
    mean_of_task_means,
    normalised_score,
    optimality_gap,
    performance_profile,
    performance_profile_ci,
    probability_of_improvement,
    probability_of_improvement_ci,
    sample_std,
    sign_test_p,
    stratified_bootstrap_ci,
    stratified_bootstrap_ci_of_task_means,
    wilcoxon_p,
    wilson_interval,
)

#: Two methods' scores on three tasks (rows are tasks, entries seeds), and what rliable 1.2.0 computes for them, in a
#: virtual environment of its own (``pip install rliable "pandas<3"``: it does not run with pandas 3, which the
#: package's other extras install, so it is no test dependency): ``rliable.metrics.aggregate_iqm(X)``,
#: ``aggregate_mean(X)``, ``aggregate_optimality_gap(X)`` and ``probability_of_improvement(X, Y)`` with
#: ``X = np.array(X_SCORES).T`` and ``Y = np.array(Y_SCORES).T`` (runs x tasks)
X_SCORES = [[0.9, 0.2, 0.5, 1.1, 0.7], [0.1, 0.3, 0.35, 0.0, 0.6], [1.2, 0.95, 0.8, 0.4, 1.0]]
Y_SCORES = [[0.5, 0.4, 0.3, 0.9, 0.6], [0.2, 0.3, 0.1, 0.05, 0.25], [0.7, 1.1, 0.6, 0.65, 0.9]]
RLIABLE = {"iqm_x": 0.6111111111111112, "mean_x": 0.6066666666666666, "gap_x": 0.41333333333333333, "poi_xy": 0.64}
#: ``rliable.library.create_performance_profile({"x": X}, PROFILE_TAUS)[0]["x"]`` in the same environment
PROFILE_TAUS = [0.0, 0.25, 0.5, 0.75, 1.0]
RLIABLE_PROFILE_X = [0.9333333333333333, 0.8, 0.5333333333333333, 0.4, 0.13333333333333333]


def test_sample_std_uses_n_minus_one() -> None:
    # deviations -1.5, -0.5, 0.5, 1.5: squares sum to 5, over n - 1 = 3
    assert sample_std([1.0, 2.0, 3.0, 4.0]) == pytest.approx(math.sqrt(5 / 3))
    assert math.isnan(sample_std([3.0]))


def test_wilson_interval_matches_the_formula() -> None:
    # 3 of 5 at z = 1.96: centre (0.6 + 1.9208 / 5) / (1 + 3.8416 / 5), half-width 1.96 / 1.76832 * sqrt(0.048 + 0.038416)
    z = 1.959963984540054
    centre = (0.6 + z * z / 10) / (1 + z * z / 5)
    half = z / (1 + z * z / 5) * math.sqrt(0.6 * 0.4 / 5 + z * z / 100)
    assert wilson_interval(3, 5) == pytest.approx((centre - half, centre + half))
    low, high = wilson_interval(0, 5)
    assert low == 0.0 and high == pytest.approx(z * z / 5 / (1 + z * z / 5))  # not empty at 0 successes
    assert wilson_interval(5, 5)[1] == 1.0 and wilson_interval(5, 5)[0] == pytest.approx(1 - high)
    assert all(math.isnan(value) for value in wilson_interval(0, 0))
    with pytest.raises(ValueError, match="within"):
        wilson_interval(6, 5)


def test_normalised_score_places_ppo_at_zero_and_the_oracle_at_one() -> None:
    assert normalised_score(100.0, 100.0, 300.0) == 0.0
    assert normalised_score(300.0, 100.0, 300.0) == 1.0
    assert normalised_score(250.0, 100.0, 300.0) == pytest.approx(0.75)
    assert normalised_score(50.0, 100.0, 300.0) == pytest.approx(-0.25)
    assert math.isnan(normalised_score(1.0, 2.0, 2.0)) and math.isnan(normalised_score(1.0, float("nan"), 2.0))


def test_optimality_gap_counts_only_the_shortfall() -> None:
    assert optimality_gap([0.5, 1.5, 0.8]) == pytest.approx((0.5 + 0.0 + 0.2) / 3)


def test_probability_of_improvement_counts_ties_half() -> None:
    # task 1: x beats y in 3 of 4 pairs; task 2: one tie of one pair
    assert probability_of_improvement([[2.0, 3.0], [1.0]], [[1.0, 2.5], [1.0]]) == pytest.approx((3 / 4 + 0.5) / 2)
    low, high = probability_of_improvement_ci([[2.0, 3.0], [1.0]], [[1.0, 2.5], [1.0]], reps=200)
    assert 0 <= low <= high <= 1
    with pytest.raises(ValueError, match="same tasks"):
        probability_of_improvement([[1.0]], [[1.0], [2.0]])


def test_aggregates_equal_rliables_numbers() -> None:
    flat = np.concatenate(X_SCORES)
    assert iqm(flat) == pytest.approx(RLIABLE["iqm_x"])
    assert np.mean([np.mean(task) for task in X_SCORES]) == pytest.approx(RLIABLE["mean_x"])
    assert optimality_gap(flat) == pytest.approx(RLIABLE["gap_x"])
    assert probability_of_improvement(X_SCORES, Y_SCORES) == pytest.approx(RLIABLE["poi_xy"])
    low, high = stratified_bootstrap_ci(X_SCORES, reps=500)
    assert low <= RLIABLE["iqm_x"] <= high


def test_performance_profile_equals_rliables_and_its_band_holds_it() -> None:
    profile = performance_profile(X_SCORES, PROFILE_TAUS)
    np.testing.assert_allclose(profile, RLIABLE_PROFILE_X)
    # By hand at tau = 0.5: 3 of 5 seeds above it on the first task, 1 on the second, 4 on the third
    assert profile[2] == pytest.approx(np.mean([3 / 5, 1 / 5, 4 / 5]))
    lower, upper = performance_profile_ci(X_SCORES, PROFILE_TAUS, reps=300)
    assert np.all(lower <= profile) and np.all(profile <= upper)
    # Tasks weigh the same whatever their number of seeds
    assert performance_profile([[1.0], [0.0, 0.0, 0.0]], [0.5])[0] == pytest.approx(0.5)


def test_wilcoxon_needs_differences_and_the_labels_have_their_thresholds() -> None:
    # six positive differences: the exact two-sided p is 2 / 2^6, the first below 0.05
    assert wilcoxon_p([1, 2, 3, 4, 5, 6]) == pytest.approx(2 / 64)
    assert math.isnan(wilcoxon_p([])) and math.isnan(wilcoxon_p([0.0, 0.0]))
    assert 2 / 2**MIN_PAIRS_FOR_WILCOXON < 0.05 <= 2 / 2 ** (MIN_PAIRS_FOR_WILCOXON - 1)
    assert MIN_SEEDS_FOR_INTERVAL == 5


def test_sign_test_against_the_binomial_by_hand() -> None:
    # all of 5 pairs one way: 2 * (1/2)^5; 4 of 5: 2 * (1 + 5) / 2^5; an even split: 1
    assert sign_test_p([-3.0, -1.0, -2.0, -0.5, -9.0]) == pytest.approx(2 / 32)
    assert sign_test_p([-3.0, -1.0, -2.0, -0.5, 9.0]) == pytest.approx(2 * 6 / 32)
    assert sign_test_p([1.0, -1.0]) == pytest.approx(1.0)
    # the sizes do not matter, the signs do: a huge rise counts as one sign like a small one
    assert sign_test_p([-1.0, -1.0, -1.0, -1.0, 1e9]) == sign_test_p([-1.0, -1.0, -1.0, -1.0, 1e-9])
    # zero and non-finite differences carry no sign: 4 of 4 signed pairs lower
    assert sign_test_p([-1.0, -2.0, 0.0, -3.0, float("nan"), -4.0]) == pytest.approx(2 / 16)
    assert math.isnan(sign_test_p([])) and math.isnan(sign_test_p([0.0, 0.0]))


def test_mean_of_task_means_and_its_interval():
    uneven = [np.array([0.0, 1.0, 2.0, 3.0]), np.array([10.0])]
    assert mean_of_task_means(uneven) == pytest.approx((1.5 + 10.0) / 2)  # not the pooled 3.2
    assert math.isnan(mean_of_task_means([])) and math.isnan(mean_of_task_means([[]]))
    # Its interval is of the same statistic: by hand, over the same stratified resamples
    rng = np.random.default_rng(0)
    estimates = [np.mean([task[rng.integers(0, task.size, task.size)].mean() for task in uneven]) for _ in range(200)]
    expected = tuple(np.percentile(estimates, [2.5, 97.5]))
    assert stratified_bootstrap_ci_of_task_means(uneven, reps=200, seed=0) == pytest.approx(expected)
    low, high = stratified_bootstrap_ci_of_task_means(uneven, reps=200, seed=0)
    assert low <= mean_of_task_means(uneven) <= high
    # With as many seeds per task, the same interval as the mean of all scores
    even = [np.array([0.1, 0.4, 0.2]), np.array([0.9, 0.5, 0.7])]
    assert stratified_bootstrap_ci_of_task_means(even, reps=300) == pytest.approx(
        stratified_bootstrap_ci(even, statistic=np.mean, reps=300)
    )


@pytest.mark.parametrize("sizes", [[1], [5], [3, 7, 2], [20, 20, 20, 20], [1, 4, 9, 2, 35], [5] * 9, [3] * 17])
def test_row_wise_bootstrap_gives_the_per_resample_numbers(sizes: list[int]) -> None:
    # The bootstrap computes IQM, optimality gap and mean of task means on all resamples at once; the numbers must be
    # those of one call per resample on the same draws, to the last bit (committed reports must not move)
    rng = np.random.default_rng(3)
    tasks = [rng.normal(size=size) * 10.0 ** rng.integers(-3, 3) for size in sizes]
    for statistic in (statistics.iqm, statistics.optimality_gap):

        def of_resample(resample: list[np.ndarray], statistic=statistic) -> float:
            return statistic(np.concatenate(resample))

        one_by_one = statistics._bootstrap_interval(tasks, of_resample, 300, 0.95, 0)
        assert statistics.stratified_bootstrap_ci(tasks, statistic=statistic, reps=300) == one_by_one
    one_by_one = statistics._bootstrap_interval(tasks, statistics.mean_of_task_means, 300, 0.95, 0)
    assert statistics.stratified_bootstrap_ci_of_task_means(tasks, reps=300) == one_by_one
    assert statistics.stratified_bootstrap_ci([[], []]) == pytest.approx((np.nan, np.nan), nan_ok=True)
    assert statistics.stratified_bootstrap_ci_of_task_means([[]]) == pytest.approx((np.nan, np.nan), nan_ok=True)


@pytest.mark.parametrize("sizes", [[(1, 1)], [(5, 5)], [(3, 4), (5, 1), (2, 2)], [(5, 5)] * 9])
def test_row_wise_probability_of_improvement_gives_the_per_resample_numbers(sizes: list[tuple[int, int]]) -> None:
    # The same draws as a loop that resamples X's seeds then Y's, task by task, and calls the statistic once per resample
    rng = np.random.default_rng(4)
    xs = [rng.integers(0, 4, size=nx).astype(float) for nx, _ in sizes]  # few values: ties happen
    ys = [rng.integers(0, 4, size=ny).astype(float) for _, ny in sizes]
    draws, estimates = np.random.default_rng(0), []
    for _ in range(300):
        pairs = zip(xs, ys, strict=True)
        resampled = [(x[draws.integers(0, x.size, x.size)], y[draws.integers(0, y.size, y.size)]) for x, y in pairs]
        estimates.append(statistics.probability_of_improvement([x for x, _ in resampled], [y for _, y in resampled]))
    one_by_one = statistics._percentile_interval(np.array(estimates), 0.95)
    assert statistics.probability_of_improvement_ci(xs, ys, reps=300) == one_by_one


@pytest.mark.parametrize("sizes", [[1], [5], [3, 7, 2], [1, 4, 9, 2, 35]])
def test_resamples_draw_the_indices_of_one_call_per_task(sizes: list[int]) -> None:
    # The reports' intervals (and so the committed reports) rest on this stream: resample by resample, task by task
    tasks = [np.arange(size, dtype=float) for size in sizes]
    rng = np.random.default_rng(0)
    expected = [[rng.integers(0, size, size) for size in sizes] for _ in range(50)]
    matrices = statistics._resample_matrices(tasks, 50, 0)
    for rep in range(50):
        for matrix, indices in zip(matrices, expected[rep], strict=True):
            assert np.array_equal(matrix[rep], indices)
    assert [[list(row) for row in resample] for resample in statistics._stratified_resamples(tasks, 50, 0)] == [
        [list(indices.astype(float)) for indices in resample] for resample in expected
    ]
