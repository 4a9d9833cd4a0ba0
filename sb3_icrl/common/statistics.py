"""
Statistics of benchmark results over seeds, with labels that say what they are at their sample size.

The aggregates follow rliable (Agarwal et al. 2021, "Deep reinforcement learning at the edge of the statistical
precipice"): the interquartile mean (IQM) is the mean of the middle 50% of the scores, the optimality gap the mean
shortfall below a target score, the probability of improvement the chance that a run of one method beats a run of
another on the same task (the Mann-Whitney U statistic over the number of pairs, averaged over tasks), and their
confidence intervals are percentile intervals of a stratified bootstrap that resamples the runs (seeds) of each task
independently. They are computed with NumPy and SciPy, so that a report needs no extra package.
"""

import math
from collections.abc import Callable, Iterator, Sequence

import numpy as np
import scipy.stats

#: Bootstrap resamples of the confidence intervals
BOOTSTRAP_REPS = 2000
#: Seed of the bootstrap, so that a report is reproducible
BOOTSTRAP_SEED = 0
#: Fewest seeds for which a cell reports an IQM with a bootstrap interval; below it, mean and [min, max]: with 3 seeds
#: the IQM is the plain mean and the bootstrap's percentile interval is the range of the seeds
MIN_SEEDS_FOR_INTERVAL = 5
#: Fewest pairs for which a Wilcoxon signed-rank test is reported: an exact two-sided test cannot go below p = 0.0625
#: with 5 pairs (2 / 2^5), so with fewer it can never show a difference at the 5% level
MIN_PAIRS_FOR_WILCOXON = 6

ScoresByTask = Sequence[Sequence[float] | np.ndarray]


def iqm(scores: Sequence[float] | np.ndarray) -> float:
    """Interquartile mean: the mean of the scores left after cutting the lowest and highest 25%."""
    values = np.asarray(scores, dtype=float).ravel()
    if values.size == 0:
        return float("nan")
    return float(scipy.stats.trim_mean(values, proportiontocut=0.25))


def iqm_of_rows(scores: np.ndarray) -> np.ndarray:
    """:func:`iqm` of each row of a 2-D array (one resample per row), with the same trimming and arithmetic."""
    return np.asarray(scipy.stats.trim_mean(scores, proportiontocut=0.25, axis=1), dtype=float)


def sample_std(values: Sequence[float] | np.ndarray) -> float:
    """The sample standard deviation (``ddof=1``); ``nan`` with fewer than two values."""
    array = np.asarray(values, dtype=float).ravel()
    return float(array.std(ddof=1)) if array.size >= 2 else float("nan")


def optimality_gap(scores: Sequence[float] | np.ndarray, target: float = 1.0) -> float:
    """The mean shortfall of the scores below ``target`` (scores above it count as reaching it)."""
    values = np.asarray(scores, dtype=float).ravel()
    if values.size == 0:
        return float("nan")
    return float(np.mean(np.maximum(target - values, 0.0)))


def optimality_gap_of_rows(scores: np.ndarray, target: float = 1.0) -> np.ndarray:
    """:func:`optimality_gap` of each row of a 2-D array (one resample per row)."""
    return np.mean(np.maximum(target - scores, 0.0), axis=1)


#: The row-wise form of a statistic, with which a bootstrap computes every resample's estimate in one call instead of
#: one call per resample (the same numbers: the same draws, trimming and summation; the report spent most of its time
#: in those calls)
_ROW_STATISTICS: dict[Callable[[np.ndarray], float], Callable[[np.ndarray], np.ndarray]] = {
    iqm: iqm_of_rows,
    optimality_gap: optimality_gap_of_rows,
}


def stratified_bootstrap_ci(
    scores_by_task: ScoresByTask,
    statistic: Callable[[np.ndarray], float] = iqm,
    reps: int = BOOTSTRAP_REPS,
    confidence: float = 0.95,
    seed: int = BOOTSTRAP_SEED,
) -> tuple[float, float]:
    """
    Percentile confidence interval of ``statistic`` over all scores, resampling the runs (seeds) of each task with
    replacement, independently per task (rliable's stratified bootstrap). One task: the plain bootstrap over seeds.

    :param scores_by_task: One array of per-seed scores per task
    :param statistic: Function of the concatenated resampled scores
    :param reps: Number of resamples
    :param confidence: Interval size
    :param seed: Seed of the resampling
    :return: ``(lower, upper)``; ``(nan, nan)`` without scores
    """
    rows = _ROW_STATISTICS.get(statistic)
    if rows is not None:
        return _row_bootstrap_interval(
            scores_by_task, lambda matrices: rows(np.concatenate(matrices, axis=1)), reps, confidence, seed
        )
    return _bootstrap_interval(scores_by_task, lambda tasks: statistic(np.concatenate(tasks)), reps, confidence, seed)


def mean_of_task_means(scores_by_task: ScoresByTask) -> float:
    """
    rliable's mean across tasks: the mean of each task's mean, every task weighing the same however many seeds it has
    (the mean of all scores when every task has as many).

    :param scores_by_task: One array of per-seed scores per task
    :return: The mean; ``nan`` without scores
    """
    tasks = _nonempty_tasks(scores_by_task)
    return float(np.mean([task.mean() for task in tasks])) if tasks else float("nan")


def stratified_bootstrap_ci_of_task_means(
    scores_by_task: ScoresByTask, reps: int = BOOTSTRAP_REPS, confidence: float = 0.95, seed: int = BOOTSTRAP_SEED
) -> tuple[float, float]:
    """
    :func:`stratified_bootstrap_ci` of :func:`mean_of_task_means`: the interval of the same statistic as the point
    estimate when tasks have different numbers of seeds (the same resamples, so the same interval as the mean of all
    scores when every task has as many).

    Arguments and return: see :func:`stratified_bootstrap_ci`.
    """

    def task_means(matrices: list[np.ndarray]) -> np.ndarray:
        # one row of task means per resample, averaged along the row: the summation of the per-resample mean
        return np.stack([matrix.mean(axis=1) for matrix in matrices], axis=1).mean(axis=1)

    return _row_bootstrap_interval(scores_by_task, task_means, reps, confidence, seed)


def _bootstrap_interval(
    scores_by_task: ScoresByTask, estimate: Callable[[list[np.ndarray]], float], reps: int, confidence: float, seed: int
) -> tuple[float, float]:
    """The percentile interval of ``estimate`` (a function of the resampled tasks) over stratified resamples."""
    tasks = _nonempty_tasks(scores_by_task)
    if not tasks:
        return float("nan"), float("nan")
    estimates = np.array([estimate(resample) for resample in _stratified_resamples(tasks, reps, seed)])
    return _percentile_interval(estimates, confidence)


def _row_bootstrap_interval(
    scores_by_task: ScoresByTask,
    estimate_rows: Callable[[list[np.ndarray]], np.ndarray],
    reps: int,
    confidence: float,
    seed: int,
) -> tuple[float, float]:
    """:func:`_bootstrap_interval` with an estimate of every resample at once (of the per-task resample matrices)."""
    tasks = _nonempty_tasks(scores_by_task)
    if not tasks:
        return float("nan"), float("nan")
    return _percentile_interval(estimate_rows(_resample_matrices(tasks, reps, seed)), confidence)


def _nonempty_tasks(scores_by_task: ScoresByTask) -> list[np.ndarray]:
    """Each task's scores as a flat float array, tasks without scores left out."""
    tasks = [np.asarray(scores, dtype=float).ravel() for scores in scores_by_task]
    return [task for task in tasks if task.size]


def _stratified_resamples(tasks: list[np.ndarray], reps: int, seed: int) -> Iterator[list[np.ndarray]]:
    """``reps`` resamples of the tasks, each task's seeds drawn with replacement on their own (rliable's stratification)."""
    matrices = _resample_matrices(tasks, reps, seed)
    for rep in range(reps):
        yield [matrix[rep] for matrix in matrices]


def _resample_matrices(tasks: list[np.ndarray], reps: int, seed: int) -> list[np.ndarray]:
    """
    ``reps`` stratified resamples as one ``(reps, task size)`` array per task, from one draw of the stream: resample by
    resample, task by task, the indices a loop of ``rng.integers(0, size, size)`` per task would draw.
    """
    sizes = [task.size for task in tasks]
    bounds = np.concatenate([np.full(size, size) for size in sizes])
    indices = np.random.default_rng(seed).integers(0, np.broadcast_to(bounds, (reps, bounds.size)))
    starts = np.cumsum([0, *sizes[:-1]])
    return [task[indices[:, start : start + task.size]] for task, start in zip(tasks, starts, strict=True)]


def performance_profile(scores_by_task: ScoresByTask, taus: Sequence[float] | np.ndarray) -> np.ndarray:
    """
    rliable's score distribution (performance profile): for each threshold ``tau``, the share of runs whose score
    exceeds it, a share per task averaged over tasks (so that each task weighs the same; with as many seeds per task,
    the share of all runs, as rliable computes it).

    :param scores_by_task: One array of per-seed scores per task
    :param taus: The thresholds
    :return: One share per threshold (NaN without scores)
    """
    tasks = _nonempty_tasks(scores_by_task)
    thresholds = np.asarray(taus, dtype=float)
    if not tasks:
        return np.full(thresholds.shape, np.nan)
    return np.mean([(task[:, None] > thresholds[None, :]).mean(axis=0) for task in tasks], axis=0)


def performance_profile_ci(
    scores_by_task: ScoresByTask,
    taus: Sequence[float] | np.ndarray,
    reps: int = BOOTSTRAP_REPS,
    confidence: float = 0.95,
    seed: int = BOOTSTRAP_SEED,
) -> tuple[np.ndarray, np.ndarray]:
    """
    Percentile confidence band of :func:`performance_profile`, from a stratified bootstrap over each task's seeds.

    :return: ``(lower, upper)``, one value per threshold
    """
    tasks = _nonempty_tasks(scores_by_task)
    thresholds = np.asarray(taus, dtype=float)
    if not tasks:
        return np.full(thresholds.shape, np.nan), np.full(thresholds.shape, np.nan)
    profiles = np.array([performance_profile(resample, thresholds) for resample in _stratified_resamples(tasks, reps, seed)])
    tail = 100 * (1 - confidence) / 2
    lower, upper = np.percentile(profiles, [tail, 100 - tail], axis=0)
    return lower, upper


def _percentile_interval(estimates: np.ndarray, confidence: float) -> tuple[float, float]:
    tail = 100 * (1 - confidence) / 2
    lower, upper = np.percentile(estimates, [tail, 100 - tail])
    return float(lower), float(upper)


def _check_same_tasks(scores_x: ScoresByTask, scores_y: ScoresByTask) -> None:
    if len(scores_x) != len(scores_y):
        raise ValueError(f"Both methods need the same tasks: got {len(scores_x)} and {len(scores_y)}.")


def probability_of_improvement(scores_x: ScoresByTask, scores_y: ScoresByTask) -> float:
    """
    P(X > Y): the chance that a run of method X scores higher than a run of method Y on the same task (ties count
    half), averaged over the tasks both have runs on, as rliable defines it.

    :param scores_x: Per task, the per-seed scores of X
    :param scores_y: Per task, the per-seed scores of Y (same task order)
    :return: A probability; ``nan`` when no task has runs of both
    """
    _check_same_tasks(scores_x, scores_y)
    probabilities = []
    for x, y in zip(scores_x, scores_y, strict=True):
        x, y = np.asarray(x, dtype=float).ravel(), np.asarray(y, dtype=float).ravel()
        if x.size and y.size:
            wins = (x[:, None] > y[None, :]).sum() + 0.5 * (x[:, None] == y[None, :]).sum()
            probabilities.append(wins / (x.size * y.size))
    return float(np.mean(probabilities)) if probabilities else float("nan")


def probability_of_improvement_ci(
    scores_x: ScoresByTask,
    scores_y: ScoresByTask,
    reps: int = BOOTSTRAP_REPS,
    confidence: float = 0.95,
    seed: int = BOOTSTRAP_SEED,
) -> tuple[float, float]:
    """
    Percentile interval of :func:`probability_of_improvement`, resampling the seeds of each method on each task
    independently (rliable's stratified bootstrap for paired methods).
    """
    _check_same_tasks(scores_x, scores_y)
    pairs = zip(scores_x, scores_y, strict=True)
    tasks = [(np.asarray(x, dtype=float).ravel(), np.asarray(y, dtype=float).ravel()) for x, y in pairs]
    tasks = [(x, y) for x, y in tasks if x.size and y.size]
    if not tasks:
        return float("nan"), float("nan")
    # each resample draws X's seeds then Y's, task by task: the order of the interleaved list below
    matrices = _resample_matrices([scores for pair in tasks for scores in pair], reps, seed)
    per_task = [_improvement_of_rows(x_rows, y_rows) for x_rows, y_rows in zip(matrices[::2], matrices[1::2], strict=True)]
    return _percentile_interval(np.stack(per_task, axis=1).mean(axis=1), confidence)


def _improvement_of_rows(x_rows: np.ndarray, y_rows: np.ndarray) -> np.ndarray:
    """P(X > Y) on one task for each resample (row) of X's and Y's seeds, ties counting half."""
    x, y = x_rows[:, :, None], y_rows[:, None, :]
    wins = (x > y).sum(axis=(1, 2)) + 0.5 * (x == y).sum(axis=(1, 2))
    return wins / (x_rows.shape[1] * y_rows.shape[1])


def wilson_interval(successes: int, trials: int, confidence: float = 0.95) -> tuple[float, float]:
    """
    The Wilson score interval of a success probability: unlike the normal approximation, it stays within [0, 1] and
    is not empty at 0 or n successes, which small numbers of seeds make common.

    :param successes: Runs that succeeded
    :param trials: Runs
    :param confidence: Interval size
    :return: ``(lower, upper)``; ``(nan, nan)`` without trials
    """
    if trials <= 0:
        return float("nan"), float("nan")
    if not 0 <= successes <= trials:
        raise ValueError(f"successes must be within [0, {trials}], got {successes}.")
    z = float(scipy.stats.norm.ppf(0.5 + confidence / 2))
    share = successes / trials
    centre = (share + z * z / (2 * trials)) / (1 + z * z / trials)
    half = z / (1 + z * z / trials) * math.sqrt(share * (1 - share) / trials + z * z / (4 * trials * trials))
    return max(0.0, centre - half), min(1.0, centre + half)


def normalised_score(value: float, low: float, high: float) -> float:
    """
    ``(value - low) / (high - low)``: 0 at ``low`` (unconstrained PPO's feasible reward), 1 at ``high`` (the oracle's,
    PPO-Lagrangian on the true cost); ``nan`` where the two references coincide or one is unknown.
    """
    if not all(math.isfinite(x) for x in (value, low, high)) or high == low:
        return float("nan")
    return (value - low) / (high - low)


def sign_test_p(differences: Sequence[float]) -> float:
    """
    Exact two-sided sign-test p-value of paired differences: the binomial chance, at one half each way, of a split of
    signs at least as uneven as the one seen; zero differences carry no sign and are left out (``nan`` without a
    signed pair). It assumes nothing of the differences' sizes, and with few pairs it cannot get small: with 5 pairs
    all of one sign it is 2 / 2^5 = 0.0625, with 4, 0.125.
    """
    values = np.asarray(differences, dtype=float).ravel()
    signed = values[np.isfinite(values) & (values != 0)]
    if not signed.size:
        return float("nan")
    return float(scipy.stats.binomtest(int(np.sum(signed < 0)), int(signed.size), 0.5).pvalue)


def wilcoxon_p(differences: Sequence[float]) -> float:
    """
    Two-sided Wilcoxon signed-rank p-value of paired differences (``nan`` with no pair or all differences zero).
    Under :data:`MIN_PAIRS_FOR_WILCOXON` pairs it cannot show a difference: reports leave it out, and ``compare`` warns.
    """
    values = np.asarray(differences, dtype=float).ravel()
    if not values.size or not np.any(values != 0):
        return float("nan")
    return float(scipy.stats.wilcoxon(values).pvalue)
