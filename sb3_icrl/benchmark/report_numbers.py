"""
How a benchmark report writes its numbers: rewards at the precision their size asks for, published violation rates,
core-hours and normalised scores, and strict JSON for the files it keeps (:func:`finite_or_null`: ``null`` for a
non-finite float). The lowest of the report's modules: :mod:`~sb3_icrl.benchmark.judgements` (a judgement's reasons
name rewards), :mod:`~sb3_icrl.benchmark.report_text`, :mod:`~sb3_icrl.benchmark.report_figures` and
:mod:`~sb3_icrl.benchmark.report` use it, and it uses none of them.
"""

import math
from typing import Any


def format_hours(hours: float) -> str:
    """Core-hours for a table: whole hours from 100 on, one decimal from 1, two below."""
    return f"{hours:,.0f}" if hours >= 100 else f"{hours:.1f}" if hours >= 1 else f"{hours:.2f}"


def format_mean_std(mean: float, std: float) -> str:
    """
    ``mean ± std`` of a reward at the precision its size asks for: whole numbers from 100 on, one decimal from 10, two
    below (a Pendulum's 0.46 does not read as 0).
    """
    digits = reward_digits(mean)
    return f"{mean:.{digits}f} ± {std:.{digits}f}"


def reward_digits(value: float) -> int:
    """Decimals a reward of this size is shown with: none from 100 on, one from 10, two below."""
    return 0 if abs(value) >= 100 else 1 if abs(value) >= 10 else 2


def format_reward(value: float) -> str:
    """A reward at the precision its size asks for (:func:`reward_digits`)."""
    return f"{value:.{reward_digits(value)}f}"


def format_rate(rate: float) -> str:
    """A published violation rate: whole percents, one decimal below 1% so that 0.004 does not read as 0."""
    return f"{100 * rate:.1f}%" if 0 < 100 * rate < 1 else f"{100 * rate:.0f}%"


def format_score(value: float) -> str:
    """A normalised score: two decimals."""
    return f"{value:.2f}"


def is_finite_number(value: Any) -> bool:
    """Whether ``value`` is a finite int or float (a summary read back from JSON has ``None`` where it had none)."""
    return isinstance(value, (int, float)) and math.isfinite(value)


def finite_or_null(value: Any) -> Any:
    """
    A copy of a JSON-like value with every NaN or infinite float replaced by ``None``, so that strict JSON readers
    can read it (a threshold error is infinite when the learned cost never crosses the threshold: the run's own
    ``identification.json`` keeps the value and the reason).

    :param value: Nested dicts, lists, tuples and scalars
    :return: The same structure, with ``null`` where a float was not finite
    """
    if isinstance(value, dict):
        return {key: finite_or_null(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_null(item) for item in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
