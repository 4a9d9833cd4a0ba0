"""Small helpers shared by the package, its benchmarks and its scripts."""

import json
import os
import pathlib
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
