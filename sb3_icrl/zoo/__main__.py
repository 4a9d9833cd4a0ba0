"""``python -m sb3_icrl.zoo train|enjoy --algo ALGO --env ENV ...`` (the same as ``sb3-icrl train|enjoy``)."""

import sys

from sb3_icrl.zoo.train import cli

if __name__ == "__main__":
    sys.exit(cli())
