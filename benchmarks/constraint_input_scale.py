"""
Does standardising the constraint net's inputs hide the constrained quantity? For each blocked MuJoCo env, prints the
range of the constrained feature (``x_position``) in the shipped demonstrations and where the start (x = 0) and the
true line land after the constraint net's own input normaliser (fitted on those demonstrations, as the ICRL
algorithms fit it)::

    python benchmarks/constraint_input_scale.py

A gap of a few hundredths of a standard deviation between start and line (HalfCheetah, whose expert runs 200 m) means
the net can barely tell the line from the start; the HalfCheetah recipes therefore feed the constraint raw inputs
(``normalize_input=False``). The true line is read only to print where it lands.
"""

import argparse

import numpy as np
import torch as th

import sb3_icrl.envs  # noqa: F401  (registers the environments)
from sb3_icrl.constraints import FeasibilityNet
from sb3_icrl.data import flatten_trajectories, load_demonstrations
from sb3_icrl.envs import CONSTRAINED_FEATURE


def standardised_positions(env_name: str) -> dict[str, float]:
    """
    The feature's range in the expert data and the normalised values of the start (0) and the true line.

    :param env_name: A key of ``CONSTRAINED_FEATURE``
    """
    feature = CONSTRAINED_FEATURE[env_name]
    transitions = flatten_trajectories(load_demonstrations(env_name).trajectories)
    obs, acts = np.asarray(transitions.obs, dtype=np.float32), np.asarray(transitions.acts, dtype=np.float32)
    net = FeasibilityNet(obs.shape[1], acts.shape[1], hidden_sizes=[4])
    net.fit_normalizer(obs, acts)
    probes = np.repeat(obs[:1], 2, axis=0)
    probes[:, feature.obs_index] = [0.0, feature.threshold]
    with th.no_grad():
        normalised = net.preprocess(probes, acts[:2]).numpy()[:, feature.obs_index]
    values = obs[:, feature.obs_index]
    return {
        "min": float(values.min()),
        "max": float(values.max()),
        "std": float(values.std()),
        "start": float(normalised[0]),
        "line": float(normalised[1]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", nargs="+", default=list(CONSTRAINED_FEATURE), help="Blocked MuJoCo envs")
    args = parser.parse_args()
    print("| env | line | expert x range | expert x std | start (x = 0) normalised | line normalised | gap (std) |")
    print("|---|---|---|---|---|---|---|")
    for env_name in args.envs:
        feature = CONSTRAINED_FEATURE[env_name]
        row = standardised_positions(env_name)
        print(
            f"| {env_name} | x {feature.op} {feature.threshold:g} | [{row['min']:.3g}, {row['max']:.3g}] | {row['std']:.3g} | "
            f"{row['start']:.3f} | {row['line']:.3f} | {abs(row['line'] - row['start']):.3f} |"
        )


if __name__ == "__main__":
    main()
