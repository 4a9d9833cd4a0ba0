"""``benchmark run --start-within``: no run starts after the time, the runs under way end, the others are left."""

import os

import pytest

from sb3_icrl.benchmark import cli, runner
from sb3_icrl.benchmark.runner import Backend, run_all
from sb3_icrl.benchmark.suite import RunSpec

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

    def submit(self, run: RunSpec, root: str) -> RunSpec:
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


@pytest.mark.parametrize("text, seconds", [("2h30m", 9000), ("90m", 5400), ("1.5h", 5400), ("600s", 600), ("45", 45)])
def test_durations(text, seconds):
    assert cli.duration_seconds(text) == seconds


@pytest.mark.parametrize("text", ["", "soon", "2d", "-5m", "0", "1h30"])
def test_a_bad_duration_is_refused_with_the_forms_it_takes(text, capsys, tmp_path):
    with pytest.raises(SystemExit):
        cli.main(["run", "smoke", "-f", str(tmp_path), f"--start-within={text}"])
    error = capsys.readouterr().err
    assert "--start-within" in error and ("2h30m, 90m" in error or "more than zero" in error)
