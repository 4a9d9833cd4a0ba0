"""Run a trained sb3-icrl agent, as in rl-baselines3-zoo: ``python enjoy.py --algo mecl --env BlockedHalfCheetah-v0``."""

import sys

from sb3_icrl.zoo.enjoy import main

if __name__ == "__main__":
    sys.exit(main())
