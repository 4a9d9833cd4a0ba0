"""Other people's demonstrations: imitation >= 1.0 folders, Minari, the reference codes' pickles, flat arrays, checks."""

import json
import pickle
import warnings

import numpy as np
import pytest

from sb3_icrl.data import (
    DemonstrationError,
    Demonstrations,
    Trajectory,
    check_env_id,
    dynamics_replay_check,
    from_arrays,
    from_liu_pickles,
    from_malik_rollouts,
    load_demonstrations,
)
from sb3_icrl.data.importers import read_pickle

HALF_CHEETAH = "sb3_icrl/BlockedHalfCheetah-v0"


def _trajectories(n: int = 3, length: int = 4, seed: int = 0) -> list[Trajectory]:
    rng = np.random.default_rng(seed)
    trajectories = []
    for index in range(n):
        steps = length + index
        trajectories.append(
            Trajectory(
                obs=rng.normal(size=(steps + 1, 3)),
                acts=rng.normal(size=(steps, 2)).astype(np.float32),
                infos=None,
                terminal=index == 0,
                rews=rng.normal(size=steps).astype(np.float32),
                costs=(rng.random(steps) > 0.5).astype(np.float32),
            )
        )
    return trajectories


def _assert_same(loaded: Demonstrations, trajectories: list[Trajectory]) -> None:
    assert len(loaded) == len(trajectories)
    for got, expected in zip(loaded, trajectories, strict=True):
        np.testing.assert_array_equal(got.obs, expected.obs)
        np.testing.assert_array_equal(got.acts, expected.acts)
        np.testing.assert_allclose(got.rews, expected.rews)
        np.testing.assert_array_equal(got.costs, expected.costs)
        assert got.terminal == expected.terminal


# imitation >= 1.0: HuggingFace datasets folders


def test_imitation_dataset_round_trip_through_load_demonstrations(tmp_path):
    datasets = pytest.importorskip("datasets")
    from sb3_icrl.data.formats import save_imitation_dataset

    trajectories = _trajectories()
    folder = tmp_path / "demos"
    save_imitation_dataset(folder, trajectories, {"env_id": "sb3_icrl/Test-v0"})
    loaded = load_demonstrations(folder)
    _assert_same(loaded, trajectories)
    assert loaded[0].obs.dtype == np.float64 and loaded[0].acts.dtype == np.float32 and loaded[0].rews.dtype == np.float32
    assert loaded.metadata["env_id"] == "sb3_icrl/Test-v0" and loaded.metadata["true_costs_known"]
    # imitation's schema: one row per trajectory, infos as JSON strings holding the cost
    dataset = datasets.load_from_disk(str(folder))
    assert set(dataset.column_names) == {"obs", "acts", "infos", "terminal", "rews"}
    assert len(dataset) == 3 and len(dataset[1]["obs"]) == len(dataset[1]["acts"]) + 1
    assert [json.loads(info)["cost"] for info in dataset[2]["infos"]] == trajectories[2].costs.tolist()
    with pytest.raises(FileExistsError, match="overwrite=True"):
        save_imitation_dataset(folder, trajectories)
    save_imitation_dataset(folder, trajectories[:1], overwrite=True)
    assert len(load_demonstrations(folder)) == 1


def test_imitation_dataset_without_costs(tmp_path):
    datasets = pytest.importorskip("datasets")
    from sb3_icrl.data.formats import load_imitation_dataset

    # As imitation writes it: no cost in the infos, no sb3_icrl.json
    trajectories = _trajectories(n=2)
    columns = {
        "obs": [t.obs for t in trajectories],
        "acts": [t.acts for t in trajectories],
        "infos": [["{}"] * len(t) for t in trajectories],
        "terminal": [t.terminal for t in trajectories],
        "rews": [t.rews for t in trajectories],
    }
    folder = tmp_path / "imitation"
    datasets.Dataset.from_dict(columns).save_to_disk(str(folder))
    with pytest.raises(DemonstrationError, match="no true costs"):
        load_imitation_dataset(folder, missing_costs="error")
    with pytest.warns(UserWarning, match="no true costs"):
        loaded = load_demonstrations(folder)
    assert not loaded.metadata["true_costs_known"]
    assert all(not t.costs.any() for t in loaded)
    np.testing.assert_array_equal(loaded[1].obs, trajectories[1].obs)
    with pytest.raises(ValueError, match="missing_costs"):
        load_imitation_dataset(folder, missing_costs="ignore")


def test_imitation_dataset_checks_env_and_refuses_other_folders(tmp_path):
    pytest.importorskip("datasets")
    from sb3_icrl.data.formats import save_imitation_dataset

    demonstrations = load_demonstrations("GridWorldWall-v0")
    folder = tmp_path / "grid"
    save_imitation_dataset(folder, demonstrations.trajectories[:2], {"env_id": demonstrations.metadata["env_id"]})
    assert len(load_demonstrations(folder, env="sb3_icrl/GridWorldWall-v0")) == 2
    with pytest.raises(DemonstrationError, match="recorded on"):
        load_demonstrations(folder, env="sb3_icrl/GridWorldSquare-v0")
    assert len(load_demonstrations(folder, env="sb3_icrl/GridWorldSquare-v0", allow_env_mismatch=True)) == 2
    (tmp_path / "empty").mkdir()
    with pytest.raises(DemonstrationError, match="folder but not a dataset"):
        load_demonstrations(tmp_path / "empty")


def test_imitation_dataset_with_numpy_infos_as_imitation_writes_them(tmp_path):
    # imitation encodes its infos with jsonpickle: numpy values come as py/ tags (the datasets extra installs it)
    datasets = pytest.importorskip("datasets")
    jsonpickle = pytest.importorskip("jsonpickle")
    warnings.filterwarnings("ignore", message="keys will default", category=DeprecationWarning)
    trajectories = _trajectories(n=2)
    columns = {
        "obs": [t.obs for t in trajectories],
        "acts": [t.acts for t in trajectories],
        "infos": [[jsonpickle.encode({"cost": np.float32(cost)}, keys=False) for cost in t.costs] for t in trajectories],
        "terminal": [t.terminal for t in trajectories],
        "rews": [t.rews for t in trajectories],
    }
    assert "py/" in columns["infos"][0][0]
    folder = tmp_path / "imitation"
    datasets.Dataset.from_dict(columns).save_to_disk(str(folder))
    loaded = load_demonstrations(folder)
    assert loaded.metadata["true_costs_known"]
    _assert_same(loaded, trajectories)
    # jsonpickle calls what an info names: anything but numpy's builders is refused before decoding
    call = {"cost": 0.0, "x": {"py/reduce": [{"py/function": "builtins.print"}, {"py/tuple": ["this must not run"]}]}}
    columns["infos"] = [[json.dumps(call)] * len(t) for t in trajectories]
    datasets.Dataset.from_dict(columns).save_to_disk(str(tmp_path / "hostile"))
    with pytest.raises(DemonstrationError, match=r"refusing an info that names 'builtins\.print'"):
        load_demonstrations(tmp_path / "hostile")


# Minari


def test_minari_round_trip(tmp_path, monkeypatch):
    pytest.importorskip("minari")
    from sb3_icrl.data.formats import from_minari, to_minari

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    source = load_demonstrations("GridWorldWall-v0")
    demonstrations = Demonstrations(source.trajectories[:3], source.metadata)
    to_minari(demonstrations, "sb3icrl/gridwall/expert-v0")
    loaded = from_minari("sb3icrl/gridwall/expert-v0")
    _assert_same(loaded, demonstrations.trajectories)
    assert loaded.metadata["env_id"] == "sb3_icrl/GridWorldWall-v0" and loaded.metadata["true_costs_known"]
    with pytest.raises(FileExistsError, match="overwrite=True"):
        to_minari(demonstrations, "sb3icrl/gridwall/expert-v0")
    to_minari(Demonstrations(source.trajectories[:1], source.metadata), "sb3icrl/gridwall/expert-v0", overwrite=True)
    assert len(from_minari("sb3icrl/gridwall/expert-v0")) == 1
    with pytest.raises(DemonstrationError, match="No Minari dataset"):
        from_minari("sb3icrl/gridwall/absent-v0")
    with pytest.raises(DemonstrationError, match="env="):
        to_minari(_trajectories(), "sb3icrl/anonymous/expert-v0")


def test_a_failed_to_minari_leaves_the_id_free(tmp_path, monkeypatch):
    minari = pytest.importorskip("minari")
    from sb3_icrl.data.formats import from_minari, to_minari

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    source = load_demonstrations("GridWorldWall-v0")
    dataset_id = "sb3icrl/gridwall/expert-v0"
    # Float observations in an env of integer cells: Minari fails once it has started writing the dataset
    with pytest.raises(Exception, match="truncated"):
        to_minari(_trajectories(), dataset_id, env="sb3_icrl/GridWorldWall-v0")
    assert not (tmp_path / "sb3icrl" / "gridwall" / "expert-v0").exists()
    assert dataset_id not in minari.list_local_datasets()
    to_minari(Demonstrations(source.trajectories[:2], source.metadata), dataset_id)  # no overwrite needed
    assert len(from_minari(dataset_id)) == 2
    # What an earlier failure left behind (a folder Minari does not list) is replaced with overwrite=True
    leftover = tmp_path / "sb3icrl" / "gridwall" / "expert-v1" / "data"
    leftover.mkdir(parents=True)
    with pytest.raises(FileExistsError, match="overwrite=True"):
        to_minari(source, "sb3icrl/gridwall/expert-v1")
    to_minari(Demonstrations(source.trajectories[:1], source.metadata), "sb3icrl/gridwall/expert-v1", overwrite=True)
    assert len(from_minari("sb3icrl/gridwall/expert-v1")) == 1
    for bad_id in ("sb3icrl", "../outside-v0"):
        with pytest.raises(DemonstrationError, match="not a Minari dataset id"):
            to_minari(source, bad_id, overwrite=True)
    assert (tmp_path / "sb3icrl" / "gridwall" / "expert-v0").exists()  # a namespace given as an id deleted nothing
    (tmp_path / "shared-v0" / "expert-v0" / "data").mkdir(parents=True)  # a namespace whose name reads as an id
    with pytest.raises(DemonstrationError, match="a namespace of other datasets"):
        to_minari(source, "shared-v0", overwrite=True)
    assert (tmp_path / "shared-v0" / "expert-v0" / "data").is_dir()


def test_minari_dataset_without_costs(tmp_path, monkeypatch):
    minari = pytest.importorskip("minari")
    from minari.data_collector import EpisodeBuffer

    from sb3_icrl.data.formats import from_minari

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    trajectory = load_demonstrations("GridWorldWall-v0")[0]
    length = len(trajectory)
    buffer = EpisodeBuffer(
        id=0,
        observations=trajectory.obs,
        actions=trajectory.acts,
        rewards=list(trajectory.rews.astype(np.float64)),
        terminations=[False] * (length - 1) + [trajectory.terminal],
        truncations=[False] * (length - 1) + [not trajectory.terminal],
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        dataset = minari.create_dataset_from_buffers(
            "other/grid/plain-v0", [buffer], env="sb3_icrl/GridWorldWall-v0", data_format="arrow"
        )
    with pytest.raises(DemonstrationError, match="no true costs"):
        from_minari(dataset, missing_costs="error")
    with pytest.warns(UserWarning, match="no true costs"):
        loaded = from_minari(dataset)  # a MinariDataset, not only an id
    assert not loaded.metadata["true_costs_known"] and not loaded[0].costs.any()
    np.testing.assert_array_equal(loaded[0].obs, trajectory.obs)
    assert loaded.metadata["env_id"] == "sb3_icrl/GridWorldWall-v0"


# The reference codes' pickles


def _pickle(path, content) -> None:
    with open(path, "wb") as file:
        pickle.dump(content, file)


def test_malik_rollouts_drop_the_unpaired_rows(tmp_path):
    # One episode s_0..s_5, actions a_0..a_4: rows hold the state after each action, the last row the next reset state
    states = np.arange(6, dtype=np.float64)[:, None] * np.ones((1, 2))
    actions = 10 + np.arange(5, dtype=np.float32)[:, None]
    observations = np.concatenate([states[1:5], [[-1.0, -1.0]]])
    folder = tmp_path / "rollouts"
    folder.mkdir()
    for index in (0, 1, 10):
        _pickle(
            folder / f"{index}.pkl",
            {"observations": observations, "actions": actions, "rewards": np.array([7.0]), "lengths": np.array([5])},
        )
    demonstrations = from_malik_rollouts(folder, env_id="HCWithPos-v0", check_replay=False)
    assert len(demonstrations) == 3 and demonstrations.metadata["source"]["files"] == ["0.pkl", "1.pkl", "10.pkl"]
    trajectory = demonstrations[0]
    np.testing.assert_array_equal(trajectory.obs, states[1:5])  # s_1..s_4
    np.testing.assert_array_equal(trajectory.acts, actions[1:4])  # a_1..a_3: obs[t] = s_{t+1} pairs with a_{t+1}
    assert not demonstrations.metadata["rewards_known"] and not demonstrations.metadata["true_costs_known"]
    assert demonstrations.metadata["episode_returns_recorded"] == [7.0, 7.0, 7.0]
    _pickle(tmp_path / "short.pkl", {"observations": observations[:2], "actions": actions[:2]})
    with pytest.raises(DemonstrationError, match="at least 3"):
        from_malik_rollouts([tmp_path / "short.pkl"])
    _pickle(tmp_path / "other.pkl", {"obs": observations})
    with pytest.raises(DemonstrationError, match="lacks"):
        from_malik_rollouts([tmp_path / "other.pkl"])


def test_liu_pickles_layout(tmp_path):
    states = np.arange(5, dtype=np.float64)[:, None] * np.ones((1, 3))
    actions = np.arange(5, dtype=np.float32)[:, None]
    rewards = np.array([1.0, 2.0, 3.0, 4.0, 5.0], dtype=np.float32)
    content = {
        "observations": states / 10,  # normalised by the expert's VecNormalize
        "original_observations": states,
        "actions": actions,
        "reward": rewards,
        "reward_sum": rewards.sum(),
    }
    _pickle(tmp_path / "scene-DEU_1_len-5_collision.pkl", content)
    _pickle(tmp_path / "scene-DEU_2_len-5_time_out.pkl", content)
    demonstrations = from_liu_pickles(tmp_path, env_id="commonroad-v1", check_replay=False)
    assert len(demonstrations) == 2
    first = demonstrations[0]
    np.testing.assert_array_equal(first.obs, states)  # row t is the state before action t
    np.testing.assert_array_equal(first.acts, actions[:-1])
    np.testing.assert_array_equal(first.rews, rewards[:-1])
    assert first.terminal and not demonstrations[1].terminal
    assert demonstrations.metadata["episodes"][0]["scene"] == "DEU_1"
    assert demonstrations.metadata["episodes"][0]["termination_reasons"] == ["collision"]
    assert demonstrations.metadata["rewards_known"] and not demonstrations.metadata["true_costs_known"]
    normalised = from_liu_pickles(tmp_path, observation_key="observations")
    np.testing.assert_array_equal(normalised[0].obs, states / 10)
    _pickle(tmp_path / "scene-x_len-9_time_out.pkl", content)
    with pytest.raises(DemonstrationError, match="the name says 9 steps"):
        from_liu_pickles([tmp_path / "scene-x_len-9_time_out.pkl"])


class _Exploit:
    def __reduce__(self):
        return (print, ("this must not run",))


def test_pickles_are_read_without_running_code(tmp_path):
    _pickle(tmp_path / "evil.pkl", {"observations": _Exploit()})
    with pytest.raises(DemonstrationError, match=r"refusing to load builtins\.print"):
        read_pickle(tmp_path / "evil.pkl")
    with pytest.raises(DemonstrationError, match="No pickle"):
        read_pickle(tmp_path / "absent.pkl")


# Flat arrays


def test_from_arrays_splits_episodes():
    observations = np.arange(6, dtype=np.float64)[:, None]
    actions = np.arange(6, dtype=np.float32)[:, None] + 100
    next_observations = np.array([1, 2, 2.5, 4, 5, 5.5])[:, None]  # the next row, inside each episode
    starts = np.array([True, False, False, True, False, False])
    demonstrations = from_arrays(
        observations, actions, next_observations=next_observations, episode_starts=starts, env_id="X-v0", check_replay=False
    )
    assert [len(t) for t in demonstrations] == [3, 3]
    np.testing.assert_array_equal(demonstrations[1].obs.ravel(), [3, 4, 5, 5.5])
    assert not demonstrations.metadata["rewards_known"] and demonstrations.metadata["env_id"] == "X-v0"
    # Without the next observations, the last step of each episode is dropped
    dropped = from_arrays(
        observations, actions, rewards=np.ones(6), costs=np.zeros(6), episode_lengths=[2, 4], terminals=[True, False]
    )
    assert [len(t) for t in dropped] == [1, 3] and dropped[0].terminal
    np.testing.assert_array_equal(dropped[1].acts.ravel(), [102, 103, 104])
    assert dropped.metadata["rewards_known"] and dropped.metadata["true_costs_known"]
    with pytest.raises(DemonstrationError, match="sum to 5"):
        from_arrays(observations, actions, episode_lengths=[2, 3])
    with pytest.raises(DemonstrationError, match="one row per step"):
        from_arrays(observations[:5], actions)
    with pytest.raises(DemonstrationError, match="not both"):
        from_arrays(observations, actions, episode_starts=starts, episode_lengths=[3, 3])
    with pytest.raises(DemonstrationError, match="at least two"):
        from_arrays(observations, actions, episode_lengths=[1, 5])


# Semantic checks


def test_check_env_id():
    metadata = {"env_id": "sb3_icrl/GridWorldWall-v0"}
    check_env_id(metadata, "GridWorldWall-v0")  # the namespace is optional
    with pytest.raises(DemonstrationError, match="not on the target env 'sb3_icrl/GridWorldWall-v1'"):
        check_env_id(metadata, "sb3_icrl/GridWorldWall-v1")
    check_env_id({}, "sb3_icrl/GridWorldWall-v0")
    with pytest.raises(DemonstrationError, match="no `env_id`"):
        check_env_id({}, "sb3_icrl/GridWorldWall-v0", require_env_id=True)


def test_dynamics_replay_passes_shipped_data_and_flags_shifted_actions():
    demonstrations = load_demonstrations("BlockedHalfCheetah-v0")
    report = dynamics_replay_check(demonstrations, HALF_CHEETAH, n_pairs=40)
    assert report.ok and report.best_shift == 0 and report.mean_error < 1e-8 and not report.flagged
    assert "aligned" in str(report)
    # Each action stored one row late
    transitions = demonstrations.transitions
    starts = np.concatenate([[True], transitions.episode_ends[:-1]])
    shifted = from_arrays(
        transitions.obs, np.roll(transitions.acts, 1, axis=0), next_observations=transitions.next_obs, episode_starts=starts
    )
    report = dynamics_replay_check(shifted, HALF_CHEETAH, n_pairs=40)
    # obs[t] now fits the action stored one row later
    assert not report.ok and report.best_shift == 1 and report.errors[1] < 1e-8 < report.errors[0]
    assert report.flagged_fraction > 0.9 and "misaligned by one step" in report.verdict


def test_dynamics_replay_needs_mujoco_and_full_states():
    with pytest.raises(DemonstrationError, match="MuJoCo"):
        dynamics_replay_check(load_demonstrations("GridWorldWall-v0"), "sb3_icrl/GridWorldWall-v0")
    partial = [
        Trajectory(
            np.zeros((5, 10)),
            np.zeros((4, 6), dtype=np.float32),
            None,
            False,
            np.zeros(4, np.float32),
            np.zeros(4, np.float32),
        )
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(DemonstrationError, match="fewer than qpos"):
            dynamics_replay_check(partial, HALF_CHEETAH)


def _flat_half_cheetah(n_trajectories: int = 3) -> dict:
    """Shipped BlockedHalfCheetah data as flat arrays, the way other code's files hold it."""
    source = load_demonstrations("BlockedHalfCheetah-v0")
    transitions = Demonstrations(source.trajectories[:n_trajectories], source.metadata).transitions
    starts = np.concatenate([[True], transitions.episode_ends[:-1]])
    return {"obs": transitions.obs, "acts": transitions.acts, "next_obs": transitions.next_obs, "starts": starts}


def test_importers_replay_the_data_on_its_env_by_default():
    flat = _flat_half_cheetah()
    common = {"next_observations": flat["next_obs"], "episode_starts": flat["starts"]}
    imported = from_arrays(flat["obs"], flat["acts"], env_id=HALF_CHEETAH, **common)  # aligned: passes in silence
    assert len(imported) == 3
    # Each action stored one row late: caught without asking
    shifted = np.roll(flat["acts"], 1, axis=0)
    with pytest.raises(DemonstrationError, match=r"from_arrays: .*misaligned by one step.*check_replay=False"):
        from_arrays(flat["obs"], shifted, env_id="BlockedHalfCheetah-v0", **common)
    assert len(from_arrays(flat["obs"], shifted, env_id=HALF_CHEETAH, check_replay=False, **common)) == 3
    # HalfCheetah data labelled as the Walker, whose observations and actions have the same shapes
    with pytest.raises(DemonstrationError, match=r"does not follow the env's dynamics.*another robot"):
        from_arrays(flat["obs"], flat["acts"], env_id="sb3_icrl/BlockedWalker-v0", **common)
    # Nothing to replay on: no env id, an env of other code not registered here (said so), an env that is not MuJoCo
    assert len(from_arrays(flat["obs"], shifted, **common)) == 3
    with pytest.warns(UserWarning, match=r"from_arrays: env_id 'HCWithPos-v0' is not registered here, so the data is stored"):
        assert len(from_arrays(flat["obs"], shifted, env_id="HCWithPos-v0", **common)) == 3
    assert len(from_arrays(np.zeros((6, 2)), np.zeros((6, 1)), episode_lengths=[3, 3], env_id="GridWorldWall-v0")) == 2


def test_the_replay_check_warns_when_it_cannot_replay():
    flat = _flat_half_cheetah(n_trajectories=1)
    # Two steps: no step with a step before and after it
    with pytest.warns(UserWarning, match=r"from_arrays: the data was not replayed on .*at least 3 steps"):
        from_arrays(flat["obs"][:2], flat["acts"][:2], next_observations=flat["next_obs"][:2], env_id=HALF_CHEETAH)
