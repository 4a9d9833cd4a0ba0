"""``python -m sb3_icrl.zoo train|enjoy|compare ...`` (the same as ``sb3-icrl train|enjoy|compare``)."""

import sys

from sb3_icrl.zoo.train import cli

if __name__ == "__main__":
    sys.exit(cli())
