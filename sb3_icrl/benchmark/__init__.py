"""
The benchmark engine: suites of runs (``sb3_icrl/benchmark/suites/*.yml``), run locally or on Ray with resume, and
their report (tables, statistics, figures). Command line: ``sb3-icrl benchmark run|status|report|list``.
"""

from sb3_icrl.benchmark.report import summarise_suite
from sb3_icrl.benchmark.suite import RunSpec, Suite, SuiteError, load_suite
from sb3_icrl.common.statistics import iqm, stratified_bootstrap_ci

__all__ = ["RunSpec", "Suite", "SuiteError", "iqm", "load_suite", "stratified_bootstrap_ci", "summarise_suite"]
