import functools

import pytest
import torch as th

# Tiny networks run fastest on one thread, and pytest-xdist already runs one worker per core
th.set_num_threads(1)


@pytest.fixture
def report_suite(tmp_path, monkeypatch):
    """
    Loads a benchmark suite from its yml text, with its report's bootstrap intervals cut to 20 resamples (fast; tests
    that read the intervals' values draw their own).
    """
    from sb3_icrl.benchmark import judgements, load_suite, report

    for module in (report, judgements):  # the report's aggregates; the cells' spreads, scores and aim
        monkeypatch.setattr(module, "stratified_bootstrap_ci", functools.partial(module.stratified_bootstrap_ci, reps=20))

    def load(text: str):
        path = tmp_path / "suite.yml"
        path.write_text(text)
        return load_suite(str(path))

    return load
