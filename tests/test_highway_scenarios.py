"""Recorded traffic of the driving environments: shipped data set, recorder, storage and CLI."""

import os
import sys

import numpy as np
import pytest

from sb3_icrl.envs.highway import DENSITIES, SPLITS, HighwayConstraintEnv, Scenario, load_scenarios, record_scenario
from sb3_icrl.envs.highway.__main__ import SHIPPED_SEEDS, main
from sb3_icrl.envs.highway.scenarios import SCENARIO_DIR, scenario_files


def overlapping_pairs(scenario: Scenario, frame: int) -> int:
    """Number of pairs of recorded vehicles whose rectangles overlap in a frame (headings are tiny)."""
    ids, states = scenario.frame(frame)
    dx = np.abs(states[:, None, 0] - states[None, :, 0])
    dy = np.abs(states[:, None, 1] - states[None, :, 1])
    lengths, widths = scenario.lengths[ids], scenario.widths[ids]
    overlap = (dx < (lengths[:, None] + lengths[None]) / 2) & (dy < (widths[:, None] + widths[None]) / 2)
    return (overlap.sum() - len(ids)) // 2


def test_shipped_dataset():
    total = 0
    for density in DENSITIES:
        seeds = {}
        for split in SPLITS:
            paths = scenario_files(density, split)
            assert len(paths) == len(SHIPPED_SEEDS[density, split])
            scenarios = [Scenario.load(path) for path in paths]
            seeds[split] = {s.seed for s in scenarios}
            for scenario in scenarios:
                assert scenario.density == DENSITIES[density]
                assert scenario.states.dtype == np.float32 and scenario.states.shape[1] == 4
                assert np.all(np.diff(scenario.frame_offsets) > 0)
                assert len(scenario.ego_candidates(200)) > 20
            total += sum(os.path.getsize(p) for p in paths)
        assert not seeds["train"] & seeds["test"]  # the test split is unseen traffic
    assert total < 4e6


def test_recordings_are_collision_free_and_on_the_road():
    for path in (scenario_files("dense", "test")[0], scenario_files("sparse", "test")[0]):
        scenario = Scenario.load(path)
        assert all(overlapping_pairs(scenario, frame) == 0 for frame in range(0, scenario.n_frames, 10))
        assert scenario.states[:, 1].min() >= -0.01 and scenario.states[:, 1].max() <= 8.01
        assert scenario.states[:, 2].min() >= 0 and scenario.states[:, 2].max() < 40.0  # recorded cars obey the limit


def test_densities_differ():
    # Dense traffic is slower and closer than sparse traffic
    dense, sparse = Scenario.load(scenario_files("dense", "test")[0]), Scenario.load(scenario_files("sparse", "test")[0])
    assert dense.states[:, 2].mean() < sparse.states[:, 2].mean() - 5.0
    assert dense.n_frames == sparse.n_frames and len(dense.states) > 2 * len(sparse.states)


def test_recording_is_seeded():
    first = record_scenario(seed=5, density=20.0, duration=6.0, warmup=4.0)
    again = record_scenario(seed=5, density=20.0, duration=6.0, warmup=4.0)
    other = record_scenario(seed=6, density=20.0, duration=6.0, warmup=4.0)
    np.testing.assert_array_equal(first.states, again.states)
    np.testing.assert_array_equal(first.car_ids, again.car_ids)
    assert first.n_frames == 31
    assert len(first.states) != len(other.states) or not np.array_equal(first.states, other.states)
    with pytest.raises(ValueError, match="density"):
        record_scenario(seed=0, density=0.0)


def test_save_load_round_trip(tmp_path):
    scenario = record_scenario(seed=1, density=10.0, duration=4.0, warmup=2.0)
    path = str(tmp_path / "one.npz")
    scenario.save(path)
    loaded = Scenario.load(path)
    for field in ("lengths", "widths", "frame_offsets", "car_ids", "states"):
        np.testing.assert_array_equal(getattr(loaded, field), getattr(scenario, field))
        assert getattr(loaded, field).dtype == getattr(scenario, field).dtype
    assert (loaded.dt, loaded.n_lanes, loaded.seed, loaded.density) == (0.2, 3, 1, 10.0)


def test_cli_generates_loadable_scenarios(tmp_path, monkeypatch):
    argv = ["sb3_icrl.envs.highway", "--density", "sparse", "--split", "test", "--count", "2", "--first-seed", "7"]
    monkeypatch.setattr(sys, "argv", [*argv, "--duration", "45", "--out", str(tmp_path)])
    main()
    assert sorted(os.listdir(tmp_path)) == ["sparse_test_0007.npz", "sparse_test_0008.npz"]
    scenarios = load_scenarios("sparse", "test", str(tmp_path))
    assert [s.seed for s in scenarios] == [7, 8]
    env = HighwayConstraintEnv(scenarios=scenarios, time_limit=10.0)
    env.reset(seed=0)
    assert env.step(env.action_space.sample())[0].shape == (23,)


def test_bad_split_or_density():
    with pytest.raises(ValueError, match="split"):
        scenario_files("dense", "validation")
    with pytest.raises(ValueError, match="density"):
        scenario_files("medium", "train")
    with pytest.raises(FileNotFoundError):
        scenario_files("dense", "train", directory=os.path.join(SCENARIO_DIR, "missing"))


def test_shipped_recording_is_what_its_seed_records():
    path = scenario_files("sparse", "test")[0]
    shipped = Scenario.load(path)
    again = record_scenario(seed=shipped.seed, density=DENSITIES["sparse"])
    np.testing.assert_array_equal(again.car_ids, shipped.car_ids)
    np.testing.assert_allclose(again.states, shipped.states, atol=1e-4)
