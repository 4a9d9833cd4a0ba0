"""``benchmark run --start-within``: no run starts after the time, the runs under way end, the others are left; a run whose
transfer test waits for references other runs train gives its turn to the next run."""

import os
import sys

import pytest

from sb3_icrl.benchmark import cli, runner
from sb3_icrl.benchmark.runner import Backend, run_all, run_lock
from sb3_icrl.benchmark.suite import RunSpec
from sb3_icrl.common.utils import held_lock_inodes, lock_held
from sb3_icrl.metrics.transfer import DEFERRED_EXIT
from sb3_icrl.run_folder import FINISHED_FILE

RUNS = [RunSpec("smoke", "base", "bc2l", "sb3_icrl/GridWorldWall-v0", seed, 2048) for seed in range(4)]


class _Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def time(self) -> float:
        return self.now


class _TenSecondRuns(Backend):
    """Every run takes ten seconds of a fake clock; the ones in ``failing`` fail."""

    def __init__(self, clock: _Clock, finished: set[RunSpec], failing: set[RunSpec] = frozenset()) -> None:
        self.clock, self.finished, self.failing = clock, finished, failing
        self.submitted: list[RunSpec] = []

    def submit(self, run: RunSpec, root: str, defer: bool = False) -> RunSpec:
        self.submitted.append(run)
        return run

    def wait_any(self, pending: set) -> tuple[set, set]:
        self.clock.now += 10
        return set(pending), set()

    def result(self, handle: RunSpec) -> tuple[str, float]:
        if handle in self.failing:
            return "failed", 10.0
        self.finished.add(handle)
        return "done", 10.0


@pytest.fixture
def clock(monkeypatch):
    clock = _Clock()
    monkeypatch.setattr(runner.time, "time", clock.time)
    return clock


@pytest.fixture
def finished(monkeypatch):
    finished: set[RunSpec] = set()
    monkeypatch.setattr(RunSpec, "complete", lambda self, root: self in finished)
    return finished


def test_no_run_starts_after_the_time(clock, finished):
    finished.add(RUNS[2])  # finished before: still counted as such after the time
    backend = _TenSecondRuns(clock, finished)
    outcomes = run_all(RUNS, "logs", backend, start_until=15)
    assert backend.submitted == RUNS[:2]  # started at 0 and 10; at 20 the time had passed
    assert [outcome.status for outcome in outcomes] == ["done", "done", "skipped", "left"]
    assert outcomes[3].attempts == 0


def test_a_failed_run_is_not_tried_again_after_the_time_and_says_it_failed(clock, finished, tmp_path):
    backend = _TenSecondRuns(clock, finished, failing={RUNS[0]})
    log = RUNS[0].log_file(str(tmp_path))
    os.makedirs(os.path.dirname(log))
    with open(log, "w") as file:
        file.write("Traceback (most recent call last):\nValueError: a broken recipe\n")
    outcomes = run_all(RUNS[:2], str(tmp_path), backend, start_until=5)
    assert backend.submitted == [RUNS[0]]
    assert [(outcome.status, outcome.attempts) for outcome in outcomes] == [("failed", 1), ("left", 0)]
    assert "ValueError: a broken recipe" in outcomes[0].log_tail


def test_without_a_time_every_run_starts(clock, finished):
    backend = _TenSecondRuns(clock, finished)
    assert [outcome.status for outcome in run_all(RUNS, "logs", backend)] == ["done"] * 4


class _Timeline(Backend):
    """Runs of given lengths on ``capacity`` cores of a fake clock; runs in ``busy`` are held by another process,
    those in ``waiting`` defer (when they may) until ``saved_at``."""

    def __init__(self, clock, finished, capacity, lengths, busy=(), waiting=(), saved_at=0.0) -> None:
        self.clock, self.finished, self.capacity, self.lengths = clock, finished, capacity, lengths
        self.busy, self.waiting, self.saved_at = set(busy), set(waiting), saved_at
        self.submitted: list[tuple[RunSpec, bool, float]] = []
        self.ends: dict[RunSpec, tuple[float, str]] = {}

    def submit(self, run: RunSpec, root: str, defer: bool = False) -> RunSpec:
        self.submitted.append((run, defer, self.clock.now))
        if run in self.busy:
            self.ends[run] = (self.clock.now, "busy")
        elif run in self.waiting and defer and self.clock.now < self.saved_at:
            self.ends[run] = (self.clock.now + 1, "deferred")
        else:
            self.ends[run] = (self.clock.now + self.lengths.get(run, 10), "done")
        return run

    @property
    def deferrable(self) -> list[tuple[RunSpec, bool]]:
        """Each run submitted, with whether it could defer, in order."""
        return [(run, defer) for run, defer, _ in self.submitted]

    def wait_any(self, pending: set) -> tuple[set, set]:
        if not pending:
            return set(), set()
        first = min(self.ends[run][0] for run in pending)
        self.clock.now = max(self.clock.now, first)
        done = {run for run in pending if self.ends[run][0] <= self.clock.now}
        return done, set(pending) - done

    def result(self, handle: RunSpec) -> tuple[str, float]:
        status = self.ends[handle][1]
        if status == "done":
            self.finished.add(handle)
        return status, 0.0


def test_a_deferred_transfer_gives_its_turn_to_the_next_run_and_comes_back_after_it(clock, finished):
    backend = _Timeline(clock, finished, 1, {}, waiting={RUNS[0]}, saved_at=5)
    events = []
    outcomes = run_all(RUNS[:3], "logs", backend, on_event=lambda event, outcome, _: events.append((event, outcome.status)))
    # Deferred at 1, the first run is back once the next has ended (at 11), before the third starts
    assert backend.deferrable == [(RUNS[0], True), (RUNS[1], True), (RUNS[0], True), (RUNS[2], False)]
    assert [(outcome.status, outcome.attempts) for outcome in outcomes] == [("done", 1), ("done", 1), ("done", 1)]
    assert ("end", "deferred") in events


def test_with_nothing_else_to_start_a_deferred_transfer_waits_for_its_references(clock, finished):
    backend = _Timeline(clock, finished, 1, {}, waiting={RUNS[0]}, saved_at=1000)
    outcomes = run_all(RUNS[:1], "logs", backend)
    assert backend.deferrable == [(RUNS[0], False)]
    backend = _Timeline(clock, finished, 1, {}, waiting={RUNS[1]}, saved_at=1000)
    outcomes = run_all(RUNS[1:3], "logs", backend)
    assert backend.deferrable == [(RUNS[1], True), (RUNS[2], False), (RUNS[1], False)]
    assert [outcome.status for outcome in outcomes] == ["done", "done"]


def test_a_deferred_transfer_past_the_start_time_waits_for_its_references_in_the_same_queue(clock, finished):
    # The second run holds the core from 1 to 21: the start time passes meanwhile; the references come at 1000
    backend = _Timeline(clock, finished, 1, {RUNS[1]: 20}, waiting={RUNS[0]}, saved_at=1000)
    outcomes = run_all(RUNS[:3], "logs", backend, start_until=15)
    # Back at 21 without deferring (nothing else may start): it waits; the third run stays left
    assert backend.submitted == [(RUNS[0], True, 0), (RUNS[1], True, 1), (RUNS[0], False, 21)]
    assert [(outcome.status, outcome.attempts) for outcome in outcomes] == [("done", 1), ("done", 1), ("left", 0)]


def test_a_run_busy_elsewhere_does_not_call_a_deferred_run_back(clock, finished, monkeypatch):
    runs = [RunSpec("smoke", "base", "bc2l", "sb3_icrl/GridWorldWall-v0", seed, 2048) for seed in range(6)]
    backend = _Timeline(clock, finished, 1, {}, busy=runs[1:4], waiting={runs[0]}, saved_at=100)
    monkeypatch.setattr(runner, "run_lock_held", lambda folder: folder in {run.run_folder("logs") for run in runs[1:4]})
    outcomes = run_all(runs, "logs", backend)
    # Back once the fifth run, which trained, has ended (and again after the sixth), not after each run held elsewhere
    assert [defer for run, defer, _ in backend.submitted if run == runs[0]] == [True, True, False]
    assert [outcome.status for outcome in outcomes] == ["done", "busy", "busy", "busy", "done", "done"]


@pytest.mark.parametrize(
    "there, start_until, started, status",
    [
        ("deferred", None, [1, 0, 2], "done"),  # its references saved since: back before the third run
        ("finished", None, [1, 2], "busy"),
        ("deferred", 5, [1], "busy"),  # let go after the start time: the other queue ends it
    ],
)
def test_a_run_another_queue_lets_go_unfinished_comes_back_once_this_queue_s_run_ends(
    clock, finished, monkeypatch, there, start_until, started, status
):
    held = {RUNS[0].run_folder("logs")}
    monkeypatch.setattr(runner, "run_lock_held", lambda folder: folder in held)
    backend = _Timeline(clock, finished, 1, {})
    wait_any = backend.wait_any

    def the_other_queue_lets_go(pending: set) -> tuple[set, set]:
        # While this queue trains the second run, the other one ends its part of the first
        held.clear()
        if there == "finished":
            finished.add(RUNS[0])
        return wait_any(pending)

    monkeypatch.setattr(backend, "wait_any", the_other_queue_lets_go)
    outcomes = run_all(RUNS[:3], "logs", backend, start_until=start_until)
    assert [run for run, _, _ in backend.submitted] == [RUNS[index] for index in started]
    assert outcomes[0].status == status
    assert outcomes[0].attempts == (1 if status == "done" else 0)


def test_a_run_the_backend_finds_busy_is_no_attempt(clock, finished):
    backend = _Timeline(clock, finished, 1, {}, busy={RUNS[0]})
    outcomes = run_all(RUNS[:2], "logs", backend)
    assert [(outcome.status, outcome.attempts) for outcome in outcomes] == [("busy", 0), ("done", 1)]


@pytest.mark.skipif(held_lock_inodes() is None, reason="no readable /proc/locks")
def test_a_run_another_queue_trains_is_busy_without_a_start(clock, finished, tmp_path):
    root = str(tmp_path)
    backend = _Timeline(clock, finished, 1, {})
    events = []
    with run_lock(RUNS[0].run_folder(root)) as taken:  # the other queue's lock (an open file of its own)
        assert taken
        outcomes = run_all(RUNS[:2], root, backend, on_event=lambda event, outcome, _: events.append((event, outcome.run)))
    assert [run for run, _, _ in backend.submitted] == [RUNS[1]]
    assert [(outcome.status, outcome.attempts) for outcome in outcomes] == [("busy", 0), ("done", 1)]
    assert events[0] == ("end", RUNS[0]) and ("start", RUNS[0]) not in events


@pytest.mark.skipif(held_lock_inodes() is None, reason="no readable /proc/locks")
def test_a_run_another_queue_holds_when_the_start_time_passes_is_busy_not_left(clock, finished, tmp_path):
    root = str(tmp_path)
    backend = _Timeline(clock, finished, 1, {RUNS[0]: 20})
    events: list[tuple[str, RunSpec, str]] = []
    with run_lock(RUNS[1].run_folder(root)) as taken:  # another queue takes the second run while the first trains
        assert taken
        outcomes = run_all(
            RUNS[:3],
            root,
            backend,
            start_until=15,
            on_event=lambda event, outcome, _: events.append((event, outcome.run, outcome.status)),
        )
    assert [run for run, _, _ in backend.submitted] == [RUNS[0]]
    assert [outcome.status for outcome in outcomes] == ["done", "busy", "left"]
    # The busy run's end is told as it is decided, as one found busy before a start is; the left one's is not
    assert ("end", RUNS[1], "busy") in events
    assert not [event for event in events if event[1] == RUNS[2] and event[0] == "end"]


def test_a_free_run_whose_inode_the_lock_table_shows_is_not_busy(tmp_path, monkeypatch):
    # The lock table names inodes only: a lock on a file of another file system may share this lock file's number
    folder = RUNS[0].run_folder(str(tmp_path))
    with run_lock(folder):
        pass
    monkeypatch.setattr(runner, "held_lock_inodes", lambda: {os.stat(folder + ".lock").st_ino})
    assert not runner.run_lock_held(folder)
    with run_lock(folder):  # held for real: busy
        assert runner.run_lock_held(folder)


def test_a_cluster_backend_does_not_look_at_this_machine_s_locks(clock, finished, tmp_path):
    root = str(tmp_path)
    backend = _Timeline(clock, finished, 1, {})
    backend.address = "ray://head:10001"  # its runs lock their folders on the nodes that train them
    with run_lock(RUNS[0].run_folder(root)):
        run_all(RUNS[:1], root, backend)
    assert [run for run, _, _ in backend.submitted] == [RUNS[0]]


def test_lock_held_without_a_lock_table_or_a_lock_file(tmp_path):
    path = tmp_path / "run.lock"
    assert not lock_held(path, {1, 2, 3})  # no such file
    path.write_text("")
    assert not lock_held(path, None)  # no lock table (not Linux)
    assert lock_held(path, {path.stat().st_ino})


def test_queued_runs_already_complete_are_no_reason_to_defer(clock, finished):
    finished.update(RUNS[1:3])
    backend = _Timeline(clock, finished, 1, {}, waiting={RUNS[0]}, saved_at=100)
    run_all(RUNS[:3], "logs", backend)
    assert [(run, defer) for run, defer, _ in backend.submitted] == [(RUNS[0], False)]


def test_after_the_start_time_a_deferred_run_ends_on_a_core_the_runs_under_way_leave_free(clock, finished):
    # Two cores; the first run defers at 1, the second takes a core until 100, the third ends at 45
    backend = _Timeline(clock, finished, 2, {RUNS[1]: 100, RUNS[2]: 44}, waiting={RUNS[0]}, saved_at=60)
    outcomes = run_all(RUNS[:3], "logs", backend, start_until=30)
    assert (RUNS[0], False, 45) in backend.submitted
    assert [(outcome.status, outcome.attempts) for outcome in outcomes] == [("done", 1)] * 3


@pytest.mark.parametrize("text, seconds", [("2h30m", 9000), ("90m", 5400), ("1.5h", 5400), ("600s", 600), ("45", 45)])
def test_durations(text, seconds):
    assert cli.duration_seconds(text) == seconds


@pytest.mark.parametrize("text", ["", "soon", "2d", "-5m", "0", "1h30"])
def test_a_bad_duration_is_refused_with_the_forms_it_takes(text, capsys, tmp_path):
    with pytest.raises(SystemExit):
        cli.main(["run", "smoke", "-f", str(tmp_path), f"--start-within={text}"])
    error = capsys.readouterr().err
    assert "--start-within" in error and ("2h30m, 90m" in error or "more than zero" in error)


@pytest.mark.parametrize("defer, status", [(True, "deferred"), (False, "failed")])
def test_a_transfer_test_ending_with_the_deferred_status_defers_its_run_only_when_asked(tmp_path, monkeypatch, defer, status):
    run_folder = tmp_path / "bc2l" / "GridWorldWall-v0_1"
    run_folder.mkdir(parents=True)
    (run_folder / FINISHED_FILE).write_text('{"num_timesteps": 2048}')  # trained: only its transfer tests are left
    commands = []

    def transfer_command(argv):
        commands.append(list(argv))
        # The reward task's references are taken; the dynamics task's are free, and it completes
        if "reward" in argv:
            return [sys.executable, "-c", f"raise SystemExit({DEFERRED_EXIT})"]
        return [sys.executable, "-c", f"open({str(run_folder / 'transfer_dynamics.json')!r}, 'w').write('{{}}')"]

    monkeypatch.setattr(runner, "transfer_command", transfer_command)
    log = str(tmp_path / "run.log")
    transfers = [
        ("transfer_reward.json", [str(run_folder), "--task", "reward"]),
        ("transfer_dynamics.json", [str(run_folder), "--task", "dynamics"]),
    ]
    assert runner.execute_run(["--algo", "bc2l"], log, str(run_folder), transfers, defer=defer)[0] == status
    no_wait = ["--no-wait"] if defer else []
    assert commands == [[str(run_folder), "--task", task, *no_wait] for task in ("reward", "dynamics")]
    # Deferred, the run's other test still runs; failed, nothing after it does
    assert (run_folder / "transfer_dynamics.json").is_file() == defer


def test_training_that_ends_with_the_deferred_status_is_a_failure(tmp_path, monkeypatch):
    run_folder = tmp_path / "bc2l" / "GridWorldWall-v0_1"
    finished = str(run_folder / FINISHED_FILE)
    command = f"import os; os.makedirs({str(run_folder)!r}); open({finished!r}, 'w').write('{{}}'); raise SystemExit(75)"
    monkeypatch.setattr(runner, "train_command", lambda argv: [sys.executable, "-c", command])
    log = str(tmp_path / "run.log")
    transfers = [("transfer_reward.json", [str(run_folder), "--task", "reward"])]
    assert runner.execute_run(["--algo", "bc2l"], log, str(run_folder), transfers, defer=True)[0] == "failed"
