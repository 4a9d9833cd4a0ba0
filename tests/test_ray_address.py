"""The Ray backend's address: --address, else $RAY_ADDRESS (as `ray job submit` sets it); --jobs refused on a cluster."""

import sys
import types

import pytest

from sb3_icrl.benchmark.runner import make_backend


@pytest.fixture
def fake_ray(monkeypatch):
    """A stand-in for the ``ray`` module that records how it was started."""
    calls = {}
    ray = types.ModuleType("ray")
    ray.is_initialized = lambda: False
    ray.init = lambda **kwargs: calls.setdefault("init", kwargs)
    ray.remote = lambda **options: (lambda function: function)
    ray.cluster_resources = lambda: {"CPU": 48.0}
    monkeypatch.setitem(sys.modules, "ray", ray)
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    return calls


def test_ray_address_from_the_environment_connects_without_cpus(fake_ray, monkeypatch):
    monkeypatch.setenv("RAY_ADDRESS", "http://head:8265")
    backend = make_backend("ray", None)
    assert fake_ray["init"] == {"address": "http://head:8265", "log_to_driver": False, "runtime_env": None}
    assert backend.address == "http://head:8265" and backend.capacity == 48  # the cluster's CPUs


def test_a_ray_instance_started_here_takes_jobs_cpus(fake_ray):
    backend = make_backend("ray", 3)
    assert fake_ray["init"]["num_cpus"] == 3 and backend.address is None


@pytest.mark.parametrize("env_address", [None, "auto"])
def test_jobs_on_a_cluster_are_refused(fake_ray, monkeypatch, env_address):
    if env_address:
        monkeypatch.setenv("RAY_ADDRESS", env_address)
    with pytest.raises(ValueError, match="drop --jobs"):
        make_backend("ray", 4, None if env_address else "auto")
    assert "init" not in fake_ray  # refused before connecting


def test_the_local_pool_takes_one_run_per_core_by_default():
    backend = make_backend("local", None)
    assert backend.capacity >= 1 and backend.address is None
    backend.close()


def test_a_runtime_env_cannot_reach_a_ray_started_before(fake_ray):
    sys.modules["ray"].is_initialized = lambda: True
    with pytest.raises(ValueError, match="already started in this process"):
        make_backend("ray", None, runtime_env={"working_dir": "."})
    assert "init" not in fake_ray
