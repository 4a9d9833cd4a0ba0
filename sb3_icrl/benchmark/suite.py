"""
Benchmark suites: which envs, algorithms, seeds and variants to run, read from a yml file and checked before anything
runs. A suite expands into runs; the folder of a run is a function of its cell and seed only, so that running a suite
again finds the runs it already made.
"""

import dataclasses
import difflib
import functools
import inspect
import math
import os
import pathlib
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import torch as th
import yaml

from sb3_icrl.common.constraint_spec import get_constraint_spec
from sb3_icrl.data.registry import DEMONSTRATIONS_DIR, available_demonstrations, dataset_file_name
from sb3_icrl.envs import NAMESPACE, REWARD_TRANSFER_TASKS
from sb3_icrl.envs.wrappers import COMPONENT_NOISE, TRANSITION_NOISE_MODELS, TransitionNoiseWrapper
from sb3_icrl.hyperparams import (
    ZOO_KEYS,
    algo_kwargs,
    check_hyperparameter_types,
    forward_solver,
    load_hyperparams,
    parse_override,
    preprocess_hyperparams,
)
from sb3_icrl.metrics.transfer import TASKS as TRANSFER_TASKS
from sb3_icrl.metrics.transfer import transfer_file
from sb3_icrl.registry import (
    ALGOS,
    ICRL_ALGOS,
    REFERENCE_ALGOS,
    env_name,
    import_gym_packages,
    resolve_env_id,
)
from sb3_icrl.run_env import create_env
from sb3_icrl.run_folder import FINISHED_FILE, LAST_TRAINING_EPISODES, is_finished

#: Where the shipped suites live
SUITES_DIR = pathlib.Path(__file__).resolve().parent / "suites"
#: How a report's held-out evaluation is counted (the suite key ``eval_budget``), with what each means
EVAL_BUDGETS = {
    "episodes": "exactly eval_episodes complete episodes per run",
    "steps": "the steps of eval_episodes full-length episodes, every episode that ends in them counted",
}
#: Top-level keys of a suite file
SUITE_KEYS = {
    "description": "one line on what the suite measures",
    "envs": "list of env ids",
    "algos": f"list of algorithms ({', '.join(ALGOS)})",
    "seeds": "list of training seeds",
    "env_seeds": "mapping env -> its own list of training seeds, instead of `seeds` (e.g. more seeds on a study's main env)",
    "variants": "mapping of variant name to its settings (default: one variant 'base' with none); a variant's `algos` "
    "lists the suite's algorithms that run it (default: all of them), for a setting only some algorithms take",
    "steps": "training steps: an integer, or a mapping env -> integer (default: the recipe's n_timesteps)",
    "eval_episodes": "held-out episodes per run in the report (default 20)",
    "eval_seed": "seed of the held-out episodes (default 100, a seed no run trains on)",
    "eval_budget": "how the report counts held-out episodes: "
    + "; ".join(f"{name}, {meaning}" for name, meaning in EVAL_BUDGETS.items())
    + " (default episodes)",
    "train_args": "extra train.py settings for every run: eval_freq, eval_episodes, save_freq, num_threads, device",
    "reference": "algorithm the report tests the others against (Wilcoxon signed-rank)",
    "forward_recipe": f"the reference rows ({', '.join(REFERENCE_ALGOS)}) learn with this algorithm's forward learner and "
    "steps, env by env, so that they stand on the same footing as the ICRL cells (default: their own recipes)",
    "paper": "mapping env -> algo -> [feasible reward, violation rate] of the paper, shown beside ours",
    "others": "mapping source name -> env -> algo -> [feasible reward, violation rate] of other published runs",
    "gym_packages": "modules to import first: they register your own envs",
    "recipe_version": "a name for the recipes the suite's runs use, frozen before its runs (each run records it; a "
    "report refuses a cell whose runs record different ones): change it whenever a recipe of the suite changes",
    "success": "what counts as a run that succeeded, written before any run: {max_violation_rate: 0.05, "
    "min_normalised_score: 0.5} (the normalised score needs the reference rows ppo and ppolag)",
    "headline_envs": "the envs whose constraint binds and can be identified (benchmarks/binding_check.py): the "
    "cross-env aggregates, probabilities of improvement and performance profile use these only, the other envs' cells "
    "are shown and marked (default: every env)",
    "transfer": "transfer tests the engine runs after each ICRL run (sb3-icrl transfer, learners seeded with the run's "
    f"seed): {{tasks: [reward], n_timesteps: 200000, envs: [...]}}; tasks among {', '.join(TRANSFER_TASKS)}, n_timesteps "
    "optional (default: ppolag.yml's), envs optional (default: every env of the suite)",
    "beats": "the judgement 'beats the paper', written before any run: {against: vicrl, envs: [...], columns: [heldout, "
    "last_training]}; each ICRL cell on those envs is judged against the `paper` row of method `against` (a higher mean "
    "feasible reward, a mean violation rate no higher) under every column named",
    "aim": "the aim written before any run: {min_oracle_fraction_iqm: 0.75, max_violation_rate_iqm: 0.05}; over the envs "
    "of the cross-env aggregates, the best ICRL method's IQM of each run's feasible reward over its env's oracle (ppolag) "
    "mean, and its violation-rate IQM (needs ppo and ppolag among the algos)",
}
#: The settings of a suite's ``success`` rule
SUCCESS_KEYS = ("max_violation_rate", "min_normalised_score")
#: The evaluation columns a ``beats`` judgement can take, with what each is
BEATS_COLUMNS = {
    "heldout": "held-out episodes of the final model",
    "last_training": f"the last {LAST_TRAINING_EPISODES} training episodes",
}
#: The settings of a suite's ``aim``
AIM_KEYS = ("min_oracle_fraction_iqm", "max_violation_rate_iqm")
#: What a variant may change, with the train.py flag it becomes
VARIANT_KEYS = {
    "transition_noise": "--transition-noise",
    "transition_noise_model": "--transition-noise-model",
    "violating_fraction": "--violating-fraction",
    "demonstrations": "--demonstrations",
    "hyperparams": "-params",
    "env_kwargs": "--env-kwargs",
}
#: The variant setting that says which of the suite's algorithms run the variant (not a train.py flag)
VARIANT_ALGOS = "algos"
#: train.py settings a suite may give every run
TRAIN_ARGS = {
    "eval_freq": "--eval-freq",
    "eval_episodes": "--eval-episodes",
    "save_freq": "--save-freq",
    "num_threads": "--num-threads",
    "device": "--device",
}
#: Runs train on the CPU unless a suite says otherwise: with MLP policies, batch-1 rollouts and many runs at a time,
#: a shared GPU is slower than one core per run (benchmarks/RESULTS.md)
DEFAULT_TRAIN_ARGS: dict[str, Any] = {
    "eval_freq": 50_000,
    "eval_episodes": 5,
    "save_freq": 100_000,
    "num_threads": 1,
    "device": "cpu",
}


class SuiteError(ValueError):
    """A suite file that cannot be run as written; the message names the file and line."""


def run_complete(run_folder: str, result_files: Sequence[str]) -> bool:
    """
    :param run_folder: A run folder
    :param result_files: Files its transfer tests write in it
    :return: Whether the run has finished training and has each of those results, of its final model
        (:func:`result_current`)
    """
    return is_finished(run_folder) and all(result_current(run_folder, file) for file in result_files)


def result_current(run_folder: str | os.PathLike, result_file: str) -> bool:
    """
    :param run_folder: A run folder
    :param result_file: A file a transfer test writes in it
    :return: Whether the file is there and no older than the run's ``finished.json``: one written before is of an
        earlier final model (the run was trained again since, its ``finished.json`` deleted), and does not count
    """
    path = os.path.join(run_folder, result_file)
    finished = os.path.join(run_folder, FINISHED_FILE)
    if not os.path.isfile(path):
        return False
    return not os.path.isfile(finished) or os.path.getmtime(path) >= os.path.getmtime(finished)


@dataclass(frozen=True)
class TransferSpec:
    """
    The transfer tests of a suite's ICRL runs (``sb3-icrl transfer``).

    :param tasks: Tasks among ``same``, ``reward``, ``dynamics``
    :param n_timesteps: Training steps of each transfer learner (``None``: ppolag.yml's)
    :param envs: Env names whose ICRL runs take the tests (``None``: every env of the suite)
    """

    tasks: tuple[str, ...]
    n_timesteps: int | None = None
    envs: tuple[str, ...] | None = None


@dataclass(frozen=True)
class BeatsRule:
    """
    A suite's judgement "beats the paper", written before its runs (the suite key ``beats``).

    :param against: The method whose row of the suite's ``paper`` numbers each ICRL cell is judged against
    :param envs: Env names judged, each with a ``paper`` number of ``against``
    :param columns: The evaluation columns (:data:`BEATS_COLUMNS`) under each of which a cell must beat it
    """

    against: str
    envs: tuple[str, ...]
    columns: tuple[str, ...]


@dataclass(frozen=True)
class RunSpec:
    """
    One training run of a suite.

    :param suite: Suite name
    :param variant: Variant name
    :param algo: Algorithm
    :param env_id: Registered env id
    :param seed: Training seed
    :param steps: Training steps (``None``: the recipe's)
    :param variant_settings: The variant's settings (see :data:`VARIANT_KEYS`)
    :param train_args: train.py settings (see :data:`TRAIN_ARGS`)
    :param gym_packages: Modules that register the env (``--gym-packages``)
    :param forward_recipe: For the reference rows: the algorithm whose forward learner they use (``--forward-recipe``)
    :param recipe_version: The suite's recipe version (``--recipe-version``)
    :param transfer: The transfer tests to run once an ICRL run has finished (``None``: none)
    """

    suite: str
    variant: str
    algo: str
    env_id: str
    seed: int
    steps: int | None
    variant_settings: dict[str, Any] = field(default_factory=dict, compare=False, hash=False)
    train_args: dict[str, Any] = field(default_factory=dict, compare=False, hash=False)
    gym_packages: tuple[str, ...] = field(default=(), compare=False, hash=False)
    forward_recipe: str | None = field(default=None, compare=False, hash=False)
    recipe_version: str | None = field(default=None, compare=False, hash=False)
    transfer: TransferSpec | None = field(default=None, compare=False, hash=False)

    @property
    def cell(self) -> tuple[str, str, str]:
        """``(env, variant, algo)``: the runs of a cell differ only by seed."""
        return (env_name(self.env_id), self.variant, self.algo)

    @property
    def name(self) -> str:
        return f"{self.variant}/{self.algo}/{env_name(self.env_id)}/seed {self.seed}"

    def log_folder(self, root: str | os.PathLike) -> str:
        """train.py's ``-f``: ``<root>/<suite>/<variant>``."""
        return os.path.join(os.fspath(root), self.suite, self.variant)

    def run_folder(self, root: str | os.PathLike) -> str:
        """The run folder, ``<root>/<suite>/<variant>/<algo>/<EnvName>_<seed>``: a function of cell and seed only."""
        return os.path.join(self.log_folder(root), self.algo, f"{env_name(self.env_id)}_{self.seed}")

    def log_file(self, root: str | os.PathLike) -> str:
        """Where the run's output goes: ``<root>/<suite>/logs/<variant>_<algo>_<EnvName>_<seed>.log``."""
        return os.path.join(
            os.fspath(root), self.suite, "logs", f"{self.variant}_{self.algo}_{env_name(self.env_id)}_{self.seed}.log"
        )

    def transfer_tasks(self) -> list[str]:
        """The transfer tasks the suite tests this run on: none unless it asks for them and the run is an ICRL one."""
        if self.transfer is None or self.algo not in ICRL_ALGOS:
            return []
        if self.transfer.envs is not None and env_name(self.env_id) not in self.transfer.envs:
            return []
        return list(self.transfer.tasks)

    def transfer_jobs(self, root: str | os.PathLike) -> list[tuple[str, list[str]]]:
        """
        The transfer tests of this run (:meth:`transfer_tasks`), each as ``(result file in the run folder, sb3-icrl
        transfer arguments)``. The learners take the run's seed.
        """
        n_timesteps = None if self.transfer is None else self.transfer.n_timesteps
        jobs = []
        for task in self.transfer_tasks():
            argv = [self.run_folder(root), "--task", task, "--seed", str(self.seed)]
            if n_timesteps is not None:
                argv += ["-n", str(n_timesteps)]
            if self.gym_packages:
                argv += ["--gym-packages", *self.gym_packages]
            jobs.append((transfer_file(task), argv))
        return jobs

    def complete(self, root: str | os.PathLike) -> bool:
        """Whether the run has finished training and has every transfer result the suite asks for."""
        return run_complete(self.run_folder(root), [file for file, _ in self.transfer_jobs(root)])

    def train_argv(self, root: str | os.PathLike) -> list[str]:
        """The train.py arguments of this run (it resumes itself when run again)."""
        argv = ["--algo", self.algo, "--env", self.env_id, "--seed", str(self.seed), "-f", self.log_folder(root)]
        argv += ["--exp-id", str(self.seed), "--resume", "--verbose", "1"]
        if self.gym_packages:
            argv += ["--gym-packages", *self.gym_packages]
        if self.steps is not None:
            argv += ["-n", str(self.steps)]
        if self.forward_recipe is not None and self.algo in REFERENCE_ALGOS:
            argv += ["--forward-recipe", self.forward_recipe]
        if self.recipe_version is not None:
            argv += ["--recipe-version", self.recipe_version]
        for key, flag in TRAIN_ARGS.items():
            if key in self.train_args:
                argv += [flag, str(self.train_args[key])]
        for key, flag in VARIANT_KEYS.items():
            value = self.variant_settings.get(key)
            if value is None:
                continue
            if isinstance(value, dict):
                argv += [flag, *(f"{name}:{_flag_text(item)}" for name, item in value.items())]
            else:
                argv += [flag, str(value)]
        return argv


def variant_algos(algos: Sequence[str], settings: dict[str, Any]) -> list[str]:
    """Of ``algos``, those that run the variant of ``settings`` (its ``algos``; all without it), in ``algos``' order."""
    chosen = settings.get(VARIANT_ALGOS)
    return [algo for algo in algos if chosen is None or algo in chosen]


@dataclass
class Suite:
    """
    A parsed and checked suite file (see :data:`SUITE_KEYS` for what each field means).
    """

    name: str
    path: str
    description: str
    envs: list[str]
    algos: list[str]
    seeds: list[int]
    variants: dict[str, dict[str, Any]]
    steps: dict[str, int | None]
    eval_episodes: int
    eval_seed: int
    train_args: dict[str, Any]
    reference: str | None
    paper: dict[str, dict[str, tuple[float, float]]]
    gym_packages: tuple[str, ...] = ()
    forward_recipe: str | None = None
    recipe_version: str | None = None
    #: The success rule (:data:`SUCCESS_KEYS`), ``None`` when the suite defines none
    success: dict[str, float] | None = None
    #: source name -> env name -> algo -> (feasible reward, violation rate), in the file's order
    others: dict[str, dict[str, dict[str, tuple[float, float]]]] = field(default_factory=dict)
    #: The transfer tests run after each ICRL run, ``None`` when the suite asks for none
    transfer: TransferSpec | None = None
    #: Env names in the headline aggregates, ``None``: every env
    headline_envs: tuple[str, ...] | None = None
    #: How the held-out evaluation is counted, one of :data:`EVAL_BUDGETS`
    eval_budget: str = "episodes"
    #: The judgement "beats the paper", ``None`` when the suite writes none
    beats: BeatsRule | None = None
    #: The aim's thresholds (:data:`AIM_KEYS`), ``None`` when the suite states none
    aim: dict[str, float] | None = None
    #: Per env with seeds of its own (``env_seeds``), its training seeds; the other envs take ``seeds``
    env_seeds: dict[str, list[int]] = field(default_factory=dict)

    def runs(self) -> list[RunSpec]:
        """Every run, env by env, then variant, algorithm and seed."""
        return [
            RunSpec(
                self.name,
                variant,
                algo,
                env_id,
                seed,
                self.steps[env_id],
                settings,
                self.train_args,
                self.gym_packages,
                self.forward_recipe,
                self.recipe_version,
                self.transfer,
            )
            for env_id in self.envs
            for variant, settings in self.variants.items()
            for algo in self.variant_algos(variant)
            for seed in self.env_seeds.get(env_id, self.seeds)
        ]

    def probe_run(self, run: RunSpec) -> RunSpec | None:
        """
        The run whose episodes join the identification probes of an ICRL run: the suite's unconstrained ``ppo`` row of
        the same variant, env and seed, the run
        :func:`~sb3_icrl.metrics.identification.find_unconstrained_run` looks for first. Grid worlds take no such
        episodes.

        :param run: A run of this suite
        :return: That ``ppo`` run; ``None`` for a run that is not an ICRL one, an env without probe episodes, or a
            suite without that row
        """
        return self.probe_runs([run]).get(run)

    def probe_runs(self, runs: Iterable[RunSpec]) -> dict[RunSpec, RunSpec]:
        """
        :meth:`probe_run` for many runs at once, reading the suite's run list once.

        :param runs: Runs of this suite
        :return: ``{run: its probe run}`` for those of ``runs`` that have one
        """
        suite_runs = set(self.runs())
        probes: dict[RunSpec, RunSpec] = {}
        for run in runs:
            if run.algo not in ICRL_ALGOS or _discrete_observations(run.env_id):
                continue
            wanted = dataclasses.replace(run, algo="ppo")
            if wanted in suite_runs:
                probes[run] = wanted
        return probes

    def variant_algos(self, variant: str) -> list[str]:
        """The suite's algorithms that run ``variant`` (its ``algos``, default all), in the suite's order."""
        return variant_algos(self.algos, self.variants[variant])

    def select(self, only: dict[str, list[str]]) -> list[RunSpec]:
        """
        The runs matching every ``--only`` filter (``env``, ``algo``, ``seed``, ``variant``; values within a key are
        alternatives).

        :param only: ``{key: [values]}``
        """
        unknown = sorted(set(only) - {"env", "algo", "seed", "variant"})
        if unknown:
            raise SuiteError(f"--only takes env=, algo=, seed= and variant=, not {', '.join(unknown)}.")
        wanted = {key: set(values) for key, values in only.items()}
        if "env" in wanted:
            wanted["env"] = {env_name(resolve_env_id(value)) for value in wanted["env"]}
        selected = [
            run
            for run in self.runs()
            if all(
                {"env": env_name(run.env_id), "algo": run.algo, "seed": str(run.seed), "variant": run.variant}[key] in values
                for key, values in wanted.items()
            )
        ]
        if not selected:
            # Name the values the suite has for each filtered key: a typo or a seed it does not run shows at once
            available = {
                "env": [env_name(env_id) for env_id in self.envs],
                "algo": list(self.algos),
                "seed": [str(seed) for seed in dict.fromkeys(run.seed for run in self.runs())],
                "variant": list(self.variants),
            }
            offered = "; ".join(f"{key}: {', '.join(available[key])}" for key in wanted)
            if all(values <= set(available[key]) for key, values in wanted.items()):
                # Each value exists, their combination does not: an env's own seeds, or a variant's own algorithms
                combos = [
                    f"{env_name(env_id)} runs seeds {', '.join(map(str, self.env_seeds.get(env_id, self.seeds)))}"
                    for env_id in self.envs
                    if "seed" in wanted and ("env" not in wanted or env_name(env_id) in wanted["env"])
                ] + [
                    f"variant {variant} runs {', '.join(self.variant_algos(variant))}"
                    for variant in self.variants
                    if "algo" in wanted and ("variant" not in wanted or variant in wanted["variant"])
                ]
                raise SuiteError(
                    f"--only {only}: each value is one of suite {self.name!r}'s own, but no run has them all"
                    + (f" ({'; '.join(combos)})." if combos else ".")
                )
            raise SuiteError(
                f"--only {only} matches none of the {len(self.runs())} runs of suite {self.name!r}; it has {offered}."
            )
        return selected

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def suite_path(name_or_path: str | os.PathLike) -> pathlib.Path:
    """
    A shipped suite's file by name (``table3``), or a user's suite file by path.

    :param name_or_path: Suite name or ``.yml`` path
    """
    text = os.fspath(name_or_path)
    if text.endswith((".yml", ".yaml")) or os.sep in text:
        path = pathlib.Path(text)
        if not path.is_file():
            raise SuiteError(f"No suite file {text}.")
        return path
    path = SUITES_DIR / f"{text}.yml"
    if not path.is_file():
        shipped = sorted(file.stem for file in SUITES_DIR.glob("*.yml"))
        raise SuiteError(f"No shipped suite {text!r}: use one of {', '.join(shipped)}, or the path of your own .yml file.")
    return path


class DuplicateKeyError(ValueError):
    """A suite file gives the same key twice in one mapping."""


def _key_lines(node: yaml.Node, prefix: tuple = ()) -> dict[tuple, int]:
    """The 1-based line of every mapping key and sequence item in a composed yml document, by its path."""
    lines: dict[tuple, int] = {prefix: node.start_mark.line + 1}
    if isinstance(node, yaml.MappingNode):
        seen: dict[Any, int] = {}
        for key_node, value_node in node.value:
            path = (*prefix, key_node.value)
            line = key_node.start_mark.line + 1
            if key_node.value in seen:  # yaml keeps the last silently: the first would be lost without a word
                where = ".".join(str(part) for part in path)
                raise DuplicateKeyError(f"line {line}: `{where}` is given twice (first on line {seen[key_node.value]}).")
            seen[key_node.value] = line
            lines.update(_key_lines(value_node, path))
            lines[path] = key_node.start_mark.line + 1
    elif isinstance(node, yaml.SequenceNode):
        for index, item in enumerate(node.value):
            lines.update(_key_lines(item, (*prefix, index)))
    return lines


class _SuiteReader:
    """Checks one suite file's content, each error naming the file and the line of the offending entry."""

    def __init__(self, path: pathlib.Path, node: yaml.Node, content: dict[str, Any]):
        self.path = path
        try:
            self.lines = _key_lines(node)
        except DuplicateKeyError as error:
            raise SuiteError(f"{path}, {error}") from error
        self.content = content
        self.env_modules: list[str] = []

    def error(self, location: tuple, message: str) -> SuiteError:
        while location not in self.lines and location:
            location = location[:-1]
        return SuiteError(f"{self.path}, line {self.lines.get(location, 1)}: {message}")

    def positive_int(self, value: Any, location: tuple, allow_zero: bool = False) -> int:
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int) or value < (0 if allow_zero else 1):
            name = ".".join(map(str, location))
            raise self.error(location, f"`{name}` must be an integer >= {0 if allow_zero else 1}, got {value!r}.")
        return value

    def env_id(self, value: Any, location: tuple) -> str:
        try:
            return resolve_env_id(str(value))
        except ValueError as error:
            raise self.error(location, str(error)) from error

    def lists(self) -> tuple[list[str], list[str], list[int]]:
        for key in self.content:
            if key not in SUITE_KEYS:
                known = "; ".join(f"{name} ({meaning})" for name, meaning in SUITE_KEYS.items())
                raise self.error((key,), f"unknown key {key!r}; a suite has: {known}")
        for key in ("envs", "algos", "seeds"):
            if not isinstance(self.content.get(key), list) or not self.content[key]:
                raise self.error((key,), f"`{key}` must be a non-empty list ({SUITE_KEYS[key]}).")
        envs = [self.env_id(env, ("envs", index)) for index, env in enumerate(self.content["envs"])]
        # An env written MODULE:EnvId registers when MODULE is imported: every run must import it too
        self.env_modules = [str(env).partition(":")[0] for env in self.content["envs"] if ":" in str(env)]
        algos = [str(algo) for algo in self.content["algos"]]
        for index, algo in enumerate(algos):
            if algo not in ALGOS:
                raise self.error(("algos", index), _unknown_algo(algo))
        seeds = self.seed_list(self.content["seeds"], ("seeds",))
        for key, values in (("envs", envs), ("algos", algos)):
            if len(set(values)) != len(values):
                raise self.error((key,), f"`{key}` repeats an entry: {self.content[key]}.")
        return envs, algos, seeds

    def seed_list(self, raw: list[Any], where: tuple[Any, ...]) -> list[int]:
        """Training seeds: integers >= 0, each once."""
        seeds = []
        for index, seed in enumerate(raw):
            if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
                raise self.error((*where, index), f"seeds are integers >= 0, got {seed!r}.")
            seeds.append(seed)
        if len(set(seeds)) != len(seeds):
            raise self.error(where, f"`{'.'.join(map(str, where))}` repeats an entry: {raw}.")
        return seeds

    def env_seeds(self, envs: list[str]) -> dict[str, list[int]]:
        """``env_seeds``: per env named, its own training seeds (the other envs take ``seeds``)."""
        raw = self.content.get("env_seeds")
        if raw is None:
            return {}
        if not isinstance(raw, dict) or not raw:
            raise self.error(("env_seeds",), f"`env_seeds` maps an env to its list of seeds ({SUITE_KEYS['env_seeds']}).")
        env_seeds: dict[str, list[int]] = {}
        for key, value in raw.items():
            env_id = self.env_id(key, ("env_seeds", key))
            if env_id not in envs:
                raise self.error(("env_seeds", key), f"{key} is not one of the suite's envs.")
            if not isinstance(value, list) or not value:
                raise self.error(("env_seeds", key), f"the seeds of {key} are a non-empty list, got {value!r}.")
            env_seeds[env_id] = self.seed_list(value, ("env_seeds", key))
        return env_seeds

    def variants(self, algos: list[str]) -> dict[str, dict[str, Any]]:
        variants = self.content.get("variants") or {"base": {}}
        if not isinstance(variants, dict):
            raise self.error(
                ("variants",), "`variants` maps a variant name to its settings, e.g. {sigma-0.01: {transition_noise: 0.01}}."
            )
        for variant, settings in variants.items():
            where = ("variants", variant)
            if not isinstance(variant, str) or not variant or "/" in variant or variant != variant.strip():
                raise self.error(where, f"variant names are folder names without '/', got {variant!r}.")
            if not isinstance(settings, dict):
                raise self.error(where, f"variant {variant!r} must map settings ({', '.join(VARIANT_KEYS)}) to values.")
            for key, value in settings.items():
                if key == VARIANT_ALGOS:
                    self.check_variant_algos(variant, value, algos)
                    continue
                if key not in VARIANT_KEYS:
                    raise self.error(
                        (*where, key), f"unknown variant setting {key!r}: use {', '.join([*VARIANT_KEYS, VARIANT_ALGOS])}."
                    )
                if key in ("hyperparams", "env_kwargs") and not isinstance(value, dict):
                    raise self.error((*where, key), f"`{key}` maps names to values.")
                if key in ("transition_noise", "violating_fraction") and (
                    isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0
                ):
                    raise self.error((*where, key), f"`{key}` is a number >= 0, got {value!r}.")
                if key == "transition_noise_model" and value not in TRANSITION_NOISE_MODELS:
                    raise self.error(
                        (*where, key),
                        f"`transition_noise_model` is one of {', '.join(TRANSITION_NOISE_MODELS)} (component: an independent "
                        f"draw per state component; shared: one draw per step added to every component), got {value!r}.",
                    )
                if key == "violating_fraction" and value > 1:
                    raise self.error(
                        (*where, key), f"`violating_fraction` is a share of trajectories, within [0, 1], got {value!r}."
                    )
                if key == "transition_noise_model" and not settings.get("transition_noise"):
                    raise self.error(
                        (*where, key),
                        f"variant {variant!r}: `transition_noise_model` says how the noise of `transition_noise` is drawn, "
                        "and the variant has none: give `transition_noise` (a number > 0), or leave out "
                        "`transition_noise_model`.",
                    )
        return {str(name): dict(settings) for name, settings in variants.items()}

    def check_variant_algos(self, variant: str, value: Any, algos: list[str]) -> None:
        """A variant's ``algos``: a non-empty list of the suite's algorithms, each once."""
        where = ("variants", variant, VARIANT_ALGOS)
        if not isinstance(value, list) or not value or not all(isinstance(algo, str) for algo in value):
            raise self.error(
                where, f"variant {variant!r}: `algos` lists the suite's algorithms that run it, e.g. [vicrl], got {value!r}."
            )
        strangers = [algo for algo in value if algo not in algos]
        if strangers:
            raise self.error(
                where,
                f"variant {variant!r}: `algos` names {', '.join(strangers)}, not among the suite's algos "
                f"({', '.join(algos)}): add it to `algos` or drop it here.",
            )
        if len(set(value)) != len(value):
            raise self.error(where, f"variant {variant!r}: `algos` names an algorithm twice: {value!r}.")

    def check_demonstrations(self, envs: list[str], algos: list[str], variants: dict[str, dict[str, Any]]) -> None:
        """Every ICRL cell has demonstrations: the variant's own file, or a dataset shipped for its env and fraction."""
        for variant, settings in variants.items():
            if not set(variant_algos(algos, settings)) & set(ICRL_ALGOS):
                continue
            if settings.get("demonstrations") is not None:
                path = os.path.expanduser(str(settings["demonstrations"]))
                if not os.path.isfile(path):
                    raise self.error(
                        ("variants", variant, "demonstrations"), f"no demonstrations file {path!r} (from {os.getcwd()})."
                    )
                continue
            fraction = settings.get("violating_fraction")
            for index, env in enumerate(envs):
                if not (DEMONSTRATIONS_DIR / dataset_file_name(env, fraction)).is_file():
                    shipped = available_demonstrations().get(env_name(env))
                    what = f" with violating_fraction {fraction:g}" if fraction else ""
                    raise self.error(
                        ("envs", index),
                        f"the ICRL algorithms learn from demonstrations, and none are shipped for {env_name(env)}{what} "
                        f"(shipped fractions: {shipped if shipped else 'none'}): give the variant "
                        "`demonstrations: PATH.npz` (python -m sb3_icrl.data generate), or drop the env.",
                    )

    def check_hyperparams(self, algos: list[str], variants: dict[str, dict[str, Any]]) -> None:
        """Every hyper-parameter a variant sets is one that each algorithm of the suite takes (each run gets them all)."""
        for variant, settings in variants.items():
            for key in settings.get("hyperparams") or {}:
                refusing = [algo for algo in variant_algos(algos, settings) if str(key) not in _hyperparameter_names(algo)]
                if refusing:
                    known = sorted(set.intersection(*(_hyperparameter_names(algo) for algo in refusing)))
                    close = difflib.get_close_matches(str(key), known, n=1, cutoff=0.8)
                    raise self.error(
                        ("variants", variant, "hyperparams", key),
                        f"`{key}` is not a hyper-parameter of {', '.join(refusing)}"
                        f"{f' (did you mean {close[0]!r}?)' if close else ''}: every run of variant {variant!r} "
                        "would stop at its start (a setting only some algorithms take: name them in the variant's "
                        "`algos`).",
                    )

    def check_costs(self, envs: list[str]) -> None:
        """Every env reports or declares its true cost: ppolag trains on it, and the report counts violations with it."""
        for index, env_id in enumerate(envs):
            if env_id.startswith(f"{NAMESPACE}/") or get_constraint_spec(env_id) is not None:
                continue
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    env = gym.make(env_id)
                    env.reset(seed=0)
                    info = env.step(env.action_space.sample())[-1]
                    env.close()
            except Exception:  # an env that needs the variant's env_kwargs: its runs say what is wrong
                continue
            if "cost" not in info:
                raise self.error(
                    ("envs", index),
                    f"{env_id} reports no true cost (its step's info has no 'cost', only {sorted(info)}) and declares no "
                    "constraint: ppolag trains on that cost and the report counts every cell's violations with it. Put "
                    "the per-step cost in info['cost'], or declare the constraint (a `constraint_spec` attribute on the "
                    "env, or sb3_icrl.common.constraint_spec.declare_constraint in a module of `gym_packages`).",
                )

    def check_envs(self, envs: list[str], variants: dict[str, dict[str, Any]]) -> None:
        """
        Every env made with each variant's ``env_kwargs`` and transition noise, as its runs make it: a keyword the env
        does not take or a value it refuses, or noise on an env without continuous states, is named at its line. An env
        that fails otherwise (a dependency missing here) is left to its runs, which say why.
        """
        for variant, settings in variants.items():
            env_kwargs = _as_train_reads(settings.get("env_kwargs") or {})
            noise = settings.get("transition_noise") or 0.0
            noise_model = settings.get("transition_noise_model", COMPONENT_NOISE)
            if not env_kwargs and not noise:
                continue
            for env_id in envs:
                try:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        env = gym.make(env_id, **env_kwargs)
                except (TypeError, ValueError) as error:
                    message = " ".join(f"{type(error).__name__}: {error}".split())
                    raise self.error(
                        ("variants", variant, "env_kwargs"),
                        f"variant {variant!r}: {env_name(env_id)} cannot be made with these env_kwargs ({message}).",
                    ) from None
                except Exception:
                    continue
                try:
                    if noise:
                        TransitionNoiseWrapper(env, sigma=float(noise), model=noise_model)
                except (TypeError, ValueError) as error:
                    raise self.error(
                        ("variants", variant, "transition_noise"),
                        f"variant {variant!r} cannot run on {env_name(env_id)}: {error}",
                    ) from None
                finally:
                    env.close()

    def check_builds(
        self, envs: list[str], algos: list[str], variants: dict[str, dict[str, Any]], forward_recipe: str | None
    ) -> None:
        """
        Every run of a variant that sets hyper-parameters gets its model made: a dry build (see :func:`_dry_build`).
        A value that the recipe reader or the algorithm refuses (``cost_budget: -1``, ``n_steps: abc``, a misspelt
        argument in ``constraint_net_kwargs``) is named at its line, with the variant, algorithm and env. Only what
        the variant's values cause is told: a build that fails the same way without each of them (an algorithm that
        needs its demonstrations to be made) is left to the run.
        """
        built: dict[str, str | None] = {}

        def build(algo: str, env_id: str, overrides: dict[str, Any], env_kwargs: dict[str, Any]) -> str | None:
            # Once per distinct model: variants that differ only in their noise or data share their builds
            recipe = forward_recipe if algo in REFERENCE_ALGOS else None
            key = repr((algo, env_id, sorted(overrides.items()), sorted(env_kwargs.items()), recipe))
            if key not in built:
                built[key] = _dry_build(algo, env_id, overrides, env_kwargs, recipe)
            return built[key]

        for variant, settings in variants.items():
            overrides = _as_train_reads(settings.get("hyperparams") or {})
            if not overrides:
                continue
            env_kwargs = _as_train_reads(settings.get("env_kwargs") or {})
            for env_id in envs:
                for algo in variant_algos(algos, settings):
                    error = build(algo, env_id, overrides, env_kwargs)
                    if error is None:
                        continue
                    for key in overrides:
                        rest = {name: value for name, value in overrides.items() if name != key}
                        if build(algo, env_id, rest, env_kwargs) != error:
                            raise self.error(
                                ("variants", variant, "hyperparams", key),
                                f"variant {variant!r} stops every {algo} run on {env_name(env_id)} at its start, at "
                                f"`{key}`: {error}",
                            )

    def steps(self, envs: list[str]) -> dict[str, int | None]:
        raw = self.content.get("steps")
        if raw is None:
            return {env: None for env in envs}
        if not isinstance(raw, dict):
            return {env: self.positive_int(raw, ("steps",)) for env in envs}
        steps: dict[str, int | None] = {env: None for env in envs}
        for key, value in raw.items():
            env_id = self.env_id(key, ("steps", key))
            if env_id not in steps:
                raise self.error(("steps", key), f"{key} is not one of the suite's envs.")
            steps[env_id] = self.positive_int(value, ("steps", key))
        return steps

    def train_args(self) -> dict[str, Any]:
        train_args = dict(DEFAULT_TRAIN_ARGS)
        for key, value in (self.content.get("train_args") or {}).items():
            if key not in TRAIN_ARGS:
                raise self.error(("train_args", key), f"unknown train setting {key!r}: use {', '.join(TRAIN_ARGS)}.")
            if key == "device":
                if not isinstance(value, str) or not value:
                    raise self.error(
                        ("train_args", key), f"`device` is a torch device name ('cpu', 'cuda', 'auto'), got {value!r}."
                    )
                if value != "auto":
                    try:
                        th.device(value)
                    except RuntimeError:
                        raise self.error(
                            ("train_args", key), f"`device` {value!r} is not a torch device: use auto, cpu, cuda or cuda:N."
                        ) from None
            elif isinstance(value, bool) or not isinstance(value, int):
                raise self.error(("train_args", key), f"`{key}` is an integer, got {value!r}.")
            elif key in ("eval_episodes", "num_threads") and value < 1:
                raise self.error(("train_args", key), f"`{key}` is at least 1, got {value!r}.")
            train_args[key] = value
        return train_args

    def numbers(self, raw: Any, where: tuple, what: str) -> dict[str, dict[str, tuple[float, float]]]:
        """
        Published numbers ``env -> algo -> [feasible reward, violation rate]``, keyed by env name.

        :param raw: The mapping as read
        :param where: Its location in the file (``("paper",)``, ``("others", source)``)
        :param what: Whose numbers, for the messages
        """
        if raw is None:
            return {}
        if not isinstance(raw, dict):
            raise self.error(where, f"{what} numbers map env -> algo -> [feasible reward, violation rate].")
        numbers: dict[str, dict[str, tuple[float, float]]] = {}
        for env, entries in raw.items():
            name = env_name(self.env_id(env, (*where, env)))
            if not isinstance(entries, dict):
                raise self.error((*where, env), f"{what} numbers map algo -> [feasible reward, violation rate].")
            for algo, pair in entries.items():
                if algo not in ALGOS:
                    raise self.error((*where, env, algo), _unknown_algo(algo))
                if not (
                    isinstance(pair, list)
                    and len(pair) == 2
                    and all(isinstance(n, (int, float)) and not isinstance(n, bool) for n in pair)
                ):
                    raise self.error((*where, env, algo), f"expected [feasible reward, violation rate], got {pair!r}.")
                if not 0 <= pair[1] <= 1:
                    raise self.error((*where, env, algo), f"a violation rate is within [0, 1], got {pair[1]!r}.")
                numbers.setdefault(name, {})[algo] = (float(pair[0]), float(pair[1]))
        return numbers

    def success(self, algos: list[str]) -> dict[str, float] | None:
        raw = self.content.get("success")
        if raw is None:
            return None
        rule = self.thresholds(
            "success", raw, SUCCESS_KEYS, "max_violation_rate", "{max_violation_rate: 0.05, min_normalised_score: 0.5}"
        )
        if not set(REFERENCE_ALGOS) <= set(algos):
            raise self.error(
                ("success",),
                f"`success` needs the normalised score, which needs the reference rows {' and '.join(REFERENCE_ALGOS)} "
                "among the algos: add them, or leave `success` out.",
            )
        return rule

    def thresholds(self, name: str, raw: Any, keys: Sequence[str], rate_key: str, example: str) -> dict[str, float]:
        """
        A setting that maps each of ``keys`` to a finite number (``success``, ``aim``), checked.

        :param name: The setting's key
        :param raw: Its value in the file
        :param keys: The keys it must have, all of them
        :param rate_key: The one that is a rate, within [0, 1]
        :param example: A valid value, for the message
        :return: The numbers by key
        """
        if not isinstance(raw, dict) or set(raw) != set(keys):
            raise self.error((name,), f"`{name}` maps {' and '.join(keys)} to numbers, e.g. {example}.")
        numbers = {}
        for key in keys:
            value = raw[key]
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise self.error((name, key), f"`{name}.{key}` is a number, got {value!r}.")
            if key == rate_key and not 0 <= value <= 1:
                raise self.error((name, key), f"`{name}.{key}` is a rate within [0, 1], got {value!r}.")
            numbers[key] = float(value)
        return numbers

    def env_subset(self, raw: Any, envs: list[str], where: tuple[str, ...]) -> tuple[str, ...]:
        """
        A setting that names some of the suite's envs, checked.

        :param raw: Its value in the file
        :param envs: The suite's envs
        :param where: Its key path (for the error's line)
        :return: The env names, in the order given
        """
        key = ".".join(where)
        names = [env_name(env) for env in envs]
        if not isinstance(raw, list) or not raw or not all(isinstance(env, str) for env in raw):
            raise self.error(where, f"`{key}` is a non-empty list of the suite's envs, got {raw!r}.")
        unknown = [env for env in raw if env_name(env) not in names]
        if unknown:
            raise self.error(where, f"{', '.join(unknown)} not among the suite's envs ({', '.join(names)}).")
        return tuple(env_name(env) for env in raw)

    def eval_budget(self) -> str:
        value = self.content.get("eval_budget", "episodes")
        if not isinstance(value, str) or value not in EVAL_BUDGETS:
            allowed = "; ".join(f"{name} ({meaning})" for name, meaning in EVAL_BUDGETS.items())
            raise self.error(("eval_budget",), f"`eval_budget` is one of {allowed}, got {value!r}.")
        return str(value)

    def headline_envs(self, envs: list[str]) -> tuple[str, ...] | None:
        raw = self.content.get("headline_envs")
        return None if raw is None else self.env_subset(raw, envs, ("headline_envs",))

    def transfer(self, envs: list[str], algos: list[str]) -> TransferSpec | None:
        raw = self.content.get("transfer")
        if raw is None:
            return None
        example = "{tasks: [reward], n_timesteps: 200000, envs: [BlockedSwimmer-v0]}"
        if not isinstance(raw, dict) or not set(raw) <= {"tasks", "n_timesteps", "envs"} or "tasks" not in raw:
            raise self.error(
                ("transfer",), f"`transfer` maps `tasks` (and optionally `n_timesteps` and `envs`), e.g. {example}."
            )
        tasks = raw["tasks"]
        if not isinstance(tasks, list) or not tasks or not all(task in TRANSFER_TASKS for task in tasks):
            raise self.error(
                ("transfer", "tasks"), f"`transfer.tasks` is a list among {', '.join(TRANSFER_TASKS)}, got {tasks!r}."
            )
        if len(set(tasks)) != len(tasks):
            raise self.error(("transfer", "tasks"), f"`transfer.tasks` names a task twice: {tasks!r}.")
        if not set(algos) & set(ICRL_ALGOS):
            raise self.error(("transfer",), "`transfer` tests learned constraints, and the suite has no ICRL algorithm.")
        tested = None if raw.get("envs") is None else self.env_subset(raw["envs"], envs, ("transfer", "envs"))
        if tested is not None:
            envs = [env for env in envs if env_name(env) in tested]
        if "reward" in tasks:
            without = [env for env in envs if env_name(env) not in REWARD_TRANSFER_TASKS]
            if without:
                raise self.error(
                    ("transfer", "tasks"),
                    f"no reward-transfer task for {', '.join(env_name(env) for env in without)}; envs with one: "
                    f"{', '.join(sorted(REWARD_TRANSFER_TASKS))}.",
                )
        steps = raw.get("n_timesteps")
        n_timesteps = None if steps is None else self.positive_int(steps, ("transfer", "n_timesteps"))
        return TransferSpec(tuple(tasks), n_timesteps, None if tested is None else tuple(env_name(env) for env in envs))

    def paper(self) -> dict[str, dict[str, tuple[float, float]]]:
        return self.numbers(self.content.get("paper"), ("paper",), "paper")

    def beats(self, envs: list[str], algos: list[str], paper: dict[str, dict[str, tuple[float, float]]]) -> BeatsRule | None:
        raw = self.content.get("beats")
        if raw is None:
            return None
        example = "{against: vicrl, envs: [BlockedHalfCheetah-v0], columns: [heldout, last_training]}"
        if not isinstance(raw, dict) or set(raw) != {"against", "envs", "columns"}:
            raise self.error(("beats",), f"`beats` maps `against`, `envs` and `columns`, e.g. {example}.")
        if not set(algos) & set(ICRL_ALGOS):
            raise self.error(("beats",), "`beats` judges the ICRL cells, and the suite has no ICRL algorithm.")
        against = raw["against"]
        rows = sorted({algo for entries in paper.values() for algo in entries})
        if not isinstance(against, str) or against not in rows:
            offered = ", ".join(rows) if rows else "none: the suite has no `paper` numbers"
            raise self.error(
                ("beats", "against"),
                f"`beats.against` names a method row of the suite's `paper` numbers ({offered}), got {against!r}.",
            )
        judged = self.env_subset(raw["envs"], envs, ("beats", "envs"))
        if len(set(judged)) != len(judged):
            raise self.error(("beats", "envs"), f"`beats.envs` names an env twice: {raw['envs']!r}.")
        for index, env in enumerate(judged):
            if against not in paper.get(env, {}):
                raise self.error(("beats", "envs", index), f"the suite's `paper` numbers have no {against} row on {env}.")
        columns = raw["columns"]
        if not isinstance(columns, list) or not columns or not all(column in BEATS_COLUMNS for column in columns):
            allowed = "; ".join(f"{name} ({meaning})" for name, meaning in BEATS_COLUMNS.items())
            raise self.error(("beats", "columns"), f"`beats.columns` is a non-empty list among {allowed}, got {columns!r}.")
        if len(set(columns)) != len(columns):
            raise self.error(("beats", "columns"), f"`beats.columns` names a column twice: {columns!r}.")
        return BeatsRule(against, judged, tuple(columns))

    def aim(self, algos: list[str]) -> dict[str, float] | None:
        raw = self.content.get("aim")
        if raw is None:
            return None
        aim = self.thresholds(
            "aim", raw, AIM_KEYS, "max_violation_rate_iqm", "{min_oracle_fraction_iqm: 0.75, max_violation_rate_iqm: 0.05}"
        )
        if not set(algos) & set(ICRL_ALGOS):
            raise self.error(("aim",), "`aim` is judged on the best ICRL method, and the suite has no ICRL algorithm.")
        if not set(REFERENCE_ALGOS) <= set(algos):
            raise self.error(
                ("aim",),
                f"`aim` is judged over the envs of the cross-env aggregates, which need the reference rows "
                f"{' and '.join(REFERENCE_ALGOS)} among the algos: add them, or leave `aim` out.",
            )
        return aim

    def others(self) -> dict[str, dict[str, dict[str, tuple[float, float]]]]:
        raw = self.content.get("others")
        if raw is None:
            return {}
        if not isinstance(raw, dict):
            raise self.error(("others",), "`others` maps a source name to env -> algo -> [feasible reward, violation rate].")
        others = {}
        for source, numbers in raw.items():
            # The name becomes a column heading and a JSON key: a plain non-empty string
            if not isinstance(source, str) or not source.strip() or "|" in source:
                raise self.error(("others", source), f"a source name is a non-empty string without '|', got {source!r}.")
            if source.strip().lower() == "paper":
                raise self.error(("others", source), "'paper' is the `paper` key's own column: give this source another name.")
            others[source] = self.numbers(numbers, ("others", source), f"source {source!r}")
        return others


@functools.cache
def _discrete_observations(env_id: str) -> bool:
    """Whether ``env_id`` observes a discrete state (the grid worlds); ``False`` where it cannot be made here."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            env = gym.make(env_id)
    except Exception:  # a dependency missing here: its runs say why
        return False
    discrete = isinstance(env.observation_space, gym.spaces.Discrete)
    env.close()
    return discrete


@functools.cache
def _hyperparameter_names(algo: str) -> set[str]:
    """What a recipe of ``algo`` may set: its constructor's arguments (through its bases) and the zoo's own keys."""
    names = set(ZOO_KEYS)
    for klass in ALGOS[algo].__mro__:
        if "__init__" in vars(klass):
            try:
                parameters = inspect.signature(vars(klass)["__init__"]).parameters.values()
            except (TypeError, ValueError):
                continue
            names |= {p.name for p in parameters if p.name != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}
    return names


def _flag_text(value: Any) -> str:
    """A variant's value as a run's train.py command line writes it (``-params key:<text>``)."""
    return value if isinstance(value, str) else repr(value)


def _as_train_reads(values: dict[str, Any]) -> dict[str, Any]:
    """
    A variant's ``hyperparams`` or ``env_kwargs`` as its runs get them: written on train.py's command line, then read
    back (``learning_rate: 3e-4`` is a string to yml, a float to train.py).
    """
    return {str(key): parse_override(str(key), _flag_text(value)) for key, value in values.items()}


def _dry_build(
    algo: str, env_id: str, overrides: dict[str, Any], env_kwargs: dict[str, Any], forward_recipe: str | None
) -> str | None:
    """
    Make a run's model as train.py does, without learning: its recipe with the variant's ``overrides`` resolved and
    checked as train.py resolves and checks them, then the algorithm built on the run's envs (on the CPU, on one
    thread, without demonstrations; torch's random state and thread count are left as they were). About 0.1 s a
    HalfCheetah model on 16 envs, once torch's optimiser module is imported (about 1.5 s, once a process).

    :param algo: Algorithm
    :param env_id: Registered env id
    :param overrides: The variant's hyper-parameters
    :param env_kwargs: The variant's env keyword arguments
    :param forward_recipe: For the reference rows: the algorithm whose forward learner they take
    :return: ``None`` when the model is made, else the error that would stop the run at its start, on one line
    """
    threads = th.get_num_threads()
    # The orthogonal initialisation of the nets is a QR per layer, some 50 times slower on threads that share cores
    # busy with runs
    th.set_num_threads(1)
    try:
        with warnings.catch_warnings(), th.random.fork_rng(devices=[]):
            warnings.simplefilter("ignore")  # batch sizes, the fallback recipe of an unknown env: the runs say them
            entry, _ = load_hyperparams(algo, env_id, dict(overrides), forward_recipe=forward_recipe)
            params = preprocess_hyperparams(entry)
            kwargs = algo_kwargs(params)
            forward_solver(algo, params, env_id)
            check_hyperparameter_types(ALGOS[algo], kwargs, example="{key}: {default!r}")
            env, _ = create_env(env_id, params, params["n_envs"], 0, dict(env_kwargs), 0.0, None)
            try:
                ALGOS[algo](params["policy"], env, verbose=0, device="cpu", **kwargs)
            finally:
                env.close()
    except Exception as error:  # whatever stops the model being made stops the run
        return " ".join(f"{type(error).__name__}: {error}".split())
    finally:
        th.set_num_threads(threads)
    return None


def _unknown_algo(algo: str) -> str:
    return (
        f"unknown algorithm {algo!r}: use one of {', '.join(ALGOS)}, or register yours with sb3_icrl.register_algorithm "
        "in a module that the suite names in `gym_packages`."
    )


def load_suite(name_or_path: str | os.PathLike, dry_build: bool = True) -> Suite:
    """
    Read and check a suite: unknown keys, envs, algorithms and variant settings are errors that name the file and line.

    :param name_or_path: A shipped suite's name (``table3``, ``smoke``, ...) or the path of a suite file
    :param dry_build: Also make the model of every run whose variant sets hyper-parameters, without learning, so that a
        value its algorithm refuses is named before any run starts (see :meth:`_SuiteReader.check_builds`)
    :return: The suite
    """
    path = suite_path(name_or_path)
    text = path.read_text()
    try:
        node = yaml.compose(text)
        content = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise SuiteError(f"{path}: not valid yml: {error}") from error
    if not isinstance(content, dict) or node is None:
        raise SuiteError(f"{path}: a suite is a mapping with the keys {', '.join(SUITE_KEYS)}.")
    reader = _SuiteReader(path, node, content)
    gym_packages = content.get("gym_packages") or []
    if not isinstance(gym_packages, list) or not all(isinstance(package, str) for package in gym_packages):
        raise reader.error(("gym_packages",), f"`gym_packages` is a list of module names, got {gym_packages!r}.")
    try:
        import_gym_packages(gym_packages)
    except ValueError as error:
        raise reader.error(("gym_packages",), str(error)) from error
    envs, algos, seeds = reader.lists()
    reference = content.get("reference")
    if reference is not None and reference not in algos:
        raise reader.error(("reference",), f"reference {reference!r} is not one of the suite's algos ({', '.join(algos)}).")
    forward_recipe = content.get("forward_recipe")
    if forward_recipe is not None and forward_recipe not in ALGOS:
        raise reader.error(("forward_recipe",), f"unknown algorithm {forward_recipe!r}: use one of {', '.join(ALGOS)}.")
    if forward_recipe is not None and not set(algos) & set(REFERENCE_ALGOS):
        raise reader.error(
            ("forward_recipe",),
            f"`forward_recipe` sets the forward learner of the reference rows ({', '.join(REFERENCE_ALGOS)}), and the "
            "suite's algos have none: add them, or leave it out.",
        )
    description = content.get("description") or ""
    if not isinstance(description, str):
        raise reader.error(
            ("description",), f"`description` is one line of text ({SUITE_KEYS['description']}), got {description!r}."
        )
    recipe_version = content.get("recipe_version")
    if recipe_version is not None and (not isinstance(recipe_version, (str, int)) or not str(recipe_version).strip()):
        raise reader.error(("recipe_version",), f"`recipe_version` is a name or a number, got {recipe_version!r}.")
    variants = reader.variants(algos)
    reader.check_demonstrations(envs, algos, variants)
    reader.check_hyperparams(algos, variants)
    reader.check_costs(envs)
    suite = Suite(
        name=path.stem,
        path=str(path),
        description=description,
        envs=envs,
        algos=algos,
        seeds=seeds,
        variants=variants,
        steps=reader.steps(envs),
        eval_episodes=reader.positive_int(content.get("eval_episodes", 20), ("eval_episodes",)),
        eval_seed=reader.positive_int(content.get("eval_seed", 100), ("eval_seed",), allow_zero=True),
        eval_budget=reader.eval_budget(),
        train_args=reader.train_args(),
        reference=reference,
        paper=reader.paper(),
        gym_packages=tuple(dict.fromkeys([*gym_packages, *reader.env_modules])),
        forward_recipe=forward_recipe,
        recipe_version=str(recipe_version) if recipe_version is not None else None,
        success=reader.success(algos),
        others=reader.others(),
        transfer=reader.transfer(envs, algos),
        headline_envs=reader.headline_envs(envs),
        beats=reader.beats(envs, algos, reader.paper()),  # read again: checked in the file's order, paper first
        aim=reader.aim(algos),
        env_seeds=reader.env_seeds(envs),
    )
    if dry_build:  # last: each cheaper check has passed
        reader.check_envs(envs, variants)
        reader.check_builds(envs, algos, variants, forward_recipe)
    return suite
