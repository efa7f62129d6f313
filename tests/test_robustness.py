"""`uavrl robustness` (eval/robustness.py): the headline methods over the declared conditions, its page, table,
figure and settings written whole; where each method's success first falls below 90 %."""

from __future__ import annotations

import json

import pandas as pd
from click.testing import CliRunner

from uavplace.cli import uavrl
from uavplace.eval.robustness import CONDITIONS, falls, searcher_spread


def test_robustness_plays_every_condition_and_says_where_each_method_falls(tiny, tmp_path):
    out = tmp_path / "rob"
    args = ["robustness", "--dataset", "tiny", "--root", str(tiny), "--episodes", "4", "--target-episodes", "6",
            "--bootstrap", "100", "--out", str(out)]  # fmt: skip
    res = CliRunner().invoke(uavrl, args)
    assert res.exit_code == 0, res.output
    for name in ("index.html", "robustness.md", "robustness.csv", "robustness.png", "robustness.json"):
        assert (out / name).is_file(), name
    table = pd.read_csv(out / "robustness.csv")
    assert list(dict.fromkeys(table["condition"])) == [c.name for c in CONDITIONS]
    methods = set(table["method"])
    assert {"genie", "map searcher", "PQN + GRU (hybrid)", "DQN (paper)", "blind DQN (paper)"} <= methods
    assert table.groupby("condition")["episodes"].first().to_dict() == {c.name: 6 if c.target else 4 for c in CONDITIONS}
    assert (table.loc[table["method"] == "genie", "success"] == 1.0).all()
    record = json.loads((out / "robustness.json").read_text())
    assert [c["name"] for c in record["conditions"]] == [c.name for c in CONDITIONS]
    assert record["config"]["datasets"] == ["tiny"] and record["config"]["episodes"] == 4
    text = (out / "robustness.md").read_text()
    assert all(f"- {m}:" in text for m in methods) and "falls below 90 %" in text
    (out / "notes.txt").write_text("mine")  # a user's file in the folder: never replaced
    res = CliRunner().invoke(uavrl, args)
    assert res.exit_code == 2 and (out / "notes.txt").read_text() == "mine", res.output


def test_falls_names_the_first_condition_under_90_percent_and_the_searcher_declares_the_spread():
    rows = [
        {"method": "a", "condition": CONDITIONS[3].name, "city": "x", "success": 0.85},
        {"method": "a", "condition": CONDITIONS[2].name, "city": "y", "success": 0.89},
        {"method": "a", "condition": CONDITIONS[1].name, "city": "x", "success": 0.95},
        {"method": "b", "condition": CONDITIONS[5].name, "city": "x", "success": 0.90},
    ]
    said = falls(pd.DataFrame(rows))
    assert said == {"a": f"{CONDITIONS[2].name} (y: 89.0 %)", "b": "none"}
    assert [searcher_spread(c) for c in CONDITIONS] == [0.0, 2.0, 4.0, 8.0, 0.0, 0.0, 4.0]
