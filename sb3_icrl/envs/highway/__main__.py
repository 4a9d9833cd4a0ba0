"""
Generate traffic recordings for the highway environments.

    python -m sb3_icrl.envs.highway --density dense --split train --count 4 --first-seed 1000 --out DIR

Files are named ``<density>_<split>_<seed>.npz``; point the environments at them with
``HighwayConstraintEnv(scenarios=load_scenarios(density, split, DIR))``. The shipped set was made with
``python -m sb3_icrl.envs.highway --shipped``.
"""

import argparse
import os

from sb3_icrl.common.utils import plain_docstring
from sb3_icrl.envs.highway.scenarios import DENSITIES, SCENARIO_DIR, SPLITS, record_scenario

#: The shipped recordings: (density, split) -> seeds. Train and test seeds never overlap.
SHIPPED_SEEDS: dict[tuple[str, str], tuple[int, ...]] = {
    ("sparse", "train"): (0, 1, 2, 3),
    ("sparse", "test"): (100, 101),
    ("dense", "train"): (0, 1, 2, 3),
    ("dense", "test"): (100, 101),
}


def generate(density: str, split: str, seeds: list[int], out: str, duration: float) -> list[str]:
    """
    :param density: A key of :data:`DENSITIES`
    :param split: ``"train"`` or ``"test"``
    :param seeds: One recording per seed
    :param out: Output folder
    :param duration: Recorded time per scenario [s]
    :return: Paths written
    """
    if density not in DENSITIES:
        raise ValueError(f"Unknown traffic density {density!r}, expected one of {tuple(DENSITIES)}")
    if split not in SPLITS:
        raise ValueError(f"Unknown scenario split {split!r}, expected one of {SPLITS}")
    os.makedirs(out, exist_ok=True)
    paths = []
    for seed in seeds:
        path = os.path.join(out, f"{density}_{split}_{seed:04d}.npz")
        record_scenario(seed, DENSITIES[density], duration=duration).save(path)
        paths.append(path)
        print(path)
    return paths


def main() -> None:
    parser = argparse.ArgumentParser(
        description=plain_docstring(__doc__), formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--density", choices=tuple(DENSITIES), default="dense")
    parser.add_argument("--split", choices=SPLITS, default="train")
    parser.add_argument("--count", type=int, default=1, help="number of recordings")
    parser.add_argument("--first-seed", type=int, default=1000, help="seeds first-seed, first-seed + 1, ...")
    parser.add_argument("--duration", type=float, default=120.0, help="recorded seconds per scenario")
    parser.add_argument("--out", default=".", help="output folder")
    parser.add_argument("--shipped", action="store_true", help="regenerate the shipped set into the package")
    args = parser.parse_args()
    if args.shipped:
        for (density, split), seeds in SHIPPED_SEEDS.items():
            generate(density, split, list(seeds), SCENARIO_DIR, 120.0)
    else:
        if args.count < 1:
            parser.error("--count must be >= 1")
        generate(args.density, args.split, list(range(args.first_seed, args.first_seed + args.count)), args.out, args.duration)


if __name__ == "__main__":
    main()
