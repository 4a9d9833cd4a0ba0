"""
Bad inputs at the edges, each with a clear error that names the bad file or option: damaged model zips and
checkpoints, output folders that cannot be written, ``MODULE:EnvId`` mistakes, partial run folders, importer data
with NaNs, suite mistakes caught before any run.
"""

import importlib
import json
import pathlib
import re
import shutil
import zipfile
from typing import Any

import pytest
from test_bad_inputs import TRAIN_TINY, CLIError, run_cli

from sb3_icrl.run_folder import FINISHED_FILE, latest_checkpoint

train_module = importlib.import_module("sb3_icrl.zoo.train")
enjoy_module = importlib.import_module("sb3_icrl.zoo.enjoy")
compare_module = importlib.import_module("sb3_icrl.zoo.compare")
data_cli = importlib.import_module("sb3_icrl.data.__main__")

ENV = "GridWorldWall-v0"
#: How each damaged copy of a model zip is made, and the words the error uses for it
DAMAGES = {
    "truncated": "is cut short or damaged",
    "empty": "is empty (0 bytes)",
    "broken-tensor": "is damaged (RuntimeError",
    "broken-json": "is damaged (JSONDecodeError",
    "broken-pickle": "is damaged (UnpicklingError",
}


def damage(source: pathlib.Path, target: pathlib.Path, how: str) -> None:
    """Write a damaged copy of the model zip ``source`` to ``target``, as ``how`` (a key of :data:`DAMAGES`) says."""
    content = source.read_bytes()
    if how == "truncated":
        target.write_bytes(content[: len(content) // 2])
        return
    if how == "empty":
        target.write_bytes(b"")
        return
    with zipfile.ZipFile(source) as original:
        entries = {info.filename: original.read(info.filename) for info in original.infolist()}
    if how == "broken-tensor":
        entries["policy.pth"] = entries["policy.pth"][:100]
    elif how == "broken-json":
        entries["data"] = b"{not json"
    else:  # a cloudpickled value cut short inside valid JSON
        data = json.loads(entries["data"])
        blob = data["observation_space"][":serialized:"]
        data["observation_space"][":serialized:"] = blob[: len(blob) // 8 * 4]
        entries["data"] = json.dumps(data).encode()
    target.unlink(missing_ok=True)
    with zipfile.ZipFile(target, "w") as archive:
        for name, value in entries.items():
            archive.writestr(name, value)


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    """A finished tiny PPO-Lagrangian run with checkpoints at 16 and 32 steps."""
    root = tmp_path_factory.mktemp("edges")
    argv = ["--algo", "ppolag", "--env", ENV, "-n", "32", "--seed", "0", "-f", str(root), "--save-freq", "16"]
    run_cli(train_module.main, argv + TRAIN_TINY)
    return root / "ppolag" / f"{ENV}_1"


def _copy(run: pathlib.Path, tmp_path: pathlib.Path) -> pathlib.Path:
    copy = tmp_path / "ppolag" / f"{ENV}_1"
    shutil.copytree(run, copy)
    return copy


# -------------------------------------------------------------------- damaged models and checkpoints


@pytest.mark.parametrize("how", DAMAGES)
def test_a_damaged_model_is_named_by_every_command(run: pathlib.Path, tmp_path: pathlib.Path, how: str) -> None:
    copy = _copy(run, tmp_path)
    model = copy / f"{ENV}.zip"
    damage(run / f"{ENV}.zip", model, how)
    expected = f"{model}' {DAMAGES[how]}"
    with pytest.raises(CLIError, match="trained agent") as raised:
        argv = ["--algo", "ppolag", "--env", ENV, "-n", "16", "-i", str(model), "--new-folder", "-f", str(tmp_path)]
        run_cli(train_module.main, argv)
    assert expected in str(raised.value)
    with pytest.raises(CLIError) as raised:
        run_cli(enjoy_module.main, ["--algo", "ppolag", "--env", ENV, "--run", str(copy), "--no-render", "-n", "10"])
    assert expected in str(raised.value)
    with pytest.raises(CLIError) as raised:
        run_cli(compare_module.main, [str(copy), "-n", "50"])
    assert expected in str(raised.value)
    with pytest.raises(CLIError) as raised:
        run_cli(data_cli.main, ["generate", "--run", str(copy), "--n", "1", "--out", str(tmp_path / "demos.npz")])
    assert f"The expert {model} {DAMAGES[how]}" in str(raised.value)


@pytest.mark.parametrize("how", DAMAGES)
def test_resume_falls_back_past_a_damaged_checkpoint_and_names_it(run: pathlib.Path, tmp_path: pathlib.Path, how: str) -> None:
    copy = _copy(run, tmp_path)
    (copy / FINISHED_FILE).unlink()
    (copy / f"{ENV}.zip").unlink()
    latest = copy / "rl_model_32_steps.zip"
    damage(run / latest.name, latest, how)
    with pytest.warns(UserWarning, match=re.escape(f"{latest} {DAMAGES[how]}") + ".*resuming from an earlier checkpoint"):
        assert latest_checkpoint(str(copy)) == str(copy / "rl_model_16_steps.zip")
    argv = ["--algo", "ppolag", "--env", ENV, "-n", "32", "--seed", "0", "-f", str(tmp_path), "--exp-id", "1", "--resume"]
    with pytest.warns(UserWarning, match="resuming from an earlier checkpoint"):
        run_cli(train_module.main, [*argv, "--save-freq", "16", *TRAIN_TINY])
    finished: dict[str, Any] = json.loads((copy / FINISHED_FILE).read_text())
    assert finished["resumed_from"] == str(copy / "rl_model_16_steps.zip") and finished["num_timesteps"] == 32


def test_resume_without_a_loadable_checkpoint_says_it_starts_afresh(run: pathlib.Path, tmp_path: pathlib.Path) -> None:
    copy = _copy(run, tmp_path)
    (copy / FINISHED_FILE).unlink()
    for steps in (16, 32):
        damage(run / f"rl_model_{steps}_steps.zip", copy / f"rl_model_{steps}_steps.zip", "truncated")
    argv = ["--algo", "ppolag", "--env", ENV, "-n", "32", "--seed", "0", "-f", str(tmp_path), "--exp-id", "1", "--resume"]
    with pytest.warns(UserWarning) as caught:
        run_cli(train_module.main, [*argv, *TRAIN_TINY])
    messages = [str(warning.message) for warning in caught]
    first = "rl_model_16_steps.zip is cut short or damaged (it has no `data` entry): no earlier checkpoint"
    assert any(first in message for message in messages)
    assert any(
        "No checkpoint of" in message
        and "can be loaded (rl_model_32_steps.zip, rl_model_16_steps.zip): the run starts afresh" in message
        for message in messages
    )
    assert json.loads((copy / FINISHED_FILE).read_text())["resumed_from"] is None
