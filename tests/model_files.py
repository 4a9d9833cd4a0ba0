"""Stand-in model files for tests of the benchmark engine, which reads a run folder's files without loading them."""

import zipfile


def write_whole_zip(path: str) -> None:
    """
    Write a model zip that reads as whole: the engine checks only that a model's zip is complete, not what it holds.

    :param path: Where to write it
    """
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("data", "{}")
