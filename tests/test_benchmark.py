"""The benchmark engine: suite files, running and resuming suites, and the report's statistics."""

import csv
import dataclasses
import io
import json
import os
import pathlib
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
import scipy.stats

from sb3_icrl.benchmark import iqm, load_suite, report, stratified_bootstrap_ci, summarise_suite
from sb3_icrl.benchmark.cli import main as benchmark_main
from sb3_icrl.benchmark.report_text import csv_rows, markdown_table
from sb3_icrl.benchmark.suite import SUITES_DIR, RunSpec, SuiteError
from sb3_icrl.run_evaluation import UnfinishedEpisodesError
from sb3_icrl.zoo.compare import RunResult
from sb3_icrl.zoo.runs import FINISHED_FILE

SHIPPED = sorted(path.stem for path in SUITES_DIR.glob("*.yml"))
# A tiny suite: two methods, two seeds, a few hundred steps, no checkpoints (an interrupted run restarts afresh)
TINY_SUITE = """\
description: tiny
envs: [GridWorldWall-v0]
algos: [bc2l, vicrl]
seeds: [0, 1]
steps: 512
eval_episodes: 2
train_args: {eval_freq: 256, eval_episodes: 1, save_freq: 0}
reference: vicrl
# PPO-Lagrangian as forward solver (the grid recipes plan instead): its 512-step rollouts fix where checkpoints fall
variants: {base: {hyperparams: {forward_solver: policy_gradient}}}
"""


def write(tmp_path, text: str, name: str = "suite.yml") -> str:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return str(path)


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_suites_parse(name):
    suite = load_suite(name)
    assert suite.runs(), name
    assert len(set(run.run_folder("logs") for run in suite.runs())) == len(suite.runs())  # one folder per run


def test_shipped_suites_are_the_benchmark():
    assert {"table3", "noise", "imperfect", "multi", "experts", "smoke"} <= set(SHIPPED)
    table3 = load_suite("table3")
    # The report of record: the paper's seven envs and the three binding variants with an expert, on fresh seeds, its
    # recipes, success rule and headline envs frozen in the file
    assert len(table3.envs) == 10 and table3.algos == ["gacl", "bc2l", "mecl", "vicrl", "irlplusppo", "ppo", "ppolag"]
    assert table3.forward_recipe == "mecl"  # the reference rows learn as MECL's forward learner does
    assert table3.seeds == [1000, 1001, 1002, 1003, 1004] and table3.recipe_version == "table3-v2"
    assert table3.success == {"max_violation_rate": 0.05, "min_normalised_score": 0.5}
    assert set(table3.headline_envs) <= {env.removeprefix("sb3_icrl/") for env in table3.envs}
    assert "BlockedAnt-v0" not in table3.headline_envs  # no variant of it passes
    assert table3.paper["BlockedHalfCheetah-v0"]["vicrl"] == (3806.0, 0.0)
    # The development table, on the paper's seeds, ships beside it
    development = load_suite("table3_dev")
    assert development.seeds == [123, 321, 456, 654, 666] and development.recipe_version is None
    assert [settings["transition_noise"] for settings in load_suite("noise").variants.values()] == [0.001, 0.01, 0.1]


@pytest.mark.parametrize(
    "text, line, message",
    [
        ("envs: [GridWorldWall-v0]\nalgos: [bc2l]\nseeds: [0]\nepisodes: 3\n", 4, "unknown key 'episodes'"),
        ("envs:\n  - GridWorldWall-v0\n  - NoSuchEnv-v0\nalgos: [bc2l]\nseeds: [0]\n", 3, "Unknown env 'NoSuchEnv-v0'"),
        ("envs: [GridWorldWall-v0]\nalgos:\n  - bc2l\n  - airl\nseeds: [0]\n", 4, "unknown algorithm 'airl'"),
        (
            "envs: [GridWorldWall-v0]\nalgos: [bc2l]\nseeds: [0]\nvariants:\n  noisy: {noise: 0.1}\n",
            5,
            "unknown variant setting 'noise'",
        ),
        ("envs: [GridWorldWall-v0]\nalgos: [bc2l]\nseeds: [0, -1]\n", 3, "seeds are integers >= 0"),
        ("envs: [GridWorldWall-v0]\nalgos: [bc2l]\nseeds: [0]\nreference: vicrl\n", 4, "reference 'vicrl' is not one"),
        ("envs: [GridWorldWall-v0]\nalgos: [bc2l]\nseeds: [0]\ntrain_args: {save_every: 3}\n", 4, "unknown train setting"),
        ("envs: [GridWorldWall-v0]\nalgos: [bc2l]\nseeds: [0]\ntrain_args: {device: 0}\n", 4, "torch device name"),
        ("envs: []\nalgos: [bc2l]\nseeds: [0]\n", 1, "`envs` must be a non-empty list"),
        (
            "envs: [GridWorldWall-v0]\nalgos: [bc2l]\nseeds: [0]\nenv_seeds: {GridWorldSquare-v0: [0]}\n",
            4,
            "GridWorldSquare-v0 is not one of the suite's envs",
        ),
        (
            "envs: [GridWorldWall-v0]\nalgos: [bc2l]\nseeds: [0]\nenv_seeds: {GridWorldWall-v0: []}\n",
            4,
            "the seeds of GridWorldWall-v0 are a non-empty list",
        ),
        (
            "envs: [GridWorldWall-v0]\nalgos: [bc2l]\nseeds: [0]\nenv_seeds: {GridWorldWall-v0: [0, -1]}\n",
            4,
            "seeds are integers >= 0, got -1",
        ),
        (
            "envs: [GridWorldWall-v0]\nalgos: [bc2l]\nseeds: [0]\nenv_seeds: {GridWorldWall-v0: [2, 2]}\n",
            4,
            "`env_seeds.GridWorldWall-v0` repeats an entry",
        ),
        (
            "envs: [GridWorldWall-v0]\nalgos: [bc2l]\nseeds: [0]\nenv_seeds: [0, 1]\n",
            4,
            "`env_seeds` maps an env to its list of seeds",
        ),
    ],
)
def test_bad_suite_files_name_file_and_line(tmp_path, text, line, message):
    path = write(tmp_path, text)
    with pytest.raises(SuiteError, match=f"line {line}: .*{message}") as error:
        load_suite(path)
    assert path in str(error.value)


def test_a_variant_can_name_the_algorithms_that_run_it(tmp_path):
    text = """\
envs: [GridWorldWall-v0]
algos: [bc2l, mecl, vicrl]
seeds: [0, 1]
variants:
  base: {}
  tight-prior: {algos: [vicrl], hyperparams: {prior: [9, 1]}}
"""
    suite = load_suite(write(tmp_path, text), dry_build=False)
    assert suite.variant_algos("base") == ["bc2l", "mecl", "vicrl"] and suite.variant_algos("tight-prior") == ["vicrl"]
    assert [run.name for run in suite.runs() if run.variant == "tight-prior"] == [
        "tight-prior/vicrl/GridWorldWall-v0/seed 0",
        "tight-prior/vicrl/GridWorldWall-v0/seed 1",
    ]
    assert len(suite.runs()) == 8
    argv = suite.runs()[-1].train_argv("logs")
    assert argv[argv.index("-params") + 1 :][:1] == ["prior:[9, 1]"] and "algos" not in " ".join(argv)
    # Without `algos`, a setting one algorithm takes would stop the others' runs: the error says how to say so
    with pytest.raises(SuiteError, match=r"line 6: `prior` is not a hyper-parameter of bc2l, mecl.*variant's `algos`"):
        load_suite(write(tmp_path, text.replace("algos: [vicrl], ", "")), dry_build=False)


@pytest.mark.parametrize(
    "algos, message",
    [
        ("[ppo]", "`algos` names ppo, not among the suite's algos \\(bc2l, vicrl\\)"),
        ("[]", "`algos` lists the suite's algorithms that run it"),
        ("vicrl", "`algos` lists the suite's algorithms that run it"),
        ("[vicrl, vicrl]", "`algos` names an algorithm twice"),
    ],
)
def test_a_variants_algorithms_are_the_suites(tmp_path, algos, message):
    text = f"envs: [GridWorldWall-v0]\nalgos: [bc2l, vicrl]\nseeds: [0]\nvariants:\n  only: {{algos: {algos}}}\n"
    with pytest.raises(SuiteError, match=f"line 5: variant 'only': {message}"):
        load_suite(write(tmp_path, text), dry_build=False)


def test_an_env_can_have_seeds_of_its_own(tmp_path):
    text = """\
envs: [GridWorldWall-v0, GridWorldSquare-v0]
algos: [bc2l]
seeds: [0, 1]
env_seeds: {GridWorldSquare-v0: [0, 1, 2, 3]}
"""
    suite = load_suite(write(tmp_path, text), dry_build=False)
    assert [run.name for run in suite.runs()] == [
        "base/bc2l/GridWorldWall-v0/seed 0",
        "base/bc2l/GridWorldWall-v0/seed 1",
        *(f"base/bc2l/GridWorldSquare-v0/seed {seed}" for seed in range(4)),
    ]
    assert [run.seed for run in suite.select({"seed": ["3"]})] == [3]
    with pytest.raises(SuiteError, match="it has seed: 0, 1, 2, 3"):
        suite.select({"seed": ["7"]})
    # Values that each exist but never together: the error says which seeds each env runs
    with pytest.raises(SuiteError, match=r"no run has them all \(GridWorldWall-v0 runs seeds 0, 1\)"):
        suite.select({"env": ["GridWorldWall-v0"], "seed": ["3"]})


def test_unknown_suite_name_lists_the_shipped_ones():
    with pytest.raises(SuiteError, match="table3"):
        load_suite("tabel3")


def test_run_folder_is_a_function_of_cell_and_seed(tmp_path):
    suite = load_suite(write(tmp_path, TINY_SUITE))
    run = suite.runs()[0]
    assert run.run_folder("logs") == os.path.join("logs", "suite", "base", "bc2l", "GridWorldWall-v0_0")
    assert run.train_argv("logs")[:10] == [
        "--algo",
        "bc2l",
        "--env",
        "sb3_icrl/GridWorldWall-v0",
        "--seed",
        "0",
        "-f",
        os.path.join("logs", "suite", "base"),
        "--exp-id",
        "0",
    ]
    assert "--resume" in run.train_argv("logs")
    assert [r.seed for r in suite.select({"algo": ["vicrl"], "seed": ["1"]})] == [1]
    with pytest.raises(SuiteError, match="matches none"):
        suite.select({"algo": ["mecl"]})


def test_runs_train_on_the_cpu_unless_the_suite_says_otherwise(tmp_path):
    argv = load_suite(write(tmp_path, TINY_SUITE)).runs()[0].train_argv("logs")
    assert argv[argv.index("--device") + 1] == "cpu"
    on_gpu = load_suite(write(tmp_path, TINY_SUITE.replace("save_freq: 0}", "save_freq: 0, device: cuda}"))).runs()[0]
    argv = on_gpu.train_argv("logs")
    assert argv[argv.index("--device") + 1] == "cuda"


def test_variant_settings_become_train_flags():
    suite = load_suite("imperfect")
    argv = suite.runs()[0].train_argv("logs")
    assert argv[argv.index("--violating-fraction") + 1] == "0.2"
    noisy = load_suite("noise").runs()[-1].train_argv("logs")
    assert noisy[noisy.index("--transition-noise") + 1] == "0.1"
    # The noise suite is compared with the paper's table: it draws the noise as the paper's code does
    assert {settings["transition_noise_model"] for settings in load_suite("noise").variants.values()} == {"shared"}
    assert noisy[noisy.index("--transition-noise-model") + 1] == "shared"


# ---------------------------------------------------------------- statistics against hand computation


def test_iqm_is_the_mean_of_the_middle_half():
    assert iqm([1, 2, 3, 4, 100, 5, 6, 7]) == pytest.approx((3 + 4 + 5 + 6) / 4)
    assert iqm([2.0]) == 2.0


def test_stratified_bootstrap_resamples_each_task_on_its_own():
    tasks = [np.array([1.0, 2.0, 3.0]), np.array([10.0, 20.0])]
    lower, upper = stratified_bootstrap_ci(tasks, statistic=np.mean, reps=500, seed=3)
    rng = np.random.default_rng(3)
    estimates = [np.mean(np.concatenate([task[rng.integers(0, len(task), len(task))] for task in tasks])) for _ in range(500)]
    assert (lower, upper) == pytest.approx(tuple(np.percentile(estimates, [2.5, 97.5])))
    # Every resample keeps three scores of the first task and two of the second: bounds within the possible means
    assert (1 * 3 + 10 * 2) / 5 <= lower <= upper <= (3 * 3 + 20 * 2) / 5


def _result(algo: str, seed: int, feasible: float, violation: float) -> RunResult:
    return RunResult(f"r/{algo}/{seed}", algo, "sb3_icrl/GridWorldWall-v0", seed, 100, 1.0, violation, feasible, feasible, 20)


def test_summary_cells_hold_hand_computed_statistics(tmp_path):
    suite = load_suite(write(tmp_path, TINY_SUITE.replace("seeds: [0, 1]", "seeds: [0, 1, 2, 3, 4]")))
    feasible = {"bc2l": [1.0, 2.0, 3.0, 4.0, 5.0], "vicrl": [2.0, 3.5, 4.0, 6.0, 9.0]}
    results = [(run, _result(run.algo, run.seed, feasible[run.algo][run.seed], 0.1 * run.seed)) for run in suite.runs()]
    summary = summarise_suite(suite, suite.runs(), results)
    bc2l = next(cell for cell in summary["cells"] if cell["algo"] == "bc2l")
    assert bc2l["feasible_reward_mean"] == pytest.approx(3.0)
    assert bc2l["feasible_reward_std"] == pytest.approx(np.sqrt(10 / 4))  # the sample std: squares summing to 10, n - 1 = 4
    assert bc2l["feasible_reward_iqm"] == pytest.approx(3.0)  # trim 25% of 5: one score each side
    assert bc2l["feasible_reward_spread"]["kind"] == "iqm"  # five seeds: an IQM with its bootstrap interval
    # bc2l is below vicrl on all five seeds: the exact two-sided signed-rank p is 2 / 2^5
    assert bc2l["wilcoxon_p"] == pytest.approx(2 / 32)
    assert bc2l["wilcoxon_p"] == pytest.approx(scipy.stats.wilcoxon(np.subtract(feasible["bc2l"], feasible["vicrl"])).pvalue)
    assert [seed["feasible_reward"] for seed in bc2l["per_seed"]] == feasible["bc2l"]
    assert summary["runs_missing"] == []
    table = markdown_table(summary)
    # Per-seed rewards at the precision their size asks for: a small reward keeps two decimals
    assert "0: 1.00 / 0%, 1: 2.00 / 10%" in table and "| vicrl |" in table
    assert "| IQM 3.00 [" in table
    # Five pairs cannot reach p < 0.05 in a two-sided Wilcoxon test: the table has no column for it
    assert "Wilcoxon" not in table
    partial = summarise_suite(suite, suite.runs(), results[:-1])
    assert partial["runs_missing"] == [suite.runs()[-1].name]


def test_identification_text_names_how_a_cost_meets_the_level_at_the_safe_end():
    from sb3_icrl.benchmark.report_text import _identification_text

    for crossing in ("everywhere", "reversed", "both ends"):
        seed = {"identification_auroc": 0.5, "threshold_error": float("inf"), "threshold_crossing": crossing}
        assert _identification_text(seed) == f"0.50 / {crossing}"
    # An infinite error with no crossing recorded: at or above the level at the safe end, its shape not known
    assert _identification_text({"identification_auroc": 0.5, "threshold_error": float("inf")}) == "0.50 / safe end"
    assert _identification_text({"identification_auroc": 0.9, "threshold_error": -4.831}) == "0.90 / -4.83"
    assert _identification_text({"identification_auroc": 0.9, "threshold_error": float("nan")}) == "0.90 / -"
    assert _identification_text({}) == "-"


def test_headline_keeps_the_safe_end_and_nowhere_apart_through_strict_json():
    """Strict JSON writes both non-finite threshold errors as null: the crossing tells a summary read back which."""
    import json

    from sb3_icrl.benchmark.report_numbers import finite_or_null
    from sb3_icrl.benchmark.report_text import _identification_text
    from sb3_icrl.metrics.identification import headline

    def scores(error: float) -> dict:
        return {"auroc": 0.5, "features": {"x": {"at_0.5": {"threshold_error": error}}}}

    rows = [headline(scores(error)) for error in (float("inf"), float("nan"), -1.25)]
    assert [row["threshold_crossing"] for row in rows] == ["safe end", "nowhere", "crosses"]
    read_back = [json.loads(json.dumps(finite_or_null(row), allow_nan=False)) for row in rows]
    assert [row["threshold_error"] for row in read_back] == [None, None, -1.25]
    assert [_identification_text(row) for row in read_back] == ["0.50 / safe end", "0.50 / -", "0.50 / -1.25"]


def test_the_held_out_episode_length_goes_with_each_seed(tmp_path):
    suite = load_suite(write(tmp_path, TINY_SUITE))
    results = [(run, _result(run.algo, run.seed, 1.0, 0.0)) for run in suite.runs()]
    results[0][1].episode_length = 12.5  # the first run ended its episodes after 12.5 steps on average
    summary = summarise_suite(suite, suite.runs(), results)
    lengths = [seed["episode_length"] for cell in summary["cells"] for seed in cell["per_seed"]]
    assert lengths[0] == 12.5 and all(np.isnan(length) for length in lengths[1:])  # unknown for the others
    rows = list(csv.DictReader(io.StringIO(csv_rows(summary))))
    assert [row["episode_length"] for row in rows] == ["12.5", "", "", ""]


def _learned_cost(algo: str) -> dict:
    """What a report keeps of one run's learned cost (a threshold on one feature)."""
    curve = {"values": [-0.02, -0.01, 0.0], "mean_cost": [0.9, 0.6, 0.1]}
    features = {"x_position": {"threshold": -0.015, "op": "<=", "curve": curve}}
    return {"run": f"r/{algo}", "env": "sb3_icrl/BiasedPendulum-v0", "algo": algo, "features": features}


def _curves(n_evals: int = 3) -> dict:
    """What a report keeps of one run's training curves."""
    steps = [256.0 * (i + 1) for i in range(n_evals)]
    return {"timesteps": steps, "violations": [0.5] * n_evals, "feasible_rewards": [1.0] * n_evals, "results": [1.0] * n_evals}


def test_constraint_figures_draw_the_scored_runs_of_each_env(tmp_path, monkeypatch):
    """One learned-cost figure per env and variant, from the runs the report scored; none where nothing can be drawn."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    import sb3_icrl.benchmark.report_figures as report_figures
    from sb3_icrl.benchmark.report_figures import constraint_figures

    suite = load_suite(write(tmp_path, TINY_SUITE))
    results = [(run, _result(run.algo, run.seed, 1.0, 0.0)) for run in suite.runs()]
    summary = summarise_suite(suite, suite.runs(), results)
    for cell in summary["cells"]:
        cell["per_seed"][0]["identification_auroc"] = 0.9  # seed 0 of each algorithm was scored, seed 1 not
    data = {run.name: {"learned_cost": _learned_cost(run.algo)} for run in suite.runs()}
    drawn = []

    def fake_figure(curves, title=None, **kwargs):
        drawn.append(([curve["algo"] for curve in curves], title))
        return Figure()

    monkeypatch.setattr(report_figures, "learned_cost_figure", fake_figure)
    output = str(tmp_path / "report")
    written = constraint_figures(summary, suite, output, data)
    assert written == [os.path.join(output, "constraint_GridWorldWall-v0_base.png")] and os.path.isfile(written[0])
    assert drawn == [(list(suite.algos), "GridWorldWall-v0 (base): learned cost")]
    # A scored run with no curve kept: the title names the methods drawn
    drawn.clear()
    del data[RunSpec(suite.name, "base", suite.algos[0], "sb3_icrl/GridWorldWall-v0", 0, 512).name]
    constraint_figures(summary, suite, output, data)
    assert drawn == [([suite.algos[1]], f"GridWorldWall-v0 (base, curves of {suite.algos[1]} only): learned cost")]

    def no_feature(curves, title=None, **kwargs):
        raise ValueError("the env's constraint is not a threshold on a feature")

    monkeypatch.setattr(report_figures, "learned_cost_figure", no_feature)
    assert constraint_figures(summary, suite, str(tmp_path / "none"), data) == []


def test_a_learned_cost_figure_does_not_miss_the_reference_rows(tmp_path):
    """The reference rows learn no cost: a learned-cost figure of every ICRL method says nothing is missing."""
    from sb3_icrl.benchmark.report_figures import _partial
    from sb3_icrl.registry import ICRL_ALGOS

    suite = load_suite(write(tmp_path, TINY_SUITE.replace("algos: [bc2l, vicrl]", "algos: [bc2l, vicrl, ppolag]")))
    summary = summarise_suite(suite, suite.runs(), [(run, _result(run.algo, run.seed, 1.0, 0.0)) for run in suite.runs()])
    env = "sb3_icrl/GridWorldWall-v0"
    assert _partial(summary, env, "base", {"bc2l", "vicrl"}, ICRL_ALGOS) == ""
    assert _partial(summary, env, "base", {"bc2l"}, ICRL_ALGOS) == ", curves of bc2l only"
    assert _partial(summary, env, "base", {"bc2l", "vicrl"}) == ", curves of bc2l, vicrl only"  # training curves: all rows


def test_figure_data_from_run_folders_else_from_the_earlier_report(tmp_path):
    """A run's figure data come from its folder; a run whose folder is gone keeps what the earlier report had."""
    from sb3_icrl.benchmark.report_figures import FIGURE_DATA_FILE, figure_data, run_figure_data
    from sb3_icrl.metrics.identification import identification_file

    suite = load_suite(write(tmp_path, TINY_SUITE))
    results = [(run, _result(run.algo, run.seed, 1.0, 0.0)) for run in suite.runs()]
    summary = summarise_suite(suite, suite.runs(), results)
    root, output = str(tmp_path / "logs"), tmp_path / "report"
    here, gone, *_ = suite.runs()
    folder = pathlib.Path(here.run_folder(root))
    folder.mkdir(parents=True)
    # Two evaluations of two episodes each: the curves keep each evaluation's mean
    np.savez(
        folder / "evaluations.npz",
        timesteps=np.array([256, 512]),
        results=np.array([[1.0, 0.0], [1.0, 1.0]]),
        violations=np.array([[1.0, 0.0], [0.0, 0.0]]),
        feasible_rewards=np.array([[0.0, 0.0], [1.0, 0.5]]),
    )
    scores = {"features": {"x": {"threshold": 0.5, "op": ">=", "curve": {"values": [0, 1], "mean_cost": [0.1, 0.8]}}}}
    identification = {"run": str(folder), "env": here.env_id, "algo": here.algo, "scores": scores, "settings": {}}
    (folder / identification_file("final")).write_text(json.dumps(identification))
    kept = run_figure_data(here, root)
    assert kept["curves"] == {
        "timesteps": [256.0, 512.0],
        "results": [0.5, 1.0],
        "violations": [0.5, 0.0],
        "feasible_rewards": [0.0, 0.75],
    }
    assert kept["learned_cost"]["features"]["x"]["curve"] == {"values": [0, 1], "mean_cost": [0.1, 0.8]}
    assert run_figure_data(gone, root) == {}
    output.mkdir()
    earlier = {gone.name: {"curves": _curves()}, here.name: {"curves": {}, "learned_cost": _learned_cost("bc2l")}}
    (output / FIGURE_DATA_FILE).write_text(json.dumps({"suite": suite.name, "model": "final", "runs": earlier}))
    # A folder whose run has not finished (trained again) gives nothing: the report's data stand
    assert figure_data(summary, suite, root, str(output)) == earlier
    (folder / "finished.json").write_text(json.dumps({"num_timesteps": 512}))
    data = figure_data(summary, suite, root, str(output))
    assert data == {here.name: kept, gone.name: {"curves": _curves()}}  # the folder's data replace the report's
    # Key by key: a finished folder without its identification keeps the report's learned cost
    (folder / identification_file("final")).unlink()
    data = figure_data(summary, suite, root, str(output))
    assert data[here.name] == {"curves": kept["curves"], "learned_cost": _learned_cost("bc2l")}
    # Another suite's or model's file in the folder draws nothing here
    for other in ({"suite": "other", "model": "final"}, {"suite": suite.name, "model": "best"}):
        (output / FIGURE_DATA_FILE).write_text(json.dumps({**other, "runs": earlier}))
        assert figure_data(summary, suite, root, str(output)) == {here.name: {"curves": kept["curves"]}}


def test_an_updated_report_tells_the_kept_runs_crossings_from_their_kept_curves(tmp_path):
    """Reports once named every cost at or above 0.5 at the safe end "everywhere": an update tells them apart."""
    from sb3_icrl.benchmark.report_figures import refresh_crossings

    suite = load_suite(write(tmp_path, TINY_SUITE))
    kept = [(run, _result(run.algo, run.seed, 1.0, 0.0)) for run in suite.runs()[:4]]
    with_curve, with_flat_curve, _, crossing = (run for run, _ in kept)

    def learned(costs: list[float]) -> dict:
        return {"learned_cost": {"features": {"x": {"op": "<=", "curve": {"values": [0, 1, 2], "mean_cost": costs}}}}}

    data = {with_curve.name: learned([0.1, 0.2, 0.9]), with_flat_curve.name: learned([0.7, 0.6, 0.9])}
    data[crossing.name] = learned([0.9, 0.2, 0.1])
    metrics = {result.run: {"threshold_crossing": "everywhere", "threshold_error": float("inf")} for _, result in kept}
    metrics[kept[3][1].run] = {"threshold_crossing": "crosses", "threshold_error": 0.5}
    assert refresh_crossings(kept, metrics, data) == 2
    assert [metrics[result.run]["threshold_crossing"] for _, result in kept] == [
        "reversed",  # x <= t is unsafe: high at the safe (right) end only
        "everywhere",
        "safe end",  # no curve kept: only that it is at or above 0.5 at the safe end
        "crosses",
    ]
    assert refresh_crossings(kept, metrics, data) == 0  # a second update changes nothing


def test_figures_follow_the_cells_the_report_keeps(tmp_path, monkeypatch):
    """Training curves only for the envs and variants of the report's cells (its --only filter), not the whole suite."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    import sb3_icrl.benchmark.report_figures as report_figures
    from sb3_icrl.benchmark.report_figures import FIGURE_DATA_FILE, write_figures

    text = TINY_SUITE.replace("envs: [GridWorldWall-v0]", "envs: [GridWorldWall-v0, GridWorldSquare-v0]")
    suite = load_suite(write(tmp_path, text))
    kept = [run for run in suite.runs() if run.env_id.endswith("GridWorldWall-v0")]
    summary = summarise_suite(suite, kept, [(run, _result(run.algo, run.seed, 1.0, 0.0)) for run in kept])
    data = {run.name: {"curves": _curves()} for run in suite.runs()}
    data[kept[0].name]["curves"]["results"][0] = float("nan")  # written as null: the file is strict JSON
    monkeypatch.setattr(report_figures, "figure_data", lambda *args: data)
    drawn = []
    monkeypatch.setattr(
        report_figures, "training_curves_figure", lambda runs, title: drawn.append((sorted(runs), title)) or Figure()
    )
    monkeypatch.setattr(report_figures, "constraint_figures", lambda *args: [])
    output = tmp_path / "report"
    written = write_figures(summary, suite, str(tmp_path / "logs"), str(output))
    assert [os.path.basename(path) for path in written] == [FIGURE_DATA_FILE, "curves_GridWorldWall-v0_base.png"]
    assert drawn == [(["BC2L", "VICRL"], "GridWorldWall-v0 (base)")]

    def strict(constant):
        raise ValueError(f"{constant} in strict JSON")

    kept_data = json.loads((output / FIGURE_DATA_FILE).read_text(), parse_constant=strict)["runs"]
    assert kept_data.keys() == data.keys() and kept_data[kept[0].name]["curves"]["results"][0] is None
    # A method with no finished run yet (a suite part-way): the others' curves are drawn, without it, and said so
    drawn.clear()
    first = [run for run in kept if run.algo == suite.algos[0]]
    summary = summarise_suite(suite, kept, [(run, _result(run.algo, run.seed, 1.0, 0.0)) for run in first])
    write_figures(summary, suite, str(tmp_path / "logs"), str(output))
    assert drawn == [(["BC2L"], "GridWorldWall-v0 (base)")]
    # A finished run with no curve kept (its folder gone, an earlier report without them): named in the title
    drawn.clear()
    summary = summarise_suite(suite, kept, [(run, _result(run.algo, run.seed, 1.0, 0.0)) for run in kept])
    data = {run.name: {"curves": _curves()} for run in first}
    write_figures(summary, suite, str(tmp_path / "logs"), str(output))
    assert drawn == [(["BC2L"], "GridWorldWall-v0 (base, curves of bc2l only)")]
    # Nothing to draw: no figure written, the one there stays
    data = {}
    written = write_figures(summary, suite, str(tmp_path / "logs"), str(output))
    assert [os.path.basename(path) for path in written] == [FIGURE_DATA_FILE]


# ---------------------------------------------------------------- the held-out evaluation budget

HEAD = "envs: [GridWorldWall-v0]\nalgos: [bc2l]\nseeds: [0]\n"


def test_eval_budget_defaults_to_episodes_and_names_a_bad_value(tmp_path):
    assert load_suite(write(tmp_path, HEAD)).eval_budget == "episodes"
    assert load_suite(write(tmp_path, HEAD + "eval_budget: steps\n")).eval_budget == "steps"
    assert load_suite(write(tmp_path, HEAD + "eval_budget: episodes\n")).eval_budget == "episodes"
    for value, shown in (("Steps", "'Steps'"), ("[steps]", r"\['steps'\]"), ("20", "20")):
        path = write(tmp_path, HEAD + f"eval_budget: {value}\n")
        allowed = r"`eval_budget` is one of episodes \(exactly eval_episodes .*\); steps \(the steps of .*\)"
        with pytest.raises(SuiteError, match=f"line 4: {allowed}, got {shown}\\.$") as error:
            load_suite(path)
        assert path in str(error.value)


def test_suites_with_a_committed_report_evaluate_by_steps_as_it_was_made():
    """Their cached evaluations and numbers stay valid; the report of record and the suites never run count episodes."""
    assert load_suite("table3").eval_budget == "episodes"
    assert load_suite("table3_dev").eval_budget == "steps"
    # The studies written before exact episodes count steps; those written after, episodes
    exact = {"multi_tuning", "vicrl_match_two_sided"}
    assert {path.stem: load_suite(str(path), dry_build=False).eval_budget for path in STUDIES} == {
        path.stem: "episodes" if path.stem in exact else "steps" for path in STUDIES
    }
    for name in ("noise", "imperfect", "multi", "experts", "smoke"):
        assert load_suite(name, dry_build=False).eval_budget == "episodes", name


def _finished_run(tmp_path, budget: str) -> tuple:
    """A suite of one GridWorldWall run (2 held-out episodes of at most 50 steps), its finished run folder and root."""
    suite = load_suite(write(tmp_path, HEAD + f"steps: 512\neval_episodes: 2\neval_budget: {budget}\n"))
    [run] = suite.runs()
    root = str(tmp_path / "logs")
    folder = pathlib.Path(run.run_folder(root))
    folder.mkdir(parents=True, exist_ok=True)
    (folder / FINISHED_FILE).write_text("{}")
    os.utime(folder / FINISHED_FILE, (0, 0))  # the caches are newer than the run's end
    return suite, run, folder, root


def _fake_evaluations(monkeypatch) -> list:
    """``report.evaluate_run`` replaced: each call's (steps, seed, episode count) recorded, a result of as many episodes."""
    calls = []

    def evaluate(folder, steps, seed, load_best=False, env_kwargs=None, **budget):
        calls.append((steps, seed, budget))
        n_episodes = budget.get("n_episodes", 7)
        return RunResult(folder, "bc2l", "sb3_icrl/GridWorldWall-v0", 0, 512, 1.0, 0.0, 1.0, 1.0, n_episodes)

    monkeypatch.setattr(report, "evaluate_run", evaluate)
    return calls


def test_a_steps_cache_written_before_the_budget_key_is_used_as_it_is(tmp_path, monkeypatch):
    """Every run folder of a committed report holds such a heldout.json: by steps, it is used, not evaluated again."""
    suite, run, folder, root = _finished_run(tmp_path, "steps")
    settings = {"eval_seed": 100, "n_timesteps": 100}  # as written before eval_budget: 2 episodes of 50 steps
    assert report.heldout_settings(suite, run.env_id) == settings
    assert report.heldout_settings(suite, run.env_id, "best") == {**settings, "model": "best"}
    saved = RunResult("elsewhere", "bc2l", "sb3_icrl/GridWorldWall-v0", 0, 512, 1.0, 0.25, 3.0, 3.0, 9)
    (folder / report.HELDOUT_FILE).write_text(json.dumps({"settings": settings, "result": dataclasses.asdict(saved)}))
    calls = _fake_evaluations(monkeypatch)
    [(_, result)] = report.evaluate_finished([run], root, suite, log=lambda line: None)
    assert calls == [] and (result.n_episodes, result.feasible_reward, result.violation_rate) == (9, 3.0, 0.25)
    # Without a cache: the steps of 2 full-length episodes, every episode ending in them counted, as before
    (folder / report.HELDOUT_FILE).unlink()
    report.evaluate_finished([run], root, suite, log=lambda line: None)
    assert calls == [(100, 100, {})]
    assert json.loads((folder / report.HELDOUT_FILE).read_text())["settings"] == settings


def test_episodes_and_steps_never_share_a_cache(tmp_path, monkeypatch):
    calls = _fake_evaluations(monkeypatch)
    suite, run, _, root = _finished_run(tmp_path, "episodes")
    assert report.heldout_settings(suite, run.env_id) == {"eval_seed": 100, "n_episodes": 2}
    [(_, result)] = report.evaluate_finished([run], root, suite, log=lambda line: None)
    # Exactly 2 episodes, under a cap of twice the steps of 2 full-length episodes
    assert calls == [(2 * 100, 100, {"n_episodes": 2})] and result.n_episodes == 2
    assert summarise_suite(suite, [run], [(run, result)])["eval_budget"] == "episodes"
    report.evaluate_finished([run], root, suite, log=lambda line: None)
    assert len(calls) == 1  # cached
    # The same run reported by steps: its episodes cache is not used, and the other way round
    steps_suite, *_ = _finished_run(tmp_path, "steps")
    [(_, by_steps)] = report.evaluate_finished([run], root, steps_suite, log=lambda line: None)
    assert calls[1:] == [(100, 100, {})] and by_steps.n_episodes == 7
    assert summarise_suite(steps_suite, [run], [(run, by_steps)])["eval_budget"] == "steps"
    report.evaluate_finished([run], root, steps_suite, log=lambda line: None)
    assert len(calls) == 2
    report.evaluate_finished([run], root, suite, log=lambda line: None)
    assert calls[2:] == [(2 * 100, 100, {"n_episodes": 2})]


def test_a_policy_that_does_not_end_its_episodes_is_left_out_and_said_why(tmp_path, monkeypatch):
    suite, run, folder, root = _finished_run(tmp_path, "episodes")

    def unfinished(*args, **kwargs):
        raise UnfinishedEpisodesError("run: only 1 of its 2 evaluation episodes ended within 200 steps, the cap")

    monkeypatch.setattr(report, "evaluate_run", unfinished)
    logged: list[str] = []
    assert report.evaluate_finished([run], root, suite, log=logged.append) == []
    assert (
        logged[-1]
        == f"{run.name}: left out of the report, run: only 1 of its 2 evaluation episodes ended within 200 steps, the cap"
    )
    assert not (folder / report.HELDOUT_FILE).exists()  # evaluated again next time


# ---------------------------------------------------------------- running suites


def _summary(root, suite: str = "suite") -> dict:
    with open(os.path.join(root, suite, "report", "summary.json")) as file:
        summary = json.load(file)
    return summary


def test_smoke_suite_runs_end_to_end_then_skips_finished_runs(tmp_path, capsys):
    root = str(tmp_path / "logs")
    assert benchmark_main(["run", "smoke", "-f", root, "--jobs", "2"]) == 0
    summary = _summary(root, "smoke")
    assert [(cell["algo"], cell["n_seeds"]) for cell in summary["cells"]] == [
        (a, 2) for a in ("gacl", "bc2l", "mecl", "vicrl")
    ]
    for name in ("table.md", "runs.csv", "table.tex", "curves_GridWorldWall-v0_base.png"):
        assert os.path.isfile(os.path.join(root, "smoke", "report", name)), name
    run = RunSpec("smoke", "base", "bc2l", "sb3_icrl/GridWorldWall-v0", 0, 2048)
    with open(os.path.join(run.run_folder(root), FINISHED_FILE)) as file:
        assert json.load(file)["num_timesteps"] == 2048
    capsys.readouterr()
    assert benchmark_main(["run", "smoke", "-f", root, "--jobs", "2", "--no-report"]) == 0
    out = capsys.readouterr().out
    assert "8/8 done (8 from before)" in out
    assert "before this run: 8 finished · 0 running · 0 interrupted · 0 failed · 0 not started" in out
    assert benchmark_main(["report", "smoke", "-f", root, "--no-figures"]) == 0
    assert _summary(root, "smoke") == summary  # held-out results cached in the run folders, same table


def _without_compute(summary: dict) -> dict:
    """A summary less its training times: two suites with the same results took different times to get them."""
    cells = [
        {
            **{key: value for key, value in cell.items() if key != "core_hours"},
            "per_seed": [
                {key: value for key, value in seed.items() if key not in ("wall_time_s", "cpu_time_s")}
                for seed in cell["per_seed"]
            ],
        }
        for cell in summary["cells"]
    ]
    times = ("core_hours", "core_hours_runs", "cpu_hours", "cpu_hours_runs", "cpu_runs_wall_hours")
    return {**{key: value for key, value in summary.items() if key not in times}, "cells": cells}


def test_kill_9_mid_suite_then_rerun_gives_the_same_table(tmp_path):
    """A suite killed at any moment, then run again, ends with the JSON of a suite that was never interrupted."""
    path = write(tmp_path, TINY_SUITE)
    uninterrupted, interrupted = str(tmp_path / "a"), str(tmp_path / "b")
    assert benchmark_main(["run", path, "-f", uninterrupted, "--jobs", "2"]) == 0
    command = [sys.executable, "-m", "sb3_icrl.benchmark", "run", path, "-f", interrupted, "--jobs", "2", "--no-report"]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 120
    first = RunSpec("suite", "base", "bc2l", "sb3_icrl/GridWorldWall-v0", 0, 512).run_folder(interrupted)
    while not os.path.isfile(os.path.join(first, FINISHED_FILE)) and time.time() < deadline:
        time.sleep(0.2)
    os.kill(process.pid, signal.SIGKILL)  # the suite only: its runs die with it
    process.wait()
    time.sleep(1.0)
    assert benchmark_main(["run", path, "-f", interrupted, "--jobs", "2"]) == 0
    assert _without_compute(_summary(interrupted)) == _without_compute(_summary(uninterrupted))
    assert _summary(interrupted)["core_hours_runs"] == 4


def test_resume_continues_a_run_from_its_checkpoint(tmp_path):
    """An unfinished run with checkpoints goes on from the latest, in the same folder, to the full step count."""
    tiny = TINY_SUITE.replace("save_freq: 0", "save_freq: 256").replace("seeds: [0, 1]", "seeds: [0]")
    path = write(tmp_path, tiny.replace("steps: 512", "steps: 1024"))
    root = str(tmp_path / "logs")
    run = RunSpec("suite", "base", "bc2l", "sb3_icrl/GridWorldWall-v0", 0, 1024)
    assert benchmark_main(["run", path, "-f", root, "--only", "algo=bc2l", "--no-report"]) == 0
    folder = run.run_folder(root)
    # Checkpoints at rollout boundaries (512 steps a rollout): after the first update and at the end
    checkpoints = sorted(name for name in os.listdir(folder) if name.startswith("rl_model_") and name.endswith(".zip"))
    assert checkpoints == ["rl_model_1024_steps.zip", "rl_model_512_steps.zip"]
    # What a kill during the second rollout leaves: no final model, no finished.json, no later checkpoint
    for name in (FINISHED_FILE, "GridWorldWall-v0.zip", "rl_model_1024_steps.zip"):
        os.remove(os.path.join(folder, name))
    with open(os.path.join(folder, "rl_model_1024_steps.zip"), "wb") as file:
        file.write(b"PK\x03\x04 half-written")  # a torn file under a checkpoint's name is passed over
    assert benchmark_main(["run", path, "-f", root, "--only", "algo=bc2l", "--no-report"]) == 0
    with open(os.path.join(folder, FINISHED_FILE)) as file:
        finished = json.load(file)
    assert finished["num_timesteps"] == 1024 and finished["resumed_from"].endswith("rl_model_512_steps.zip")
    with np.load(os.path.join(folder, "evaluations.npz")) as evaluations:
        # The evaluations up to the checkpoint are kept, the later one is made again
        assert evaluations["timesteps"].tolist() == [256, 512, 768, 1024]


def test_failing_run_is_retried_once_then_listed_with_its_log(tmp_path, capsys):
    # (the tiny suite's own variants replaced: a key given twice is a mistake the suite check reports)
    text = TINY_SUITE.replace("variants: {base: {hyperparams: {forward_solver: policy_gradient}}}", "")
    # Demonstrations that do not load: the suite check sees only that the file is there, the run fails on loading them
    # (a hyper-parameter the algorithm refuses is caught by the check, before any run)
    demonstrations = tmp_path / "broken.npz"
    demonstrations.write_bytes(b"not an npz")
    path = write(tmp_path, text + f"variants:\n  broken: {{demonstrations: {demonstrations}}}\n")
    root = str(tmp_path / "logs")
    assert benchmark_main(["run", path, "-f", root, "--jobs", "2", "--only", "algo=bc2l", "seed=0", "--no-report"]) == 1
    out = capsys.readouterr().out
    assert "FAILED: broken/bc2l/GridWorldWall-v0/seed 0" in out
    assert "start (attempt 2)" in out
    log = RunSpec("suite", "broken", "bc2l", "sb3_icrl/GridWorldWall-v0", 0, 512).log_file(root)
    with open(log) as file:
        assert file.read().count("=== ") == 2


def test_ray_backend_runs_the_smoke_suite(tmp_path):
    ray = pytest.importorskip("ray")
    root = str(tmp_path / "logs")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        assert benchmark_main(["run", "smoke", "-f", root, "--backend", "ray", "--only", "algo=bc2l", "seed=0"]) == 0
    finally:
        ray.shutdown()
    run = RunSpec("smoke", "base", "bc2l", "sb3_icrl/GridWorldWall-v0", 0, 2048)
    with open(os.path.join(run.run_folder(root), FINISHED_FILE)) as file:
        assert json.load(file)["num_timesteps"] == 2048
    assert [(cell["algo"], cell["n_seeds"]) for cell in _summary(root, "smoke")["cells"]] == [("bc2l", 1)]


def test_summary_json_is_strict_json(tmp_path):
    from sb3_icrl.benchmark.report import write_report
    from sb3_icrl.benchmark.report_numbers import finite_or_null

    nested = {"cells": [{"threshold_error": float("inf"), "auroc": np.float64(0.9), "ratio": float("nan")}], "n": 3}
    assert finite_or_null(nested) == {"cells": [{"threshold_error": None, "auroc": 0.9, "ratio": None}], "n": 3}
    shipped = os.path.join(os.path.dirname(__file__), "..", "benchmarks", "results", "halfcheetah_tuning", "summary.json")
    with open(shipped) as file:
        summary = json.load(file)
    summary["cells"][0]["threshold_error_mean"] = float("-inf")
    write_report(summary, str(tmp_path))
    text = (tmp_path / "summary.json").read_text()
    assert "Infinity" not in text and "NaN" not in text
    assert json.loads(text)["cells"][0]["threshold_error_mean"] is None


REPOSITORY = pathlib.Path(__file__).resolve().parents[1]
STUDIES = sorted((REPOSITORY / "benchmarks" / "suites").glob("*.yml"))


@pytest.mark.parametrize("path", STUDIES, ids=lambda path: path.stem)
def test_study_suites_build_their_runs_on_tuning_seeds_and_have_a_written_rule(path):
    """
    The studies in benchmarks/suites decide recipes: each parses and builds every run's train.py arguments (a typo
    would otherwise show only when its runs start), runs on the tuning seeds only, and is named in the results' log
    (benchmarks/log/, indexed by RESULTS.md), where its rule is written before its runs.
    """
    suite = load_suite(str(path))
    runs = suite.runs()
    assert runs and all(run.train_argv("logs")[:2] == ["--algo", run.algo] for run in runs)
    assert set(suite.seeds) <= {0, 1, 2}, f"{path.name}: a study decides on the tuning seeds 0, 1, 2 only"
    log = "".join(entry.read_text() for entry in sorted((REPOSITORY / "benchmarks" / "log").glob("*.md")))
    assert f"benchmarks/suites/{path.name}" in log, f"{path.name} has no entry (and rule) in the log of benchmarks/log/"


def test_there_are_study_suites():
    assert {"walker_inputs", "gacl_termination", "highway_velocity_steps"} <= {path.stem for path in STUDIES}
