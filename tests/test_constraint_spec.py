"""An env declares its true constraint (sb3_icrl.common.constraint_spec); plots and evaluation read the declaration."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.env_util import make_vec_env

from sb3_icrl import ConstraintSpec, FeatureConstraint, declare_constraint, get_constraint_spec
from sb3_icrl.envs import CONSTRAINED_FEATURE, BlockedSwimmerEnv
from sb3_icrl.plots.figures import constraint_feature, constraint_features


class StaticEnv(gym.Env):
    """A fixed declaration, as a class attribute: read without making the env."""

    constraint_spec = FeatureConstraint(obs_index=1, threshold=0.25, op=">=", name="speed")
    observation_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
    action_space = spaces.Discrete(2)
    instances = 0

    def __init__(self) -> None:
        type(self).instances += 1


class TunableEnv(gym.Env):
    """A declaration set by the constructor's arguments."""

    metadata = {"render_modes": ["rgb_array"]}
    observation_space = spaces.Box(-1.0, 1.0, (3,), np.float32)
    action_space = spaces.Discrete(2)

    def __init__(self, limit: float = 0.5) -> None:
        self.constraint_spec = ConstraintSpec(features=(FeatureConstraint(2, limit, "<", "height"),))


class PlainEnv(gym.Env):
    """No declaration."""

    observation_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
    action_space = spaces.Discrete(2)


@pytest.fixture(scope="module", autouse=True)
def registered_envs():
    ids = {"specs/Static-v0": StaticEnv, "specs/Tunable-v0": TunableEnv, "specs/Plain-v0": PlainEnv}
    for env_id, entry_point in ids.items():
        gym.register(env_id, entry_point=entry_point)
    yield
    for env_id in ids:
        gym.registry.pop(env_id, None)


def test_feature_constraint_semantics_and_errors() -> None:
    observations = np.array([[0.0, -1.0], [0.0, 0.0], [0.0, 1.0]])
    for op, expected in (("<=", [1, 1, 0]), ("<", [1, 0, 0]), (">=", [0, 1, 1]), (">", [0, 0, 1])):
        assert FeatureConstraint(1, 0.0, op).violated(observations).tolist() == [bool(e) for e in expected], op
    feature = FeatureConstraint(np.int64(3), 2, "<=")
    assert (feature.obs_index, feature.threshold, feature.name, feature.unsafe_side) == (3, 2.0, "obs[3]", "below")
    with pytest.raises(ValueError, match="`op` must be one of"):
        FeatureConstraint(0, 1.0, "==")
    with pytest.raises(ValueError, match="`obs_index` must be an int >= 0"):
        FeatureConstraint(-1, 1.0, "<=")
    with pytest.raises(ValueError, match="`threshold` must be a finite number"):
        FeatureConstraint(0, float("nan"), "<=")
    with pytest.raises(ValueError, match="reads obs\\[3\\]"):
        feature.violated(observations)


def test_true_cost_of_features_cells_and_cost_function() -> None:
    two = ConstraintSpec(features=(FeatureConstraint(0, -3.0, "<="), FeatureConstraint(1, 40.0, ">")))
    # any one broken feature costs 1
    assert two.true_cost(np.array([[-3.0, 0.0], [0.0, 41.0], [0.0, 40.0], [-5.0, 50.0]])).tolist() == [1, 1, 0, 1]
    assert two.true_cost(np.array([-4.0, 0.0])).tolist() == [1.0]  # one observation: a batch of one
    cells = ConstraintSpec(unsafe_states=[3, 4])
    assert cells.true_cost(np.array([2, 3, 4, 5])).tolist() == [0, 1, 1, 0]
    by_function = ConstraintSpec(cost_fn=lambda obs, acts: (obs[:, 0] * acts > 1).astype(float))
    assert by_function.true_cost(np.array([[1.0], [2.0]]), np.array([2.0, 0.0])).tolist() == [1.0, 0.0]
    with pytest.raises(ValueError, match="declares nothing"):
        ConstraintSpec()
    with pytest.raises(TypeError, match="FeatureConstraint objects"):
        ConstraintSpec(features=((0, 1.0, "<="),))  # type: ignore[arg-type]


def test_user_declarations_by_id_by_env_and_by_vec_env() -> None:
    StaticEnv.instances = 0
    assert get_constraint_spec("specs/Static-v0").features == (FeatureConstraint(1, 0.25, ">=", "speed"),)
    assert StaticEnv.instances == 0  # a class attribute is read without making the env
    assert get_constraint_spec("specs/Tunable-v0", {"limit": 0.1}).features[0].threshold == 0.1
    assert get_constraint_spec(gym.make("specs/Tunable-v0", limit=0.2)).features[0].threshold == 0.2
    assert get_constraint_spec(make_vec_env("specs/Tunable-v0", n_envs=1)).features[0].threshold == 0.5
    assert get_constraint_spec("specs/Plain-v0") is None
    assert constraint_feature("specs/Static-v0")[1:] == (1, 0.25, ">=")  # the plots' lookup reads the same
    with pytest.raises(ValueError, match="--feature INDEX"):
        constraint_features("specs/Plain-v0")
    with pytest.raises(ValueError, match="Unknown env"):
        get_constraint_spec("specs/Nowhere-v0")


def test_declare_constraint_for_an_env_class_one_cannot_edit() -> None:
    gym.register("specs/Declared-v0", entry_point=PlainEnv)
    try:
        declare_constraint("specs/Declared-v0", lambda limit=0.3: FeatureConstraint(0, limit, ">", "x"))
        assert get_constraint_spec("specs/Declared-v0").features[0].threshold == 0.3
        assert get_constraint_spec("specs/Declared-v0", {"limit": 0.7}).features[0].threshold == 0.7
        assert get_constraint_spec(gym.make("specs/Declared-v0")).features[0].threshold == 0.3
        with pytest.raises(TypeError, match="declare_constraint"):
            declare_constraint("specs/Declared-v0", 0.3)  # type: ignore[arg-type]
    finally:
        gym.registry.pop("specs/Declared-v0", None)


def test_constrained_feature_is_a_view_of_the_mujoco_declarations() -> None:
    assert CONSTRAINED_FEATURE["BlockedSwimmer-v0"] == ("x_position", 0, 0.5, ">=")
    declared = BlockedSwimmerEnv.default_constraint
    assert CONSTRAINED_FEATURE["BlockedSwimmer-v0"] == (declared.name, declared.obs_index, declared.threshold, declared.op)
    assert get_constraint_spec("BlockedAnt-v0", {"cost_threshold": -2.0}).features[0].threshold == -2.0
    driving = get_constraint_spec("sb3_icrl/HighwayVelocityDistance-v0", {"min_gap": 25.0})
    assert [(f.name, f.obs_index, f.threshold, f.op) for f in driving.features] == [
        ("ego_speed", 0, 40.0, ">"),
        ("lead_gap", 10, 25.0, "<"),
    ]
    assert get_constraint_spec("GridWorldWall-v0").unsafe_states == frozenset({21, 22, 23, 24, 25})


@pytest.mark.parametrize(
    "env_id, env_kwargs",
    [
        ("sb3_icrl/ConstrainedCorridor-v0", {"safe_limit": 1}),
        ("sb3_icrl/GridWorldWall-v0", {}),
        # thresholds inside the range a random policy visits, so that both outcomes occur
        ("sb3_icrl/BlockedHalfCheetah-v0", {"cost_threshold": -0.5}),
        ("sb3_icrl/BlockedSwimmer-v0", {"cost_threshold": 0.15}),
        ("sb3_icrl/HighwayVelocityDistance-v0", {"speed_limit": 14.0}),
    ],
)
def test_declared_true_cost_matches_the_env_cost(env_id: str, env_kwargs: dict) -> None:
    """The declaration says what info["cost"] says, on the state each step reaches."""
    env = gym.make(env_id, **env_kwargs)
    spec = get_constraint_spec(env)
    assert spec is not None
    env.action_space.seed(0)
    observation, _ = env.reset(seed=0)
    declared, reported = [], []
    for _ in range(60):
        action = env.action_space.sample()
        observation, _, terminated, truncated, info = env.step(action)
        declared.append(float(spec.true_cost(np.asarray(observation)[None], np.asarray(action)[None])[0]))
        reported.append(float(np.sum(info["cost"]) > 0))
        if terminated or truncated:
            observation, _ = env.reset()
    env.close()
    assert declared == reported
    assert 0 < sum(reported) < len(reported)


@pytest.mark.parametrize(
    "op, values, expected",
    [
        ("<=", [-4.0, -3.0, 1.0], [-1.0, 0.0, 4.0]),  # broken at or below -3: the allowed side is above
        ("<", [-4.0, -3.0, 1.0], [-1.0, 0.0, 4.0]),
        (">=", [-4.0, -3.0, 1.0], [1.0, 0.0, -4.0]),  # broken at or above -3: the allowed side is below
        (">", [-4.0, -3.0, 1.0], [1.0, 0.0, -4.0]),
    ],
)
def test_margin_is_the_distance_on_the_allowed_side(op, values, expected):
    """Positive on the allowed side, negative beyond the threshold, for each operator."""
    feature = FeatureConstraint(obs_index=0, threshold=-3.0, op=op)
    np.testing.assert_allclose(feature.margin(values), expected)
    on_the_line_breaks = op in ("<=", ">=")
    margins = feature.margin(values)
    expected_violated = (margins < 0) | ((margins == 0) & on_the_line_breaks)
    np.testing.assert_array_equal(feature.violated(np.asarray(values)[:, None]), expected_violated)
