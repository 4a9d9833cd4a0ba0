"""
Expert demonstrations for ICRL: trajectories with true costs, ``.npz`` files in ``imitation``'s layout, their
generation from constrained experts, and the datasets shipped with the package.

    from sb3_icrl.data import load_demonstrations

    demos = load_demonstrations("GridWorldWall-v0")
    transitions = demos.transitions  # obs, acts, next_obs, dones, rews, costs (costs: evaluation only)

Command line: ``python -m sb3_icrl.data generate --env NAME --expert PATH_OR_pilag --n 50 --out FILE``.
"""

from sb3_icrl.data.generate import NormalizedExpert, build_dataset, generate_demonstrations, load_expert
from sb3_icrl.data.registry import (
    DEMONSTRATIONS_DIR,
    EXPERTS_DIR,
    available_demonstrations,
    dataset_file_name,
    expert_paths,
    load_demonstrations,
    regenerate_shipped,
)
from sb3_icrl.data.serialize import DemonstrationError, from_imitation, load, metadata_path, save
from sb3_icrl.data.types import Demonstrations, Trajectory, Transitions, flatten_trajectories

__all__ = [
    "DEMONSTRATIONS_DIR",
    "EXPERTS_DIR",
    "DemonstrationError",
    "Demonstrations",
    "NormalizedExpert",
    "Trajectory",
    "Transitions",
    "available_demonstrations",
    "build_dataset",
    "dataset_file_name",
    "expert_paths",
    "flatten_trajectories",
    "from_imitation",
    "generate_demonstrations",
    "load",
    "load_demonstrations",
    "load_expert",
    "metadata_path",
    "regenerate_shipped",
    "save",
]
