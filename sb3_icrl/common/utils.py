"""Small helpers shared by the package, its benchmarks and its scripts."""

import json
import os
import tempfile
from typing import Any


def atomic_write_json(path: str, data: Any, **json_kwargs: Any) -> None:
    """
    Write ``data`` as JSON to ``path`` through a temporary file in the same folder and an atomic rename,
    so that readers never see a half-written file.

    :param path: Destination file
    :param data: JSON-serialisable data
    :param json_kwargs: Passed to ``json.dump`` (e.g. ``indent=2``)
    """
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    with tempfile.NamedTemporaryFile("w", dir=directory, delete=False, suffix=".tmp") as handle:
        try:
            json.dump(data, handle, **json_kwargs)
        except BaseException:
            os.unlink(handle.name)
            raise
    os.replace(handle.name, path)
