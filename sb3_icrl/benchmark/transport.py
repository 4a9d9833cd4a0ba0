"""
Moving a suite's runs between machines that share no file system (a lent machine, a cluster node without a shared
disk): ``pack`` writes the selected runs' folders into tarballs of a capped size with a manifest; ``unpack`` puts them
under another log root, where ``benchmark run`` resumes the interrupted ones and ``benchmark report`` reads the finished
ones.

A finished run travels without its checkpoints (the report reads its final and best models), an interrupted one with
the checkpoint it resumes from only; its output log and the suite's transfer references go with it. Each run is one
``.tgz`` (split into numbered parts when larger than the cap), stored in ``bundle-<k>.tar`` files of at most the cap
each, so that a transfer limited in file size and count can carry them a few at a time. ``manifest.json`` names each
run's parts and their SHA-256, which ``unpack`` checks before it writes anything.
"""

import dataclasses
import hashlib
import io
import json
import os
import re
import shutil
import tarfile
import tempfile
import time
from collections.abc import Callable, Sequence
from typing import Any

from sb3_icrl.benchmark.runner import run_lock_held
from sb3_icrl.benchmark.suite import RunSpec
from sb3_icrl.common.utils import atomic_write_bytes, atomic_write_json
from sb3_icrl.metrics.transfer import REFERENCES_FOLDER
from sb3_icrl.run_folder import FINISHED_FILE, latest_checkpoint

#: The manifest ``pack`` writes beside its bundles
MANIFEST = "manifest.json"
#: Version of the manifest's layout
PACK_FORMAT = 1
#: A checkpoint file of a run folder: the model, its normalisation statistics, its training state, a replay buffer
CHECKPOINT_FILE = re.compile(r"^rl_model_(?:[a-z_]+_)?(?P<steps>\d+)_steps\.(?:zip|pkl)$")
#: Bytes a tar file adds: per member a header block and the padding of its data to a block; per file the end blocks
#: and the padding of the whole to a record (tarfile's 10 KiB)
_MEMBER_OVERHEAD = 2 * tarfile.BLOCKSIZE
_BUNDLE_OVERHEAD = 2 * tarfile.RECORDSIZE


@dataclasses.dataclass
class PackedRun:
    """
    One run in a pack.

    :param folder: The run folder relative to the log root (``<suite>/<variant>/<algo>/<EnvName>_<seed>``)
    :param state: ``"finished"`` or ``"interrupted"``
    :param steps: The steps it resumes from (interrupted), else ``None``
    :param sha256: Of the whole run archive
    :param size: Bytes of the whole run archive
    :param parts: ``[bundle file, member name]`` of each part, in order
    """

    folder: str
    state: str
    steps: int | None
    sha256: str
    size: int
    parts: list[list[str]]


def packed_files(run_folder: str, all_checkpoints: bool = False) -> tuple[str, int | None, list[str]]:
    """
    The files of a run folder worth carrying to another machine.

    :param run_folder: The run folder
    :param all_checkpoints: Carry every checkpoint, not only the one an interrupted run resumes from
    :return: ``(state, steps, files)``: ``"finished"`` (with ``finished.json``), ``"interrupted"`` (with a checkpoint it
        resumes from, whose steps are ``steps``) or ``"empty"`` (nothing to carry); the files relative to the folder
    """
    resume_steps = None
    if os.path.isfile(os.path.join(run_folder, FINISHED_FILE)):
        state = "finished"
    else:
        checkpoint = latest_checkpoint(run_folder, warn=False)
        if checkpoint is None:
            return "empty", None, []
        state = "interrupted"
        match = CHECKPOINT_FILE.match(os.path.basename(checkpoint))
        assert match is not None  # latest_checkpoint returns a checkpoint's path
        resume_steps = int(match["steps"])
    files = []
    for folder, _, names in os.walk(run_folder):
        for name in names:
            relative = os.path.relpath(os.path.join(folder, name), run_folder)
            match = CHECKPOINT_FILE.match(name) if folder == run_folder else None
            if match and not all_checkpoints and int(match["steps"]) != resume_steps:
                continue
            if name.endswith(".tmp") and name.startswith("."):  # an atomic write under way or cut short
                continue
            files.append(relative)
    return state, resume_steps, sorted(files)


def _run_archive(run: RunSpec, root: str, files: list[str]) -> bytes:
    """The run's files and its output log as a ``.tgz``, their names relative to the log root."""
    paths = [os.path.join(run.run_folder(root), relative) for relative in files]
    log_file = run.log_file(root)
    return _tgz([*paths, log_file] if os.path.isfile(log_file) else paths, root)


def _tgz(paths: list[str], root: str) -> bytes:
    """The files ``paths`` as a ``.tgz``, each named by its path relative to ``root``."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz") as archive:
        for path in paths:
            archive.add(path, arcname=os.path.relpath(path, root), recursive=False)
    return buffer.getvalue()


def _references_archive(runs: Sequence[RunSpec], root: str) -> bytes | None:
    """The saved transfer references of the runs' variants (small JSON files), as a ``.tgz``; ``None`` when none."""
    found = []
    for folder in sorted({os.path.join(run.log_folder(root), REFERENCES_FOLDER) for run in runs}):
        if os.path.isdir(folder):
            found += [os.path.join(folder, name) for name in sorted(os.listdir(folder)) if name.endswith(".json")]
    return _tgz(found, root) if found else None


def pack_runs(
    runs: Sequence[RunSpec],
    root: str,
    output: str,
    max_bytes: int,
    all_checkpoints: bool = False,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """
    Write the runs that have something to carry into ``bundle-<k>.tar`` files of at most ``max_bytes`` each, and the
    manifest.

    :param runs: The selected runs
    :param root: The log root they train under (``-f``)
    :param output: Folder for the bundles and ``manifest.json`` (created; it must hold no earlier pack)
    :param max_bytes: Largest bundle; a run archive larger than this is split into parts
    :param all_checkpoints: Carry every checkpoint (see :func:`packed_files`)
    :param log: Where progress lines go
    :return: The manifest written
    :raises ValueError: On a cap too small to be useful, or an output folder that holds an earlier pack
    """
    if max_bytes < 2**20:
        raise ValueError(f"--max-mib must allow at least 1 MiB per bundle, got {max_bytes / 2**20:g} MiB.")
    if os.path.exists(os.path.join(output, MANIFEST)):
        raise ValueError(f"{output} holds an earlier pack ({MANIFEST}): pick an empty -o folder.")
    archives: list[tuple[str, bytes, str, int | None]] = []
    skipped: dict[str, str] = {}
    for run in runs:
        folder = run.run_folder(root)
        relative = os.path.relpath(folder, root)
        if not os.path.isdir(folder):
            continue
        if run_lock_held(folder):
            skipped[relative] = "being trained: pack it once it stops"
            continue
        state, steps, files = packed_files(folder, all_checkpoints)
        if state == "empty":
            skipped[relative] = "no checkpoint to resume from and not finished: nothing to carry"
            continue
        archives.append((relative, _run_archive(run, root, files), state, steps))
    references = _references_archive(runs, root)
    if references is not None:
        archives.append((REFERENCES_FOLDER, references, "references", None))
    # Parts that fit a bundle with the tar format's own bytes, then first-fit in decreasing size: few bundles, each
    # under the cap
    part_bytes = max_bytes - _BUNDLE_OVERHEAD - _MEMBER_OVERHEAD
    pieces: list[tuple[str, str, bytes]] = []
    for relative, data, _, _ in archives:
        chunks = [data[start : start + part_bytes] for start in range(0, len(data), part_bytes)] or [b""]
        for index, chunk in enumerate(chunks):
            member = _member_name(relative) + (f".part{index + 1:03d}-of-{len(chunks):03d}" if len(chunks) > 1 else "")
            pieces.append((relative, member, chunk))
    bundles: list[list[tuple[str, bytes]]] = []
    sizes: list[int] = []
    where: dict[str, list[list[str]]] = {}
    for relative, member, chunk in sorted(pieces, key=lambda piece: -len(piece[2])):
        cost = len(chunk) + _MEMBER_OVERHEAD
        fitting = next((k for k, size in enumerate(sizes) if size + cost <= max_bytes), None)
        if fitting is None:
            bundles.append([])
            sizes.append(_BUNDLE_OVERHEAD)
        index = len(bundles) - 1 if fitting is None else fitting
        bundles[index].append((member, chunk))
        sizes[index] += cost
        where.setdefault(relative, []).append([f"bundle-{index + 1:03d}.tar", member])
    os.makedirs(output, exist_ok=True)
    for index, members in enumerate(bundles):
        buffer = io.BytesIO()
        with tarfile.open(fileobj=buffer, mode="w") as bundle:
            for member, chunk in members:
                info = tarfile.TarInfo(member)
                info.size = len(chunk)
                info.mtime = int(time.time())
                bundle.addfile(info, io.BytesIO(chunk))
        atomic_write_bytes(os.path.join(output, f"bundle-{index + 1:03d}.tar"), buffer.getvalue())
    packed = [
        PackedRun(
            folder=relative,
            state=state,
            steps=steps,
            sha256=hashlib.sha256(data).hexdigest(),
            size=len(data),
            parts=sorted(where[relative], key=lambda part: part[1]),
        )
        for relative, data, state, steps in archives
    ]
    manifest = {
        "format": PACK_FORMAT,
        "root": os.path.abspath(root),
        "runs": [dataclasses.asdict(entry) for entry in packed],
        "skipped": skipped,
    }
    atomic_write_json(os.path.join(output, MANIFEST), manifest, indent=2)
    for entry in packed:
        bundles_of = sorted({part[0] for part in entry.parts})
        steps_text = f" at {entry.steps:,} steps" if entry.steps is not None else ""
        log(f"packed {entry.folder} ({entry.state}{steps_text}, {entry.size / 2**20:.1f} MiB) in {', '.join(bundles_of)}")
    for relative, reason in skipped.items():
        log(f"not packed: {relative}: {reason}")
    log(f"wrote {len(bundles)} bundle(s) of at most {max_bytes / 2**20:g} MiB and {MANIFEST} to {output}")
    return manifest


def _member_name(relative: str) -> str:
    """A bundle member's name for a run archive: the relative folder with its separators as ``__``."""
    return relative.replace(os.sep, "__").replace("/", "__") + ".tgz"


def unpack_bundles(paths: Sequence[str], root: str, replace: bool = False, log: Callable[[str], None] = print) -> list[str]:
    """
    Put the packed runs whose parts are all among ``paths`` under the log root ``root``.

    :param paths: ``manifest.json`` and the bundles, or folders holding them (the bundles may come in several
        folders: those of earlier transfers)
    :param root: The log root here (``-f``)
    :param replace: Replace a run folder that is already here (it is kept otherwise)
    :param log: Where progress lines go
    :return: The run folders written
    :raises ValueError: Without a manifest, on a part that does not match it, on a run being trained here
    """
    files = []
    for path in paths:
        if os.path.isdir(path):
            files += [os.path.join(path, name) for name in sorted(os.listdir(path))]
        elif os.path.isfile(path):
            files.append(path)
        else:
            raise ValueError(f"{path} does not exist: pass the manifest and the bundles `benchmark pack` wrote.")
    manifests = [path for path in files if os.path.basename(path) == MANIFEST]
    if len(manifests) != 1:
        found = "none" if not manifests else ", ".join(manifests)
        raise ValueError(f"unpack needs exactly one {MANIFEST} among its paths (found {found}): pass the pack's own.")
    with open(manifests[0]) as file:
        manifest = json.load(file)
    if manifest.get("format") != PACK_FORMAT:
        raise ValueError(f"{manifests[0]} is of pack format {manifest.get('format')!r}; this version reads {PACK_FORMAT}.")
    members: dict[str, bytes] = {}
    for path in files:
        if path.endswith(".tar") and tarfile.is_tarfile(path):
            with tarfile.open(path) as bundle:
                for info in bundle.getmembers():
                    extracted = bundle.extractfile(info)
                    if extracted is not None:
                        members[info.name] = extracted.read()
    written = []
    for entry in manifest["runs"]:
        folder = entry["folder"]
        missing = sorted({bundle for bundle, member in entry["parts"] if member not in members})
        if missing:
            log(f"not unpacked: {folder}: its parts are in {', '.join(missing)}, not given")
            continue
        data = b"".join(members[member] for _, member in entry["parts"])
        if hashlib.sha256(data).hexdigest() != entry["sha256"]:
            raise ValueError(f"{folder}: its parts do not match the manifest's SHA-256 (a damaged copy): bring them again.")
        if entry["state"] == "references":
            _extract(data, root, os.path.join(root, folder), merge=True)
            log(f"transfer references added under {root}")
            continue
        target = os.path.join(root, folder)
        if run_lock_held(target):
            raise ValueError(f"{target} is being trained here: stop its queue before unpacking a copy over it.")
        if os.path.exists(target) and not replace:
            log(f"kept: {target} is already here (--replace puts the packed copy in its place)")
            continue
        _extract(data, root, target, merge=False)
        written.append(target)
        resumes = f"; `benchmark run` resumes it from {entry['steps']:,} steps" if entry["state"] == "interrupted" else ""
        log(f"unpacked {target} ({entry['state']}{resumes})")
    return written


def _extract(data: bytes, root: str, target: str, merge: bool) -> None:
    """
    Extract a run archive into a temporary folder under ``root``, then move its files in place: the run folder as a
    whole (replacing one that is there), the others (the log, the references) one by one.
    """
    os.makedirs(root, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=root, prefix=".unpack-") as staging:
        with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as archive:
            archive.extractall(staging, filter="data")  # refuses absolute paths, links out of the folder, ..
        relative_target = os.path.relpath(target, root)
        staged_target = os.path.join(staging, relative_target)
        if not merge and os.path.isdir(staged_target):
            if os.path.exists(target):
                shutil.rmtree(target)
            os.makedirs(os.path.dirname(target), exist_ok=True)
            os.replace(staged_target, target)
        for folder, _, names in os.walk(staging):
            for name in names:
                source = os.path.join(folder, name)
                destination = os.path.join(root, os.path.relpath(source, staging))
                os.makedirs(os.path.dirname(destination), exist_ok=True)
                os.replace(source, destination)


def pack_summary(manifest: dict[str, Any]) -> str:
    """One line: how many runs were packed, finished and interrupted, in how many bundles."""
    runs = [run for run in manifest["runs"] if run["state"] != "references"]
    bundles = {part[0] for run in manifest["runs"] for part in run["parts"]}
    finished = sum(run["state"] == "finished" for run in runs)
    return f"{len(runs)} runs ({finished} finished, {len(runs) - finished} interrupted) in {len(bundles)} bundle(s)"


__all__ = ["MANIFEST", "PackedRun", "pack_runs", "pack_summary", "packed_files", "unpack_bundles"]
