"""`benchmark pack` / `unpack`: runs carried between machines in size-capped bundles, resumed or reported there."""

import json
import os
import tarfile
import textwrap

import pytest
from model_files import write_whole_zip

from sb3_icrl.benchmark import load_suite
from sb3_icrl.benchmark.cli import main as benchmark_main
from sb3_icrl.benchmark.runner import run_lock
from sb3_icrl.benchmark.status import suite_status
from sb3_icrl.benchmark.transport import MANIFEST, pack_runs, packed_files, unpack_bundles
from sb3_icrl.common.utils import held_lock_inodes
from sb3_icrl.zoo.runs import FINISHED_FILE

SUITE = """\
description: four runs to carry
envs: [GridWorldWall-v0]
algos: [bc2l]
seeds: [0, 1, 2, 3]
steps: 1000
"""


def _checkpoint(folder: str, steps: int) -> None:
    write_whole_zip(os.path.join(folder, f"rl_model_{steps}_steps.zip"))
    for kind in ("vecnormalize", "training_state"):
        with open(os.path.join(folder, f"rl_model_{kind}_{steps}_steps.pkl"), "wb") as file:
            file.write(b"\x80\x04N.")  # pickle of None: it reads


@pytest.fixture
def carried(tmp_path):
    """Seed 0 finished (two checkpoints kept), seed 1 interrupted at 200 (a checkpoint at 100 too), seed 2 started with
    no checkpoint, seed 3 never started; each started run with its output log, the variant with a transfer reference."""
    path = tmp_path / "carry.yml"
    path.write_text(textwrap.dedent(SUITE))
    suite = load_suite(str(path))
    root = str(tmp_path / "here")
    runs = suite.runs()
    folders = [run.run_folder(root) for run in runs]
    for run, folder in zip(runs[:3], folders[:3], strict=True):
        os.makedirs(os.path.join(folder, "GridWorldWall-v0"))
        with open(os.path.join(folder, "command.txt"), "w") as file:
            file.write("python train.py\n")
        os.makedirs(os.path.dirname(run.log_file(root)), exist_ok=True)
        with open(run.log_file(root), "w") as file:
            file.write(f"log of seed {run.seed}\n")
    with open(os.path.join(folders[0], FINISHED_FILE), "w") as file:
        json.dump({"num_timesteps": 1000, "wall_time_total_s": 10.0}, file)
    write_whole_zip(os.path.join(folders[0], "GridWorldWall-v0.zip"))
    with open(os.path.join(folders[0], "GridWorldWall-v0", "config.yml"), "w") as file:
        file.write("n_timesteps: 1000\n")
    for steps in (100, 200):
        _checkpoint(folders[0], steps)
        _checkpoint(folders[1], steps)
    references = os.path.join(runs[0].log_folder(root), "transfer_references")
    os.makedirs(references)
    with open(os.path.join(references, "oracle_GridWorldWall-v0_0123.json"), "w") as file:
        json.dump({"result": {"feasible_reward": 1.0}}, file)
    return suite, root, runs, folders


def _archive_names(pack: str, member_prefix: str) -> list[str]:
    """The file names inside the run archive whose bundle member starts with ``member_prefix`` (not split)."""
    for name in sorted(os.listdir(pack)):
        if name.endswith(".tar"):
            with tarfile.open(os.path.join(pack, name)) as bundle:
                for info in bundle.getmembers():
                    if info.name.startswith(member_prefix):
                        extracted = bundle.extractfile(info)
                        assert extracted is not None
                        with tarfile.open(fileobj=extracted, mode="r:gz") as archive:
                            return sorted(archive.getnames())
    raise AssertionError(f"no member {member_prefix} in {pack}")


def test_a_finished_run_travels_without_checkpoints_an_interrupted_one_with_the_one_it_resumes_from(carried):
    _, _, _, folders = carried
    state, steps, files = packed_files(folders[0])
    assert (state, steps) == ("finished", None)
    assert not [name for name in files if name.startswith("rl_model_")]
    assert {"finished.json", "GridWorldWall-v0.zip", "command.txt", os.path.join("GridWorldWall-v0", "config.yml")} <= set(
        files
    )
    state, steps, files = packed_files(folders[1])
    assert (state, steps) == ("interrupted", 200)
    assert [name for name in files if name.startswith("rl_model_")] == [
        "rl_model_200_steps.zip",
        "rl_model_training_state_200_steps.pkl",
        "rl_model_vecnormalize_200_steps.pkl",
    ]
    assert packed_files(folders[2]) == ("empty", None, [])
    assert len([name for name in packed_files(folders[0], all_checkpoints=True)[2] if name.startswith("rl_model_")]) == 6


def test_unpacked_runs_are_the_packed_ones_and_resume_from_their_checkpoint(carried, tmp_path):
    _, root, runs, folders = carried
    pack = str(tmp_path / "pack")
    lines: list[str] = []
    manifest = pack_runs(runs, root, pack, max_bytes=2**20, log=lines.append)
    assert [run["folder"] for run in manifest["runs"]] == [
        os.path.relpath(folders[0], root),
        os.path.relpath(folders[1], root),
        "transfer_references",
    ]
    assert list(manifest["skipped"]) == [os.path.relpath(folders[2], root)]  # nothing to carry; seed 3 has no folder
    assert "no checkpoint to resume from" in manifest["skipped"][os.path.relpath(folders[2], root)]
    # The archive names are relative to the log root, the output log beside the run folder
    names = _archive_names(pack, "carry__base__bc2l__GridWorldWall-v0_1")
    assert os.path.join("carry", "logs", "base_bc2l_GridWorldWall-v0_1.log") in names
    assert os.path.join("carry", "base", "bc2l", "GridWorldWall-v0_1", "rl_model_200_steps.zip") in names

    there = str(tmp_path / "there")
    written = unpack_bundles([pack], there, log=lines.append)
    assert written == [folders[0].replace(root, there), folders[1].replace(root, there)]
    for folder in folders[:2]:
        for relative in packed_files(folder)[2]:
            with open(os.path.join(folder, relative), "rb") as here_file, open(
                os.path.join(folder.replace(root, there), relative), "rb"
            ) as there_file:
                assert here_file.read() == there_file.read()
    with open(runs[1].log_file(there)) as file:
        assert file.read() == "log of seed 1\n"
    assert os.path.isfile(os.path.join(runs[0].log_folder(there), "transfer_references", "oracle_GridWorldWall-v0_0123.json"))
    states = {status.run.seed: (status.state, status.steps_done) for status in suite_status(runs, there)}
    assert states[0][0] == "finished"
    assert states[1] == ("interrupted", 200)
    assert states[2][0] == states[3][0] == "not started"
    assert any("resumes it from 200 steps" in line for line in lines)


def test_a_run_larger_than_the_cap_is_split_and_unpacks_only_with_every_part(carried, tmp_path):
    _, root, runs, folders = carried
    with open(os.path.join(folders[1], "GridWorldWall-v0", "replay.bin"), "wb") as file:
        file.write(os.urandom(3 * 2**20))  # does not compress
    pack = str(tmp_path / "pack")
    manifest = pack_runs(runs[:2], root, pack, max_bytes=2**20, log=lambda line: None)
    big = manifest["runs"][1]
    assert len(big["parts"]) >= 3
    bundles = sorted(name for name in os.listdir(pack) if name.endswith(".tar"))
    assert all(os.path.getsize(os.path.join(pack, name)) <= 2**20 for name in bundles)

    # Without one of its bundles the run is left out (and named), the others unpack
    missing = big["parts"][-1][0]
    given = [os.path.join(pack, name) for name in bundles if name != missing] + [os.path.join(pack, MANIFEST)]
    lines: list[str] = []
    there = str(tmp_path / "there")
    written = unpack_bundles(given, there, log=lines.append)
    assert folders[1].replace(root, there) not in written
    assert not os.path.exists(folders[1].replace(root, there))
    assert any("not unpacked" in line and missing in line for line in lines)
    # The missing bundle may come in another folder (a later transfer)
    later = tmp_path / "later"
    later.mkdir()
    os.replace(os.path.join(pack, missing), later / missing)
    assert folders[1].replace(root, there) in unpack_bundles([pack, str(later)], there, log=lambda line: None)
    with open(os.path.join(folders[1], "GridWorldWall-v0", "replay.bin"), "rb") as file:
        original = file.read()
    with open(os.path.join(folders[1].replace(root, there), "GridWorldWall-v0", "replay.bin"), "rb") as file:
        assert file.read() == original


def test_unpack_refuses_parts_that_do_not_match_the_manifest(carried, tmp_path):
    _, root, runs, folders = carried
    pack = str(tmp_path / "pack")
    pack_runs(runs[:2], root, pack, max_bytes=2**20, log=lambda line: None)
    manifest_path = os.path.join(pack, MANIFEST)
    with open(manifest_path) as file:
        manifest = json.load(file)
    manifest["runs"][0]["sha256"] = "0" * 64
    with open(manifest_path, "w") as file:
        json.dump(manifest, file)
    with pytest.raises(ValueError, match="do not match the manifest's SHA-256"):
        unpack_bundles([pack], str(tmp_path / "there"), log=lambda line: None)
    assert not os.path.exists(folders[0].replace(root, str(tmp_path / "there")))
    with pytest.raises(ValueError, match=f"exactly one {MANIFEST}"):
        unpack_bundles([os.path.join(pack, "bundle-001.tar")], str(tmp_path / "there"))


def test_unpack_keeps_a_run_already_here_unless_told_to_replace_it(carried, tmp_path):
    _, root, runs, folders = carried
    pack = str(tmp_path / "pack")
    pack_runs(runs[:2], root, pack, max_bytes=2**20, log=lambda line: None)
    there = str(tmp_path / "there")
    here_already = folders[1].replace(root, there)
    os.makedirs(here_already)
    with open(os.path.join(here_already, "mine.txt"), "w") as file:
        file.write("trained here")
    lines: list[str] = []
    assert folders[1].replace(root, there) not in unpack_bundles([pack], there, log=lines.append)
    assert os.path.isfile(os.path.join(here_already, "mine.txt"))
    assert any(line.startswith(f"kept: {here_already}") for line in lines)
    assert folders[1].replace(root, there) in unpack_bundles([pack], there, replace=True, log=lines.append)
    assert not os.path.exists(os.path.join(here_already, "mine.txt"))
    assert os.path.isfile(os.path.join(here_already, "rl_model_200_steps.zip"))


@pytest.mark.skipif(held_lock_inodes() is None, reason="no readable /proc/locks")
def test_a_run_being_trained_is_not_packed(carried, tmp_path):
    _, root, runs, folders = carried
    with run_lock(folders[1]) as taken:
        assert taken
        manifest = pack_runs(runs[:2], root, str(tmp_path / "pack"), max_bytes=2**20, log=lambda line: None)
    assert [run["folder"] for run in manifest["runs"]] == [os.path.relpath(folders[0], root), "transfer_references"]
    assert "being trained" in manifest["skipped"][os.path.relpath(folders[1], root)]


def test_pack_and_unpack_from_the_command_line(carried, tmp_path, capsys):
    _, root, _, folders = carried
    pack = str(tmp_path / "pack")
    suite_file = str(tmp_path / "carry.yml")
    assert benchmark_main(["pack", suite_file, "-f", root, "-o", pack, "--only", "seed=1", "--max-mib", "1"]) == 0
    assert "1 runs (0 finished, 1 interrupted) in 1 bundle(s)" in capsys.readouterr().out
    # A second pack into the same folder would mix two manifests' bundles
    assert benchmark_main(["pack", suite_file, "-f", root, "-o", pack]) == 2
    assert "holds an earlier pack" in capsys.readouterr().err
    assert benchmark_main(["pack", suite_file, "-f", root, "-o", str(tmp_path / "other"), "--max-mib", "0.5"]) == 2
    assert "at least 1 MiB" in capsys.readouterr().err
    there = str(tmp_path / "there")
    assert benchmark_main(["unpack", pack, "-f", there]) == 0
    assert os.path.isfile(os.path.join(folders[1].replace(root, there), "rl_model_200_steps.zip"))
    assert benchmark_main(["unpack", str(tmp_path / "nowhere"), "-f", there]) == 2
    assert "does not exist" in capsys.readouterr().err
