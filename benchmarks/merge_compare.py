"""
Merge the ``--json`` files of several ``sb3-icrl compare`` calls into one per-seed table and summary::

    python benchmarks/merge_compare.py logs/s7/compare_*_final.json logs/s8/compare_*_final.json --reference vicrl

Runs finish at different times; each is evaluated once, when it finishes, and the tables are merged here. The files
must share the held-out evaluation seed. A run found in several files keeps its last row.
"""

import argparse
import json

from sb3_icrl.zoo.compare import RunFolderError, RunResult, format_table, summarise


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("files", nargs="+", help="JSON files written by `sb3-icrl compare --json`")
    parser.add_argument("--reference", default=None, help="Algorithm to test the others against (Wilcoxon)")
    args = parser.parse_args()
    rows: dict[str, dict] = {}
    eval_seeds = set()
    for path in args.files:
        with open(path) as file:
            data = json.load(file)
        eval_seeds.add(data["eval_seed"])
        rows.update({row["run"]: row for row in data["runs"]})
    if len(eval_seeds) != 1:
        raise SystemExit(f"The files were evaluated on different held-out seeds {sorted(eval_seeds)}: rerun them on one.")
    results = sorted((RunResult(**row) for row in rows.values()), key=lambda result: (result.algo, result.seed))
    try:
        summary = summarise(results, args.reference)  # as sb3-icrl compare: an absent reference or a repeated seed is an error
    except RunFolderError as error:
        raise SystemExit(f"error: {error}") from None
    print(format_table(results, summary, args.reference))


if __name__ == "__main__":
    main()
