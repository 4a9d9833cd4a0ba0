"""A user env that declares its constraint but puts no info["cost"] gets the true cost wherever the library evaluates."""

import json
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.vec_env import DummyVecEnv
from test_user_envs import FAST

from sb3_icrl.common.constraint_spec import ConstraintSpec, FeatureConstraint, declare_constraint
from sb3_icrl.constraints.wrappers import LearnedCostVecEnvWrapper
from sb3_icrl.data import load_demonstrations
from sb3_icrl.data.__main__ import main as data_main
from sb3_icrl.data.generate import generate_demonstrations
from sb3_icrl.envs.wrappers import DeclaredCostWrapper, MissingCostError
from sb3_icrl.zoo import main
from sb3_icrl.zoo.compare import main as compare_main
from sb3_icrl.zoo.hyperparams import env_name, preprocess_hyperparams
from sb3_icrl.zoo.train import create_env

LEFT, RIGHT = 0, 1


class LineEnv(gym.Env):
    """
    A walk on the integers from ``start``: action 0 steps left, 1 right. Observation ``[x, t]``, reward ``x``.
    Its ``step`` reports no cost: only its declaration (where one is given) says what is unsafe.
    """

    def __init__(self, start: int = 0):
        self.observation_space = spaces.Box(-100.0, 100.0, shape=(2,), dtype=np.float32)
        self.action_space = spaces.Discrete(2)
        self.start = start
        self.x, self.t = start, 0

    def _obs(self) -> np.ndarray:
        return np.array([self.x, self.t], dtype=np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self.x, self.t = self.start, 0
        return self._obs(), {}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self.x += 1 if int(action) == RIGHT else -1
        self.t += 1
        return self._obs(), float(self.x), False, False, {"x": self.x}


class DeclaredLineEnv(LineEnv):
    """Unsafe where ``x >= 2``, declared by a class attribute."""

    constraint_spec = ConstraintSpec(features=(FeatureConstraint(obs_index=0, threshold=2.0, op=">=", name="x"),))


class SelfReportingLineEnv(DeclaredLineEnv):
    """Declares a constraint but reports a cost of its own, which must win."""

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = super().step(action)
        return observation, reward, terminated, truncated, {**info, "cost": 0.25}


DECLARED = "declaredcost/DeclaredLine-v0"
SELF_REPORTING = "declaredcost/SelfReportingLine-v0"
UNDECLARED = "declaredcost/UndeclaredLine-v0"
BY_FUNCTION = "declaredcost/FunctionLine-v0"
# Starts at x = 5 and lives 3 steps: x >= 2 at every step, whatever the policy does
ALWAYS_UNSAFE = "declaredcost/AlwaysUnsafeLine-v0"

gym.register(id=DECLARED, entry_point=DeclaredLineEnv, max_episode_steps=10)
gym.register(id=SELF_REPORTING, entry_point=SelfReportingLineEnv, max_episode_steps=10)
gym.register(id=UNDECLARED, entry_point=LineEnv, max_episode_steps=10)
gym.register(id=BY_FUNCTION, entry_point=LineEnv, max_episode_steps=10)
gym.register(id=ALWAYS_UNSAFE, entry_point=LineEnv, max_episode_steps=3, kwargs={"start": 5})
# The env class declares nothing: declared for its ids, as for a class the user cannot edit
declare_constraint(ALWAYS_UNSAFE, FeatureConstraint(obs_index=0, threshold=2.0, op=">=", name="x"))


def left_steps_cost(observations: np.ndarray, actions: np.ndarray | None) -> np.ndarray:
    """A cost that reads the action: every step to the left costs 1 (batched, as a ConstraintSpec's cost_fn)."""
    assert observations.shape == (1, 2) and actions is not None and actions.shape == (1,)
    return (actions == LEFT).astype(np.float64)


declare_constraint(BY_FUNCTION, ConstraintSpec(cost_fn=left_steps_cost))


def step_costs(env: gym.Env, actions: list[int]) -> list[Any]:
    env.reset(seed=0)
    return [env.step(action)[4].get("cost") for action in actions]


def test_declared_feature_gives_the_cost_of_the_state_the_step_reached():
    env = DeclaredCostWrapper(gym.make(DECLARED))
    # x: 1, 2, 3, 2, 1: unsafe once a step lands on x >= 2, safe again when it leaves
    assert step_costs(env, [RIGHT, RIGHT, RIGHT, LEFT, LEFT]) == [0.0, 1.0, 1.0, 1.0, 0.0]
    _, _, _, _, info = env.step(LEFT)
    assert info == {"x": 0, "cost": 0.0}  # the env's own keys are kept


def test_env_that_reports_its_own_cost_is_left_as_it_is():
    env = DeclaredCostWrapper(gym.make(SELF_REPORTING))
    # Its declaration says x >= 2 costs 1; its own info["cost"] says 0.25 and is not overwritten
    assert step_costs(env, [RIGHT, RIGHT, RIGHT]) == [0.25, 0.25, 0.25]


def test_callable_cost_fn_declaration_reads_the_action():
    env = DeclaredCostWrapper(gym.make(BY_FUNCTION))
    assert step_costs(env, [RIGHT, LEFT, LEFT, RIGHT]) == [0.0, 1.0, 1.0, 0.0]
    # An explicit declaration replaces the env's own
    explicit = DeclaredCostWrapper(gym.make(DECLARED), spec=ConstraintSpec(cost_fn=left_steps_cost))
    assert step_costs(explicit, [RIGHT, RIGHT, LEFT]) == [0.0, 0.0, 1.0]


def test_no_cost_and_no_declaration_fails_clearly_only_where_a_cost_is_required():
    with pytest.raises(MissingCostError, match=r"declares no constraint.*constraint_spec.*declare_constraint"):
        step_costs(DeclaredCostWrapper(gym.make(UNDECLARED)), [RIGHT])
    # Learners that do not read the true cost train on such an env as before
    assert step_costs(DeclaredCostWrapper(gym.make(UNDECLARED), required=False), [RIGHT]) == [None]


def test_learner_never_reads_the_declared_cost():
    venv = DummyVecEnv([lambda: DeclaredCostWrapper(gym.make(DECLARED))])
    learned = LearnedCostVecEnvWrapper(venv, lambda observations, actions: np.full(len(observations), 0.5))
    learned.reset()
    for _ in range(2):
        learned.step_async(np.array([RIGHT]))
        _, _, _, infos = learned.step_wait()
    assert infos[0]["cost"] == 0.5  # the learned cost
    assert infos[0]["true_cost"] == 1.0  # the declared one, moved aside for evaluation


def test_zoo_envs_add_the_cost_below_the_yml_wrappers():
    # A yml wrapper that rescales observations: the declaration still reads the env's own x
    scale = (gym.wrappers.TransformObservation, {"func": lambda obs: obs / 100.0, "observation_space": None})
    params = preprocess_hyperparams({"normalize": False, "n_timesteps": 1})
    params["env_wrapper"] = [scale]
    venv, _ = create_env(DECLARED, params, 1, 0, {}, 0.0, None, eval_env=True)
    venv.reset()
    costs = [venv.step(np.array([RIGHT]))[3][0]["cost"] for _ in range(3)]
    assert costs == [0.0, 1.0, 1.0]
    # A training env of a learner that does not read the cost accepts an env without one
    train_env, _ = create_env(UNDECLARED, params, 1, 0, {}, 0.0, None)
    train_env.reset()
    assert "cost" not in train_env.step(np.array([RIGHT]))[3][0]
    eval_env, _ = create_env(UNDECLARED, params, 1, 0, {}, 0.0, None, eval_env=True)
    eval_env.reset()
    with pytest.raises(MissingCostError):
        eval_env.step(np.array([RIGHT]))


def test_generated_demonstrations_record_the_declared_cost():
    class AlwaysRight:
        def predict(self, observation: Any, deterministic: bool = True) -> tuple[int, None]:
            return RIGHT, None

    demos = generate_demonstrations(AlwaysRight(), ALWAYS_UNSAFE, 1, violating_fraction=1.0, seed=0)
    assert demos.trajectories[0].costs.tolist() == [1.0, 1.0, 1.0]


def test_train_ppolag_then_compare_and_generate_report_the_violations_of_a_declared_constraint(tmp_path):
    logs = tmp_path / "logs"
    assert main(["--algo", "ppolag", "--env", ALWAYS_UNSAFE, "-f", str(logs), *FAST, "--verbose", "0"]) == 0
    run = logs / "ppolag" / f"{env_name(ALWAYS_UNSAFE)}_1"
    with np.load(run / "evaluations.npz") as evaluations:
        assert np.asarray(evaluations["violations"]).all()  # every episode of every evaluation
    out = tmp_path / "compare.json"
    assert compare_main([str(run), "-n", "12", "--json", str(out)]) == 0
    (result,) = json.loads(out.read_text())["runs"]
    assert result["violation_rate"] == 1.0 and result["n_episodes"] == 4
    # The expert's demonstrations record the declared cost too (with one violating trajectory: none can be clean)
    demos = tmp_path / "demos.npz"
    assert data_main(["generate", "--run", str(run), "--n", "1", "--violating-fraction", "1", "--out", str(demos)]) == 0
    assert load_demonstrations(str(demos)).trajectories[0].costs.tolist() == [1.0, 1.0, 1.0]
