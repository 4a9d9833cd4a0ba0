"""
How well do the constraints learned by finished ICRL runs identify the true one, and would the scores notice a
constraint that knows nothing? For each run folder, the learned cost of its final model and of the same model with
its constraint net re-initialised at random are scored on one probe set (the run's demonstrations, three of the
learner's own episodes and a sweep of the constrained feature; :mod:`sb3_icrl.metrics.identification`)::

    python benchmarks/identification_runs.py logs/suites/table3/base/mecl/BlockedHalfCheetah-v0_* \\
        logs/suites/table3/base/vicrl/BlockedHalfCheetah-v0_* --json logs/identification_halfcheetah.json

Printed per run: AUROC of the learned cost against the true label, calibration error, precision / recall / IoU of
"learned cost > 0.5" and of "learned cost > budget", and the threshold error (where the partial dependence of the
learned cost over the constrained feature crosses the level, minus the true threshold, in the feature's units;
``-`` where it never crosses). The true constraint is read for scoring only.
"""

import argparse
import copy
import json
import math
import os
import pathlib
from typing import Any

import numpy as np
import torch as th

from sb3_icrl.metrics.identification import identify_model, run_probes


def with_random_constraint(model: Any, seed: int) -> Any:
    """A copy of an ICRL model whose constraint net has fresh random weights (same architecture and inputs)."""
    random_model = copy.deepcopy(model)
    th.manual_seed(seed)
    for module in random_model.constraint_net.modules():
        if module is not random_model.constraint_net and hasattr(module, "reset_parameters"):
            module.reset_parameters()
    return random_model


def score_run(run_folder: str, n_episodes: int, seed: int) -> dict[str, Any]:
    """Identification scores of a run's learned constraint and of a random one, on the same probe set."""
    probes = run_probes(run_folder, n_episodes=n_episodes, seed=seed)
    learner = probes.learner
    budget = float(np.asarray(learner.cost_budget).reshape(-1)[0])
    scores = {
        name: identify_model(model, probes.env_id, probes.expert, probes.env_kwargs, probes.other, budget=budget, seed=seed)
        for name, model in (("learned", learner), ("random", with_random_constraint(learner, seed)))
    }
    return {
        "run": str(pathlib.Path(run_folder)),
        "algo": probes.args["algo"],
        "seed": int(probes.args["seed"]),
        "env": probes.env_id,
        "budget": budget,
        **scores,
    }


def row(scores: dict[str, Any]) -> list[str]:
    """The table cells of one scored constraint."""
    feature = next(iter(scores["features"].values()))

    def error(level: str) -> str:
        value = feature[f"at_{level}"]["threshold_error"]
        return "-" if value is None or not math.isfinite(value) else f"{value:+.2f}"

    cells = [f"{scores['auroc']:.3f}", f"{scores['ece']:.3f}"]
    for level in ("0.5", "budget"):
        at = scores[f"at_{level}"]
        cells += [f"{at['precision']:.2f} / {at['recall']:.2f} / {at['iou']:.2f}", error(level)]
    return cells


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", help="Finished ICRL run folders")
    parser.add_argument("--episodes", type=int, default=3, help="Learner episodes in the probe set")
    parser.add_argument("--seed", type=int, default=0, help="Seed of the episodes, draws and random weights")
    parser.add_argument("--json", type=str, default=None, help="Also write every score here")
    args = parser.parse_args()

    results = [score_run(run, args.episodes, args.seed) for run in args.runs]
    header = ["algo", "seed", "constraint", "AUROC", "ECE", "P / R / IoU @0.5", "threshold error @0.5"]
    header += ["P / R / IoU @budget", "threshold error @budget"]
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for result in sorted(results, key=lambda r: (r["algo"], r["seed"])):
        for name in ("learned", "random"):
            print("| " + " | ".join([result["algo"], str(result["seed"]), name, *row(result[name])]) + " |")
    for algo in sorted({r["algo"] for r in results}):
        for name in ("learned", "random"):
            values = [r[name]["auroc"] for r in results if r["algo"] == algo]
            print(f"{algo} {name}: AUROC {np.mean(values):.3f} +- {np.std(values):.3f} over {len(values)} runs")
    if args.json:
        from sb3_icrl.common.utils import atomic_write_json

        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        atomic_write_json(args.json, json.loads(json.dumps(results, default=float)), indent=2)


if __name__ == "__main__":
    main()
