"""benchmarks/pooled_rule.py: the pooled-means rule that decides between two recipes from report runs.csv files."""

import csv
import json
from pathlib import Path

import pytest
from script_loader import load_script

pooled_rule = load_script("benchmarks/pooled_rule.py")

ENV = "BlockedHalfCheetah-v0"


def write_report(
    folder: Path, rows: list[tuple[str, str, int, float, float]], eval_seed: int = 100, budget: dict | None = None
) -> Path:
    folder.mkdir(parents=True)
    path = folder / "runs.csv"
    with open(path, "w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(["env", "variant", "algo", "seed", "feasible_reward", "violation_rate"])
        for variant, algo, seed, reward, violation in rows:
            writer.writerow([ENV, variant, algo, seed, reward, violation])
        writer.writerow(["BlockedSwimmer-v0", "a", "mecl", 0, 1.0, 1.0])  # another env: left out
    (folder / "summary.json").write_text(json.dumps({"eval_episodes": 20, "eval_seed": eval_seed, **(budget or {})}))
    return path


def test_pooled_means_decide_by_hand(tmp_path, capsys) -> None:
    old = write_report(tmp_path / "old", [("a", "mecl", 0, 100.0, 0.0), ("a", "mecl", 1, 300.0, 0.1)])
    new = write_report(tmp_path / "new", [("b", "mecl", 0, 250.0, 0.05), ("b", "mecl", 1, 150.0, 0.0)])
    out = tmp_path / "decision.json"
    assert pooled_rule.main(["--env", ENV, "--before", str(old), "--after", f"{new}:b", "--json", str(out)]) == 0
    decision = json.loads(out.read_text())
    # before: (100 + 300) / 2 = 200, (0 + 0.1) / 2 = 0.05; after: (250 + 150) / 2 = 200, (0.05 + 0) / 2 = 0.025
    assert decision["before"] == pytest.approx({"feasible_reward": 200.0, "violation_rate": 0.05})
    assert decision["after"] == pytest.approx({"feasible_reward": 200.0, "violation_rate": 0.025})
    assert decision["ships"] is True  # equal reward, fewer violations: no worse on both
    assert "ships (no worse on both means)" in capsys.readouterr().out


def test_worse_on_one_mean_does_not_ship(tmp_path) -> None:
    before = {("mecl", 0): pooled_rule.RunRow("mecl", 0, 100.0, 0.0, "x")}
    after = {("mecl", 0): pooled_rule.RunRow("mecl", 0, 500.0, 0.05, "y")}
    assert pooled_rule.decide(before, after)["ships"] is False


def test_unmatched_runs_and_evaluations_are_refused(tmp_path, capsys) -> None:
    old = write_report(tmp_path / "old", [("a", "mecl", 0, 1.0, 0.0), ("a", "mecl", 1, 1.0, 0.0)])
    new = write_report(tmp_path / "new", [("a", "mecl", 0, 1.0, 0.0)])
    assert pooled_rule.main(["--env", ENV, "--before", str(old), "--after", str(new)]) == 2
    assert "only before [('mecl', 1)]" in capsys.readouterr().err
    other = write_report(tmp_path / "other", [("a", "mecl", 0, 1.0, 0.0), ("a", "mecl", 1, 1.0, 0.0)], eval_seed=7)
    assert pooled_rule.main(["--env", ENV, "--before", str(old), "--after", str(other)]) == 2
    assert "evaluated differently" in capsys.readouterr().err
    # A report by exactly 20 episodes against one by the steps of 20 (a summary without the key was by steps)
    exact = write_report(
        tmp_path / "exact", [("a", "mecl", 0, 1.0, 0.0), ("a", "mecl", 1, 1.0, 0.0)], budget={"eval_budget": "episodes"}
    )
    assert pooled_rule.main(["--env", ENV, "--before", str(old), "--after", str(exact)]) == 2
    assert "evaluated differently" in capsys.readouterr().err
    steps = write_report(
        tmp_path / "steps", [("a", "mecl", 0, 1.0, 0.0), ("a", "mecl", 1, 1.0, 0.0)], budget={"eval_budget": "steps"}
    )
    assert pooled_rule.main(["--env", ENV, "--before", str(old), "--after", str(steps)]) == 0
    capsys.readouterr()
    assert pooled_rule.main(["--env", ENV, "--before", str(tmp_path / "none.csv"), "--after", str(new)]) == 2
    assert "no such file" in capsys.readouterr().err
    assert pooled_rule.main(["--env", ENV, "--before", f"{old}:nope", "--after", str(new)]) == 2
    assert "no run of" in capsys.readouterr().err
