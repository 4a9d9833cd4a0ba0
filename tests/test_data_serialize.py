"""Demonstration files: exact round trip, imitation's npz layout, no unpickling, validation errors, checksums, atomicity."""

import hashlib
import json
import os
from collections.abc import Sequence
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest

import sb3_icrl  # noqa: F401  (registers the envs)
from sb3_icrl.data import (
    DemonstrationError,
    Trajectory,
    flatten_trajectories,
    from_imitation,
    load,
    metadata_path,
    save,
)


def make_trajectories(lengths: Sequence[int] = (3, 1, 5), n_costs: int | None = None, seed: int = 0) -> list[Trajectory]:
    rng = np.random.default_rng(seed)
    trajectories = []
    for index, length in enumerate(lengths):
        cost_shape = (length,) if n_costs is None else (length, n_costs)
        trajectories.append(
            Trajectory(
                obs=rng.normal(size=(length + 1, 3)).astype(np.float32),
                acts=rng.uniform(-1, 1, size=(length, 2)).astype(np.float32),
                infos=None,
                terminal=index % 2 == 0,
                rews=rng.normal(size=length).astype(np.float32),
                costs=(rng.random(cost_shape) < 0.3).astype(np.float32),
            )
        )
    return trajectories


def assert_same(loaded: Sequence[Trajectory], original: Sequence[Trajectory]) -> None:
    assert len(loaded) == len(original)
    for new, old in zip(loaded, original, strict=True):
        for field in ("obs", "acts", "rews", "costs"):
            a, b = getattr(new, field), getattr(old, field)
            assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b), field
        assert new.terminal == old.terminal


@pytest.mark.parametrize("n_costs", [None, 2])
def test_round_trip_is_exact(tmp_path, n_costs):
    trajectories = make_trajectories(n_costs=n_costs)
    path = tmp_path / "demos.npz"
    sidecar = save(path, trajectories, {"env_id": "test", "seed": 3})
    demos = load(path)
    assert_same(demos, trajectories)
    assert all(t.infos is None for t in demos)
    on_disk = json.loads(metadata_path(path).read_text())
    assert demos.metadata == on_disk == sidecar
    assert sidecar["env_id"] == "test" and sidecar["seed"] == 3
    assert sidecar["n_trajectories"] == 3 and sidecar["n_transitions"] == 9
    assert sidecar["episode_returns"] == pytest.approx([t.episode_return for t in trajectories])
    assert sidecar["n_violating_trajectories"] == sum(t.violates for t in trajectories)
    assert sidecar["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    assert sidecar["versions"]["numpy"] == np.__version__


def test_same_trajectories_give_the_same_bytes(tmp_path):
    # Fixed zip timestamps: regenerating a dataset does not change its checksum
    save(tmp_path / "a.npz", make_trajectories())
    save(tmp_path / "b.npz", make_trajectories())
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()


def imitation_split(path) -> list[tuple]:
    """
    The npz branch of ``imitation.data.serialize.load`` (imitation v1.0.1, src/imitation/data/serialize.py),
    copied without the imitation classes: returns the ``(obs, acts, infos, terminal, rews)`` it passes to
    ``TrajectoryWithRew``.
    """
    data = np.load(path, allow_pickle=True)
    num_trajs = len(data["indices"])
    fields = [
        # Account for the extra obs in each trajectory
        np.split(data["obs"], data["indices"] + np.arange(num_trajs) + 1),
        np.split(data["acts"], data["indices"]),
        np.split(data["infos"], data["indices"]),
        data["terminal"],
    ]
    assert "rews" in data
    fields = [*fields, np.split(data["rews"], data["indices"])]
    return list(zip(*fields, strict=True))


def test_imitation_reads_our_layout(tmp_path):
    trajectories = make_trajectories(lengths=(4, 2, 1, 6))
    path = tmp_path / "demos.npz"
    save(path, trajectories)
    read = imitation_split(path)
    assert len(read) == len(trajectories)
    for (obs, acts, infos, terminal, rews), original in zip(read, trajectories, strict=True):
        assert np.array_equal(obs, original.obs) and np.array_equal(acts, original.acts)
        assert np.array_equal(rews, original.rews) and terminal == original.terminal
        # imitation's Trajectory checks: one info dict per action
        assert len(infos) == len(acts) and all(info == {} for info in infos)


def test_single_trajectory_layout(tmp_path):
    trajectories = make_trajectories(lengths=(7,))
    save(tmp_path / "one.npz", trajectories)
    with np.load(tmp_path / "one.npz") as archive:
        assert archive["indices"].shape == (0,)
    assert_same(load(tmp_path / "one.npz"), trajectories)
    obs, acts, _, _, _ = imitation_split(tmp_path / "one.npz")[0]
    assert obs.shape == (8, 3) and acts.shape == (7, 2)


UNPICKLED = []


def _record_unpickling():
    UNPICKLED.append(True)
    return {"cost": 0.0}


class RecordsUnpickling:
    def __reduce__(self):
        return (_record_unpickling, ())


def test_loading_never_unpickles_unless_asked(tmp_path):
    trajectory = make_trajectories(lengths=(2,))[0]
    trajectory = Trajectory(
        trajectory.obs,
        trajectory.acts,
        np.array([RecordsUnpickling(), RecordsUnpickling()]),
        True,
        trajectory.rews,
        trajectory.costs,
    )
    path = tmp_path / "demos.npz"
    save(path, [trajectory])
    UNPICKLED.clear()
    assert load(path)[0].infos is None
    assert UNPICKLED == []
    infos = load(path, load_infos=True)[0].infos
    assert UNPICKLED and list(infos) == [{"cost": 0.0}, {"cost": 0.0}]


def write_raw(path, arrays: dict, metadata: dict | None = None) -> None:
    """An archive written with np.savez and a sidecar with its true checksum: only the tested defect is wrong."""
    np.savez(path, **arrays)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    metadata_path(path).write_text(json.dumps({**(metadata or {}), "sha256": digest}))


def valid_arrays() -> dict:
    return {
        "obs": np.zeros((6, 3), dtype=np.float32),
        "acts": np.zeros((4, 2), dtype=np.float32),
        "infos": np.array([{} for _ in range(4)], dtype=object),
        "terminal": np.array([True, False]),
        "rews": np.zeros(4, dtype=np.float32),
        "indices": np.array([3]),
        "costs": np.zeros(4, dtype=np.float32),
    }


def _drop(key):
    return lambda a: {k: v for k, v in a.items() if k != key}


def _set(key, value):
    return lambda a: {**a, key: value}


def _nan(key):
    def corrupt(arrays):
        value = arrays[key].copy()
        value.flat[1] = np.nan
        return {**arrays, key: value}

    return corrupt


BROKEN_FILES = {
    "missing costs": (_drop("costs"), r"lacks the keys \['costs'\].*from_imitation"),
    "missing indices": (_drop("indices"), r"lacks the keys \['indices'\]"),
    "missing infos": (_drop("infos"), r"lacks the keys \['infos'\]"),
    "integer rewards": (_set("rews", np.zeros(4, dtype=np.int64)), r"`rews` must be a float array, got dtype int64"),
    "integer costs": (_set("costs", np.zeros(4, dtype=np.int64)), r"`costs` must be a float array"),
    "terminal not bool": (_set("terminal", np.array([1, 0])), r"`terminal` must be a bool array"),
    "float indices": (_set("indices", np.array([3.0])), r"`indices` must be an integer array"),
    "obs without the extra row": (
        _set("obs", np.zeros((5, 3), np.float32)),
        r"`obs` has 5 rows, expected 6 for 2 trajectories",
    ),
    "costs too short": (_set("costs", np.zeros(3, np.float32)), r"`costs` has 3 rows, expected 4"),
    "terminal per step": (_set("terminal", np.zeros(4, bool)), r"`terminal` has 4 rows, expected 2"),
    "costs 3-D": (_set("costs", np.zeros((4, 1, 1), np.float32)), r"`costs` must have shape \(N,\) or \(N, n_costs\)"),
    "empty trajectory": (_set("indices", np.array([0])), r"`indices` must increase strictly"),
    "index past the end": (_set("indices", np.array([4])), r"`indices` must increase strictly"),
    "NaN observation": (_nan("obs"), r"`obs` holds NaN or infinite values"),
    "NaN action": (_nan("acts"), r"`acts` holds NaN"),
    "NaN reward": (_nan("rews"), r"`rews` holds NaN"),
    "NaN cost": (_nan("costs"), r"`costs` holds NaN"),
    "pickled observations": (_set("obs", np.array([[0.0]] * 6, dtype=object)), r"`obs` is stored as pickled Python objects"),
    "empty dataset": (
        lambda a: {
            **a,
            "obs": np.zeros((0, 3), np.float32),
            "acts": np.zeros((0, 2), np.float32),
            "indices": np.array([], int),
        },
        r"the dataset is empty",
    ),
}


@pytest.mark.parametrize("defect", list(BROKEN_FILES))
def test_each_defect_raises_a_clear_error(tmp_path, defect):
    corrupt, message = BROKEN_FILES[defect]
    write_raw(tmp_path / "valid.npz", valid_arrays())
    assert len(load(tmp_path / "valid.npz")) == 2  # the unbroken file loads: the error below comes from the defect
    path = tmp_path / "broken.npz"
    write_raw(path, corrupt(valid_arrays()))
    with pytest.raises(DemonstrationError, match=message) as error:
        load(path)
    assert str(path) in str(error.value)


def test_checksum_mismatch(tmp_path):
    path = tmp_path / "demos.npz"
    save(path, make_trajectories())
    # Same trajectories but one reward changed: a valid archive that is not the one the sidecar describes
    other = make_trajectories()
    other[0].rews[0] += 1.0
    sidecar = metadata_path(path).read_text()
    save(path, other)
    metadata_path(path).write_text(sidecar)
    with pytest.raises(DemonstrationError, match=r"Checksum mismatch .* regenerate it"):
        load(path)
    assert load(path, verify_checksum=False)[0].rews[0] == other[0].rews[0]


def test_missing_sidecar_bad_sidecar_missing_file_and_not_a_zip(tmp_path):
    path = tmp_path / "demos.npz"
    save(path, make_trajectories())
    metadata_path(path).write_text("{not json")
    with pytest.raises(DemonstrationError, match="not valid JSON"):
        load(path)
    metadata_path(path).unlink()
    with pytest.raises(DemonstrationError, match=r"no metadata sidecar demos\.json.*require_metadata=False"):
        load(path)
    assert len(load(path, require_metadata=False)) == 3
    with pytest.raises(DemonstrationError, match="No demonstration file"):
        load(tmp_path / "absent.npz")
    (tmp_path / "text.npz").write_text("hello")
    with pytest.raises(DemonstrationError, match=r"not an \.npz archive"):
        load(tmp_path / "text.npz", require_metadata=False)


def grid_trajectory(actions: Sequence[int], states: Sequence[int]) -> Trajectory:
    length = len(actions)
    return Trajectory(
        obs=np.array(states, dtype=np.int64),
        acts=np.array(actions, dtype=np.int64),
        infos=None,
        terminal=False,
        rews=np.zeros(length, np.float32),
        costs=np.zeros(length, np.float32),
    )


def test_spaces_must_match_the_target_env(tmp_path):
    grid = tmp_path / "grid.npz"
    save(grid, [grid_trajectory([0, 2], [0, 1, 8])], {"env_id": "sb3_icrl/GridWorldWall-v0"})
    assert len(load(grid, env="sb3_icrl/GridWorldWall-v0")) == 1
    with pytest.raises(
        DemonstrationError,
        match=r"observations have shape \(\) per step; Box.*expects \(2,\).*recorded on .sb3_icrl/GridWorldWall-v0",
    ):
        load(grid, env="sb3_icrl/ConstrainedCorridor-v0")
    save(grid, [grid_trajectory([0, 2], [0, 1, 49])])
    with pytest.raises(DemonstrationError, match=r"observations range over \[0, 49\], outside Discrete\(49\)"):
        load(grid, env=gym.make("sb3_icrl/GridWorldWall-v0"))
    save(grid, [grid_trajectory([0, 8], [0, 1, 2])])
    with pytest.raises(DemonstrationError, match=r"actions range over \[0, 8\], outside Discrete\(8\)"):
        load(grid, env="sb3_icrl/GridWorldWall-v0")

    box = tmp_path / "box.npz"
    trajectory = make_trajectories(lengths=(3,))[0]
    # Corridor: Box(0, 1, (2,)) observations, Discrete(3) actions
    corridor_obs = np.clip(trajectory.obs[:, :2], 0, 1)
    save(box, [Trajectory(corridor_obs, np.array([0, 1, 2]), None, False, trajectory.rews, trajectory.costs)])
    assert len(load(box, env="sb3_icrl/ConstrainedCorridor-v0")) == 1
    save(box, [Trajectory(corridor_obs + 2.0, np.array([0, 1, 2]), None, False, trajectory.rews, trajectory.costs)])
    with pytest.raises(DemonstrationError, match=r"values of the observations lie outside the bounds"):
        load(box, env="sb3_icrl/ConstrainedCorridor-v0")
    save(box, [trajectory])
    with pytest.raises(DemonstrationError, match=r"observations have shape \(3,\) per step; Box.* expects \(2,\)"):
        load(box, env="sb3_icrl/ConstrainedCorridor-v0")


def test_save_refuses_bad_input(tmp_path):
    with pytest.raises(DemonstrationError, match="empty"):
        save(tmp_path / "x.npz", [])
    first, second = make_trajectories(lengths=(2, 2))
    mixed = Trajectory(second.obs.astype(np.float64), second.acts, None, False, second.rews, second.costs)
    with pytest.raises(DemonstrationError, match="share the dtype and per-step shape of `obs`"):
        save(tmp_path / "x.npz", [first, mixed])
    with pytest.raises(DemonstrationError, match="JSON-serialisable"):
        save(tmp_path / "x.npz", [first], {"expert": object()})
    assert not list(tmp_path.iterdir())


def test_saved_files_are_shared_readable(tmp_path):
    # Atomicity itself is tested with the shared writer in test_utils.py
    path = tmp_path / "demos.npz"
    save(path, make_trajectories())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demos.json", "demos.npz"]
    assert oct(os.stat(path).st_mode & 0o777) == "0o644" and oct(os.stat(metadata_path(path)).st_mode & 0o777) == "0o644"


def test_trajectory_checks_its_fields():
    obs, acts = np.zeros((3, 1)), np.zeros((2, 1))
    with pytest.raises(ValueError, match="one more observation than actions"):
        Trajectory(obs[:2], acts, None, False, np.zeros(2), np.zeros(2))
    with pytest.raises(ValueError, match="`costs` must be a float numpy array"):
        Trajectory(obs, acts, None, False, np.zeros(2), np.zeros(2, dtype=int))
    with pytest.raises(ValueError, match=r"`rews` must have shape \(2,\)"):
        Trajectory(obs, acts, None, False, np.zeros(3), np.zeros(2))
    with pytest.raises(ValueError, match="at least one action"):
        Trajectory(obs[:1], acts[:0], None, False, np.zeros(0), np.zeros(0))


def test_transitions_view():
    trajectories = make_trajectories(lengths=(3, 2))
    transitions = flatten_trajectories(trajectories)
    assert len(transitions) == 5
    assert np.array_equal(transitions.obs[3:], trajectories[1].obs[:-1])
    assert np.array_equal(transitions.next_obs[3:], trajectories[1].obs[1:])
    # Trajectory 0 ended in a terminal state, trajectory 1 on a time limit
    assert transitions.dones.tolist() == [False, False, True, False, False]
    assert transitions.episode_ends.tolist() == [False, False, True, False, True]
    assert np.array_equal(transitions.costs, np.concatenate([t.costs for t in trajectories]))
    row = transitions[1]
    assert isinstance(row, dict) and np.array_equal(row["acts"], trajectories[0].acts[1])
    subset = transitions[np.array([0, 4])]
    assert len(subset) == 2 and np.array_equal(subset.rews, transitions.rews[[0, 4]])


def test_from_imitation_is_duck_typed(tmp_path):
    base = make_trajectories(lengths=(2, 3))
    # Stand-ins for imitation.data.types.TrajectoryWithRew (same attribute names; imitation is not imported)
    with_cost_infos = [
        SimpleNamespace(
            obs=t.obs, acts=t.acts, infos=np.array([{"cost": float(c)} for c in t.costs]), terminal=t.terminal, rews=t.rews
        )
        for t in base
    ]
    converted = from_imitation(with_cost_infos)
    assert_same(converted, base)
    save(tmp_path / "converted.npz", converted)
    assert_same(load(tmp_path / "converted.npz"), base)

    no_infos = [SimpleNamespace(obs=t.obs, acts=t.acts, infos=None, terminal=t.terminal, rews=t.rews) for t in base]
    assert_same(from_imitation(no_infos, costs=[t.costs for t in base]), base)
    with pytest.raises(DemonstrationError, match=r"no true costs.*costs="):
        from_imitation(no_infos)
    with pytest.raises(DemonstrationError, match="TrajectoryWithRew"):
        from_imitation([SimpleNamespace(obs=base[0].obs, acts=base[0].acts, infos=None, terminal=True)], costs=[base[0].costs])
    with pytest.raises(DemonstrationError, match="one per trajectory"):
        from_imitation(no_infos, costs=[base[0].costs])
