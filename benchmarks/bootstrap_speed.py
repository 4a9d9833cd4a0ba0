"""
Speed of the report's bootstrap intervals: the row-wise statistics (every resample's estimate in one call) against one
call per resample on the same draws, interleaved round by round on the same synthetic scores, timed on this process's
CPU time and on wall time; each round also checks that both give the same interval to the last bit::

    python benchmarks/bootstrap_speed.py --rounds 5 --tasks 4 --seeds 35

The default shape is a table3-like aggregate: four envs of 35 runs each (seven rows of five seeds).
"""

import argparse
import statistics as stats
import time
from collections.abc import Callable

import numpy as np

from sb3_icrl.common import statistics

Interval = tuple[float, float]


def one_call_per_resample(tasks: list[np.ndarray]) -> list[Interval]:
    """The intervals as computed before the row-wise statistics: one statistic call per resample."""

    def of_resample(statistic: Callable[[np.ndarray], float]) -> Callable[[list[np.ndarray]], float]:
        return lambda resample: statistic(np.concatenate(resample))

    reps, confidence, seed = statistics.BOOTSTRAP_REPS, 0.95, statistics.BOOTSTRAP_SEED
    return [
        statistics._bootstrap_interval(tasks, of_resample(statistics.iqm), reps, confidence, seed),
        statistics._bootstrap_interval(tasks, of_resample(statistics.optimality_gap), reps, confidence, seed),
        statistics._bootstrap_interval(tasks, statistics.mean_of_task_means, reps, confidence, seed),
    ]


def row_wise(tasks: list[np.ndarray]) -> list[Interval]:
    """The intervals as the report computes them."""
    return [
        statistics.stratified_bootstrap_ci(tasks),
        statistics.stratified_bootstrap_ci(tasks, statistic=statistics.optimality_gap),
        statistics.stratified_bootstrap_ci_of_task_means(tasks),
    ]


def timed(
    function: Callable[[list[np.ndarray]], list[Interval]], tasks: list[np.ndarray]
) -> tuple[list[Interval], float, float]:
    """:return: the function's intervals, its CPU seconds and its wall seconds"""
    cpu, wall = time.process_time(), time.perf_counter()
    intervals = function(tasks)
    return intervals, time.process_time() - cpu, time.perf_counter() - wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=5, help="Interleaved rounds")
    parser.add_argument("--tasks", type=int, default=4, help="Tasks (envs) in the aggregate")
    parser.add_argument("--seeds", type=int, default=35, help="Runs per task")
    args = parser.parse_args()
    if min(args.rounds, args.tasks, args.seeds) < 1:
        parser.error("--rounds, --tasks and --seeds must be >= 1")
    rng = np.random.default_rng(0)
    cpu_ratios, wall_ratios = [], []
    for round_ in range(args.rounds):
        tasks = [rng.normal(0.3, 0.5, size=args.seeds) for _ in range(args.tasks)]
        old, old_cpu, old_wall = timed(one_call_per_resample, tasks)
        new, new_cpu, new_wall = timed(row_wise, tasks)
        if old != new:
            raise SystemExit(f"round {round_}: the intervals differ: {old} against {new}")
        cpu_ratios.append(old_cpu / new_cpu)
        wall_ratios.append(old_wall / new_wall)
        print(
            f"round {round_}: one call per resample {old_cpu:.3f} s CPU ({old_wall:.3f} wall), row-wise {new_cpu:.3f} s"
            f" CPU ({new_wall:.3f} wall): {cpu_ratios[-1]:.1f}x on CPU time, {wall_ratios[-1]:.1f}x on wall time"
        )
    print(
        f"row-wise speed-up over {args.rounds} rounds ({args.tasks} tasks x {args.seeds} runs, "
        f"{statistics.BOOTSTRAP_REPS} resamples, three intervals): CPU time median {stats.median(cpu_ratios):.1f}x "
        f"[{min(cpu_ratios):.1f}, {max(cpu_ratios):.1f}], wall time median {stats.median(wall_ratios):.1f}x "
        f"[{min(wall_ratios):.1f}, {max(wall_ratios):.1f}]; every interval identical"
    )


if __name__ == "__main__":
    main()
