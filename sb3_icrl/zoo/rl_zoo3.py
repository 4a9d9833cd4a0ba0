"""
Train and evaluate sb3-icrl's algorithms with rl_zoo3 itself (``pip install rl_zoo3``)::

    python -m sb3_icrl.zoo.rl_zoo3 train --algo mecl --env sb3_icrl/BlockedHalfCheetah-v0 --gym-packages sb3_icrl
    python -m sb3_icrl.zoo.rl_zoo3 enjoy --algo mecl --env sb3_icrl/BlockedHalfCheetah-v0 --gym-packages sb3_icrl -f logs

``train`` and ``enjoy`` are rl_zoo3's own commands (``rl_zoo3.train``, ``rl_zoo3.enjoy``), run after
:func:`register_rl_zoo3` has added ``ppolag``, ``gacl``, ``bc2l``, ``mecl``, ``vicrl`` and ``irlplus`` to rl_zoo3's ``ALGOS``
(rl_zoo3 checks ``--algo`` against ``ALGOS`` before it imports ``--gym-packages``, so ``python -m rl_zoo3.train --algo
mecl`` alone cannot know them). Without ``--conf-file``, ``train`` uses the shipped ``zoo_hyperparams/<algo>.yml``,
written for rl_zoo3 by :func:`export_rl_zoo3_config` (rl_zoo3 looks entries up by the full env id,
``sb3_icrl/BlockedHalfCheetah-v0``, while our files use the bare name).

The registered classes are the library's algorithms with what rl_zoo3 lacks: the dict arguments written as strings in
the yml files (``constraint_net_kwargs``, ``lagrange_kwargs``, ``trainer_kwargs``, ``planner_kwargs``) are evaluated as
``policy_kwargs`` is; an ICRL algorithm given no ``demonstrations`` hyper-parameter learns from the shipped dataset of
its env (pass another with ``--hyperparams demonstrations:"'path/to/data.npz'"``, a shipped name, an ``.npz`` or an
``imitation`` dataset folder); and the ``forward_solver`` of the grid-world entries (exact planning) is honoured.

rl_zoo3's own evaluation callback knows nothing of the constraint: it logs the reward only and picks
``best_model.zip`` on it (with ``normalize``, the registered classes let it copy the normalisation statistics into
its evaluation env, which SB3 cannot do alone for the ICRL algorithms' wrapped envs). Score saved models with
``sb3-icrl compare`` / ``enjoy``, or train with ``sb3-icrl train``, whose evaluations log the constraint metrics and
select the best model on what the learner knows. rl_zoo3's ``all_plots`` reads our runs' ``evaluations.npz`` with any
of its keys as ``--key``: all are per-episode arrays ``(n_eval, n_episodes)`` as in SB3 (``results``, ``ep_lengths``,
``feasible_rewards``, ``violations``, ``episode_costs``, ``learned_feasible_rewards``, ``learned_episode_costs``,
``learned_penalised_rewards``...); the values with one number per evaluation (``selection_score``,
``best_model_rescored``, ``lagrange_multiplier``) are in ``model_selection.npz`` beside it.
"""

import os
import pathlib
import sys
import tempfile
from collections.abc import Sequence
from copy import deepcopy
from typing import Any

import yaml
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, EvalCallback, EventCallback
from stable_baselines3.common.vec_env import VecEnv, unwrap_vec_normalize

from sb3_icrl import BC2L, GACL, MECL, VICRL, IRLPlus, PPOLagrangian
from sb3_icrl.common.utils import atomic_write_bytes
from sb3_icrl.data.checks import env_id_of
from sb3_icrl.data.registry import available_demonstrations, env_name
from sb3_icrl.hyperparams import EVAL_KEYS, _eval_string, forward_solver
from sb3_icrl.icrl.tabular import learn_function
from sb3_icrl.registry import DEFAULT_HYPERPARAMS_DIR, NAMESPACE
from sb3_icrl.zoo.callbacks import ConstraintEvalCallback

#: The dict-valued arguments our yml files write as strings, evaluated by the registered classes (rl_zoo3 evaluates
#: ``policy_kwargs`` itself)
STRING_DICT_KEYS = tuple(key for key in EVAL_KEYS if key not in ("policy_kwargs", "normalize_kwargs"))


def _prepare_kwargs(kwargs: dict[str, Any]) -> dict[str, Any]:
    prepared = dict(kwargs)
    for key in STRING_DICT_KEYS:
        if isinstance(prepared.get(key), str):
            prepared[key] = _eval_string(key, prepared[key])
    if isinstance(prepared.get("prior"), list):
        prepared["prior"] = tuple(prepared["prior"])
    return prepared


def shipped_demonstrations_for(env: VecEnv | Any) -> str | None:
    """
    :param env: The training env (rl_zoo3 gives a VecEnv)
    :return: The name of the shipped dataset for its env id (``"BlockedHalfCheetah-v0"``), ``None`` if there is none
    """
    env_id = env_id_of(env) if env is not None else None
    if env_id is None:
        return None
    name = env_name(env_id)
    return name if name in available_demonstrations() else None


def _callbacks(callback: BaseCallback | None) -> list[BaseCallback]:
    """A callback and all those it holds (``CallbackList`` members, ``EventCallback`` children)."""
    if callback is None:
        return []
    found = [callback]
    if isinstance(callback, CallbackList):
        for member in callback.callbacks:
            found += _callbacks(member)
    if isinstance(callback, EventCallback):
        found += _callbacks(callback.callback)
    return found


#: Evaluation callback class -> its subclass that copies the ``VecNormalize`` statistics itself
_PAIRED_EVAL_CLASSES: dict[type, type] = {}


def _paired_eval_class(callback_class: type[EvalCallback]) -> type[EvalCallback]:
    if callback_class not in _PAIRED_EVAL_CLASSES:

        class PairedEvalCallback(callback_class):  # type: ignore[valid-type,misc]
            @property
            def training_env(self) -> VecEnv:
                # SB3's own synchronisation then pairs the evaluation env with itself: a no-op
                return self.eval_env

            def _on_step(self) -> bool:
                if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
                    train_normalize = self.model.get_vec_normalize_env()
                    eval_normalize = unwrap_vec_normalize(self.eval_env)
                    if train_normalize is not None and eval_normalize is not None:
                        eval_normalize.obs_rms = deepcopy(train_normalize.obs_rms)
                        eval_normalize.ret_rms = deepcopy(train_normalize.ret_rms)
                return super()._on_step()

        PairedEvalCallback.__name__ = PairedEvalCallback.__qualname__ = callback_class.__name__
        _PAIRED_EVAL_CLASSES[callback_class] = PairedEvalCallback
    return _PAIRED_EVAL_CLASSES[callback_class]


class _EvalNormalizationMixin:
    """
    Lets rl_zoo3's ``EvalCallback`` copy the ``VecNormalize`` statistics into its evaluation env. SB3 walks the training
    and evaluation env stacks in step, and the ICRL algorithms wrap the training env with layers the evaluation env
    lacks, so that walk fails; the callback copies the statistics itself instead (as ``ConstraintEvalCallback`` does).
    """

    def _setup_learn(self, *args: Any, **kwargs: Any) -> Any:
        total_timesteps, callback = super()._setup_learn(*args, **kwargs)  # type: ignore[misc]
        for member in _callbacks(callback):
            if isinstance(member, EvalCallback) and not isinstance(member, ConstraintEvalCallback):
                member.__class__ = _paired_eval_class(type(member))
        return total_timesteps, callback


class ZooPPOLagrangian(_EvalNormalizationMixin, PPOLagrangian):
    """:class:`~sb3_icrl.PPOLagrangian` for rl_zoo3: string ``lagrange_kwargs`` are evaluated."""

    def __init__(self, policy: Any, env: Any, **kwargs: Any):
        super().__init__(policy, env, **_prepare_kwargs(kwargs))


def _demonstrations_or_shipped(algo: type, env: Any, demonstrations: Any, kwargs: dict[str, Any]) -> Any:
    """The demonstrations given, or the shipped dataset of ``env`` (not when ``load`` rebuilds a saved model)."""
    if demonstrations is not None or not kwargs.get("_init_setup_model", True):
        return demonstrations
    shipped = shipped_demonstrations_for(env)
    if shipped is None:
        raise ValueError(
            f"{algo.__name__} learns from demonstrations and none are shipped for this env: pass "
            "--hyperparams demonstrations:\"'path/to/data.npz'\"."
        )
    return shipped


class _ICRLZooMixin(_EvalNormalizationMixin):
    """
    The ICRL algorithms for rl_zoo3: string dict arguments evaluated, the shipped demonstrations of the env by default,
    and the zoo's ``forward_solver`` / ``planner_kwargs`` hyper-parameters (``pi_lagrangian``: exact planning on tabular
    envs, :func:`sb3_icrl.icrl.tabular.learn_with_planner`), which ``sb3-icrl train`` handles outside the algorithm.
    """

    #: rl_zoo3 name of the algorithm (for error messages of the forward solver's checks)
    zoo_name: str = ""

    def __init__(self, policy: Any, env: Any, demonstrations: Any = None, **kwargs: Any):
        prepared = _prepare_kwargs(kwargs)
        solver = prepared.pop("forward_solver", "policy_gradient")
        planner_kwargs = prepared.pop("planner_kwargs", None)
        parent = type(self).__mro__[type(self).__mro__.index(_ICRLZooMixin) + 1]
        demonstrations = _demonstrations_or_shipped(parent, env, demonstrations, kwargs)
        if solver != "policy_gradient" or planner_kwargs:
            env_id = env_id_of(env) if env is not None else None
            params = {"forward_solver": solver, "planner_kwargs": planner_kwargs}
            solver = forward_solver(self.zoo_name, params, env_id) if env_id is not None else solver
        super().__init__(policy, env, demonstrations=demonstrations, **prepared)  # type: ignore[call-arg]
        self.forward_solver = solver
        self.planner_kwargs = planner_kwargs

    def _learn(self, total_timesteps: int, callback: Any = None, log_interval: int = 1, **kwargs: Any) -> Any:
        if getattr(self, "forward_solver", "policy_gradient") == "policy_gradient":
            return super().learn(total_timesteps, callback=callback, log_interval=log_interval, **kwargs)  # type: ignore[misc]

        learn_function(self, self.forward_solver, self.planner_kwargs)(total_timesteps, callback=callback, **kwargs)
        return self

    # Typed loosely: the algorithms' ``learn`` signatures differ in their defaults
    learn: Any = _learn


class ZooGACL(_ICRLZooMixin, GACL):
    """:class:`~sb3_icrl.GACL` for rl_zoo3 (see :class:`_ICRLZooMixin`)."""

    zoo_name = "gacl"


class ZooBC2L(_ICRLZooMixin, BC2L):
    """:class:`~sb3_icrl.BC2L` for rl_zoo3 (see :class:`_ICRLZooMixin`)."""

    zoo_name = "bc2l"


class ZooMECL(_ICRLZooMixin, MECL):
    """:class:`~sb3_icrl.MECL` for rl_zoo3 (see :class:`_ICRLZooMixin`)."""

    zoo_name = "mecl"


class ZooVICRL(_ICRLZooMixin, VICRL):
    """:class:`~sb3_icrl.VICRL` for rl_zoo3 (see :class:`_ICRLZooMixin`)."""

    zoo_name = "vicrl"


class ZooIRLPlus(_ICRLZooMixin, IRLPlus):
    """:class:`~sb3_icrl.IRLPlus` for rl_zoo3 (see :class:`_ICRLZooMixin`)."""

    zoo_name = "irlplus"


#: The algorithms added to rl_zoo3's ``ALGOS``
RL_ZOO3_ALGOS: dict[str, type[BaseAlgorithm]] = {
    "ppolag": ZooPPOLagrangian,
    "gacl": ZooGACL,
    "bc2l": ZooBC2L,
    "mecl": ZooMECL,
    "vicrl": ZooVICRL,
    "irlplus": ZooIRLPlus,
}


def register_rl_zoo3() -> dict[str, type[BaseAlgorithm]]:
    """
    Add sb3-icrl's algorithms to rl_zoo3's ``ALGOS`` (the dict ``rl_zoo3.train``, ``rl_zoo3.enjoy`` and the experiment
    manager read), and register the benchmark envs. Call it before rl_zoo3 parses its command line.

    :return: rl_zoo3's ``ALGOS``
    :raises ImportError: When rl_zoo3 is not installed
    """
    try:
        import rl_zoo3.utils
    except ImportError as error:
        raise ImportError(f"register_rl_zoo3 needs rl_zoo3: pip install rl_zoo3 ({error}).") from error
    import sb3_icrl.envs  # noqa: F401  (registers the sb3_icrl/ envs)

    clashes = [name for name, algo in RL_ZOO3_ALGOS.items() if rl_zoo3.utils.ALGOS.get(name, algo) is not algo]
    if clashes:
        raise ValueError(f"rl_zoo3 already has algorithms named {clashes}: sb3-icrl will not replace them.")
    rl_zoo3.utils.ALGOS.update(RL_ZOO3_ALGOS)
    return rl_zoo3.utils.ALGOS


def rl_zoo3_hyperparams(algo: str, directory: str | os.PathLike = DEFAULT_HYPERPARAMS_DIR) -> dict[str, Any]:
    """
    Our ``<algo>.yml`` with each env entry also under its full id (``sb3_icrl/BlockedHalfCheetah-v0``), which is how
    rl_zoo3 looks entries up.

    :param algo: ``ppolag``, ``gacl``, ``bc2l``, ``mecl`` or ``vicrl``
    :param directory: Folder of the yml files
    :return: The entries, ready for ``yaml.safe_dump``
    """
    path = pathlib.Path(directory) / f"{algo}.yml"
    if not path.is_file():
        raise FileNotFoundError(
            f"No hyper-parameter file {path}; shipped: {sorted(p.stem for p in path.parent.glob('*.yml'))}."
        )
    with open(path) as file:
        entries = yaml.safe_load(file) or {}
    exported = dict(entries)
    for key, entry in entries.items():
        if key != "default" and "/" not in key:
            exported.setdefault(f"{NAMESPACE}/{key}", entry)
    return exported


def export_rl_zoo3_config(algo: str, path: str | os.PathLike, directory: str | os.PathLike = DEFAULT_HYPERPARAMS_DIR) -> str:
    """
    Write :func:`rl_zoo3_hyperparams` to ``path`` (for rl_zoo3's ``--conf-file``).

    :param algo: The algorithm
    :param path: The yml file to write
    :param directory: Folder of our yml files
    :return: The path written
    """
    content = yaml.safe_dump(rl_zoo3_hyperparams(algo, directory), sort_keys=False)
    atomic_write_bytes(pathlib.Path(path), content.encode())
    return os.fspath(path)


def _option_value(argv: Sequence[str], names: Sequence[str]) -> str | None:
    for index, argument in enumerate(argv):
        for name in names:
            if argument == name and index + 1 < len(argv):
                return argv[index + 1]
            if argument.startswith(f"{name}="):
                return argument.split("=", 1)[1]
    return None


def main(argv: Sequence[str] | None = None) -> None:
    """
    ``python -m sb3_icrl.zoo.rl_zoo3 {train,enjoy} RL_ZOO3_ARGS...``: rl_zoo3's command with our algorithms registered.

    :param argv: The arguments (default: ``sys.argv[1:]``)
    """
    arguments = list(sys.argv[1:] if argv is None else argv)
    if not arguments or arguments[0] not in ("train", "enjoy"):
        raise SystemExit("usage: python -m sb3_icrl.zoo.rl_zoo3 {train,enjoy} [rl_zoo3's arguments] (see --help of each)")
    command, rest = arguments[0], arguments[1:]
    algo = _option_value(rest, ("--algo",))
    optimize = [argument for argument in rest if argument == "-optimize" or argument.startswith("--optimize")]
    if command == "train" and algo in RL_ZOO3_ALGOS and optimize:
        raise SystemExit(
            f"error: {optimize[0]} is rl_zoo3's Optuna search, whose samplers know its own algorithms only: it has no "
            f"search space for {algo}. Train with the shipped recipe (drop {optimize[0]}) or set hyper-parameters with "
            "--hyperparams KEY:VALUE."
        )
    register_rl_zoo3()
    if command == "train" and algo in RL_ZOO3_ALGOS and _option_value(rest, ("-conf", "--conf-file")) is None:
        config = pathlib.Path(tempfile.mkdtemp(prefix="sb3_icrl_rl_zoo3_")) / f"{algo}.yml"
        rest += ["--conf-file", export_rl_zoo3_config(algo, config)]
    sys.argv = [f"rl_zoo3.{command}", *rest]
    if command == "train":
        from rl_zoo3.train import train

        train()
    else:
        from rl_zoo3.enjoy import enjoy

        enjoy()


if __name__ == "__main__":
    main()
