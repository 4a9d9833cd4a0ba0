"""enjoy.py / sb3-icrl enjoy: run a trained agent of a zoo run folder and report its constraint metrics."""

import pathlib
import pickle
import shutil
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import VecNormalize

from sb3_icrl.common.envs import ConstrainedCorridorEnv
from sb3_icrl.common.evaluation import evaluate_constraint
from sb3_icrl.zoo import ALGOS
from sb3_icrl.zoo import enjoy as enjoy_module
from sb3_icrl.zoo.enjoy import get_parser
from sb3_icrl.zoo.enjoy import main as enjoy_main
from sb3_icrl.zoo.hyperparams import preprocess_hyperparams
from sb3_icrl.zoo.train import cli, create_env
from sb3_icrl.zoo.train import main as train_main

ROOT = pathlib.Path(__file__).resolve().parents[1]
ENV = "ConstrainedCorridor-v0"
TRAIN = ["-n", "256", "-params", "n_steps:128", "batch_size:32", "--eval-freq", "128", "--eval-episodes", "2", "--seed", "1"]
TRAIN += ["--save-freq", "128", "--verbose", "0"]


def corridor_factory(render_mode: str | None = None, **kwargs: object) -> gym.Env:
    """A user's env made by a function that takes ``render_mode`` and passes it on: no class metadata to read."""
    return ConstrainedCorridorEnv(render_mode=render_mode, **kwargs)  # type: ignore[arg-type]


def corridor_factory_without_rendering(safe_limit: int = 6) -> gym.Env:
    """A factory that takes no ``render_mode``: its env cannot be recorded."""
    return ConstrainedCorridorEnv(safe_limit=safe_limit)


FACTORY_ENVS = {"factory/Corridor-v0": corridor_factory, "factory/NoRendering-v0": corridor_factory_without_rendering}
for _env_id, _factory in FACTORY_ENVS.items():
    if _env_id not in gym.registry:
        gym.register(id=_env_id, entry_point=_factory, max_episode_steps=20)


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    """A normalised PPO-Lagrangian run on a corridor where every step right costs (safe_limit 0), and a BC2L grid run."""
    folder = tmp_path_factory.mktemp("logs")
    normalized = [*TRAIN[:5], "normalize:True", *TRAIN[5:]]  # -n 256 -params n_steps:128 batch_size:32 normalize:True
    args = ["--algo", "ppolag", "--env", ENV, *normalized, "-f", str(folder), "--env-kwargs", "safe_limit:0"]
    assert train_main(args) == 0
    assert train_main(["--algo", "bc2l", "--env", "GridWorldWall-v0", *TRAIN, "-f", str(folder)]) == 0
    return folder


def _enjoy(logs: pathlib.Path, *args: str) -> list[str]:
    return ["--algo", "ppolag", "--env", ENV, "-f", str(logs), "--no-render", *args]


def _reference(run: pathlib.Path, algo: str, env: str, zip_name: str, stats: str | None, seed: int, n_episodes: int):
    """evaluate_constraint on the same env (saved settings, frozen statistics), model and seeds as enjoy."""
    import yaml

    name = env.split("/")[-1]
    params = preprocess_hyperparams(yaml.safe_load((run / name / "config.yml").read_text()))
    env_kwargs = yaml.safe_load((run / name / "args.yml").read_text())["env_kwargs"] or {}
    venv, _ = create_env(f"sb3_icrl/{name}", params, 1, seed, env_kwargs, 0.0, None, eval_env=True, stats_path=stats)
    model = ALGOS[algo].load(run / zip_name, device="cpu")
    model.set_random_seed(seed)
    return evaluate_constraint(model, venv, n_eval_episodes=n_episodes, deterministic=False)


def test_reports_the_true_constraint_metrics(logs: pathlib.Path, monkeypatch, capsys) -> None:
    """Per-episode reward, true cost, violation and feasible reward, as evaluate_constraint measures them (VecNormalize)."""
    built: list = []
    monkeypatch.setattr(enjoy_module, "create_env", lambda *a, **k: built.append(create_env(*a, **k)) or built[-1])
    evaluation = enjoy_module.enjoy(get_parser().parse_args(_enjoy(logs, "-n", "60", "--stochastic", "--seed", "3")))
    out = capsys.readouterr().out
    run = logs / "ppolag" / f"{ENV}_1"
    assert f"Loaded {run / ENV}.zip with" in out and "vecnormalize.pkl" in out
    stats = str(run / ENV / "vecnormalize.pkl")
    with open(stats, "rb") as file:
        saved = pickle.load(file)
    normalize = built[0][0]  # the saved statistics, frozen: unchanged by the run
    assert isinstance(normalize, VecNormalize) and not normalize.training and not normalize.norm_reward
    np.testing.assert_array_equal(normalize.obs_rms.mean, saved.obs_rms.mean)
    assert normalize.obs_rms.count == saved.obs_rms.count
    reference = _reference(run, "ppolag", ENV, f"{ENV}.zip", stats, 3, 3)
    assert len(evaluation.violations) == 3  # 60 steps of 20-step episodes
    for field in ("episode_rewards", "episode_costs", "feasible_rewards", "violations", "episode_lengths"):
        np.testing.assert_allclose(getattr(evaluation, field), getattr(reference, field), err_msg=field)
    assert evaluation.episode_costs.sum() > 0 and evaluation.violations.any()  # the comparison saw costs
    first = evaluation
    assert (
        f"Episode 1: reward {first.episode_rewards[0]:.2f}, true cost {first.episode_costs[0]:.2f}, "
        f"violated {'yes' if first.violations[0] else 'no'}, feasible reward {first.feasible_rewards[0]:.2f} (20 steps)"
    ) in out
    assert f"3 episodes: violation rate {first.violation_rate:.2f}, feasible reward {first.mean_feasible_reward:.2f}" in out


def test_icrl_model_reports_the_true_cost_not_its_learned_one(logs: pathlib.Path, capsys) -> None:
    args = ["--algo", "bc2l", "--env", "GridWorldWall-v0", "-f", str(logs), "--no-render", "--stochastic", "--seed", "5"]
    evaluation = enjoy_module.enjoy(get_parser().parse_args([*args, "-n", "150"]))
    run = logs / "bc2l" / "GridWorldWall-v0_1"
    reference = _reference(run, "bc2l", "GridWorldWall-v0", "GridWorldWall-v0.zip", None, 5, len(evaluation.violations))
    assert len(evaluation.violations) >= 1
    np.testing.assert_allclose(evaluation.episode_costs, reference.episode_costs)
    assert set(np.unique(evaluation.episode_costs)) <= set(range(200))  # whole counts of true unit costs
    assert "episodes: violation rate" in capsys.readouterr().out


def test_model_choice_and_statistics(logs: pathlib.Path, capsys) -> None:
    run = logs / "ppolag" / f"{ENV}_1"
    assert enjoy_main(_enjoy(logs, "-n", "5", "--load-checkpoint", "128")) == 0
    out = capsys.readouterr().out
    assert f"Loaded {run / 'rl_model_128_steps.zip'} with {run.resolve() / 'rl_model_vecnormalize_128_steps.pkl'}" in out
    assert "No episode finished in 5 steps" in out
    assert enjoy_main(_enjoy(logs, "-n", "5", "--load-last-checkpoint", "--exp-id", "1")) == 0
    assert "rl_model_vecnormalize_256_steps.pkl" in capsys.readouterr().out
    # The best model runs with the statistics saved with it (the final ones scale observations differently)
    assert enjoy_main(_enjoy(logs, "-n", "5", "--load-best", "--deterministic")) == 0
    out = capsys.readouterr().out
    assert f"Loaded {run / 'best_model.zip'} with {run.resolve() / 'best_model_vecnormalize.pkl'}" in out


def test_a_best_model_saved_without_its_statistics_runs_with_the_final_ones_and_says_so(logs, tmp_path, capsys) -> None:
    folder = tmp_path / "logs"
    shutil.copytree(logs / "ppolag" / f"{ENV}_1", folder / "ppolag" / f"{ENV}_1")
    run = folder / "ppolag" / f"{ENV}_1"
    (run / "best_model_vecnormalize.pkl").unlink()  # a run from before they were saved with the best model
    with pytest.warns(UserWarning, match="best_model.zip has no normalisation statistics of its own"):
        assert enjoy_main(_enjoy(folder, "-n", "5", "--load-best")) == 0
    assert f"with {run.resolve() / ENV / 'vecnormalize.pkl'}" in capsys.readouterr().out


def test_latest_run_and_clear_errors(logs: pathlib.Path, tmp_path: pathlib.Path, capsys) -> None:
    folder = tmp_path / "logs"
    shutil.copytree(logs / "ppolag" / f"{ENV}_1", folder / "ppolag" / f"{ENV}_2")
    (folder / "ppolag" / f"{ENV}_2" / f"{ENV}.zip").unlink()
    cases = [
        ([], f"No {ENV}.zip in {folder / 'ppolag' / f'{ENV}_2'}; models there: best_model.zip"),  # --exp-id 0: the latest
        (["--exp-id", "7"], "No run folder"),
        (["--load-checkpoint", "100"], "rl_model_128_steps.zip, rl_model_256_steps.zip"),
    ]
    for args, message in cases:
        assert enjoy_main(_enjoy(folder, *args)) == 2
        assert message in capsys.readouterr().err
    assert enjoy_main(["--algo", "mecl", "--env", ENV, "-f", str(folder)]) == 2
    assert f"No mecl run of {ENV}" in capsys.readouterr().err
    (folder / "ppolag" / f"{ENV}_2" / ENV / "vecnormalize.pkl").unlink()
    (folder / "ppolag" / f"{ENV}_2" / "best_model_vecnormalize.pkl").unlink()
    assert enjoy_main(_enjoy(folder, "--load-best")) == 2
    assert "statistics (vecnormalize.pkl) are missing" in capsys.readouterr().err


@pytest.mark.parametrize("backend", ["pillow", "matplotlib"])
def test_record_without_moviepy(backend: str, logs: pathlib.Path, tmp_path: pathlib.Path, monkeypatch, capsys) -> None:
    """--record: a GIF (Pillow) or PNG frames (matplotlib) per episode of every rendered frame, in the run's videos folder."""
    from PIL import Image, ImageSequence

    shutil.copytree(logs / "ppolag", tmp_path / "ppolag")
    monkeypatch.setattr(enjoy_module, "recording_backend", lambda: backend)
    assert enjoy_main(_enjoy(tmp_path, "-n", "30", "--record", "--stochastic")) == 0
    out = capsys.readouterr().out
    assert "Recorded 31 frames, one file per episode" in out  # the reset frame and one per step
    videos = tmp_path / "ppolag" / f"{ENV}_1" / "videos"
    if backend == "pillow":
        gifs = sorted(videos.glob(f"ppolag-{ENV}-{ENV}-episode-*.gif"))
        # Pillow merges repeated frames into one longer frame: the durations still add up to 31 frames at 4 fps
        durations = [frame.info["duration"] for gif in gifs for frame in ImageSequence.Iterator(Image.open(gif))]
        assert len(gifs) >= 2 and sum(durations) == 31 * 250 and Image.open(gifs[0]).size == (176, 16)
    else:
        frames = sorted(videos.glob(f"ppolag-{ENV}-{ENV}-episode-*/frame_*.png"))
        assert len(frames) == 31 and np.asarray(Image.open(frames[0])).shape[:2] == (16, 176)
    assert len(list(videos.glob(".*"))) == 0  # no temporary file left


def test_record_errors(logs: pathlib.Path, monkeypatch, capsys) -> None:
    monkeypatch.setattr(enjoy_module, "recording_backend", lambda: None)
    assert enjoy_main(_enjoy(logs, "-n", "5", "--record")) == 2
    assert "--record needs imageio-ffmpeg (mp4), Pillow (GIF) or matplotlib (PNG frames)" in capsys.readouterr().err
    monkeypatch.setattr(enjoy_module, "render_modes", lambda env_id: ["ansi"])
    assert enjoy_main(_enjoy(logs, "-n", "5", "--record")) == 2
    assert "cannot render rgb_array frames" in capsys.readouterr().err


def test_record_an_env_made_by_a_factory_function(tmp_path: pathlib.Path, monkeypatch, capsys) -> None:
    """--record passes render_mode="rgb_array" through gym.make to a factory function, as to an env class."""
    monkeypatch.setattr(enjoy_module, "recording_backend", lambda: "matplotlib")
    for env_id in FACTORY_ENVS:
        train = ["--algo", "ppo", "--env", env_id, "-n", "64", "-params", "n_steps:64", "batch_size:32", "--eval-freq", "0"]
        assert train_main([*train, "-f", str(tmp_path), "--verbose", "0"]) == 0
    assert enjoy_main(["--algo", "ppo", "--env", "factory/Corridor-v0", "-f", str(tmp_path), "-n", "20", "--record"]) == 0
    assert "Recorded 21 frames, one file per episode" in capsys.readouterr().out
    frames = sorted((tmp_path / "ppo" / "factory-Corridor-v0_1" / "videos").glob("*/frame_*.png"))
    assert len(frames) == 21
    # A factory without a render_mode argument is refused before any env is made, and says why
    assert enjoy_main(["--algo", "ppo", "--env", "factory/NoRendering-v0", "-f", str(tmp_path), "--record"]) == 2
    assert "takes no render_mode" in capsys.readouterr().err


def test_record_mp4_with_moviepy(logs: pathlib.Path, tmp_path: pathlib.Path) -> None:
    pytest.importorskip("moviepy")
    shutil.copytree(logs / "ppolag", tmp_path / "ppolag")
    assert enjoy_main(_enjoy(tmp_path, "-n", "40", "--record")) == 0
    assert list((tmp_path / "ppolag" / f"{ENV}_1" / "videos").glob("*.mp4"))


def test_console_subcommand_and_root_script(logs: pathlib.Path, capsys) -> None:
    assert cli(["enjoy", *_enjoy(logs, "-n", "20")]) == 0
    assert "1 episodes: violation rate" in capsys.readouterr().out
    assert cli(["bogus"]) == 2 and "sb3-icrl enjoy" in capsys.readouterr().err
    command = [sys.executable, str(ROOT / "enjoy.py"), *_enjoy(logs, "-n", "20", "--verbose", "0")]
    result = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "1 episodes: violation rate" in result.stdout and "Episode 1" not in result.stdout
