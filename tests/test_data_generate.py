"""Generating demonstrations: violating trajectories dropped, exact violating shares, experts under VecNormalize, the CLI."""

import json
import zipfile

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common import base_class
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

import sb3_icrl  # noqa: F401  (registers the envs)
from sb3_icrl import PPOLagrangian
from sb3_icrl.common import saved
from sb3_icrl.data import NormalizedExpert, generate_demonstrations, load, save
from sb3_icrl.data.__main__ import main
from sb3_icrl.data.importers import from_arrays

CORRIDOR = "sb3_icrl/ConstrainedCorridor-v0"  # Box obs [x, t], actions 0 left / 1 stay / 2 right, cost when x > 6 of 10


class CorridorExpert:
    """Walks right and stops on the last safe cell; with ``overshoot_prob`` it keeps walking (and breaks the constraint)."""

    def __init__(self, overshoot_prob: float = 0.0, seed: int = 0):
        self.overshoot_prob = overshoot_prob
        self.rng = np.random.default_rng(seed)
        self.calls = []
        self.overshoot = False

    def predict(self, observation, state=None, episode_start=None, deterministic=False):
        self.calls.append((np.array(observation), deterministic))
        if self.overshoot_prob and observation[1] == 0.0:  # first step: decide for the whole episode
            self.overshoot = self.rng.random() < self.overshoot_prob
        position = round(observation[0] * 10)
        return np.int64(2 if position < 6 or self.overshoot else 1), state


def test_violating_trajectories_are_dropped():
    expert = CorridorExpert(overshoot_prob=0.5)
    demos = generate_demonstrations(expert, CORRIDOR, n_trajectories=20, seed=0)
    generation = demos.metadata["generation"]
    assert len(demos) == 20 and not demos.violations.any()
    assert all(t.episode_cost == 0.0 for t in demos)
    # The expert did break the constraint: those episodes were run and dropped
    assert generation["expert_violating_episodes"] > 0
    assert generation["expert_episodes"] == 20 + generation["expert_violating_episodes"]
    assert 0.2 < generation["expert_violation_rate"] < 0.8
    assert all(deterministic for _, deterministic in expert.calls)
    assert demos.metadata["env_id"] == CORRIDOR and demos.metadata["expert"]["algorithm"] == "CorridorExpert"


@pytest.mark.parametrize("fraction", [0.2, 0.5, 0.8])
def test_violating_fraction_gives_the_requested_share(fraction):
    n = 30
    demos = generate_demonstrations(CorridorExpert(), CORRIDOR, n_trajectories=n, violating_fraction=fraction, seed=1)
    violations = demos.violations
    assert len(demos) == n and violations.sum() == round(fraction * n)
    # Violating slots are spread over the dataset, not stacked at one end
    assert 0 < violations[: n // 2].sum() < violations.sum()
    # Perturbed rollouts are not clean expert rollouts: a clean one never leaves the safe cells
    assert all(t.violates == (t.episode_cost > 0) for t in demos)
    generation = demos.metadata["generation"]
    assert generation["n_violating_requested"] == round(fraction * n) and generation["expert_violation_rate"] == 0.0


def test_generation_is_reproducible_and_fails_clearly():
    first = generate_demonstrations(CorridorExpert(), CORRIDOR, 10, violating_fraction=0.5, seed=4)
    second = generate_demonstrations(CorridorExpert(), CORRIDOR, 10, violating_fraction=0.5, seed=4)
    assert all(np.array_equal(a.acts, b.acts) for a, b in zip(first, second, strict=True))
    with pytest.raises(RuntimeError, match=r"Kept only 0 of 3 .* broke the true constraint in 100%"):
        generate_demonstrations(CorridorExpert(overshoot_prob=1.0), CORRIDOR, 3, max_attempts=5)
    with pytest.raises(ValueError, match=r"`violating_fraction` is a share"):
        generate_demonstrations(CorridorExpert(), CORRIDOR, 3, violating_fraction=1.5)
    with pytest.raises(KeyError, match="true cost in info"):
        generate_demonstrations(CorridorExpert(), gym.make(CORRIDOR), 1, cost_info_key="missing")


def test_normalized_expert_acts_on_normalized_observations():
    venv = VecNormalize(DummyVecEnv([lambda: gym.make(CORRIDOR)]))
    venv.obs_rms.mean = np.array([-0.5, -0.5])
    venv.obs_rms.var = np.array([0.25, 0.25])
    inner = CorridorExpert()
    demos = generate_demonstrations(NormalizedExpert(inner, venv), CORRIDOR, 1)
    seen = np.array([obs for obs, _ in inner.calls])
    raw = demos[0].obs[:-1]
    # The expert saw (obs - mean) / std; the dataset keeps the raw observations
    assert np.allclose(seen, (raw + 0.5) / 0.5, atol=1e-3) and raw[:, 1].max() > 0.9
    assert demos.metadata["expert"]["vec_normalize"] is True


def test_cli_generates_from_a_saved_ppo_lagrangian_with_vecnormalize(tmp_path, capsys):
    # An untrained PPOLagrangian stands in for a MuJoCo expert: the point is the loading path, not the policy
    venv = VecNormalize(DummyVecEnv([lambda: gym.make(CORRIDOR)]))
    PPOLagrangian("MlpPolicy", venv, n_steps=32, batch_size=16, seed=0, device="cpu").save(tmp_path / "expert.zip")
    venv.save(tmp_path / "vecnormalize.pkl")
    out = tmp_path / "demos.npz"
    args = [
        "generate",
        "--env",
        CORRIDOR,
        "--expert",
        str(tmp_path / "expert.zip"),
        "--vecnormalize",
        str(tmp_path / "vecnormalize.pkl"),
    ]
    args += ["--n", "2", "--out", str(out), "--max-attempts", "500", "--seed", "3", "--no-deterministic"]
    assert main(args) == 0
    demos = load(out, env=CORRIDOR)
    metadata = json.loads(out.with_suffix(".json").read_text())
    assert len(demos) == 2 and not demos.violations.any()
    assert metadata["expert"]["algorithm"] == "PPOLagrangian" and metadata["expert"]["vec_normalize"] is True
    assert metadata["expert"]["hyperparameters"]["n_steps"] == 32
    assert len(metadata["expert"]["sha256"]) == 64 and metadata["seed"] == 3
    assert metadata["command"].startswith("python -m sb3_icrl.data generate --env")
    assert "Wrote" in capsys.readouterr().out


def _recording(unpack, paths):
    """``unpack`` (SB3's ``load_from_zip_file``), which also records each path it unpacks."""

    def recorded(path, *args, **kwargs):
        paths.append(str(path))
        return unpack(path, *args, **kwargs)

    return recorded


def test_generate_unpacks_a_zip_expert_once_and_still_names_a_broken_entry(tmp_path, monkeypatch, capsys):
    expert = tmp_path / "expert.zip"
    venv = DummyVecEnv([lambda: gym.make(CORRIDOR)])
    PPOLagrangian("MlpPolicy", venv, n_steps=32, batch_size=16, seed=0, device="cpu").save(expert)
    unpacked = []
    # SB3's load and the damage check each call their own imported name
    for module in (base_class, saved):
        monkeypatch.setattr(module, "load_from_zip_file", _recording(module.load_from_zip_file, unpacked))
    args = ["generate", "--env", CORRIDOR, "--expert", str(expert), "--n", "1", "--violating-fraction", "1"]
    assert main([*args, "--out", str(tmp_path / "demos.npz")]) == 0
    assert unpacked == [str(expert)]
    # A data entry that is not JSON: SB3's load fails, and the error names the file and the entry
    with zipfile.ZipFile(expert) as archive:
        entries = {name: archive.read(name) for name in archive.namelist()}
    with zipfile.ZipFile(expert, "w") as archive:
        for name, content in {**entries, "data": b"{not json"}.items():
            archive.writestr(name, content)
    capsys.readouterr()
    assert main([*args, "--out", str(tmp_path / "broken.npz")]) == 1
    assert f"The expert {expert} is damaged (JSONDecodeError" in capsys.readouterr().err


def test_cli_reports_errors(tmp_path, capsys):
    assert main(["generate", "--env", "NoSuchEnv-v9", "--expert", "pilag", "--out", str(tmp_path / "x.npz")]) == 1
    assert "Unknown env 'NoSuchEnv-v9'" in capsys.readouterr().err
    assert main(["generate", "--env", "GridWorldWall-v0", "--expert", "missing.zip", "--out", str(tmp_path / "x.npz")]) == 1
    assert "No expert file" in capsys.readouterr().err
    assert main(["info", "NoSuchEnv-v9"]) == 1
    available = "Available: BiasedPendulum-v0 (violating_fraction 0, 0.2, 0.5, 0.8); BiasedPendulumReach-v0"
    assert available in capsys.readouterr().err


def test_info_says_unknown_for_data_without_true_costs(tmp_path, capsys):
    demos = from_arrays(np.zeros((6, 2)), np.zeros((6, 1)), episode_lengths=[3, 3], env_id="sb3_icrl/GridWorldWall-v0")
    assert demos.metadata["true_costs_known"] is False
    path = str(tmp_path / "imported.npz")
    save(path, demos.trajectories, demos.metadata)
    assert main(["info", path]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["violating_share"].startswith("unknown") and shown["n_trajectories"] == 2
    clean = str(tmp_path / "clean.npz")
    save(clean, demos.trajectories, {**demos.metadata, "true_costs_known": True})
    assert main(["info", clean]) == 0 and json.loads(capsys.readouterr().out)["violating_share"] == 0.0


@pytest.mark.parametrize("fraction", [0.3, 1.0])
def test_cli_keeps_the_violating_share_asked(tmp_path, fraction):
    """``python -m sb3_icrl.data generate --violating-fraction``: the saved dataset holds that share, on the true cost."""
    out = tmp_path / "demos.npz"
    args = ["generate", "--env", "GridWorldWall-v0", "--expert", "pilag", "--n", "10", "--out", str(out)]
    assert main([*args, "--violating-fraction", str(fraction), "--seed", "0"]) == 0
    demos = load(out)
    sidecar = json.loads(out.with_suffix(".json").read_text())
    assert demos.violations.sum() == round(fraction * 10) == sidecar["n_violating_trajectories"]
    assert sidecar["violating_share"] == pytest.approx(fraction)
    # A trajectory counts as violating by its own true costs, not by the slot it was drawn for
    assert all(t.violates == (t.episode_cost > 0) for t in demos)
    words = sidecar["command"].split()
    assert float(words[words.index("--violating-fraction") + 1]) == fraction  # the command that makes it again


def test_a_share_of_a_count_that_is_not_whole_rounds_to_the_nearest():
    demos = generate_demonstrations(CorridorExpert(), CORRIDOR, n_trajectories=5, violating_fraction=0.3, seed=2)
    assert demos.violations.sum() == 2  # round(1.5)
    assert demos.metadata["generation"]["n_violating_requested"] == 2


def test_cli_refuses_a_share_outside_zero_to_one(tmp_path, capsys):
    out = tmp_path / "demos.npz"
    args = ["generate", "--env", "GridWorldWall-v0", "--expert", "pilag", "--n", "4", "--out", str(out)]
    assert main([*args, "--violating-fraction", "1.5"]) == 1
    assert "`violating_fraction` is a share of trajectories in [0, 1], got 1.5" in capsys.readouterr().err
    assert not out.exists()
