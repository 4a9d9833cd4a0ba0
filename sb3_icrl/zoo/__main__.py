"""``python -m sb3_icrl.zoo train --algo ALGO --env ENV ...`` (the same as ``sb3-icrl train``)."""

import sys

from sb3_icrl.zoo.train import cli

if __name__ == "__main__":
    sys.exit(cli())
