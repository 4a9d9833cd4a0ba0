"""benchmarks/multi_tuning_rule.py: the rule that decides the several-constraints recipes, on small fixed reports."""

import json
from pathlib import Path

import pytest
from script_loader import load_script

rule = load_script("benchmarks/multi_tuning_rule.py")

#: Half of it, 40, is where episodes "end on purpose"
MEAN_LENGTH = 80.0


def _seeds(*runs: tuple[float, float, float]) -> list[dict]:
    """(feasible reward, violation rate, episode length) per seed 0, 1, 2."""
    return [
        {"seed": seed, "feasible_reward": reward, "violation_rate": rate, "episode_length": length}
        for seed, (reward, rate, length) in enumerate(runs)
    ]


def _runs(changes: dict | None = None) -> dict:
    runs = {
        ("base", "vicrl"): _seeds((10, 0.1, 80), (12, 0.0, 80), (14, 0.2, 80)),  # means 12, 10%
        ("prior-9-1", "vicrl"): _seeds((13, 0.2, 80), (13, 0.1, 80), (13, 0.15, 80)),  # 13, 15%: 5 points more
        ("base", "gacl"): _seeds((2, 0.0, 10), (4, 0.0, 30), (6, 0.0, 90)),  # 4; on purpose on seeds 0 and 1
        ("repeat", "gacl"): _seeds((5, 0.0, 90), (5, 0.0, 30), (5, 0.0, 90)),  # 5; on purpose on seed 1 only
        ("base", "bc2l"): _seeds((1, 0.6, 80), (1, 0.6, 80), (1, 0.6, 80)),  # 60% violations: fails
        ("base", "mecl"): _seeds((1, 0.0, 39.9), (1, 0.0, 20), (1, 0.0, 80)),  # on purpose on 2 seeds: fails
    }
    runs.update(changes or {})
    return runs


def test_each_part_of_the_rule_by_hand():
    decision = rule.decide(_runs(), MEAN_LENGTH)
    assert decision["on_purpose_threshold"] == 40.0
    # 1. [9, 1]: 13 > 12, and 15% is no more than 10% + 5 points: ships
    assert decision["vicrl_prior"]["prior-9-1"] == pytest.approx({"feasible_reward": 13.0, "violation_rate": 0.15})
    assert decision["vicrl_prior"]["ships"] is True
    # 2. zero on purpose on 2 seeds, repeat on 1 with a higher mean (5 > 4): repeat ships
    gacl = decision["gacl_termination_reward"]
    assert (gacl["zero"]["seeds_on_purpose"], gacl["repeat"]["seeds_on_purpose"], gacl["ships"]) == (2, 1, True)
    # 3. BC2L and MECL fail, GACL (on purpose on 2 seeds) fails, VICRL does not: the design carries over
    assert {algo: entry["fails"] for algo, entry in decision["design"]["methods"].items()} == {
        "vicrl": False,
        "gacl": True,
        "bc2l": True,
        "mecl": True,
    }
    assert decision["design"]["carries_over"] is True


def test_each_part_of_the_rule_keeps_the_shipped_recipe_short_of_its_condition():
    # [9, 1] earning more but 5.1 points above in violations (15.1% against 10%): [0.9, 0.1] stays
    prior = _seeds((13, 0.2, 80), (13, 0.1, 80), (13, 0.153, 80))
    # repeat as often on purpose as zero (2 seeds each): zero stays, however much more repeat earns
    repeat = _seeds((50, 0.0, 10), (50, 0.0, 30), (50, 0.0, 90))
    decision = rule.decide(_runs({("prior-9-1", "vicrl"): prior, ("repeat", "gacl"): repeat}), MEAN_LENGTH)
    assert decision["vicrl_prior"]["ships"] is False
    assert decision["gacl_termination_reward"]["ships"] is False
    # With VICRL at 60% violations too, every method fails: the design does not carry over
    vicrl = _seeds((10, 0.6, 80), (12, 0.6, 80), (14, 0.6, 80))
    assert rule.decide(_runs({("base", "vicrl"): vicrl}), MEAN_LENGTH)["design"]["carries_over"] is False


def test_gacls_repeat_needs_each_of_its_three_conditions():
    # Less often on purpose (1 seed against 2) but earning less (3 < 4): zero stays on reward alone
    lower = _seeds((3, 0.0, 90), (3, 0.0, 30), (3, 0.0, 90))
    assert rule.decide(_runs({("repeat", "gacl"): lower}), MEAN_LENGTH)["gacl_termination_reward"]["ships"] is False
    # Earning as much as zero is not enough: higher, strictly
    equal = _seeds((4, 0.0, 90), (4, 0.0, 30), (4, 0.0, 90))
    assert rule.decide(_runs({("repeat", "gacl"): equal}), MEAN_LENGTH)["gacl_termination_reward"]["ships"] is False
    # zero on purpose on one seed only (episodes of exactly 40 steps are not shorter than 40): zero stays
    zero = _seeds((2, 0.0, 10), (4, 0.0, 40), (6, 0.0, 90))
    decision = rule.decide(_runs({("base", "gacl"): zero}), MEAN_LENGTH)
    assert decision["gacl_termination_reward"]["zero"]["seeds_on_purpose"] == 1
    assert decision["gacl_termination_reward"]["ships"] is False
    # GACL then passes rule 3 too (one seed on purpose, no violations)
    assert decision["design"]["methods"]["gacl"]["fails"] is False


def test_the_script_reads_a_report_and_the_shipped_demonstrations(tmp_path, capsys):
    cells = [
        {"env": rule.ENV, "variant": variant, "algo": algo, "per_seed": seeds} for (variant, algo), seeds in _runs().items()
    ]
    cells.append({"env": "HighwayVelocity-v0", "variant": "base", "algo": "vicrl", "per_seed": []})  # another env: left out
    (tmp_path / "summary.json").write_text(json.dumps({"cells": cells, "model": "final", **rule.EVALUATION}))
    out = tmp_path / "decision.json"
    assert rule.main([str(tmp_path), "--json", str(out)]) == 0
    decision = json.loads(out.read_text())
    # The shipped demonstrations: 8242 transitions over 100 episodes
    assert decision["on_purpose_threshold"] == pytest.approx(41.21)
    text = capsys.readouterr().out
    assert "1. VICRL prior: [0.9, 0.1] 12.00 / 10%, [9, 1] 13.00 / 15%: [9, 1] ships." in text
    assert "2. GACL termination reward: zero 4.00, on purpose on 2 seeds; repeat 5.00, on purpose on 1 seeds" in text
    assert "base | mecl | 1 | 1.00 | 0% | 20.0" in text


def test_a_report_the_rule_cannot_judge_is_refused_clearly(tmp_path, capsys):
    assert rule.main([str(tmp_path)]) == 2
    assert "run `benchmark report` first" in capsys.readouterr().err
    runs = _runs()
    del runs[("repeat", "gacl")][2]
    with pytest.raises(
        rule.RuleInputError, match=r"gacl \(repeat\) has seeds \[0, 1\] in the report, the rule judges \[0, 1, 2\]"
    ):
        rule.decide(runs, MEAN_LENGTH)
    (tmp_path / "summary.json").write_text(json.dumps({"cells": [], "model": "best"}))
    with pytest.raises(rule.RuleInputError, match="evaluates best models"):
        rule.read_runs(str(tmp_path))
    Path(tmp_path / "summary.json").write_text(json.dumps({"cells": [], **rule.EVALUATION}))
    with pytest.raises(rule.RuleInputError, match="no run of HighwayVelocityDistance-v0"):
        rule.read_runs(str(tmp_path))
    seeds = _seeds((1, 0.0, 80))
    del seeds[0]["episode_length"]
    Path(tmp_path / "summary.json").write_text(
        json.dumps({"cells": [{"env": rule.ENV, "variant": "base", "algo": "mecl", "per_seed": seeds}], **rule.EVALUATION})
    )
    with pytest.raises(rule.RuleInputError, match=r"mecl \(base\) seed 0 has no episode_length"):
        rule.read_runs(str(tmp_path))
    # Another evaluation, and a method missing from base, are refused too
    Path(tmp_path / "summary.json").write_text(json.dumps({"cells": [], **rule.EVALUATION, "eval_seed": 7}))
    with pytest.raises(rule.RuleInputError, match="evaluates otherwise"):
        rule.read_runs(str(tmp_path))
    runs = _runs()
    del runs[("base", "bc2l")]
    with pytest.raises(rule.RuleInputError, match=r"bc2l \(base\) has seeds \[\]"):
        rule.decide(runs, MEAN_LENGTH)
