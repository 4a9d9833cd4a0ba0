import os
import signal

import pytest

from sb3_icrl.common.utils import atomic_write_bytes, atomic_write_json, sigterm_interrupts


def test_atomic_write_json_leaves_old_file_on_failure(tmp_path):
    path = tmp_path / "sub" / "result.json"
    atomic_write_json(path, {"a": 1})
    with pytest.raises(TypeError):
        atomic_write_json(path, {"a": object()})
    assert path.read_text() == '{"a": 1}'
    assert [name.name for name in path.parent.iterdir()] == ["result.json"], "no temporary file left behind"


def test_atomic_write_bytes_fails_half_way_without_damage(tmp_path):
    path = tmp_path / "data.bin"
    atomic_write_bytes(path, b"old")
    with pytest.raises(TypeError):
        atomic_write_bytes(path, "not bytes")  # type: ignore[arg-type]
    assert path.read_bytes() == b"old"
    assert [name.name for name in tmp_path.iterdir()] == ["data.bin"]
    assert oct(os.stat(path).st_mode & 0o777) == "0o644"


def test_atomic_save_model_and_pickle_round_trip_and_keep_the_old_file_on_failure(tmp_path, monkeypatch):
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from sb3_icrl.common.envs import ConstrainedCorridorEnv
    from sb3_icrl.common.utils import atomic_save_model, atomic_save_pickle

    venv = VecNormalize(DummyVecEnv([ConstrainedCorridorEnv]))
    model = PPO("MlpPolicy", venv, n_steps=32, batch_size=16, policy_kwargs=dict(net_arch=[8]))
    path = atomic_save_model(model, tmp_path / "model")
    assert path.endswith("model.zip")
    loaded = PPO.load(path)
    assert all(
        (a == b).all() for a, b in zip(loaded.policy.state_dict().values(), model.policy.state_dict().values(), strict=True)
    )
    atomic_save_pickle(venv, tmp_path / "stats.pkl")
    assert VecNormalize.load(str(tmp_path / "stats.pkl"), DummyVecEnv([ConstrainedCorridorEnv])).clip_obs == venv.clip_obs

    before = (tmp_path / "model.zip").read_bytes()
    monkeypatch.setattr(os, "replace", lambda *args: (_ for _ in ()).throw(OSError("disk full")))
    with pytest.raises(OSError, match="disk full"):
        atomic_save_model(model, tmp_path / "model.zip")
    assert (tmp_path / "model.zip").read_bytes() == before
    assert sorted(path.name for path in tmp_path.iterdir()) == ["model.zip", "stats.pkl"]  # no temporary file left


def test_sigterm_interrupts_raises_keyboard_interrupt_inside_and_restores_the_handler_after():
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt), sigterm_interrupts():
        os.kill(os.getpid(), signal.SIGTERM)
    assert signal.getsignal(signal.SIGTERM) is before
