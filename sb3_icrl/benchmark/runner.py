"""
Running a suite's runs: each is a ``train.py`` process with its output in a log file, on a local pool of processes or
as Ray tasks. A run that finished is skipped; an interrupted one resumes from its last checkpoint (``train.py
--resume``); a failing one is tried once more, then reported with the end of its log.
"""

import contextlib
import ctypes
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from typing import Any

import yaml

from sb3_icrl.benchmark.suite import RunSpec, result_current, run_complete
from sb3_icrl.common.utils import file_lock, held_lock_inodes, lock_held
from sb3_icrl.common.versions import versions
from sb3_icrl.metrics.transfer import DEFERRED_EXIT, LOG_COMMAND_PREFIX
from sb3_icrl.run_folder import FINISHED_FILE, is_finished

#: Attempts per run before it is listed as failed
MAX_ATTEMPTS = 2
#: Lines of a failed run's log shown in the summary
LOG_TAIL_LINES = 15
BACKENDS = ("local", "ray")
#: Seconds an interrupted engine gives its runs to stop on their own (a terminal's Ctrl-C reaches them too) before it
#: sends them SIGTERM, and then to save their models and end before it kills them
STOP_GRACE_S = 5.0
STOP_TIMEOUT_S = 60.0
#: The training processes of this engine that still run (see :func:`stop_runs`)
_RUNNING: set[subprocess.Popen] = set()
_RUNNING_LOCK = threading.Lock()
#: The git revision :func:`~sb3_icrl.zoo.train.versions` records outside a git checkout (then only versions are compared)
UNKNOWN_REVISION = "unknown"


class CodeMismatchError(RuntimeError):
    """A Ray worker runs another sb3-icrl than the driver that sent it the run."""


@dataclass
class RunOutcome:
    """
    What became of one run.

    :param run: The run
    :param status: ``"done"`` (trained now), ``"skipped"`` (had finished before), ``"busy"`` (another process holds
        it), ``"failed"``, ``"left"`` (not started: the time to start runs had passed), or, while the queue runs,
        ``"deferred"`` (trained, its transfer test waiting for references other runs train, see :func:`run_all`)
    :param attempts: How many times it was started
    :param seconds: Wall time of its last attempt
    :param log_tail: The end of its log, when it failed
    """

    run: RunSpec
    status: str
    attempts: int = 0
    seconds: float = 0.0
    log_tail: list[str] = field(default_factory=list)


def _die_with_parent() -> None:
    """In the child: get SIGKILL when the parent dies, so a killed suite leaves no orphaned runs behind (Linux)."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG


@contextlib.contextmanager
def run_lock(run_folder: str) -> Iterator[bool]:
    """
    An exclusive lock on a run folder (a ``.lock`` file beside it), so that two suites never train the same run.

    :param run_folder: The run folder
    :return: Whether the lock was taken (``False``: another process holds it)
    """
    os.makedirs(os.path.dirname(run_folder), exist_ok=True)
    with file_lock(run_folder + ".lock") as taken:
        if taken:  # when the attempt began: `benchmark status` tells a record of an earlier attempt by it
            os.utime(run_folder + ".lock")
        yield taken


def run_lock_held(run_folder: str) -> bool:
    """
    Whether another open file (another suite's, as a rule) holds :func:`run_lock` on a run folder. The lock table is
    read first, which takes no lock; only a lock it shows is confirmed by trying it (the table names inodes, and a file
    of another file system may share the number), so a run nobody holds is looked at without touching its lock.

    :param run_folder: The run folder
    :return: ``True`` when held; ``False`` when free, or where the lock table cannot be read (not Linux)
    """
    if not lock_held(run_folder + ".lock", held_lock_inodes()):
        return False
    with run_lock(run_folder) as taken:
        return not taken


def train_command(argv: Sequence[str]) -> list[str]:
    """The command line of a training run: ``sb3-icrl train`` with this Python and the arguments."""
    return [sys.executable, "-m", "sb3_icrl.zoo", "train", *argv]


def transfer_command(argv: Sequence[str]) -> list[str]:
    """The command line of a transfer test: ``sb3-icrl transfer`` with this Python and the arguments."""
    return [sys.executable, "-m", "sb3_icrl.metrics.transfer", *argv]


def execute_run(
    argv: Sequence[str],
    log_file: str,
    run_folder: str,
    transfers: Sequence[tuple[str, Sequence[str]]] = (),
    defer: bool = False,
) -> tuple[str, float]:
    """
    Train one run to its end (or find it finished), then run the transfer tests it lacks, the output of each appended
    to ``log_file``.

    :param argv: train.py arguments (with ``--exp-id`` and ``--resume``)
    :param log_file: The run's log
    :param run_folder: The run folder (for the lock and the finished check)
    :param transfers: ``(result file in the run folder, sb3-icrl transfer arguments)`` per transfer test
    :param defer: A transfer test whose missing references other runs are all training ends at once (``--no-wait``)
        rather than waiting for them: the run is then ``"deferred"``
    :return: ``(status, seconds)``: status ``"done"``, ``"skipped"`` (nothing left to do), ``"busy"``, ``"deferred"``
        or ``"failed"``
    """

    def complete() -> bool:
        return run_complete(run_folder, [file for file, _ in transfers])

    if complete():
        return "skipped", 0.0
    with run_lock(run_folder) as locked:
        if not locked:
            return "busy", 0.0
        if complete():
            return "skipped", 0.0
        os.makedirs(os.path.dirname(log_file), exist_ok=True)
        start = time.time()
        commands = [] if is_finished(run_folder) else [train_command(argv)]
        missing = [targv for file, targv in transfers if not result_current(run_folder, file)]
        commands += [transfer_command([*targv, "--no-wait"] if defer else targv) for targv in missing]
        deferred = False
        first_transfer = len(commands) - len(missing)
        for index, command in enumerate(commands):
            # Unbuffered: nothing is left to flush at close, where a full disk would fail again without the file's name
            with open(log_file, "ab", buffering=0) as log:
                try:
                    log.write(f"\n{LOG_COMMAND_PREFIX}{time.strftime('%Y-%m-%d %H:%M:%S')} {' '.join(command)}\n".encode())
                except OSError as error:  # a full disk: say which file, as the run's own writes do
                    raise OSError(error.errno, error.strerror, log_file) from error
                env = {**os.environ, "PYTHONUNBUFFERED": "1"}
                process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=env, preexec_fn=_die_with_parent)
                with _RUNNING_LOCK:
                    _RUNNING.add(process)
                try:
                    process.wait()
                finally:
                    with _RUNNING_LOCK:
                        _RUNNING.discard(process)
            if defer and index >= first_transfer and process.returncode == DEFERRED_EXIT:
                deferred = True  # its other transfer tests, whose references may be free, still run
                continue
            if process.returncode != 0 or not is_finished(run_folder):
                return "failed", time.time() - start
        if deferred:
            return "deferred", time.time() - start
        return ("done" if complete() else "failed"), time.time() - start


def stop_runs(grace_s: float = STOP_GRACE_S, timeout_s: float = STOP_TIMEOUT_S) -> None:
    """
    Stop the training processes this engine still runs, as a Ctrl-C at a terminal does. A SIGINT or SIGTERM sent to
    the engine alone (``kill``, a job scheduler) does not reach them: each that has not ended ``grace_s`` seconds later
    gets a SIGTERM (it saves its model and ends); one still running ``timeout_s`` seconds after that is killed. Each
    resumes from its last checkpoint on the next ``benchmark run``.

    :param grace_s: Seconds to wait for the runs to end on their own first
    :param timeout_s: Seconds to wait for each run to end after its SIGTERM
    """
    with _RUNNING_LOCK:
        processes = list(_RUNNING)
    deadline = time.monotonic() + grace_s
    for process in processes:
        with contextlib.suppress(subprocess.TimeoutExpired):
            process.wait(max(deadline - time.monotonic(), 0.0))
    for process in processes:
        if process.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                # Not SIGINT: runs started from a shell's background command (`nohup ... &`) ignore it
                process.send_signal(signal.SIGTERM)
    for process in processes:
        try:
            process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            process.kill()


def log_tail(log_file: str, lines: int = LOG_TAIL_LINES) -> list[str]:
    """The last ``lines`` lines of a log (empty when there is none)."""
    if not os.path.isfile(log_file):
        return []
    with open(log_file, errors="replace") as file:
        return [line.rstrip("\n") for line in file.readlines()[-lines:]]


def code_identity() -> dict[str, str]:
    """
    What identifies the sb3-icrl running here, to compare a Ray worker's with the driver's.

    :return: ``{"sb3_icrl": version, "git_revision": revision}`` (revision ``unknown`` outside a git checkout, with
        ``-dirty`` when the checkout has changes)
    """
    found = versions()
    return {"sb3_icrl": found["sb3_icrl"], "git_revision": found["git_revision"]}


def code_mismatch(driver: dict[str, str], worker: dict[str, str]) -> str | None:
    """
    :param driver: :func:`code_identity` on the machine that runs the suite
    :param worker: :func:`code_identity` on the node that would train the run
    :return: Why the worker must not train the run (another version, or another git revision when both know theirs),
        ``None`` when it runs the same code
    """
    driver_revision = driver.get("git_revision", UNKNOWN_REVISION)
    worker_revision = worker.get("git_revision", UNKNOWN_REVISION)
    if driver.get("sb3_icrl") != worker.get("sb3_icrl"):
        what = f"sb3-icrl {worker.get('sb3_icrl')}, the driver {driver.get('sb3_icrl')}"
    elif UNKNOWN_REVISION not in (driver_revision, worker_revision) and driver_revision != worker_revision:
        what = f"sb3-icrl at git revision {worker_revision}, the driver {driver_revision}"
    else:
        return None
    return (
        f"This Ray worker runs {what}: runs trained with other code would not be comparable. Install the same sb3-icrl "
        "on every node (or pass it with --runtime-env, e.g. working_dir of your clone) and run again."
    )


def execute_run_checked(
    driver: dict[str, str],
    argv: Sequence[str],
    log_file: str,
    run_folder: str,
    transfers: Sequence[tuple[str, Sequence[str]]] = (),
    defer: bool = False,
) -> tuple[str, float]:
    """
    :func:`execute_run` on a Ray worker, once it has checked that it runs the driver's sb3-icrl.

    :param driver: :func:`code_identity` of the driver
    :raises CodeMismatchError: When the worker runs other code (the run is not started)
    """
    mismatch = code_mismatch(driver, code_identity())
    if mismatch is not None:
        raise CodeMismatchError(mismatch)
    return execute_run(argv, log_file, run_folder, transfers, defer)


class Backend:
    """Starts runs and reports them as they end (``submit`` then ``wait_any``); at most ``capacity`` at a time."""

    capacity: int = 1
    #: The cluster the runs go to (``None``: this machine)
    address: str | None = None

    def submit(self, run: RunSpec, root: str, defer: bool = False) -> Any:
        """Start ``run`` (``defer``: see :func:`execute_run`); return a handle for ``wait_any`` and ``result``."""
        raise NotImplementedError

    def wait_any(self, pending: set[Any]) -> tuple[set[Any], set[Any]]:
        raise NotImplementedError

    def result(self, handle: Any) -> tuple[str, float]:
        raise NotImplementedError

    def stop(self) -> None:
        """Stop the runs under way (the engine was interrupted)."""

    def close(self) -> None:
        pass


class LocalBackend(Backend):
    """A pool of ``jobs`` concurrent training processes on this machine."""

    def __init__(self, jobs: int):
        self.capacity = jobs
        self.executor = ThreadPoolExecutor(max_workers=jobs)

    def submit(self, run: RunSpec, root: str, defer: bool = False) -> Future:
        return self.executor.submit(
            execute_run, run.train_argv(root), run.log_file(root), run.run_folder(root), run.transfer_jobs(root), defer
        )

    def wait_any(self, pending: set[Any]) -> tuple[set[Any], set[Any]]:
        done, not_done = wait(pending, timeout=1.0, return_when=FIRST_COMPLETED)
        return set(done), set(not_done)

    def result(self, handle: Any) -> tuple[str, float]:
        return handle.result()

    def stop(self) -> None:
        stop_runs()

    def close(self) -> None:
        self.executor.shutdown(wait=True, cancel_futures=True)


class RayBackend(Backend):
    """
    Each run a Ray task asking for one CPU, on the cluster at ``address`` or on a Ray instance started here with
    ``jobs`` CPUs. The run folders must be on storage every node sees.
    """

    def __init__(self, jobs: int, address: str | None = None, runtime_env: dict[str, Any] | None = None):
        try:
            import ray
        except ImportError as error:
            raise RuntimeError('The ray backend needs Ray: pip install "sb3-icrl[cluster]".') from error
        self.ray = ray
        #: The cluster's address (``None``: a Ray instance started here)
        self.address = address
        if ray.is_initialized() and runtime_env is not None:
            raise ValueError(
                "Ray is already started in this process, so --runtime-env cannot reach its workers: pass the runtime_env "
                "to your own ray.init(runtime_env=...) instead."
            )
        if not ray.is_initialized():
            # runtime_env=None is Ray's own default: no environment set up on the workers
            if address:
                ray.init(address=address, log_to_driver=False, runtime_env=runtime_env)
            else:
                ray.init(num_cpus=jobs, log_to_driver=False, include_dashboard=False, runtime_env=runtime_env)
        #: What each task checks its worker's sb3-icrl against
        self.driver_code = code_identity()
        self.task = ray.remote(num_cpus=1, max_retries=0)(execute_run_checked)
        # Ray queues tasks until a CPU is free: submit as many as the cluster has CPUs
        self.capacity = max(int(ray.cluster_resources().get("CPU", jobs)), 1)

    def submit(self, run: RunSpec, root: str, defer: bool = False) -> Any:
        root = os.path.abspath(root)
        return self.task.remote(  # type: ignore[call-arg]
            self.driver_code,
            run.train_argv(root),
            run.log_file(root),
            run.run_folder(root),
            run.transfer_jobs(root),
            defer,
        )

    def wait_any(self, pending: set[Any]) -> tuple[set[Any], set[Any]]:
        done, not_done = self.ray.wait(list(pending), num_returns=1, timeout=1.0)
        return set(done), set(not_done)

    def result(self, handle: Any) -> tuple[str, float]:
        try:
            return self.ray.get(handle)
        except CodeMismatchError as error:  # Ray's error is also one of these: keep its message, not the worker's traceback
            raise CodeMismatchError(str(getattr(error, "cause", error))) from None


def load_runtime_env(value: str | None) -> dict[str, Any] | None:
    """
    The Ray ``runtime_env`` of ``--runtime-env``.

    :param value: A JSON object (``'{"working_dir": "."}'``) or the path of a YAML file holding one; ``None``: none
    :return: The mapping passed to ``ray.init(runtime_env=...)``, ``None`` for none
    :raises ValueError: When it is neither, or not a mapping
    """
    if value is None:
        return None
    if os.path.isfile(value):
        with open(value) as file:
            try:
                runtime_env = yaml.safe_load(file)
            except yaml.YAMLError as error:
                raise ValueError(f"--runtime-env {value}: not a YAML file ({error}).") from error
    else:
        try:
            runtime_env = json.loads(value)
        except json.JSONDecodeError as error:
            raise ValueError(
                f"--runtime-env takes a JSON object or the path of a YAML file; {value!r} is neither (no such file, and "
                f'not JSON: {error}). Example: --runtime-env \'{{"working_dir": "."}}\'.'
            ) from error
    if not isinstance(runtime_env, dict):
        raise ValueError(
            f"--runtime-env must be a mapping (working_dir, pip, env_vars, ...), got {type(runtime_env).__name__}: {value!r}."
        )
    return runtime_env


def make_backend(
    backend: str, jobs: int | None, address: str | None = None, runtime_env: dict[str, Any] | None = None
) -> Backend:
    """
    :param backend: ``"local"`` or ``"ray"``
    :param jobs: Concurrent runs (local pool size; CPUs of a Ray instance started here); ``None``: one per core
    :param address: A running Ray cluster (``ray`` only; default ``$RAY_ADDRESS``, as ``ray job submit`` sets it)
    :param runtime_env: Ray's ``runtime_env`` for the workers (``ray`` only; see :func:`load_runtime_env`)
    """
    if jobs is not None and jobs < 1:
        raise ValueError(f"--jobs must be >= 1, got {jobs}.")
    if backend == "local":
        if address:
            raise ValueError("--address is for --backend ray.")
        if runtime_env is not None:
            raise ValueError("--runtime-env is for --backend ray.")
        return LocalBackend(jobs or os.cpu_count() or 1)
    if backend == "ray":
        address = address or os.environ.get("RAY_ADDRESS") or None
        if address and jobs is not None:
            raise ValueError(
                f"--jobs sets the CPUs of a Ray instance started here; on the cluster at {address} (--address or "
                "$RAY_ADDRESS) each run asks for one CPU and the cluster's CPUs decide how many run at once: drop --jobs."
            )
        return RayBackend(jobs or os.cpu_count() or 1, address, runtime_env)
    raise ValueError(f"Unknown backend {backend!r}: use one of {', '.join(BACKENDS)}.")


def unseen_run_message(run_folder: str) -> str:
    """Why a run a worker reports finished is not counted: the driver cannot read its folder's finished marker."""
    return (
        f"A worker reports this run finished, but here its folder {run_folder} lacks a readable {FINISHED_FILE} (or a "
        "transfer result): the workers write to storage this machine does not see. Put the log folder (-f) on storage "
        "every node mounts at the same path, then run again (finished runs are then found and skipped)."
    )


def _ended_run(backend: Backend, handle: Any, outcome: RunOutcome, root: str) -> tuple[str, bool]:
    """
    What became of a run the backend reports ended (its outcome's ``seconds`` and ``log_tail`` set here).

    :return: ``(status, whether a failure may be tried again)``
    """
    try_again = outcome.attempts < MAX_ATTEMPTS
    try:
        status, outcome.seconds = backend.result(handle)
    except Exception as error:  # a backend failure (a lost Ray worker): the run failed this time
        status, outcome.seconds = "failed", 0.0
        outcome.log_tail = [f"{type(error).__name__}: {error}"]
        # (a second try would meet the same code)
        try_again = try_again and not isinstance(error, CodeMismatchError)
    if status in ("done", "skipped") and not outcome.run.complete(root):
        # (and would find the run finished out of sight again)
        status, try_again = "failed", False
        outcome.log_tail = [unseen_run_message(outcome.run.run_folder(root))]
    return status, try_again


def _after_the_start_window(
    queue: list[RunSpec],
    stepped_aside: list[RunSpec],
    outcomes: dict[RunSpec, RunOutcome],
    root: str,
    backend: Backend,
    notify: Callable[[str, RunOutcome], None],
) -> list[RunSpec]:
    """
    What a queue still runs once its start window has closed: its deferred runs, which were started in time and end in
    this queue, on the cores the runs under way leave free (waiting for their references once nothing else is under
    way). Each other queued run gets its status: ``"skipped"`` (finished meanwhile) or ``"busy"`` (held by another
    queue), told as its end as before a start, else ``"left"`` (listed when the command ends).

    :return: The deferred runs, queued and stepped aside
    """
    for run in queue:
        if outcomes[run].status != "deferred":
            reason = _reason_not_to_start(run, root, backend)
            outcomes[run].status = reason or "left"
            if reason:
                notify("end", outcomes[run])
    return [run for run in (*queue, *stepped_aside) if outcomes[run].status == "deferred"]


def _reason_not_to_start(run: RunSpec, root: str, backend: Backend) -> str | None:
    """
    Why a run the queue reaches is not started, looked at before its start line would be printed.

    :param run: The run
    :param root: The log root (``-f``)
    :param backend: Where it would go (only a backend on this machine can see this machine's locks)
    :return: ``"skipped"`` for a run with nothing left to do, ``"busy"`` for one another suite on this machine trains,
        ``None`` for a run to start
    """
    if run.complete(root):
        return "skipped"
    if backend.address is None and run_lock_held(run.run_folder(root)):
        return "busy"
    return None


def _window_closed(start_until: float | None) -> bool:
    """Whether the start window (``start_until``, see :func:`run_all`) has closed."""
    return start_until is not None and time.time() >= start_until


def _released_elsewhere(outcomes: dict[RunSpec, RunOutcome], root: str, backend: Backend) -> list[RunSpec]:
    """
    The runs found busy that another queue has let go unfinished since: a run whose transfer test it deferred (its
    references may be saved by now: ending it takes seconds), or one it was stopped in (it resumes from its checkpoint).

    :param outcomes: Each run's outcome so far
    :param root: The log root (``-f``)
    :param backend: Where the runs go (only a backend on this machine can see this machine's locks: none for others)
    :return: Those runs, in the order of ``outcomes``
    """
    if backend.address is not None:  # (it would find every unfinished run free)
        return []
    return [
        run for run, outcome in outcomes.items() if outcome.status == "busy" and not _reason_not_to_start(run, root, backend)
    ]


def run_all(
    runs: Sequence[RunSpec],
    root: str,
    backend: Backend,
    on_event: Callable[[str, RunOutcome | None, dict[str, int]], None] | None = None,
    start_until: float | None = None,
) -> list[RunOutcome]:
    """
    Run every run to its end; finished runs are skipped, failed ones retried once. A run whose transfer test finds
    the references it lacks all being trained by other runs (two queues on one seed) steps aside, its learned-cost
    result kept, and gives its core to the next run; it comes back first once another run has run and ended (not one
    busy elsewhere: by then the references are most likely saved), or when nothing else is left to start (then it
    waits for them); after ``start_until``, on a core the runs under way leave free, waiting for its references if need be
    (it was started in time). Stepping aside does not count as an attempt. A run found busy (another queue held it)
    that the other queue has let go unfinished by the time one of this queue's runs ends is queued next, while the start
    window is open: a transfer test deferred there, or a run stopped there.

    :param runs: The runs
    :param root: The log root (``-f``)
    :param backend: Where the runs go
    :param on_event: Called with ``("start" | "end", outcome, counts)`` as runs start and end (for the display)
    :param start_until: A time (``time.time()``) after which no run starts, nor starts again after a failure: the runs
        under way go on to their end, the others stay ``"left"`` (``"busy"`` where another queue holds them by then), a
        run that failed once is ``"failed"``; a run whose transfer test was deferred still ends (``None``: no such time)
    :return: One outcome per run, in the order of ``runs``
    """
    outcomes = {run: RunOutcome(run, "left") for run in runs}
    queue = list(runs)
    pending: dict[Any, RunSpec] = {}
    #: Deferred runs not back in the queue yet
    stepped_aside: list[RunSpec] = []

    def notify(event: str, outcome: RunOutcome) -> None:
        if on_event:
            on_event(event, outcome, counts())

    def counts() -> dict[str, int]:
        statuses = [outcome.status for outcome in outcomes.values()]
        return {
            status: statuses.count(status) for status in ("done", "skipped", "running", "failed", "busy", "left", "deferred")
        }

    try:
        while queue or pending or stepped_aside:
            if stepped_aside and not queue and len(pending) < backend.capacity:
                queue, stepped_aside = stepped_aside, []  # nothing else to start: they wait for their references
            if _window_closed(start_until):
                queue, stepped_aside = _after_the_start_window(queue, stepped_aside, outcomes, root, backend, notify), []
                if not pending and not queue:
                    break
            while queue and len(pending) < backend.capacity:
                run = queue.pop(0)
                reason = _reason_not_to_start(run, root, backend)
                if reason:
                    outcomes[run].status = reason
                    notify("end", outcomes[run])
                    continue
                outcomes[run].attempts += 1
                outcomes[run].status = "running"
                # Deferring a transfer test pays only while there is other work for the core meanwhile
                defer = any(outcomes[other].status != "deferred" and not other.complete(root) for other in queue)
                pending[backend.submit(run, root, defer=defer)] = run
                notify("start", outcomes[run])
            done, _ = backend.wait_any(set(pending))
            for handle in done:
                run = pending.pop(handle)
                outcome = outcomes[run]
                status, try_again = _ended_run(backend, handle, outcome, root)
                if status == "deferred":
                    outcome.attempts -= 1
                    outcome.status = "deferred"
                    stepped_aside.append(run)
                    notify("end", outcome)
                    continue
                if status == "busy":
                    outcome.attempts -= 1  # (another process held it: not an attempt; it may come back, see below)
                else:  # another run ran and ended: their turn first, then the runs other queues let go
                    released = [] if _window_closed(start_until) else _released_elsewhere(outcomes, root, backend)
                    for other in released:
                        outcomes[other].status = "left"
                    queue[:0], stepped_aside = [*stepped_aside, *released], []
                if status == "failed" and try_again:
                    outcome.status = "left"
                    queue.insert(0, run)  # once more, from its last checkpoint
                    continue
                outcome.status = status
                if status == "failed":
                    outcome.log_tail = outcome.log_tail or log_tail(run.log_file(root))
                notify("end", outcome)
        for outcome in outcomes.values():
            if outcome.status == "left" and outcome.attempts:  # failed, its second try left by the start time
                outcome.status = "failed"
                outcome.log_tail = outcome.log_tail or log_tail(outcome.run.log_file(root))
    except KeyboardInterrupt:
        backend.stop()
        raise
    finally:
        backend.close()
    return [outcomes[run] for run in runs]
