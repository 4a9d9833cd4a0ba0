"""
Equal footing: on each env of the shipped ``table3`` suite and on the binding variants, GACL, BC2L, MECL and VICRL (and
IRL-Plus on PPO where ``irlplusppo.yml`` has the env) learn with the same forward learner for as many steps, so that
only the constraint side differs. The binding variants take their experts' forward learner and their source env's
constraint settings. The recipes are read as a run reads them, settings left out resolved to the algorithm's defaults.
"""

import inspect
import warnings
from typing import Any

import pytest

from sb3_icrl.benchmark.suite import load_suite
from sb3_icrl.common.env_ids import env_name
from sb3_icrl.envs import BINDING_VARIANTS
from sb3_icrl.hyperparams import constructor_defaults, load_hyperparams, preprocess_hyperparams, read_hyperparams_file
from sb3_icrl.registry import ALGOS

#: The paper's methods, which every benchmark env has a recipe of
PAPER_ALGOS = ("gacl", "bc2l", "mecl", "vicrl")
#: The forward learner: the settings the throughput family sets (docs/guide/speed.md), the run's length, the zoo's
FORWARD_KEYS = ("n_envs", "n_steps", "batch_size", "n_epochs", "learning_rate", "gamma", "gae_lambda", "clip_range")
FORWARD_KEYS += ("ent_coef", "max_grad_norm", "vf_coef", "policy_kwargs", "use_sde", "n_timesteps", "normalize", "policy")
#: The binding variants that have an expert, and so recipes (BlockedAntReach-v0 has none): variant -> (source env, the
#: source env's run length on the throughput family)
VARIANTS = {
    "BlockedHalfCheetahReach-v0": ("BlockedHalfCheetah-v0", 6_000_000),
    "BlockedWalkerReach-v0": ("BlockedWalker-v0", 7_500_000),
    "BiasedPendulumReach-v0": ("BiasedPendulum-v0", 3_000_000),
}
TABLE3_ENVS = [env_name(env_id) for env_id in load_suite("table3", dry_build=False).envs]


def recipe(algo: str, env_id: str) -> dict[str, Any]:
    """
    The hyper-parameters a run of ``algo`` on ``env_id`` starts from: its shipped entry, read and evaluated as
    train.py does, with the algorithm's defaults for the forward-learner settings that the entry leaves out.

    :param algo: Algorithm
    :param env_id: Env name; the shipped file must have an entry for it (no fallback to ``default``)
    :return: The hyper-parameters
    """
    assert env_id in read_hyperparams_file(algo), f"{algo}.yml has no entry for {env_id}"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        params = preprocess_hyperparams(load_hyperparams(algo, env_id)[0])
    defaults = constructor_defaults(ALGOS[algo])
    for key in FORWARD_KEYS:
        if key not in params and defaults.get(key, inspect.Parameter.empty) is not inspect.Parameter.empty:
            params[key] = defaults[key]
    if params.get("policy_kwargs") is None:
        params["policy_kwargs"] = {}  # SB3's default nets either way
    return params


def forward_learner(params: dict[str, Any]) -> dict[str, Any]:
    """The forward-learner part of :func:`recipe`'s hyper-parameters."""
    return {key: params.get(key) for key in FORWARD_KEYS}


def algos_of(env_id: str) -> list[str]:
    """The ICRL algorithms with a recipe for ``env_id``: the paper's four, and IRL-Plus on PPO where it has one."""
    return [*PAPER_ALGOS, *(["irlplusppo"] if env_id in read_hyperparams_file("irlplusppo") else [])]


def test_the_variants_are_the_binding_envs_with_an_expert() -> None:
    """Each variant named here is the binding variant of its source env; only Ant's is left out."""
    assert {variant: source for variant, (source, _) in VARIANTS.items()} == {
        variant: source for source, variant in BINDING_VARIANTS.items() if source != "BlockedAnt-v0"
    }
    assert all(source in TABLE3_ENVS for source, _ in VARIANTS.values())


@pytest.mark.parametrize("env_id", [*TABLE3_ENVS, *VARIANTS])
def test_every_method_of_an_env_has_the_same_forward_learner(env_id: str) -> None:
    """The forward-learner settings and the run length are MECL's for every ICRL method of the env."""
    mecl = forward_learner(recipe("mecl", env_id))
    for algo in algos_of(env_id):
        learner = forward_learner(recipe(algo, env_id))
        assert learner == mecl, {key: (learner[key], mecl[key]) for key in FORWARD_KEYS if learner[key] != mecl[key]}


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("algo", [*PAPER_ALGOS, "irlplusppo"])
def test_a_variant_takes_its_expert_s_forward_learner_and_its_source_env_s_constraint_settings(
    algo: str, variant: str
) -> None:
    """
    A binding variant's recipe: its expert's forward learner (ppolag.yml's entry, the throughput family's F2) for the
    source env's length on the family, and every other setting of the source env's recipe (IRL-Plus waits a twentieth
    of its own run before its first cost update, as its other recipes).
    """
    if algo == "irlplusppo" and variant not in read_hyperparams_file(algo):
        pytest.skip("irlplusppo.yml has no entry for this variant")
    source, n_timesteps = VARIANTS[variant]
    params, source_params = recipe(algo, variant), recipe(algo, source)
    expert = forward_learner(recipe("ppolag", variant))
    expected = {**expert, "n_timesteps": n_timesteps}
    assert forward_learner(params) == expected
    assert (params["n_envs"], params["n_steps"], params["batch_size"], params["n_epochs"]) == (16, 256, 512, 10)
    rest = {key: value for key, value in params.items() if key not in FORWARD_KEYS}
    source_rest = {key: value for key, value in source_params.items() if key not in FORWARD_KEYS}
    if algo == "irlplusppo":
        assert rest.pop("warmup_timesteps") == n_timesteps // 20
        assert source_rest.pop("warmup_timesteps") == source_params["n_timesteps"] // 20
        # Resets every 250 PPO updates of each one's own rollout
        assert rest.pop("reset_every") == 250 * params["n_envs"] * params["n_steps"]
        assert source_rest.pop("reset_every") == 250 * source_params["n_envs"] * source_params["n_steps"]
    assert rest == source_rest


def test_irlplus_on_ppo_resets_every_250_updates_of_each_env_s_rollout() -> None:
    """
    The rule that chose it: 250 PPO updates between resets, whatever an env's rollout size (the grid worlds plan
    exactly on the learned cost: there is no policy layer to reset).
    """
    entries = read_hyperparams_file("irlplusppo")
    assert len(entries) > 10
    for env, params in entries.items():
        if params.get("forward_solver") == "pi_lagrangian":
            assert params["policy_resets"] is False, env
            continue
        assert params["policy_resets"] is True, env
        assert params["reset_every"] == 250 * params["n_envs"] * params["n_steps"], env
