"""Small helpers shared by the package, its benchmarks and its scripts."""

import contextlib
import difflib
import errno
import fcntl
import io
import json
import os
import pathlib
import pickle
import re
import signal
import tempfile
import threading
import zipfile
from collections.abc import Callable, Iterator, Mapping
from typing import IO, Any, cast

import numpy as np
import yaml


def did_you_mean(value: str, choices: list[str]) -> str:
    """
    :param value: A name as typed
    :param choices: The names it may mean
    :return: `` Did you mean 'NAME'?`` with the closest of ``choices``, or ``""`` when none is close
    """
    close = difflib.get_close_matches(value, choices, n=1)
    return f" Did you mean {close[0]!r}?" if close else ""


def atomic_write(path: str | pathlib.Path, write: Callable[[IO[bytes]], Any], mode: int = 0o644) -> None:
    """
    Write ``path`` through a temporary file in the same folder and an atomic rename, so that readers never see a
    half-written file and a failed write leaves the old file intact. Every file the library writes goes through here.

    :param path: Destination file (its folder is created if needed)
    :param write: Called with the temporary file, opened in binary mode, to write the content
    :param mode: File permissions (temporary files are created private, 0600; results are meant to be shared)
    """
    path = pathlib.Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # The name remove_temporaries looks for
        file_descriptor, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as error:
        raise _naming(error, path) from error
    try:
        with os.fdopen(file_descriptor, "wb") as file:
            write(file)
            file.flush()
            # On disk before the rename: after a power cut the name holds the old file or the whole new one
            os.fsync(file.fileno())
        os.chmod(temporary, mode)
        os.replace(temporary, path)
    except BaseException as error:
        os.unlink(temporary)
        if isinstance(error, OSError):
            raise _naming(error, path) from error
        raise
    _fsync_folder(path.parent)


def _naming(error: OSError, path: pathlib.Path) -> OSError:
    """``error`` naming the file that was to be written (not the temporary one, or none: a full disk names no file)."""
    return OSError(error.errno, error.strerror or str(error), str(path))


#: Where Linux lists the file locks held on this machine
PROC_LOCKS = "/proc/locks"
#: The errors of a write that the user fixes by freeing space or by writing elsewhere
WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EFBIG}


def write_error_message(error: OSError) -> str | None:
    """
    One line saying which file could not be written and what to do, for the command lines.

    :param error: An error raised while writing (by :func:`atomic_write`, which names the file)
    :return: The line, or ``None`` when ``error`` is not of a write that the user can fix
    """
    if error.errno not in WRITE_ERRNOS:
        return None
    where = f"cannot write {error.filename}" if error.filename else "cannot write"
    if error.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
        return f"{where}: {error.strerror}; free some space there, or write elsewhere."
    return f"{where}: {error.strerror}; pass a folder you can write to."


def check_writable_folder(path: str, option: str) -> None:
    """
    Fail clearly unless ``path`` is, or can be made, a folder this process can write to.

    :param path: The folder
    :param option: The command-line option that named it (for the message)
    :raises ValueError: When it is a file, cannot be created or is not writable
    """
    if os.path.exists(path) and not os.path.isdir(path):
        raise ValueError(f"{option} {path!r} is a file, not a folder: pass a folder.")
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as error:
        raise ValueError(f"{option} {path!r} cannot be created ({error.strerror or error}): pass a writable folder.") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise ValueError(f"{option} {path!r} is not writable: pass a writable folder.")


def remove_temporaries(folder: str | pathlib.Path) -> list[str]:
    """
    Delete the temporary files that writes cut short by a kill left in ``folder`` and its sub-folders
    (``.<name>.<random>.tmp``, see :func:`atomic_write`). Call it only while no other process writes there.

    :param folder: A folder (nothing happens when it does not exist)
    :return: The paths removed
    """
    removed = []
    for path in sorted(pathlib.Path(folder).rglob(".*.tmp")):
        if path.is_file():
            path.unlink()
            removed.append(str(path))
    return removed


def _fsync_folder(folder: pathlib.Path) -> None:
    # The rename itself on disk too (POSIX); folders cannot be opened this way on Windows
    try:
        descriptor = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(descriptor)
    except OSError:
        pass
    finally:
        os.close(descriptor)


def atomic_write_bytes(path: str | pathlib.Path, data: bytes, mode: int = 0o644) -> None:
    """
    Write ``data`` to ``path`` atomically (see :func:`atomic_write`).

    :param path: Destination file (its folder is created if needed)
    :param data: The bytes to write
    :param mode: File permissions
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise TypeError(f"atomic_write_bytes writes bytes, got {type(data).__name__}: use atomic_write_text for text.")
    atomic_write(path, lambda file: file.write(data), mode=mode)


def atomic_write_text(path: str | pathlib.Path, text: str, append: bool = False) -> None:
    """
    Write ``text`` (UTF-8) to ``path`` atomically (see :func:`atomic_write`).

    :param path: Destination file
    :param text: The text
    :param append: Keep the file's current content and add ``text`` after it (a small log such as ``command.txt``)
    """
    path = pathlib.Path(path)
    data = text.encode()
    if append and path.is_file():
        data = path.read_bytes() + data
    atomic_write_bytes(path, data)


def atomic_write_yaml(path: str | pathlib.Path, data: Any) -> None:
    """
    Write ``data`` as YAML (``yaml.safe_dump``) to ``path`` atomically.

    :param path: Destination file
    :param data: Plain data (dicts, lists, strings, numbers)
    """
    atomic_write_text(path, yaml.safe_dump(data))


def read_npz(path: str | pathlib.Path) -> dict[str, np.ndarray]:
    """
    Every array of an ``.npz`` file (no pickles).

    :param path: The file
    :return: Its arrays, by name
    :raises ValueError: When it is cut short or not an ``.npz`` at all (naming the file; numpy's own error does not)
    """
    try:
        with np.load(path) as data:
            return {key: np.asarray(data[key]) for key in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
        if isinstance(error, FileNotFoundError):
            raise
        raise ValueError(f"{path} cannot be read ({type(error).__name__}: {error}): it is cut short or damaged.") from error


def check_evaluation_rows(arrays: Mapping[str, np.ndarray], path: str | os.PathLike) -> None:
    """
    Refuse an evaluation history (``evaluations.npz``, ``model_selection.npz``) that train.py did not write.

    :param arrays: The arrays of the file (``{}``: none)
    :param path: The file, for the message
    :raises ValueError: Unless it has ``timesteps`` and one row per evaluation in every array (another npz file)
    """
    if not arrays:
        return
    if "timesteps" not in arrays:
        raise ValueError(f"{path} holds no 'timesteps' array (keys: {sorted(arrays)}): it was not written by train.py.")
    n_eval = len(np.atleast_1d(arrays["timesteps"]))
    ragged = sorted(key for key, value in arrays.items() if len(np.atleast_1d(value)) != n_eval)
    if ragged:
        raise ValueError(f"{path} has {n_eval} timesteps, but not as many rows in {ragged}: it was not written by train.py.")


def atomic_save_npz(path: str | pathlib.Path, arrays: Mapping[str, Any], compressed: bool = False) -> str:
    """
    ``np.savez`` (or ``np.savez_compressed``) atomically.

    :param path: Destination (``.npz`` is added when missing, as numpy does)
    :param arrays: The arrays, by name
    :param compressed: Compress the arrays
    :return: The path written
    """
    path = str(path)
    if not path.endswith(".npz"):
        path += ".npz"
    save = np.savez_compressed if compressed else np.savez
    atomic_write(path, lambda file: save(file, **arrays))
    return path


def held_lock_inodes(proc_locks: str = PROC_LOCKS) -> set[int] | None:
    """
    The inodes of the files that some process holds a lock on, read from ``/proc/locks``; reading it takes no lock,
    so a process taking one of those locks at that moment never finds it taken because of this look.

    :param proc_locks: The lock table (Linux)
    :return: The inodes, or ``None`` where the table cannot be read (not Linux)
    """
    try:
        with open(proc_locks) as file:
            lines = file.readlines()
    except OSError:
        return None
    inodes = set()
    for line in lines:
        fields = line.split()
        # "1: FLOCK  ADVISORY  WRITE 1234 00:2f:5678 0 EOF": the sixth field is major:minor:inode
        if len(fields) >= 6 and fields[1] == "FLOCK" and fields[5].count(":") == 2:
            inode = fields[5].rsplit(":", 1)[1]
            if inode.isdigit():
                inodes.add(int(inode))
    return inodes


def lock_held(path: str | pathlib.Path, locked_inodes: set[int] | None) -> bool:
    """
    Whether the lock table shows a lock on ``path``. The table names inodes only, and a file of another file system may
    share the number: where that matters, confirm by trying the lock.

    :param path: A lock file of :func:`file_lock`
    :param locked_inodes: :func:`held_lock_inodes`
    :return: ``True`` when the table holds the file's inode; ``False`` when it does not, when the table could not be
        read, or when the file cannot be looked at (missing, ...)
    """
    if locked_inodes is None:
        return False
    try:
        return os.stat(path).st_ino in locked_inodes
    except OSError:
        return False


@contextlib.contextmanager
def file_lock(path: str | pathlib.Path, blocking: bool = False) -> Iterator[bool]:
    """
    An exclusive advisory lock on ``path`` (created if missing), held for the ``with`` block; released when the
    process ends, however it ends.

    :param path: The lock file
    :param blocking: Wait for another process to release it, instead of giving up at once
    :return: Whether the lock was taken (``False`` only when not blocking and another process holds it)
    """
    with open(path, "a") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX if blocking else fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            yield False
            return
        try:
            yield True
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


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
    # SB3 writes its zip to a buffer first: a model that fails to serialise leaves no file at all
    buffer = io.BytesIO()
    model.save(buffer)
    atomic_write_bytes(path, buffer.getvalue())
    return path


def atomic_save_replay_buffer(model: Any, path: str | pathlib.Path) -> None:
    """
    ``model.save_replay_buffer(path)`` for an SB3 off-policy model, atomically: SB3's own pickle (highest protocol,
    for buffers over 4 GB), which ``model.load_replay_buffer`` reads back.

    :param model: An SB3 off-policy algorithm with a replay buffer
    :param path: Destination file
    """
    # SB3 writes to an open binary file as it does to a path
    atomic_write(path, lambda file: model.save_replay_buffer(cast(io.BufferedIOBase, file)))


def atomic_save_pickle(obj: Any, path: str | pathlib.Path) -> None:
    """
    Pickle ``obj`` to ``path`` atomically (e.g. ``VecNormalize`` statistics, which ``VecNormalize.load`` reads back).

    :param obj: A picklable object
    :param path: Destination file
    """
    atomic_write(path, lambda file: pickle.dump(obj, file))


#: A Sphinx cross-reference: ``:role:`~module.Name``` or ``:role:`text <target>```
_SPHINX_ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|data|attr|obj|exc|ref|doc):`(~?)([^`<]*?)(?:\s*<[^>]*>)?`")


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")


@contextlib.contextmanager
def sigterm_interrupts() -> Iterator[None]:
    """
    Inside the block, SIGTERM stops the program as a Ctrl-C does (``KeyboardInterrupt``): a run saves its model and
    ends. ``kill PID``, a job scheduler's time limit and the benchmark engine's stop send it; SIGINT cannot serve for
    them, since a shell starts background commands (``nohup ... &``) with SIGINT ignored. Outside the main thread
    (where Python cannot set handlers) the block changes nothing. The previous handler comes back after the block.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def plain_docstring(text: str | None) -> str:
    """
    A module docstring as a command's ``--help`` shows it: Sphinx roles reduced to their names (``~a.b.Name`` to
    ``Name``, ``a.b.name`` kept whole), double backquotes to single ones.

    :param text: The docstring
    :return: Plain text
    """

    def name(match: re.Match) -> str:
        target = match.group(2).strip()
        return target.rsplit(".", 1)[-1] if match.group(1) else target

    return _SPHINX_ROLE.sub(name, text or "").replace("``", "`")
