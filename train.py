"""Train an sb3-icrl algorithm, as in rl-baselines3-zoo: ``python train.py --algo mecl --env BlockedHalfCheetah-v0``."""

import sys

from sb3_icrl.zoo.train import main

if __name__ == "__main__":
    sys.exit(main())
