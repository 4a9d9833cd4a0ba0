"""
What identifies the code and the stack a run was made with: written into each run folder (``versions.yml``) and
compared between a Ray worker and its driver.
"""

import os
import platform
import subprocess

import gymnasium as gym
import numpy as np
import stable_baselines3
import torch as th

#: The ``sb3_icrl`` package folder
PACKAGE_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def package_version() -> str:
    """sb3-icrl's version (read from the package's ``version.txt``, as ``sb3_icrl.__version__`` is)."""
    with open(os.path.join(PACKAGE_DIR, "version.txt")) as file:
        return file.read().strip()


def versions() -> dict[str, str]:
    """Package versions and the git revision of the sb3-icrl checkout (``unknown`` outside a git checkout)."""
    info = {
        "python": platform.python_version(),
        "sb3_icrl": package_version(),
        "stable_baselines3": stable_baselines3.__version__,
        "gymnasium": gym.__version__,
        "torch": str(th.__version__),
        "numpy": np.__version__,
        "platform": platform.platform(),
    }
    root = os.path.dirname(PACKAGE_DIR)
    try:
        revision = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, check=True)
        status = subprocess.run(["git", "status", "--porcelain"], cwd=root, capture_output=True, text=True, check=True)
        info["git_revision"] = revision.stdout.strip() + ("-dirty" if status.stdout.strip() else "")
    except (OSError, subprocess.CalledProcessError):
        info["git_revision"] = "unknown"
    return info
