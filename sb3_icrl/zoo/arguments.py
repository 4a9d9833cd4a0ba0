"""
The argument types and first steps that ``train.py``, ``enjoy.py`` and ``compare`` share: rl-zoo's ``key:value``
dictionaries, checked numbers, and ``--algo`` names that a ``--gym-packages`` module may register.
"""

import argparse
import sys
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from sb3_icrl.common.utils import did_you_mean
from sb3_icrl.hyperparams import HyperparameterError, is_mapping_argument, parse_override, read_mapping
from sb3_icrl.registry import ALGOS, import_gym_packages, unknown_algo_message


class StoreDict(argparse.Action):
    """
    rl-zoo's ``-params k:v k2:v2``: each value is evaluated as a Python literal/expression, else kept as a string.
    One JSON object (``-params '{"constraint_net_kwargs": {"hidden_sizes": [32]}}'``) or one yml/JSON file works too.
    """

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any, option_string=None):
        result: dict[str, Any] = {}
        if is_mapping_argument(values):
            try:
                setattr(namespace, self.dest, read_mapping(values[0], str(option_string)))
            except HyperparameterError as error:
                parser.error(str(error))
            return
        for item in values:
            key, sep, value = item.partition(":")
            if not sep or not key:
                parser.error(f"{option_string} expects key:value pairs, got {item!r}.")
            result[key] = parse_override(key, value)
        setattr(namespace, self.dest, result)


def _number(text: str, kind: type, condition: str) -> Any:
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {condition}, got {text!r}") from None
    return value


def positive_int(text: str) -> int:
    """argparse type: an integer > 0."""
    value = _number(text, int, "an integer > 0")
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected an integer > 0, got {text!r}")
    return value


def non_negative_int(text: str) -> int:
    """argparse type: an integer >= 0 (seeds: gymnasium refuses negative ones)."""
    value = _number(text, int, "an integer >= 0")
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return value


def non_negative_float(text: str) -> float:
    """argparse type: a finite float >= 0."""
    value = _number(text, float, "a finite number >= 0")
    if not np.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0, got {text!r}")
    return value


def fraction(text: str) -> float:
    """argparse type: a share in [0, 1)."""
    value = _number(text, float, "a fraction in [0, 1)")
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError(f"expected a fraction in [0, 1), got {text!r}")
    return value


def registered_algo(text: str) -> str:
    """
    ``--algo``: a name in :data:`~sb3_icrl.registry.ALGOS` (ours, or one a ``--gym-packages`` module registered).

    :param text: The value given
    :return: It, when registered
    :raises argparse.ArgumentTypeError: For an unknown name (the message says how to register one)
    """
    if text not in ALGOS:
        raise argparse.ArgumentTypeError(unknown_algo_message(text) + did_you_mean(text, list(ALGOS)))
    return text


def algo_help() -> str:
    """``--algo``'s help: the names registered now."""
    return f"Algorithm: {', '.join(ALGOS)}, or one that a --gym-packages module registers (sb3_icrl.register_algorithm)"


def import_named_packages(argv: Sequence[str]) -> None:
    """
    Import the ``--gym-packages`` of ``argv`` before the rest is parsed: a module named there may register the
    ``--algo`` (:func:`sb3_icrl.register_algorithm`), as well as envs.

    :param argv: Command-line arguments
    :raises ValueError: When a module cannot be imported
    """
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--gym-packages", type=str, nargs="+", default=[])
    known, _ = parser.parse_known_args(argv)
    import_gym_packages(known.gym_packages)


def parse_after_packages(
    get_parser: Callable[[str | None], argparse.ArgumentParser], argv: list[str], prog: str | None
) -> argparse.Namespace | None:
    """
    ``argv`` parsed once its ``--gym-packages`` are imported (:func:`import_named_packages`).

    :param get_parser: The command's parser, built after the import (its ``--algo`` help lists the names registered)
    :param argv: Command-line arguments
    :param prog: Program name in the usage line
    :return: The arguments, or ``None`` after saying why a module could not be imported
    """
    try:
        import_named_packages(argv)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return None
    return get_parser(prog).parse_args(argv)
