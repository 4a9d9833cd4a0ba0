"""
Hyper-parameter files (``zoo_hyperparams/<algo>.yml``) read with rl-baselines3-zoo's conventions.

Strings that rl-zoo evaluates are evaluated here too: ``policy_kwargs`` (and the ICRL dict arguments
``constraint_net_kwargs``, ``lagrange_kwargs``, ``trainer_kwargs``) as Python expressions with ``nn`` and ``th``
in scope, ``lin_<value>`` learning rates and clip ranges as linear schedules, ``normalize`` as a bool or a dict
string, ``env_wrapper`` and ``callback`` as import paths (optionally ``{path: kwargs}``).
"""

import importlib
import inspect
import json
import os
import pathlib
import re
import types
import typing
import warnings
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import torch as th
import yaml

from sb3_icrl.icrl.tabular import FORWARD_SOLVERS, PLANNER_LOOP_KEYS
from sb3_icrl.pi_lagrangian import PILagrangian
from sb3_icrl.registry import (
    ALGOS,
    ICRL_ALGOS,
    REFERENCE_ALGOS,
    env_name,
    hyperparams_file,
    unknown_algo_message,
)

#: Keys handled by the zoo itself, not passed to the algorithm (``forward_solver`` and ``planner_kwargs``: the ICRL
#: algorithms' exact planner on tabular envs, see :func:`sb3_icrl.icrl.tabular.learn_with_planner`)
ZOO_KEYS = (
    "n_timesteps",
    "n_envs",
    "normalize",
    "normalize_kwargs",
    "env_wrapper",
    "callback",
    "policy",
    "forward_solver",
    "planner_kwargs",
)
#: Dict-valued arguments that may be written as strings
EVAL_KEYS = (
    "policy_kwargs",
    "constraint_net_kwargs",
    "lagrange_kwargs",
    "trainer_kwargs",
    "normalize_kwargs",
    "planner_kwargs",
)


#: What BC2L, MECL and VICRL use on an env the shipped yml does not know, instead of the ``default`` entry's budget 0
#: (a cost ``1 - phi`` never reaches 0, so that multiplier only grows): the budget is the expert's own mean learned cost
#: per step, with the PID multiplier of the BlockedHalfCheetah recipes, which can fall again; and, as the recipes of the
#: benchmark envs whose episodes end early (Walker, Pendulum, driving), a terminated episode costs that budget per step
#: for ever, so that a learner gains nothing by ending its episodes (it changes nothing where episodes only time out)
UNKNOWN_ENV_ICRL_DEFAULTS: dict[str, Any] = {
    "cost_budget": "expert",
    "budget_statistic": "step",
    "lagrange_update": "pid",
    "lagrange_kwargs": "dict(init=1.0, kp=5.0, ki=0.005, kd=0.0)",
    "termination_cost": "budget",
}
#: Top-level keys of a hyper-parameter file that name entries (``default``, ``MyEnv-v0``), not hyper-parameters
_ENTRY_KEY = re.compile(r"^default$|-v\d+$")
#: Algorithms whose fallback to ``default`` has been announced in this process
_ANNOUNCED_DEFAULTS: set[str] = set()


class HyperparameterError(ValueError):
    """A hyper-parameter file, entry or override that cannot be used."""


def read_mapping(text: str, what: str = "-params") -> dict[str, Any]:
    """
    A mapping given on the command line as a JSON string (``'{"constraint_net_kwargs": {"hidden_sizes": [32]}}'``) or
    as the path of a yml/JSON file.

    :param text: The JSON text or the file path
    :param what: The option, for error messages
    :return: The mapping
    :raises HyperparameterError: When it is neither, or not a mapping
    """
    if text.lstrip().startswith("{"):
        try:
            content = json.loads(text)
        except json.JSONDecodeError as error:
            raise HyperparameterError(f"{what}: {text!r} is not valid JSON ({error}).") from error
    elif os.path.isfile(text):
        with open(text) as file:
            try:
                content = yaml.safe_load(file)  # JSON is yml too
            except yaml.YAMLError as error:
                raise HyperparameterError(f"{what}: cannot read {text} ({error}).") from error
    else:
        raise HyperparameterError(f"{what}: {text!r} is neither a JSON object ('{{\"key\": value}}') nor an existing file.")
    if not isinstance(content, dict):
        raise HyperparameterError(f"{what}: {text!r} must hold a mapping of names to values, got {type(content).__name__}.")
    return content


def is_mapping_argument(values: Sequence[str]) -> bool:
    """Whether command-line values are one JSON object or one yml/JSON file (rather than ``key:value`` pairs)."""
    if len(values) != 1:
        return False
    text = values[0]
    return text.lstrip().startswith("{") or (text.endswith((".yml", ".yaml", ".json")) and os.path.isfile(text))


def parse_override(key: str, text: str) -> Any:
    """
    The value of one ``-params key:value`` (or ``--env-kwargs``) item as train.py takes it: evaluated as a Python
    literal or expression, else kept as the string; the dict-valued arguments (:data:`EVAL_KEYS`) stay strings.

    :param key: The name
    :param text: The value as written on the command line
    """
    if key in EVAL_KEYS:
        return text  # evaluated with the yml's strings, so config.yml records it as written
    try:
        return eval(text, {"nn": th.nn, "th": th, "dict": dict})  # rl-zoo convention: trusted config strings
    except Exception:
        return text  # plain strings such as lin_3e-4 or MlpPolicy


def linear_schedule(initial_value: float | str) -> Any:
    """rl-zoo's ``lin_<value>``: a schedule decreasing linearly from ``initial_value`` to 0."""
    initial = float(initial_value)

    def schedule(progress_remaining: float) -> float:
        return progress_remaining * initial

    return schedule


def _eval_string(key: str, value: str) -> Any:
    try:
        return eval(value, {"nn": th.nn, "th": th, "dict": dict})  # rl-zoo convention: trusted config strings
    except Exception as error:
        raise HyperparameterError(f"Cannot evaluate {key}: {value!r} ({error}).") from error


def import_object(path: str) -> Any:
    """Import ``package.module.Name`` (or ``package.module:Name``)."""
    module_name, _, name = path.replace(":", ".").rpartition(".")
    try:
        return getattr(importlib.import_module(module_name), name)
    except (ImportError, AttributeError, ValueError) as error:
        raise HyperparameterError(f"Cannot import {path!r}: {error}.") from error


def _import_specs(value: Any) -> list[tuple[Any, dict[str, Any]]]:
    """``"a.B"``, ``{"a.B": {kwargs}}`` or a list of those -> ``[(object, kwargs), ...]``."""
    items = value if isinstance(value, list) else [value]
    specs: list[tuple[Any, dict[str, Any]]] = []
    for item in items:
        if isinstance(item, str):
            specs.append((import_object(item), {}))
        elif isinstance(item, dict) and len(item) == 1:
            path, kwargs = next(iter(item.items()))
            specs.append((import_object(path), dict(kwargs or {})))
        else:
            raise HyperparameterError(f"Expected an import path or {{path: kwargs}}, got {item!r}.")
    return specs


def read_hyperparams_file(algo: str, directory: str | os.PathLike | None = None, conf_file: str | None = None) -> dict:
    """
    The whole ``<algo>.yml`` (or ``conf_file``) as a dict of entries.

    :param algo: Command-line algorithm name
    :param directory: Folder of the yml files (default: the file ``algo`` was registered with, else
        :data:`~sb3_icrl.registry.DEFAULT_HYPERPARAMS_DIR`: see :func:`~sb3_icrl.registry.hyperparams_file`)
    :param conf_file: Explicit file, as rl-zoo's ``-conf`` (or a JSON object: see :func:`read_mapping`)
    """
    if conf_file and conf_file.lstrip().startswith("{"):
        return read_mapping(conf_file, "--conf-file")
    path = pathlib.Path(conf_file) if conf_file else hyperparams_file(algo, directory)
    if not path.is_file():
        raise HyperparameterError(f"No hyper-parameter file {path}.")
    with open(path) as file:
        content = yaml.safe_load(file)
    if not isinstance(content, dict):
        raise HyperparameterError(f"{path} must map env names to entries.")
    return content


def load_hyperparams(
    algo: str,
    env_id: str,
    overrides: dict[str, Any] | None = None,
    directory: str | os.PathLike | None = None,
    conf_file: str | None = None,
    forward_recipe: str | None = None,
) -> tuple[dict[str, Any], str]:
    """
    The raw entry for ``env_id`` (falling back to ``default``) with ``overrides`` applied, as saved in ``config.yml``.

    On an env the shipped file has no entry for, BC2L, MECL and VICRL take :data:`UNKNOWN_ENV_ICRL_DEFAULTS` over the
    ``default`` entry (said once per process). ``conf_file`` is either a whole file (env names or ``default`` mapped
    to entries), which replaces the shipped one, or a single entry (hyper-parameters at the top level, a yml file or a
    JSON object), applied over the shipped entry as ``overrides`` are.

    :param algo: Command-line algorithm name
    :param env_id: Registered or short env id
    :param overrides: ``-params`` values (replace the file's)
    :param directory: Folder of the yml files
    :param conf_file: Explicit file, or a JSON object
    :param forward_recipe: For ``ppo`` and ``ppolag``: take the forward learner of this algorithm's entry instead
        (see :func:`forward_learner_entry`); not with ``conf_file``
    :return: The entry (strings not yet evaluated) and the key it came from
    """
    if algo not in ALGOS:
        raise HyperparameterError(unknown_algo_message(algo))
    if forward_recipe is not None and conf_file:
        raise HyperparameterError("--forward-recipe takes the entry of another algorithm: leave out -conf/--conf-file.")
    if forward_recipe is not None:
        return forward_learner_entry(algo, env_id, forward_recipe, overrides, directory)
    partial: dict[str, Any] = {}
    if conf_file:
        conf = read_hyperparams_file(algo, directory, conf_file)
        if any(_ENTRY_KEY.search(str(key)) for key in conf):
            content, shipped = conf, False
        else:  # a single entry: what changes from the shipped one
            partial, content, shipped = conf, read_hyperparams_file(algo, directory), True
    else:
        content, shipped = read_hyperparams_file(algo, directory), True
    for key in (env_name(env_id), env_id, "default"):
        if key in content:
            entry = dict(content[key] or {})
            break
    else:
        raise HyperparameterError(f"No entry for {env_name(env_id)!r} and no `default` in the {algo} hyper-parameters.")
    if key == "default" and shipped and algo in ("bc2l", "mecl", "vicrl"):
        entry.update(UNKNOWN_ENV_ICRL_DEFAULTS)
        if algo not in _ANNOUNCED_DEFAULTS:
            _ANNOUNCED_DEFAULTS.add(algo)
            used = ", ".join(f"{name}={value}" for name, value in UNKNOWN_ENV_ICRL_DEFAULTS.items())
            warnings.warn(
                f"No {algo} entry for {env_name(env_id)}: the `default` entry with {used} (the BlockedHalfCheetah "
                "recipes' budget and multiplier); change them with -params or --conf-file.",
                stacklevel=2,
            )
    entry.update(partial)
    entry.update(overrides or {})
    return entry, key


def constructor_defaults(algo_class: type) -> dict[str, Any]:
    """
    The keyword arguments ``algo_class`` takes, with their defaults (``inspect.Parameter.empty``: none): its own
    ``__init__``'s and, where that passes ``**kwargs`` on, its bases' (the nearest class's default wins).
    """
    defaults: dict[str, Any] = {}
    for klass in algo_class.__mro__:
        if "__init__" not in vars(klass):
            continue
        parameters = inspect.signature(vars(klass)["__init__"]).parameters.values()
        for parameter in parameters:
            if parameter.kind is parameter.POSITIONAL_OR_KEYWORD and parameter.name not in ("self", "_init_setup_model"):
                defaults.setdefault(parameter.name, parameter.default)
        if not any(parameter.kind is parameter.VAR_KEYWORD for parameter in parameters):
            break
    return defaults


def forward_learner_entry(
    algo: str,
    env_id: str,
    forward_recipe: str,
    overrides: dict[str, Any] | None = None,
    directory: str | os.PathLike | None = None,
) -> tuple[dict[str, Any], str]:
    """
    A reference row's entry: ``algo`` (``ppo`` or ``ppolag``) on the forward learner of ``forward_recipe``'s entry for
    ``env_id``, so that the reference rows of a benchmark learn with the same settings and steps as its ICRL cells.

    Only the settings ``algo`` takes are kept (and the zoo's own: envs, steps, normalisation): ``ppo`` drops the
    constraint model's and the Lagrangian's, ``ppolag`` the constraint model's. Where the recipe's algorithm and
    ``algo`` default a shared setting differently (the ICRL learners' budget is per step, PPOLagrangian's per episode),
    the recipe's default is written out. A budget of ``'expert'`` (the expert's learned cost) becomes 0, the true
    cost's budget: the expert's demonstrations break the true constraint nowhere.

    :param algo: ``ppo`` or ``ppolag``
    :param env_id: Registered or short env id
    :param forward_recipe: The algorithm whose entry gives the forward learner (e.g. ``mecl``)
    :param overrides: ``-params`` values, applied last
    :param directory: Folder of the yml files
    :return: The entry and the key it came from, as ``<forward_recipe>:<key>``
    """
    if algo not in REFERENCE_ALGOS:
        raise HyperparameterError(
            f"A forward recipe is for the reference rows ({', '.join(REFERENCE_ALGOS)}), not {algo!r}: leave it out."
        )
    if forward_recipe not in ALGOS:
        raise HyperparameterError(f"Unknown forward recipe {forward_recipe!r}: use one of {', '.join(ALGOS)}.")
    entry, key = load_hyperparams(forward_recipe, env_id, directory=directory)
    defaults = constructor_defaults(ALGOS[algo])
    entry = {name: value for name, value in entry.items() if name in defaults or name in ZOO_KEYS}
    for name, default in constructor_defaults(ALGOS[forward_recipe]).items():
        if name in defaults and name not in entry and default is not inspect.Parameter.empty and default != defaults[name]:
            entry[name] = default
    if entry.get("cost_budget") == "expert":
        entry["cost_budget"] = 0.0
    entry.update(overrides or {})
    return entry, f"{forward_recipe}:{key}"


def preprocess_hyperparams(entry: dict[str, Any]) -> dict[str, Any]:
    """
    Evaluate rl-zoo's string conventions; the zoo keys stay in the returned dict.

    :param entry: Raw entry from :func:`load_hyperparams`
    :return: A copy with dict strings evaluated, ``lin_`` schedules built, ``normalize`` parsed,
        ``env_wrapper`` and ``callback`` imported (as lists of ``(object, kwargs)``)
    """
    params = dict(entry)
    for key in EVAL_KEYS:
        if isinstance(params.get(key), str):
            params[key] = _eval_string(key, params[key])
    for key in ("learning_rate", "clip_range", "clip_range_vf"):
        value = params.get(key)
        if isinstance(value, str):
            if not value.startswith("lin_"):
                raise HyperparameterError(f"{key}: {value!r} is neither a number nor 'lin_<value>'.")
            params[key] = linear_schedule(value[len("lin_") :])
    normalize = params.get("normalize", False)
    if isinstance(normalize, str):
        normalize = _eval_string("normalize", normalize)
    if isinstance(normalize, dict):
        params["normalize_kwargs"] = {**params.get("normalize_kwargs", {}), **normalize}
        normalize = True
    params["normalize"] = bool(normalize)
    for key in ("env_wrapper", "callback"):
        params[key] = _import_specs(params[key]) if params.get(key) else []
    if isinstance(params.get("prior"), list):
        params["prior"] = tuple(params["prior"])
    params.setdefault("policy", "MlpPolicy")
    params.setdefault("n_envs", 1)
    if "n_timesteps" not in params:
        raise HyperparameterError("The hyper-parameters lack `n_timesteps`.")
    params["n_timesteps"] = int(float(params["n_timesteps"]))
    return params


def algo_kwargs(params: dict[str, Any]) -> dict[str, Any]:
    """The part of preprocessed ``params`` that goes to the algorithm's constructor."""
    return {key: value for key, value in params.items() if key not in ZOO_KEYS}


def _accepts_text(annotation: Any) -> bool:
    """Whether a parameter annotated ``annotation`` may receive a string (unknown annotations: yes)."""
    if annotation is inspect.Parameter.empty or annotation is Any or annotation is str:
        return True
    if isinstance(annotation, str):  # postponed annotation
        return "str" in annotation or "Any" in annotation
    arguments = typing.get_args(annotation)
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        return any(_accepts_text(argument) for argument in arguments)
    return False


def check_hyperparameter_types(algo_class: type, kwargs: dict[str, Any], example: str = "-params {key}:{default!r}") -> None:
    """
    Fail clearly when a hyper-parameter that is not text was given as text (``-params n_steps:abc``: the value could
    not be evaluated, so it stayed a string that the algorithm would reject deep inside).

    :param algo_class: The algorithm class
    :param kwargs: Its constructor arguments
    :param example: How the fix is written where the value came from, formatted with ``key`` and ``default``
    :raises HyperparameterError: Naming the first such hyper-parameter and the type it takes
    """
    parameters: dict[str, inspect.Parameter] = {}
    for klass in reversed(algo_class.__mro__):
        if "__init__" in vars(klass):
            try:
                parameters.update(inspect.signature(vars(klass)["__init__"]).parameters)
            except (TypeError, ValueError):
                continue
    for key, value in kwargs.items():
        parameter = parameters.get(key)
        if not isinstance(value, str) or parameter is None or _accepts_text(parameter.annotation):
            continue
        expected = getattr(parameter.annotation, "__name__", None) or str(parameter.annotation)
        expected = expected.replace("typing.", "").replace("collections.abc.", "")
        raise HyperparameterError(
            f"Hyper-parameter {key}={value!r} is text, but {algo_class.__name__} expects {expected} "
            f"(default {parameter.default!r}): give a Python value, e.g. {example.format(key=key, default=parameter.default)}."
        )


def forward_solver(algo: str, params: dict[str, Any], env_id: str) -> str:
    """
    The forward solver a zoo run asks for (``forward_solver`` in its hyper-parameters; default ``"policy_gradient"``),
    checked: ``"pi_lagrangian"`` needs an ICRL algorithm and a tabular env (one that exposes ``P``, ``R``, ``C`` and
    ``start_state``, as :class:`~sb3_icrl.envs.GridWorldEnv`).

    :param algo: Command-line algorithm name
    :param params: The run's hyper-parameters
    :param env_id: The registered env id
    :return: One of :data:`~sb3_icrl.icrl.tabular.FORWARD_SOLVERS`
    :raises ValueError: For an unknown solver, or a planner asked for where it cannot plan
    """
    solver = params.get("forward_solver", "policy_gradient")
    if solver not in FORWARD_SOLVERS:
        raise ValueError(f"forward_solver must be one of {', '.join(FORWARD_SOLVERS)}, got {solver!r}.")
    if solver == "policy_gradient":
        return solver  # a recipe's planner_kwargs stay unused (-params forward_solver:policy_gradient on a grid entry)
    if algo not in ICRL_ALGOS:
        raise ValueError(
            f"forward_solver: pi_lagrangian is the forward solver of the ICRL algorithms ({', '.join(ICRL_ALGOS)}); "
            f"{algo} trains its own policy (use sb3_icrl.PILagrangian directly to plan on the true cost)."
        )
    unwrapped = gym.make(env_id).unwrapped
    missing = [name for name in ("P", "R", "C", "start_state") if not hasattr(unwrapped, name)]
    if missing:
        raise ValueError(
            f"forward_solver: pi_lagrangian plans on tables, and {env_id} has no {', '.join(missing)} (tabular envs such as "
            "the grid worlds have them): pass -params forward_solver:policy_gradient."
        )
    planner_kwargs = params.get("planner_kwargs") or {}
    if not isinstance(planner_kwargs, dict):
        raise ValueError(f'planner_kwargs must be a dict, e.g. "dict(nominal_buffer_size=500)", got {planner_kwargs!r}.')
    accepted = set(inspect.signature(PILagrangian).parameters) - {"env", "cost_table", "seed", "verbose"}
    unknown = sorted(set(planner_kwargs) - accepted - set(PLANNER_LOOP_KEYS))
    if unknown:
        raise ValueError(
            f"planner_kwargs: unknown {', '.join(unknown)}. PILagrangian takes {', '.join(sorted(accepted))}; the ICRL loop "
            f"takes {', '.join(PLANNER_LOOP_KEYS)}."
        )
    if int(planner_kwargs.get("nominal_buffer_size", 0)) < 0:
        raise ValueError(f"nominal_buffer_size must be >= 0 (0: no buffer), got {planner_kwargs['nominal_buffer_size']}.")
    return solver
