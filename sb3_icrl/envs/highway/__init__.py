"""
Highway driving environments (the paper's HighD environments, rebuilt on highway-env with replayed IDM traffic).

- :mod:`sb3_icrl.envs.highway.env`: :class:`HighwayConstraintEnv`, its observation layout and :data:`HIGHWAY_CONSTRAINTS`
- :mod:`sb3_icrl.envs.highway.scenarios`: recording, storing and loading the traffic
- ``python -m sb3_icrl.envs.highway --help``: generate more recordings
"""

from sb3_icrl.envs.highway.env import (
    DRIVING_CONSTRAINTS,
    FEATURE_INDEX,
    FEATURES,
    HIGHWAY_CONSTRAINTS,
    DrivingConstraint,
    HighwayConstraintEnv,
)
from sb3_icrl.envs.highway.scenarios import DENSITIES, SPLITS, Scenario, load_scenarios, record_scenario, scenario_files

__all__ = [
    "DENSITIES",
    "DRIVING_CONSTRAINTS",
    "FEATURES",
    "FEATURE_INDEX",
    "HIGHWAY_CONSTRAINTS",
    "SPLITS",
    "DrivingConstraint",
    "HighwayConstraintEnv",
    "Scenario",
    "load_scenarios",
    "record_scenario",
    "scenario_files",
]
