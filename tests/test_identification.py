"""Identification metrics of learned constraints: the scores against hand-computed values, the probe set, run folders."""

import json
import os

import gymnasium as gym
import numpy as np
import pytest
import torch as th

import sb3_icrl.envs  # noqa: F401  (registers the environments)
from sb3_icrl.benchmark.report import constraint_metrics, summarise_suite
from sb3_icrl.benchmark.report_text import csv_rows, markdown_table
from sb3_icrl.benchmark.suite import RunSpec, load_suite
from sb3_icrl.constraints import FeasibilityNet
from sb3_icrl.data import load_demonstrations
from sb3_icrl.icrl.tabular import precision_recall
from sb3_icrl.metrics import (
    IDENTIFICATION_FILE,
    auroc,
    build_probe_set,
    expected_calibration_error,
    grid_identification,
    identification_scores,
    identify_model,
    identify_run,
    learned_threshold,
    overlap_scores,
    threshold_error,
)
from sb3_icrl.metrics.identification import crossing_kind, find_unconstrained_run, headline, headline_crossing, policy_pairs
from sb3_icrl.plots.figures import TrueConstraint, methods_partial_dependence_figure
from sb3_icrl.zoo.compare import RunResult
from sb3_icrl.zoo.train import main as train_main

CHEETAH = "sb3_icrl/BlockedHalfCheetah-v0"
X_LIMIT = TrueConstraint("x_position", 0, -3.0, "<=")
VALUES = np.arange(-10.0, 11.0)  # -10, -9, ..., 10


# ---------------------------------------------------------------- scores against hand-computed values


def test_auroc_of_a_perfect_step_a_ramp_and_a_constant():
    labels = [0, 0, 1, 1]
    assert auroc([0.0, 0.0, 1.0, 1.0], labels) == 1.0
    assert auroc([1.0, 1.0, 0.0, 0.0], labels) == 0.0
    assert auroc([0.3, 0.3, 0.3, 0.3], labels) == 0.5  # all tied: chance
    # Pairs (positive, negative): 0.35 > 0.1, 0.35 < 0.4, 0.8 > both: 3 of 4
    assert auroc([0.1, 0.4, 0.35, 0.8], labels) == pytest.approx(0.75)
    # One tie between a positive and a negative counts one half: (1 + 0.5 + 1 + 1) / 4
    assert auroc([0.1, 0.4, 0.4, 0.8], labels) == pytest.approx(0.875)
    assert np.isnan(auroc([0.2, 0.7], [0, 0]))  # one class: undefined, not 0.5


def test_overlap_scores_by_hand():
    # predicted {1, 2, 3}, true {2, 3, 4}: 2 hits, union 4
    scores = overlap_scores([0, 1, 1, 1, 0], [0, 0, 1, 1, 1])
    assert scores == {"precision": pytest.approx(2 / 3), "recall": pytest.approx(2 / 3), "iou": pytest.approx(0.5)}
    nothing = overlap_scores([0, 0], [0, 1])
    assert nothing["precision"] == 0.0 and nothing["recall"] == 0.0 and nothing["iou"] == 0.0
    assert np.isnan(overlap_scores([0, 0], [0, 0])["iou"])
    # The grid worlds' precision and recall are those of icrl.tabular
    recovered, unsafe = np.array([[1, 1], [0, 1]], bool), np.array([[0, 1], [1, 1]], bool)
    scores = overlap_scores(recovered.ravel(), unsafe.ravel())
    assert (scores["precision"], scores["recall"]) == pytest.approx(precision_recall(recovered, unsafe))


def test_expected_calibration_error_by_hand():
    labels = np.array([0, 0, 1, 1, 0, 0, 0, 0, 1, 0])  # 30% violate
    assert expected_calibration_error(labels.astype(float), labels) == 0.0  # a perfect step
    assert expected_calibration_error(np.full(10, 0.3), labels) == pytest.approx(0.0)  # a calibrated constant
    assert expected_calibration_error(np.full(10, 0.5), labels) == pytest.approx(0.2)
    # Two bins: [0, 0.5) holds 0.1 (label 0): |0.1 - 0| = 0.1; [0.5, 1] holds 0.9, 0.9 (labels 1, 0): |0.9 - 0.5|
    assert expected_calibration_error([0.1, 0.9, 0.9], [0, 1, 0], n_bins=2) == pytest.approx(0.1 / 3 + 0.4 * 2 / 3)
    with pytest.raises(ValueError, match="probabilities in"):
        expected_calibration_error([1.5], [1])
    with pytest.raises(ValueError, match="0/1"):
        auroc([0.5], [2])
    with pytest.raises(ValueError, match="one per labelled pair"):
        auroc([0.5, 0.1], [1])


def test_threshold_error_of_a_step_a_ramp_and_constants():
    step = (VALUES <= -3).astype(float)  # cost 1 up to -3, 0 from -2 on: crosses 0.5 half-way, at -2.5
    error, crossing = threshold_error(VALUES, step, 0.5, -3.0, "<=")
    assert crossing.value == pytest.approx(-2.5) and crossing.reason is None and error == pytest.approx(0.5)
    ramp = np.clip(0.5 - VALUES / 10, 0.0, 1.0)  # 0.5 at x = 0, linear: the crossing is exact
    assert threshold_error(VALUES, ramp, 0.5, -3.0, "<=")[0] == pytest.approx(3.0)
    assert threshold_error(VALUES, ramp, 0.8, -3.0, "<=")[0] == pytest.approx(0.0)
    # Never reaches the level: nothing learned, NaN with the reason
    error, crossing = threshold_error(VALUES, np.full(21, 0.2), 0.5, -3.0, "<=")
    assert np.isnan(error) and "never reaches 0.5" in crossing.reason
    # At or above the level up to the safe end: the learned constraint forbids everything, an infinite error
    error, crossing = threshold_error(VALUES, np.full(21, 0.7), 0.5, -3.0, "<=")
    assert error == np.inf and "no crossing" in crossing.reason
    # Cost on the wrong side (forward): high up to the safe end as well
    assert threshold_error(VALUES, (VALUES >= 0).astype(float), 0.5, -3.0, "<=")[0] == np.inf


def test_crossing_kind_tells_apart_how_a_cost_meets_the_level():
    # x <= -3 is unsafe: the safe end is the right one (x = 10), the unsafe end the left one (x = -10)
    cases = {
        "crosses": (VALUES <= -3).astype(float),
        "everywhere": np.full(21, 0.7),
        "reversed": (VALUES >= 0).astype(float),  # high on the safe side only: the wrong side
        "both ends": (np.abs(VALUES) >= 5).astype(float),  # high at both ends, 0 between
        "nowhere": np.full(21, 0.2),
    }
    for kind, curve in cases.items():
        assert crossing_kind(VALUES, curve, 0.5, "<=") == kind
        # The same curves mirrored, for a constraint broken above (x >= 3): the safe end is now the left one
        assert crossing_kind(VALUES, curve[::-1], 0.5, ">=") == kind
    # The reasons say which
    assert "over the whole of [-10, 10]" in learned_threshold(VALUES, cases["everywhere"], 0.5, "<=").reason
    reversed_reason = learned_threshold(VALUES, cases["reversed"], 0.5, "<=").reason
    assert "safe (right) end" in reversed_reason and "rises toward the safe side" in reversed_reason
    assert "at both ends" in learned_threshold(VALUES, cases["both ends"], 0.5, "<=").reason
    assert learned_threshold(VALUES, cases["both ends"][::-1], 0.5, ">=").value == -np.inf


def test_headline_reads_the_crossing_from_the_curve():
    def scores(curve: np.ndarray, error: float) -> dict:
        feature = {"op": "<=", "curve": {"values": VALUES.tolist(), "mean_cost": curve.tolist()}}
        return {"auroc": 0.9, "features": {"x": {**feature, "at_0.5": {"threshold_error": error}}}}

    both_ends = (np.abs(VALUES) >= 5).astype(float)
    assert headline(scores(both_ends, float("inf")))["threshold_crossing"] == "both ends"
    assert headline(scores((VALUES >= 0).astype(float), float("inf")))["threshold_crossing"] == "reversed"
    assert headline(scores((VALUES <= -3).astype(float), 0.5))["threshold_crossing"] == "crosses"
    # No curve (or one read back from strict JSON with a null): the error alone names the crossing
    assert headline_crossing({}) is None
    assert headline_crossing({"x": {"op": "<=", "curve": {"values": [0.0, 1.0], "mean_cost": [None, 0.2]}}}) is None
    assert headline({"auroc": 0.9, "features": {"x": {"at_0.5": {"threshold_error": np.inf}}}})["threshold_crossing"] == (
        "safe end"
    )


def test_threshold_error_of_a_constraint_broken_above():
    step = (VALUES >= 1).astype(float)
    assert learned_threshold(VALUES, step, 0.5, ">=").value == pytest.approx(0.5)
    assert threshold_error(VALUES, step, 0.5, 0.5, ">=")[0] == pytest.approx(0.0)
    assert learned_threshold(VALUES, np.ones(21), 0.5, ">").value == -np.inf
    with pytest.raises(ValueError, match="strictly increasing"):
        learned_threshold(VALUES[::-1], step, 0.5, ">=")


# ---------------------------------------------------------------- probe set and scores on a benchmark env


@pytest.fixture(scope="module")
def expert():
    transitions = load_demonstrations("BlockedHalfCheetah-v0").transitions
    obs, acts = np.asarray(transitions.obs), np.asarray(transitions.acts)
    keep = np.random.default_rng(0).choice(len(obs), size=min(2000, len(obs)), replace=False)
    return obs[keep], acts[keep]


def step_cost(threshold: float):
    def cost(observations: np.ndarray, actions: np.ndarray | None) -> np.ndarray:
        return (np.asarray(observations)[:, 0] <= threshold).astype(np.float32)

    return cost


def test_probe_set_holds_each_source_and_a_sweep_of_the_feature(expert):
    probes = build_probe_set([X_LIMIT], {"expert": expert}, n_sweep_values=11, n_sweep_states=7, seed=0)
    assert probes.counts() == {"expert": len(expert[0]), "sweep:x_position": 77}
    swept = probes.observations[probes.sources == "sweep:x_position"]
    assert len(np.unique(swept[:, 0])) == 11 and swept[:, 0].min() < -3.0  # across the threshold
    # The other features come from visited states
    assert np.isin(swept[:, 1], expert[0][:, 1]).all()
    for array in (probes.observations, probes.actions, probes.sources):
        assert not array.flags.writeable
    with pytest.raises(ValueError, match="at least the expert"):
        build_probe_set([X_LIMIT], {})


def test_identification_separates_the_true_step_from_a_random_net_and_a_too_strict_one(expert):
    th.manual_seed(0)
    random_net = FeasibilityNet(obs_dim=18, action_dim=6, normalize_input=False)
    scores = {
        name: identify_model(model, CHEETAH, expert, budget=0.1, seed=0)
        for name, model in (("true", step_cost(-3.0)), ("random", random_net), ("strict", step_cost(50.0)))
    }
    true, random, strict = (scores[name] for name in ("true", "random", "strict"))
    spacing = np.diff(true["features"]["x_position"]["curve"]["values"])[0]
    assert true["auroc"] == 1.0 and true["ece"] == 0.0
    assert true["at_0.5"] == {"precision": 1.0, "recall": 1.0, "iou": 1.0}
    assert abs(true["features"]["x_position"]["at_0.5"]["threshold_error"]) <= spacing
    # Any cost that grows as x falls ranks the pairs well, and a random net on the raw x often does (AUROC ~0.9):
    # the threshold error, IoU and calibration tell it from the true constraint
    assert random["auroc"] < true["auroc"]
    assert not abs(random["features"]["x_position"]["at_0.5"]["threshold_error"]) < 5 * spacing  # also NaN/inf
    assert random["at_0.5"]["iou"] < 0.5 and random["ece"] > 0.1
    # Forbidding x <= 50 keeps every violation away too, but is no identification: the threshold is 53 m off
    assert strict["at_0.5"]["recall"] == 1.0 and strict["at_0.5"]["precision"] < 0.5
    assert strict["features"]["x_position"]["at_0.5"]["threshold_error"] == pytest.approx(53.0, abs=spacing)
    assert headline(true) == {
        "identification_auroc": 1.0,
        "threshold_error": pytest.approx(0.0, abs=spacing),
        "threshold_crossing": "crosses",
        "cost_budget": 0.1,
    }


def test_headline_sets_the_learners_own_cost_beside_its_budget(expert):
    """The learned cost on the learner's own pairs against its budget: the sign of a learner that ends episodes."""
    probes = build_probe_set([X_LIMIT], {"expert": expert, "learner": expert}, n_sweep_values=11, n_sweep_states=5)
    learner_x = probes.observations[probes.sources == "learner"][:, 0]
    scores = identification_scores(step_cost(0.0), probes, [X_LIMIT], budget=0.25)  # too strict: x <= 0 costs 1
    row = headline(scores)
    assert row["learner_cost"] == pytest.approx(float(np.mean(learner_x <= 0.0)))
    assert row["cost_budget"] == 0.25
    # Without the learner's pairs or a budget, neither key
    expert_only = build_probe_set([X_LIMIT], {"expert": expert}, n_sweep_values=11, n_sweep_states=5)
    row = headline(identification_scores(step_cost(0.0), expert_only, [X_LIMIT]))
    assert "learner_cost" not in row and "cost_budget" not in row


def test_scores_report_each_source_and_both_levels(expert):
    probes = build_probe_set([X_LIMIT], {"expert": expert, "other": expert}, n_sweep_values=11, n_sweep_states=5)
    scores = identification_scores(step_cost(-3.0), probes, [X_LIMIT], budget=0.25)
    assert scores["levels"] == {"0.5": 0.5, "budget": 0.25}
    assert set(scores["sources"]) == {"expert", "other", "sweep:x_position"}
    assert scores["sources"]["expert"]["violation_share"] == 0.0  # the expert keeps to x > -3
    feature = scores["features"]["x_position"]
    assert feature["threshold"] == -3.0 and feature["op"] == "<="
    assert {"at_0.5", "at_budget"} <= set(feature) and feature["at_budget"]["reason"] is None
    json.dumps(scores)  # JSON-ready
    with pytest.raises(ValueError, match="budget"):
        identification_scores(step_cost(-3.0), probes, [X_LIMIT], budget=float("nan"))


def test_grid_identification_by_hand():
    unsafe = np.array([[0, 1, 1], [0, 0, 1]], bool)
    perfect = grid_identification(unsafe.astype(float), unsafe, budget=0.2)
    assert perfect["auroc"] == 1.0 and perfect["at_0.5"] == {"precision": 1.0, "recall": 1.0, "iou": 1.0}
    costs = np.array([[0.9, 0.8, 0.1], [0.0, 0.3, 0.7]])  # learned unsafe > 0.5: (0,0), (0,1), (1,2)
    scores = grid_identification(costs, unsafe)
    assert scores["at_0.5"] == {"precision": pytest.approx(2 / 3), "recall": pytest.approx(2 / 3), "iou": 0.5}
    # Positive scores 0.8, 0.1, 0.7 against negatives 0.9, 0.0, 0.3: 0.8 beats 2, 0.1 beats 1, 0.7 beats 2
    assert scores["auroc"] == pytest.approx(5 / 9)
    with pytest.raises(ValueError, match="no unsafe cell"):
        grid_identification(costs, np.zeros_like(unsafe))


def test_probe_set_never_reaches_the_learner(expert):
    """Scoring an ICRL model reads its constraint and policy and changes nothing: no update, no new data."""
    from sb3_icrl import MECL

    model = MECL("MlpPolicy", CHEETAH, demonstrations="BlockedHalfCheetah-v0", n_steps=64, batch_size=32, seed=0)
    before = {key: value.clone() for key, value in model.constraint_net.state_dict().items()}
    policy_before = {key: value.clone() for key, value in model.policy.state_dict().items()}
    expert_before = None if model.expert_obs is None else np.array(model.expert_obs, copy=True)
    steps_before = model.num_timesteps
    learner = policy_pairs(model, CHEETAH, n_episodes=1, seed=0, max_steps=100)
    identify_model(model, CHEETAH, expert, other_sources={"learner": learner}, seed=0)
    assert all(th.equal(before[key], value) for key, value in model.constraint_net.state_dict().items())
    assert all(th.equal(policy_before[key], value) for key, value in model.policy.state_dict().items())
    assert model.num_timesteps == steps_before
    if expert_before is not None:
        np.testing.assert_array_equal(np.asarray(model.expert_obs), expert_before)


# ---------------------------------------------------------------- run folders, the report and the figure


@pytest.fixture(scope="module")
def grid_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("logs")
    argv = ["--algo", "mecl", "--env", "GridWorldWall-v0", "-n", "512", "-f", str(root), "--seed", "0"]
    assert train_main([*argv, "--eval-freq", "0", "--save-freq", "0", "--num-threads", "1", "--verbose", "0"]) == 0
    return str(root / "mecl" / "GridWorldWall-v0_1")


def test_identify_run_scores_a_grid_run_and_caches_it(grid_run):
    result = identify_run(grid_run)
    cache = os.path.join(grid_run, IDENTIFICATION_FILE)
    assert os.path.isfile(cache)
    scores = result["scores"]
    assert scores["n_probes"] == gym.make("sb3_icrl/GridWorldWall-v0").unwrapped.n_states
    assert 0.0 <= scores["auroc"] <= 1.0 and set(scores["at_0.5"]) == {"precision", "recall", "iou"}
    written = os.path.getmtime(cache)
    assert identify_run(grid_run) == json.loads(json.dumps(result)) and os.path.getmtime(cache) == written
    assert "threshold_error" not in headline(scores)  # a set of cells has no threshold


def test_identify_run_refuses_what_is_not_an_icrl_run(tmp_path, grid_run):
    with pytest.raises(FileNotFoundError, match="No run folder"):
        identify_run(tmp_path / "missing")
    with pytest.raises(FileNotFoundError, match=r"args\.yml"):
        identify_run(tmp_path)


def test_unconstrained_run_is_found_beside_the_run_kept_from_a_report_or_in_the_experts_suite(tmp_path):
    run = tmp_path / "table3" / "base" / "mecl" / "BlockedHalfCheetah-v0_123"
    run.mkdir(parents=True)
    assert find_unconstrained_run(run) is None
    expert = tmp_path / "experts" / "base" / "ppo" / "BlockedHalfCheetah-v0_0"
    expert.mkdir(parents=True)
    assert find_unconstrained_run(run) is None  # not finished yet
    (expert / "finished.json").write_text("{}")
    assert find_unconstrained_run(run) == expert.resolve()
    beside = tmp_path / "table3" / "base" / "ppo" / "BlockedHalfCheetah-v0_1"
    beside.mkdir(parents=True)
    (beside / "finished.json").write_text("{}")
    assert find_unconstrained_run(run) == beside.resolve()  # the same folder first
    kept = tmp_path / "table3" / "base" / "probe_policies" / "ppo" / "BlockedHalfCheetah-v0_123"
    kept.mkdir(parents=True)
    (kept / "finished.json").write_text("{}")
    assert find_unconstrained_run(run) == kept.resolve()  # the own seed's policy kept from a report before another seed
    same_seed = tmp_path / "table3" / "base" / "ppo" / "BlockedHalfCheetah-v0_123"
    same_seed.mkdir()
    assert find_unconstrained_run(run) == kept.resolve()  # not finished yet
    (same_seed / "finished.json").write_text("{}")
    assert find_unconstrained_run(run) == same_seed.resolve()  # the run's own training before its kept policy
    (tmp_path / "experts" / "base" / "ppo" / "BlockedAnt-v0_0").mkdir()
    assert find_unconstrained_run(tmp_path / "table3" / "base" / "mecl" / "BlockedAnt-v0_1") is None  # not finished


def test_report_gets_identification_columns(grid_run):
    root = os.path.dirname(os.path.dirname(grid_run))
    suite = load_suite("smoke")
    run = RunSpec("smoke", "base", "mecl", "sb3_icrl/GridWorldWall-v0", 0, 512)
    result = RunResult(os.path.relpath(grid_run, root), "mecl", run.env_id, 0, 512, 0.1, 0.0, 1.0, 1.0, 2)
    metrics = constraint_metrics([(run, result)], root, log=lambda line: None)
    expected = identify_run(grid_run)["scores"]["auroc"]
    assert metrics[result.run]["identification_auroc"] == expected
    # The report's other per-run facts come with it: the run's wall time and the shipped expert's return
    assert metrics[result.run]["wall_time_s"] > 0 and metrics[result.run]["expert_return"] == pytest.approx(1.0)
    summary = summarise_suite(suite, [run], [(run, result)], metrics)
    cell = summary["cells"][0]
    assert cell["per_seed"][0]["identification_auroc"] == expected and cell["identification_auroc_mean"] == expected
    assert f"0: {expected:.2f} / -" in markdown_table(summary)
    header, row = csv_rows(summary).splitlines()[:2]
    columns = header.split(",")
    assert columns[columns.index("identification_auroc") + 1] == "threshold_error"
    assert float(row.split(",")[columns.index("identification_auroc")]) == pytest.approx(expected)


def test_methods_figure_marks_the_threshold_and_one_line_per_seed():
    curves = {"MECL": [(VALUES, (VALUES <= -3).astype(float)), (VALUES, np.clip(0.5 - VALUES / 10, 0, 1))], "VICRL": []}
    figure = methods_partial_dependence_figure(curves, -3.0, "<=", "x_position", title="BlockedHalfCheetah-v0")
    axis = figure.axes[0]
    labels = [line.get_label() for line in axis.get_lines()]
    assert "MECL (2 seeds)" in labels and "true threshold -3" in labels and "t = 0.5" in labels
    assert len([line for line in axis.get_lines() if line.get_linewidth() < 1.0]) == 2  # the seeds
    with pytest.raises(ValueError, match="No curve"):
        methods_partial_dependence_figure({"MECL": []}, -3.0, "<=")


def test_an_untrained_cost_net_is_flat_and_scores_one_half(expert):
    """A fresh CostNet charges 0 everywhere (its output layer starts at zero): its untrained baseline is 0.5 exactly."""
    from sb3_icrl.constraints import CostNet
    from sb3_icrl.metrics.identification import untrained_copy

    net = CostNet(obs_dim=18, action_dim=6, hidden_sizes=[20], normalize_input=False)
    with th.no_grad():
        for parameter in net.parameters():
            parameter.add_(1.0)  # stands for training
    copy = untrained_copy(net, seed=3)
    obs, acts = expert
    np.testing.assert_array_equal(copy.cost(obs[:50], acts[:50]), np.zeros(50, dtype=np.float32))
    assert not th.equal(copy.network[0].weight, untrained_copy(net, seed=4).network[0].weight)  # the hidden layers drawn
    scores = identify_model(net, CHEETAH, expert, seed=0, n_untrained=3)
    assert scores["untrained_draws"] == [0.5, 0.5, 0.5] and scores["untrained_auroc"] == 0.5


def test_a_learned_net_is_read_against_an_untrained_one_of_its_shape(expert):
    from sb3_icrl.metrics.identification import untrained_copy

    th.manual_seed(1)
    net = FeasibilityNet(obs_dim=18, action_dim=6, hidden_sizes=[20], normalize_input=False)
    with th.no_grad():
        for parameter in net.parameters():
            parameter.add_(1.0)  # stands for training: weights the initialisation would not draw
    copy = untrained_copy(net, seed=3)
    assert [tuple(p.shape) for p in copy.parameters()] == [tuple(p.shape) for p in net.parameters()]
    assert not any(th.equal(a, b) for a, b in zip(copy.parameters(), net.parameters(), strict=True))
    assert all(th.equal(a, b) for a, b in zip(copy.parameters(), untrained_copy(net, seed=3).parameters(), strict=True))
    scores = identify_model(net, CHEETAH, expert, seed=0, n_untrained=3)
    # The baseline: the median of three initialisations (seeds 0, 1, 2), each scored as a learned net is
    draws = [identify_model(untrained_copy(net, seed=s), CHEETAH, expert, seed=0, n_untrained=1)["auroc"] for s in range(3)]
    assert scores["untrained_draws"] == pytest.approx(draws)
    assert scores["untrained_auroc"] == pytest.approx(sorted(draws)[1])
    assert scores["untrained_auroc_range"] == pytest.approx([min(draws), max(draws)])
    row = headline(scores)
    assert (row["untrained_auroc"], row["untrained_auroc_low"], row["untrained_auroc_high"]) == pytest.approx(
        (sorted(draws)[1], min(draws), max(draws))
    )
    assert "untrained_auroc" not in identify_model(step_cost(-3.0), CHEETAH, expert, seed=0)  # a function has no shape
    with pytest.raises(ValueError, match="n_untrained"):
        identify_model(net, CHEETAH, expert, seed=0, n_untrained=0)
    from sb3_icrl.benchmark.report_text import _identification_text

    seed = {"identification_auroc": 0.9, "untrained_auroc": 0.5, "untrained_auroc_low": 0.02, "threshold_error": 0.5}
    assert _identification_text({**seed, "untrained_auroc_high": 0.97}) == "0.90 (untrained 0.50, 0.02-0.97) / 0.50"
    # Every draw alike (IRL-Plus's nets start constant: 0.5 on each) is not one draw
    assert _identification_text({**seed, "untrained_auroc_high": 0.02}) == "0.90 (untrained 0.50 on every draw) / 0.50"
    assert _identification_text({**seed, "untrained_auroc": float("nan")}) == "0.90 / 0.50"
    # A run scored when the baseline was one net says so
    assert _identification_text({"identification_auroc": 0.9, "untrained_auroc": 0.87, "threshold_error": 0.5}) == (
        "0.90 (untrained 0.87, one draw) / 0.50"
    )


def test_a_cache_of_an_older_version_of_the_scores_is_not_current(tmp_path):
    from sb3_icrl.metrics.identification import IDENTIFICATION_VERSION, identification_cached, identification_file

    assert not identification_cached(tmp_path)
    cache = tmp_path / identification_file("final")
    cache.write_text(json.dumps({"settings": {"version": IDENTIFICATION_VERSION - 1}, "scores": {}}))
    assert not identification_cached(tmp_path)  # scored again, and the report says so
    cache.write_text(json.dumps({"settings": {"version": IDENTIFICATION_VERSION}, "scores": {}}))
    assert identification_cached(tmp_path) and not identification_cached(tmp_path, "best")
    cache.write_text("{cut short")
    assert not identification_cached(tmp_path)
