"""Import the repository's stand-alone scripts (``benchmarks/*.py``, ``examples/*.py``) as modules in tests."""

import importlib.util
import pathlib
from types import ModuleType

ROOT = pathlib.Path(__file__).resolve().parents[1]


def load_script(relative_path: str, module_name: str | None = None) -> ModuleType:
    """
    Import a script of the repository by its path, without running its ``__main__`` block.

    :param relative_path: The script's path from the repository root, e.g. ``benchmarks/readme_table.py``
    :param module_name: The module's name (default: the file's stem)
    :return: The imported module
    """
    path = ROOT / relative_path
    spec = importlib.util.spec_from_file_location(module_name or path.stem, path)
    assert spec is not None and spec.loader is not None, f"cannot import {path}"
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
