"""Small helpers shared by the package, its benchmarks and its scripts."""

import io
import json
import os
import pathlib
import pickle
import tempfile
from typing import Any


def atomic_write_bytes(path: str | pathlib.Path, data: bytes, mode: int = 0o644) -> None:
    """
    Write ``data`` to ``path`` through a temporary file in the same folder and an atomic rename, so that readers
    never see a half-written file and a failed write leaves the old file intact.

    :param path: Destination file (its folder is created if needed)
    :param data: The bytes to write
    :param mode: File permissions (temporary files are created private, 0600; results are meant to be shared)
    """
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    file_descriptor, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(file_descriptor, "wb") as file:
            file.write(data)
            file.flush()
            # On disk before the rename: after a power cut the name holds the old file or the whole new one
            os.fsync(file.fileno())
        os.chmod(temporary, mode)
        os.replace(temporary, path)
    except BaseException:
        os.unlink(temporary)
        raise


def atomic_write_json(path: str | pathlib.Path, data: Any, **json_kwargs: Any) -> None:
    """
    Write ``data`` as JSON to ``path`` atomically (see :func:`atomic_write_bytes`).

    :param path: Destination file
    :param data: JSON-serialisable data
    :param json_kwargs: Passed to ``json.dumps`` (e.g. ``indent=2``)
    """
    atomic_write_bytes(path, json.dumps(data, **json_kwargs).encode())


def atomic_save_model(model: Any, path: str | pathlib.Path) -> str:
    """
    ``model.save(path)`` for an SB3 model, atomically: a run killed while saving keeps the previous file or none,
    never a truncated zip under the model's name.

    :param model: An SB3 algorithm
    :param path: Destination (``.zip`` is added when missing, as SB3 does)
    :return: The path written
    """
    path = str(path)
    if not path.endswith(".zip"):
        path += ".zip"
    buffer = io.BytesIO()
    model.save(buffer)
    atomic_write_bytes(path, buffer.getvalue())
    return path


def atomic_save_pickle(obj: Any, path: str | pathlib.Path) -> None:
    """
    Pickle ``obj`` to ``path`` atomically (e.g. ``VecNormalize`` statistics, which ``VecNormalize.load`` reads back).

    :param obj: A picklable object
    :param path: Destination file
    """
    atomic_write_bytes(path, pickle.dumps(obj))
