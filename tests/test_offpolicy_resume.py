"""Off-policy runs resume with their replay buffer: saved at checkpoints (the newest only) and restored by -i/--resume."""

import os
import pathlib
import pickle
import random
import shutil
import warnings
from typing import Any

import numpy as np
import pytest
import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import ReplayBuffer
from test_irlplus import line_demonstrations, make_env, make_irlplus

from sb3_icrl import IRLPlus, PPOLagrangian, SACLagrangian
from sb3_icrl.sac_lagrangian import CostReplayBuffer
from sb3_icrl.zoo import callbacks as zoo_callbacks
from sb3_icrl.zoo.callbacks import (
    AtomicCheckpointCallback,
    load_replay_buffer,
    load_training_state,
    replay_buffer_path,
    training_state_path,
)
from sb3_icrl.zoo.hyperparams import algo_kwargs, load_hyperparams, preprocess_hyperparams
from sb3_icrl.zoo.train import _go_on, _setup, get_parser, main, resolve_env_id

#: The buffer's arrays that a restored buffer must hold as saved
BUFFER_ARRAYS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts", "costs")


def _irlplus(**kwargs: Any) -> IRLPlus:
    """IRL-Plus on the 8-step line (deterministic resets), tiny networks, on the CPU."""
    return make_irlplus(**{"device": "cpu", "policy_kwargs": {"net_arch": [16]}, **kwargs})


def _read_buffer(path: pathlib.Path) -> ReplayBuffer:
    with open(path, "rb") as file:
        return pickle.load(file)


def _assert_same_buffer(buffer: ReplayBuffer, saved: ReplayBuffer, n: int | None = None) -> None:
    """``buffer`` holds ``saved``'s transitions (its first ``n``; all of them and its position when ``n`` is None)."""
    if n is None:
        assert (buffer.pos, buffer.full, buffer.size()) == (saved.pos, saved.full, saved.size())
        n = saved.size()
    for name in BUFFER_ARRAYS:
        np.testing.assert_array_equal(getattr(buffer, name)[:n], getattr(saved, name)[:n], err_msg=name)


def _buffer_files(folder: pathlib.Path) -> list[str]:
    return sorted(path.name for path in folder.glob("*replay_buffer*"))


# ---------------------------------------------------------------------------------------------------- checkpoints


def test_checkpoints_save_the_replay_buffer_before_the_model_and_keep_the_newest(tmp_path, monkeypatch) -> None:
    model = _irlplus()
    seen: list[tuple[str, list[str]]] = []
    save_model = zoo_callbacks.atomic_save_model

    def saving_model(model: Any, path: str) -> str:
        # When each model is written: its own buffer is there, and the previous one is not yet removed
        seen.append((os.path.basename(path), _buffer_files(tmp_path)))
        return save_model(model, path)

    monkeypatch.setattr(zoo_callbacks, "atomic_save_model", saving_model)
    (tmp_path / "rl_model_replay_buffer_40_steps.pkl").write_bytes(b"the buffer of a model a kill left unwritten")
    checkpoint = AtomicCheckpointCallback(16, str(tmp_path), save_replay_buffer=True, save_training_state=True)
    model.learn(48, callback=checkpoint)

    assert seen == [
        ("rl_model_16_steps.zip", ["rl_model_replay_buffer_16_steps.pkl", "rl_model_replay_buffer_40_steps.pkl"]),
        ("rl_model_32_steps.zip", ["rl_model_replay_buffer_16_steps.pkl", "rl_model_replay_buffer_32_steps.pkl"]),
        ("rl_model_48_steps.zip", ["rl_model_replay_buffer_32_steps.pkl", "rl_model_replay_buffer_48_steps.pkl"]),
    ]
    assert _buffer_files(tmp_path) == ["rl_model_replay_buffer_48_steps.pkl"]  # the newest only
    saved = _read_buffer(tmp_path / "rl_model_replay_buffer_48_steps.pkl")
    assert isinstance(saved, CostReplayBuffer) and saved.pos == 48 and not saved.full
    _assert_same_buffer(model.replay_buffer, saved)
    assert str(tmp_path / "rl_model_replay_buffer_48_steps.pkl") == replay_buffer_path(
        str(tmp_path / "rl_model_48_steps.zip"), 48
    )
    # SB3's own reader takes the file too
    restored = IRLPlus.load(tmp_path / "rl_model_48_steps.zip", env=make_env(), demonstrations=line_demonstrations())
    assert restored.replay_buffer.size() == 0
    restored.load_replay_buffer(tmp_path / "rl_model_replay_buffer_48_steps.pkl")
    _assert_same_buffer(restored.replay_buffer, saved)


def test_the_clean_up_leaves_a_folder_named_like_an_older_replay_buffer(tmp_path) -> None:
    # Not a buffer this callback wrote: os.remove would fail on it and end the run
    folder = tmp_path / "rl_model_replay_buffer_8_steps.pkl"
    folder.mkdir()
    (folder / "notes.txt").write_text("kept")
    checkpoint = AtomicCheckpointCallback(16, str(tmp_path), save_replay_buffer=True, save_training_state=True)
    _irlplus().learn(32, callback=checkpoint)
    assert _buffer_files(tmp_path) == ["rl_model_replay_buffer_32_steps.pkl", "rl_model_replay_buffer_8_steps.pkl"]
    assert (tmp_path / "rl_model_replay_buffer_32_steps.pkl").is_file() and (folder / "notes.txt").read_text() == "kept"


def test_without_the_flag_or_a_replay_buffer_no_buffer_is_saved(tmp_path) -> None:
    _irlplus().learn(32, callback=AtomicCheckpointCallback(16, str(tmp_path / "off"), save_training_state=True))
    assert (tmp_path / "off" / "rl_model_32_steps.zip").is_file() and not _buffer_files(tmp_path / "off")
    on_policy = PPOLagrangian("MlpPolicy", make_env(), n_steps=16, batch_size=16, policy_kwargs={"net_arch": [16]}, seed=0)
    on_policy.learn(32, callback=AtomicCheckpointCallback(16, str(tmp_path / "on"), save_replay_buffer=True))
    assert (tmp_path / "on" / "rl_model_32_steps.zip").is_file() and not _buffer_files(tmp_path / "on")


def test_loading_a_replay_buffer_checks_the_file(tmp_path) -> None:
    model = _irlplus()
    model.learn(24)
    path = tmp_path / "buffer.pkl"
    model.save_replay_buffer(path)
    other = _irlplus()
    empty = other.replay_buffer
    assert not load_replay_buffer(other, str(tmp_path / "missing.pkl")) and other.replay_buffer is empty
    assert load_replay_buffer(other, str(path))
    _assert_same_buffer(other.replay_buffer, model.replay_buffer)
    assert other.replay_buffer.cost_info_key is None  # the learned cost is computed on batches, never stored

    path.write_bytes(path.read_bytes()[:500])  # cut short
    fresh = _irlplus()
    with pytest.raises(ValueError, match=r"The replay buffer .*buffer\.pkl cannot be read .*delete it to continue"):
        load_replay_buffer(fresh, str(path))
    assert fresh.replay_buffer.size() == 0
    # SAC's buffer stores no costs: refused, and the model keeps its own
    sac = SAC("MlpPolicy", make_env(), learning_starts=4, buffer_size=100, policy_kwargs={"net_arch": [8]})
    sac.learn(8)
    sac.save_replay_buffer(tmp_path / "sac.pkl")
    kept = other.replay_buffer
    with pytest.raises(TypeError, match="needs a CostReplayBuffer"):
        other.load_replay_buffer(tmp_path / "sac.pkl")
    assert other.replay_buffer is kept
    with pytest.raises(ValueError, match=r"sac\.pkl cannot be read \(TypeError"):
        load_replay_buffer(other, str(tmp_path / "sac.pkl"))
    assert other.replay_buffer is kept


def test_a_loaded_buffer_stores_costs_as_the_model_asks(tmp_path) -> None:
    """The cost function is not saved: a buffer saved while it stored the env's costs stores none under one."""
    sac_kwargs: dict[str, Any] = {"learning_starts": 4, "buffer_size": 100, "policy_kwargs": {"net_arch": [8]}}
    env_costs = SACLagrangian("MlpPolicy", make_env(), **sac_kwargs)
    env_costs.learn(8)
    env_costs.save_replay_buffer(tmp_path / "buffer.pkl")
    assert env_costs.replay_buffer.cost_info_key == "cost" and env_costs.replay_buffer.costs[:8].max() > 0
    learned = SACLagrangian("MlpPolicy", make_env(), cost_fn=_zero_cost, budget_statistic="critic", **sac_kwargs)
    learned.load_replay_buffer(tmp_path / "buffer.pkl")
    assert learned.replay_buffer.cost_info_key is None
    np.testing.assert_array_equal(learned.replay_buffer.costs, env_costs.replay_buffer.costs)


def _zero_cost(observations: np.ndarray, actions: np.ndarray) -> np.ndarray:
    return np.zeros(len(observations))


# ---------------------------------------------------------------------------------------------------- resuming


def _rng_states(model: IRLPlus) -> dict[str, Any]:
    """Every random stream an off-policy learner draws from, which no checkpoint saves."""
    return {
        "torch": th.get_rng_state(),
        "numpy": np.random.get_state(),
        "python": random.getstate(),
        "action_space": model.action_space.np_random.bit_generator.state,
    }


def _set_rng_states(model: IRLPlus, states: dict[str, Any]) -> None:
    th.set_rng_state(states["torch"])
    np.random.set_state(states["numpy"])
    random.setstate(states["python"])
    model.action_space.np_random.bit_generator.state = states["action_space"]


class _Interrupted(AtomicCheckpointCallback):
    """Checkpoints; at ``stop`` steps also keeps the random streams and a copy of the buffer (which the next
    checkpoint removes), as a run killed right after that checkpoint would have left them."""

    def __init__(self, stop: int, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.stop = stop
        self.rng_states: dict[str, Any] = {}

    def _on_rollout_start(self) -> None:
        super()._on_rollout_start()
        if self.num_timesteps == self.stop == self._last_saved and not self.rng_states:
            self.rng_states = _rng_states(self.model)
            path = self._checkpoint_path("replay_buffer_", extension="pkl")
            shutil.copy(path, path + ".kept")


def test_a_resumed_irlplus_run_with_its_buffer_and_random_streams_matches_the_uninterrupted_one(tmp_path) -> None:
    """
    The model zip, the training state and the replay buffer hold everything an IRL-Plus run needs: resumed at an
    episode boundary with the random streams it had, it ends with the uninterrupted run's weights, bit for bit.
    (``train.py`` draws fresh streams from the seed and starts a fresh episode instead: see docs/guide/benchmark.md.)
    """
    uninterrupted = _irlplus()
    callback = _Interrupted(64, 32, str(tmp_path), save_replay_buffer=True, save_training_state=True)
    uninterrupted.learn(128, callback=callback)  # 16 episodes; constraint updates and policy resets on the way
    assert uninterrupted.n_constraint_updates >= 4

    checkpoint = str(tmp_path / "rl_model_64_steps.zip")
    resumed = IRLPlus.load(checkpoint, env=make_env(), demonstrations=line_demonstrations(), device="cpu")
    assert load_training_state(resumed, training_state_path(checkpoint, "Line"), None)
    assert load_replay_buffer(resumed, str(tmp_path / "rl_model_replay_buffer_64_steps.pkl.kept"))
    assert resumed.replay_buffer.pos == 64
    _set_rng_states(resumed, callback.rng_states)
    resumed.learn(64, reset_num_timesteps=False)

    assert resumed.num_timesteps == uninterrupted.num_timesteps == 128
    _assert_same_buffer(resumed.replay_buffer, uninterrupted.replay_buffer)
    for name in ("policy", "constraint_net"):
        mine, theirs = getattr(resumed, name).state_dict(), getattr(uninterrupted, name).state_dict()
        assert mine.keys() == theirs.keys()
        assert all(th.equal(mine[key], theirs[key]) for key in theirs), name
    assert resumed.log_ent_coef.item() == uninterrupted.log_ent_coef.item()


#: IRL-Plus on the biased pendulum (100-step episodes, shipped demonstrations), checkpoints every 100 steps
PENDULUM = ["--algo", "irlplus", "--env", "BiasedPendulum-v0", "--save-freq", "100", "--eval-freq", "-1", "--seed", "1"]
PENDULUM += ["--verbose", "0"]
#: Its tiny recipe (-i keeps the zip's instead)
TINY = ["-params", "warmup_timesteps:0", "update_every:100", "learning_starts:50", "batch_size:16", "buffer_size:1000"]
TINY += ["n_nominal_trajectories:1", "policy_kwargs:dict(net_arch=[16])"]
TINY += ["constraint_net_kwargs:dict(hidden_sizes=[8], normalize_input=False)"]


def _interrupt(run: pathlib.Path) -> None:
    """What a run killed after its last checkpoint leaves: no final model, not finished."""
    for path in (run / "BiasedPendulum-v0.zip", run / "finished.json"):
        path.unlink(missing_ok=True)


def test_train_resume_and_i_restore_the_replay_buffer(tmp_path, capsys) -> None:
    args = [*PENDULUM, *TINY, "-f", str(tmp_path), "-n", "350"]
    assert main([*args, "--exp-id", "1"]) == 0
    run = tmp_path / "irlplus" / "BiasedPendulum-v0_1"
    # Checkpoints at 100, 200 and 300 steps; the run ends at 350, between two
    assert sorted(path.name for path in run.glob("rl_model_*0_steps.zip")) == [
        f"rl_model_{n}_steps.zip" for n in (100, 200, 300)
    ]
    assert _buffer_files(run) == ["rl_model_replay_buffer_300_steps.pkl"]
    assert not list((run / "BiasedPendulum-v0").glob("*replay*"))  # the final model is saved without its buffer
    saved = _read_buffer(run / "rl_model_replay_buffer_300_steps.pkl")
    assert saved.pos == 300 and not saved.full

    # The model -i starts from, built by the command line's own set-up
    checkpoint = str(run / "rl_model_300_steps.zip")
    probe = get_parser().parse_args([*PENDULUM, "-f", str(tmp_path), "-i", checkpoint])
    env_id = resolve_env_id(probe.env)
    params = preprocess_hyperparams(load_hyperparams("irlplus", env_id, probe.hyperparams)[0])
    model, callbacks = _setup(probe, env_id, params, algo_kwargs(params), str(tmp_path / "probe"))
    assert model.replay_buffer.size() == 0
    _go_on(probe, model, callbacks, "BiasedPendulum-v0", resuming=False)
    _assert_same_buffer(model.replay_buffer, saved)

    # --resume after a kill: from the 300-step checkpoint, with its buffer, no warning
    _interrupt(run)
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*replay buffer")
        assert main([*args, "--exp-id", "1", "--resume"]) == 0
    assert (run / "finished.json").is_file()

    # -i branches from the checkpoint: the new run's buffer begins with the checkpoint's transitions
    assert main([*PENDULUM, "-f", str(tmp_path), "-n", "100", "-i", checkpoint, "--new-folder"]) == 0
    branch = tmp_path / "irlplus" / "BiasedPendulum-v0_2"
    assert _buffer_files(branch) == ["rl_model_replay_buffer_400_steps.pkl"]
    continued = _read_buffer(branch / "rl_model_replay_buffer_400_steps.pkl")
    assert continued.pos == 400
    _assert_same_buffer(continued, saved, n=300)
    # The final model of a run that ended on a checkpoint goes on with that checkpoint's buffer
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*replay buffer")
        assert main([*PENDULUM, "-f", str(tmp_path), "-n", "100", "-i", str(branch / "BiasedPendulum-v0.zip")]) == 0
    assert _buffer_files(branch) == ["rl_model_replay_buffer_500_steps.pkl"]
    _assert_same_buffer(_read_buffer(branch / "rl_model_replay_buffer_500_steps.pkl"), continued, n=400)

    # A damaged buffer stops the resume, naming the file and what to do
    buffer_file = run / "rl_model_replay_buffer_300_steps.pkl"
    buffer_file.write_bytes(buffer_file.read_bytes()[:2000])
    _interrupt(run)
    capsys.readouterr()
    assert main([*args, "--exp-id", "1", "--resume"]) == 2
    error = capsys.readouterr().err
    assert f"The replay buffer {buffer_file} cannot be read" in error and "delete it to continue" in error
    # Deleted (or an older checkpoint's, removed): the run goes on with an empty buffer, and says so
    buffer_file.unlink()
    with pytest.warns(UserWarning, match=r"No replay buffer with .*rl_model_300_steps\.zip .*empty replay buffer"):
        assert main([*args, "--exp-id", "1", "--resume"]) == 0
    assert (run / "finished.json").is_file()


def test_a_resumed_run_short_of_learning_starts_waits_for_its_buffer_to_refill(tmp_path, monkeypatch) -> None:
    """
    SB3 compares learning_starts with the total steps: resumed at 200 steps with an empty buffer, it would update at
    once on the few transitions collected since. The resumed run waits until the buffer holds learning_starts (100)
    transitions again, acting with its policy meanwhile; one resumed with its buffer updates at once, as it did.
    """
    recipe = [*TINY[:3], "learning_starts:100", *TINY[4:]]
    args = [*PENDULUM, *recipe, "--exp-id", "1", "-n", "400"]
    # A run killed after its 200-step checkpoint (its buffers kept, to resume from there with one)
    with monkeypatch.context() as keep_buffers:
        keep_buffers.setattr(AtomicCheckpointCallback, "_remove_other_replay_buffers", lambda self, keep: None)
        assert main([*args, "-f", str(tmp_path / "a")]) == 0
    run = tmp_path / "a" / "irlplus" / "BiasedPendulum-v0_1"
    _interrupt(run)
    for path in [*run.glob("rl_model_*300_steps.*"), *run.glob("rl_model_*400_steps.*")]:
        path.unlink()
    assert _buffer_files(run) == ["rl_model_replay_buffer_100_steps.pkl", "rl_model_replay_buffer_200_steps.pkl"]
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    (tmp_path / "b" / "irlplus" / "BiasedPendulum-v0_1" / "rl_model_replay_buffer_200_steps.pkl").unlink()

    updates: list[int] = []  # the step count at each gradient update
    random_actions: list[int] = []  # SB3's warm-up draws them: none after a resume
    train, sample_action = IRLPlus.train, IRLPlus._sample_action

    def recording_train(model: IRLPlus, *call: Any, **kwargs: Any) -> None:
        updates.append(model.num_timesteps)
        train(model, *call, **kwargs)

    def recording_sample(model: IRLPlus, learning_starts: int, *call: Any, **kwargs: Any) -> Any:
        if model.num_timesteps < learning_starts:
            random_actions.append(model.num_timesteps)
        return sample_action(model, learning_starts, *call, **kwargs)

    monkeypatch.setattr(IRLPlus, "train", recording_train)
    monkeypatch.setattr(IRLPlus, "_sample_action", recording_sample)
    assert main([*args, "-f", str(tmp_path / "a"), "--resume"]) == 0
    assert updates[0] == 201 and len(updates) == 200 and not random_actions

    updates.clear()
    with pytest.warns(UserWarning, match=r"wait until it holds learning_starts \(100\) transitions again \(after step 300\)"):
        assert main([*args, "-f", str(tmp_path / "b"), "--resume"]) == 0
    assert updates[0] == 301 and len(updates) == 100 and not random_actions
    # The wait is not saved: the checkpoints and the final model keep the recipe's gradient_steps and learning_starts
    resumed = tmp_path / "b" / "irlplus" / "BiasedPendulum-v0_1"
    for path in (resumed / "rl_model_300_steps.zip", resumed / "BiasedPendulum-v0.zip"):
        saved = IRLPlus.load(path, device="cpu")
        assert (saved.gradient_steps, saved.learning_starts) == (1, 100), path


def test_a_resume_counts_the_restored_transitions_of_every_env(tmp_path, capsys) -> None:
    # Two envs: each buffer row holds two transitions, and the line says how many transitions came back
    args = [*PENDULUM[:-1], "1", *TINY, "n_envs:2", "-f", str(tmp_path), "-n", "500", "--exp-id", "1"]
    assert main(args) == 0
    run = tmp_path / "irlplus" / "BiasedPendulum-v0_1"
    (buffer_file,) = _buffer_files(run)
    rows = _read_buffer(run / buffer_file).pos
    assert rows > 0
    _interrupt(run)
    capsys.readouterr()
    assert main([*args, "--resume"]) == 0
    assert f"({2 * rows} transitions)" in capsys.readouterr().out
