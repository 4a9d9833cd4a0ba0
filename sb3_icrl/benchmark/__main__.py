"""``python -m sb3_icrl.benchmark run|report|list``."""

import sys

from sb3_icrl.benchmark.cli import main

sys.exit(main(prog="python -m sb3_icrl.benchmark"))
