"""
Expert demonstrations for ICRL: trajectories with true costs, ``.npz`` files in ``imitation``'s layout, their
generation from constrained experts, and the datasets shipped with the package.

    from sb3_icrl.data import load_demonstrations

    demos = load_demonstrations("GridWorldWall-v0")
    transitions = demos.transitions  # obs, acts, next_obs, dones, rews, costs (costs: evaluation only)

Command line: ``python -m sb3_icrl.data generate --env NAME --expert PATH_OR_pilag --n 50 --out FILE``.

Other people's data: :mod:`sb3_icrl.data.importers` (flat arrays, the reference codes' pickles),
:mod:`sb3_icrl.data.formats` (``imitation`` >= 1.0 dataset folders, Minari), and :mod:`sb3_icrl.data.checks` to check
them against the env (recorded env id, MuJoCo dynamics replay).
"""

from sb3_icrl.data.checks import DynamicsReport, check_env_id, dynamics_replay_check
from sb3_icrl.data.formats import from_minari, load_imitation_dataset, save_imitation_dataset, to_minari
from sb3_icrl.data.generate import NormalizedExpert, build_dataset, generate_demonstrations, load_expert
from sb3_icrl.data.importers import from_arrays, from_liu_pickles, from_malik_rollouts
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
    "DynamicsReport",
    "NormalizedExpert",
    "Trajectory",
    "Transitions",
    "available_demonstrations",
    "build_dataset",
    "check_env_id",
    "dataset_file_name",
    "dynamics_replay_check",
    "expert_paths",
    "flatten_trajectories",
    "from_arrays",
    "from_imitation",
    "from_liu_pickles",
    "from_malik_rollouts",
    "from_minari",
    "generate_demonstrations",
    "load",
    "load_demonstrations",
    "load_expert",
    "load_imitation_dataset",
    "metadata_path",
    "regenerate_shipped",
    "save",
    "save_imitation_dataset",
    "to_minari",
]
