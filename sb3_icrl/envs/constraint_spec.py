"""
The true-constraint declaration, under the path it has always had: :mod:`sb3_icrl.common.constraint_spec` defines it
(envs, metrics and plots all read it, so it sits in the lowest layer); import it from there, from here, or from
:mod:`sb3_icrl` itself (``from sb3_icrl import ConstraintSpec, FeatureConstraint``).
"""

from sb3_icrl.common.constraint_spec import (
    OPERATORS,
    SPEC_ATTRIBUTE,
    ConstraintSpec,
    FeatureConstraint,
    as_constraint_spec,
    declare_constraint,
    get_constraint_spec,
)

__all__ = [
    "OPERATORS",
    "SPEC_ATTRIBUTE",
    "ConstraintSpec",
    "FeatureConstraint",
    "as_constraint_spec",
    "declare_constraint",
    "get_constraint_spec",
]
