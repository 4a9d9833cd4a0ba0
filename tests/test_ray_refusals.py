"""The Ray backend refuses what it cannot do right: workers with other code, run folders the driver cannot see."""

import json

import pytest

from sb3_icrl.benchmark.runner import (
    Backend,
    RayBackend,
    code_identity,
    code_mismatch,
    load_runtime_env,
    make_backend,
    run_all,
)
from sb3_icrl.benchmark.suite import RunSpec

RUN = RunSpec("smoke", "base", "bc2l", "sb3_icrl/GridWorldWall-v0", 0, 2048)


def test_the_same_code_passes():
    here = code_identity()
    assert code_mismatch(here, dict(here)) is None
    # a worker without a git checkout (a wheel, a runtime_env copy) is compared by version only
    assert code_mismatch(here, {"sb3_icrl": here["sb3_icrl"], "git_revision": "unknown"}) is None


def test_another_version_or_revision_is_named():
    driver = {"sb3_icrl": "0.2.0", "git_revision": "abc"}
    message = code_mismatch(driver, {"sb3_icrl": "0.1.0", "git_revision": "abc"})
    assert message is not None and "sb3-icrl 0.1.0, the driver 0.2.0" in message and "every node" in message
    message = code_mismatch(driver, {"sb3_icrl": "0.2.0", "git_revision": "def-dirty"})
    assert message is not None and "git revision def-dirty, the driver abc" in message


def test_runtime_env_from_json_or_yaml(tmp_path):
    assert load_runtime_env(None) is None
    assert load_runtime_env('{"working_dir": ".", "pip": ["minari"]}') == {"working_dir": ".", "pip": ["minari"]}
    path = tmp_path / "runtime_env.yml"
    path.write_text("working_dir: /home/me/sb3-icrl\nenv_vars: {OMP_NUM_THREADS: '1'}\n")
    assert load_runtime_env(str(path)) == {"working_dir": "/home/me/sb3-icrl", "env_vars": {"OMP_NUM_THREADS": "1"}}
    with pytest.raises(ValueError, match="JSON object or the path of a YAML file"):
        load_runtime_env("missing.yml")
    with pytest.raises(ValueError, match="must be a mapping"):
        load_runtime_env('["working_dir"]')
    with pytest.raises(ValueError, match="--runtime-env is for --backend ray"):
        make_backend("local", 1, runtime_env={"working_dir": "."})


class _InvisibleBackend(Backend):
    """Reports every run finished, as a worker writing to storage the driver does not see would."""

    def __init__(self) -> None:
        self.submitted = 0

    def submit(self, run: RunSpec, root: str, defer: bool = False) -> RunSpec:
        self.submitted += 1
        return run

    def wait_any(self, pending: set) -> tuple[set, set]:
        return set(pending), set()

    def result(self, handle: RunSpec) -> tuple[str, float]:
        return "done", 12.0


def test_a_finished_run_the_driver_cannot_see_is_not_done(tmp_path):
    backend = _InvisibleBackend()
    [outcome] = run_all([RUN], str(tmp_path), backend)
    assert outcome.status == "failed" and backend.submitted == 1  # no second try: it would not be seen either
    assert "finished.json" in outcome.log_tail[0] and "storage every node mounts at the same path" in outcome.log_tail[0]


def test_a_ray_worker_with_other_code_fails_the_run(tmp_path):
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        backend = RayBackend(2)
        # The worker reads its own sb3-icrl; the driver's is made to differ
        backend.driver_code = {**backend.driver_code, "sb3_icrl": "0.0.0-another"}
        [outcome] = run_all([RUN], str(tmp_path), backend)
    finally:
        ray.shutdown()
    assert outcome.status == "failed" and outcome.attempts == 1
    assert outcome.log_tail[0].startswith("CodeMismatchError: This Ray worker runs sb3-icrl")
    assert "the driver 0.0.0-another" in outcome.log_tail[0] and "Traceback" not in outcome.log_tail[0]
    assert not (tmp_path / "smoke").exists()  # refused before training


def test_the_run_command_passes_the_runtime_env(monkeypatch, tmp_path):
    from sb3_icrl.benchmark import cli

    seen = {}

    def fake_make_backend(backend, jobs, address=None, runtime_env=None):
        seen["runtime_env"] = runtime_env
        raise RuntimeError("stop here")

    monkeypatch.setattr(cli, "make_backend", fake_make_backend)
    runtime_env = {"working_dir": str(tmp_path)}
    argv = ["run", "smoke", "-f", str(tmp_path), "--backend", "ray", "--runtime-env", json.dumps(runtime_env)]
    assert cli.main(argv) == 2
    assert seen["runtime_env"] == runtime_env
