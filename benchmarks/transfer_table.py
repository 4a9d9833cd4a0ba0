"""
The transfers saved in finished ICRL run folders (``sb3-icrl transfer RUN --task TASK`` writes
``<run>/transfer_<task>.json``), one markdown row per run: the learned-cost learner's violation rate, feasible reward
and reward on held-out episodes, beside the oracle's (PPO-Lagrangian on the true cost) and unconstrained PPO's::

    python benchmarks/transfer_table.py logs/suites/table3/base/mecl/BlockedHalfCheetah-v0_* \\
        logs/suites/table3/base/vicrl/BlockedHalfCheetah-v0_* --task reward

Runs without that transfer are listed as missing; paths that are not folders (a glob's ``.lock`` files) are
skipped. The feasible-reward ratio is the learned learner's over the oracle's (``nan`` when the oracle's is not
positive).
"""

import argparse
import pathlib
from collections.abc import Sequence

from sb3_icrl.metrics.transfer import TASKS, read_transfers


def _cell(result: dict) -> str:
    return f"{100 * result['violation_rate']:.0f}% / {result['feasible_reward']:.1f} / {result['reward']:.1f}"


def transfer_rows(runs: Sequence[str], task: str) -> list[str]:
    """
    :param runs: ICRL run folders ``<folder>/<algo>/<EnvName>_<seed>``
    :param task: One of :data:`~sb3_icrl.metrics.transfer.TASKS`
    :return: The markdown table's lines
    """
    lines = [
        "| run | learned: violation / feasible reward / reward | oracle | PPO | feasible reward / oracle's | steps |",
        "|---|---|---|---|---|---|",
    ]
    for run in runs:
        folder = pathlib.Path(run)
        if not folder.is_dir():  # a glob's lock files
            continue
        name = f"{folder.parent.name} {folder.name}"
        transfer = read_transfers(folder).get(task)
        if transfer is None:
            lines.append(f"| {name} | missing | | | | |")
            continue
        results = transfer["results"]
        others = [_cell(results[learner]) if learner in results else "-" for learner in ("learned", "oracle", "ppo")]
        ratio = transfer["feasible_reward_ratio"]
        lines.append(f"| {name} | {' | '.join(others)} | {ratio:.2f} | {transfer['settings']['n_timesteps']} |")
    return lines


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", help="ICRL run folders")
    parser.add_argument("--task", default="reward", choices=TASKS, help="The transfer task")
    args = parser.parse_args(argv)
    print("\n".join(transfer_rows(args.runs, args.task)))


if __name__ == "__main__":
    main()
