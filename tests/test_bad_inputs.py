"""Every CLI, fed the whole bad-input corpus (``tests/bad_inputs/``): exit 2, one ``error:`` line, no traceback."""

from __future__ import annotations

import json

import pytest
import torch
from click.testing import CliRunner

from tests.bad_inputs.cases import CASES
from tests.bad_inputs.workspace import Workspace
from tests.conftest import write_grid_city
from uavplace.cli import uavdata, uavrl
from uavplace.dataset.build import build_city
from uavplace.ingest.pipeline import ingest_city
from uavplace.schemas.bundle import BuildConfig

CLIS = {"uavdata": uavdata, "uavrl": uavrl}


@pytest.fixture(scope="module")
def shared(tmp_path_factory):
    """Built once: a root with the small city ingested and built, and an agent folder (untrained fast-preset weights)."""
    from uavplace.rl.agent.config import preset_config
    from uavplace.rl.agent.dqn import make_network
    from uavplace.rl.agent.runs import RunRecord

    base = tmp_path_factory.mktemp("shared")
    ingest_city(write_grid_city(base / "raw" / "city"), base / "root")
    build_city("city", BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=-60.0), base / "root")
    agent = base / "agent"
    (agent / "checkpoints").mkdir(parents=True)
    config = preset_config("fast")
    env = config.env_config()
    net = make_network(config, env.num_channels, env.window)
    torch.save(
        {"online": net.state_dict(), "config": config.model_dump(mode="json"), "eval": {}}, agent / "checkpoints" / "best.pt"
    )
    record = RunRecord(config=config, datasets={"elsewhere": "0123456789ab"}, train_split=None, eval_split=None, command="",
                       uavplace_version="0", torch_version=torch.__version__, created_utc="")  # fmt: skip
    (agent / "run.json").write_text(json.dumps(json.loads(record.model_dump_json())))
    return base


def test_the_corpus_is_large_and_named_uniquely():
    ids = [c.id for c in CASES]
    assert len(ids) >= 80 and len(set(ids)) == len(ids)
    assert {c.cli for c in CASES} == set(CLIS)


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_input_gives_one_error_line(case, tmp_path, shared, monkeypatch):
    monkeypatch.chdir(tmp_path)  # nothing a case writes by default lands in the repository
    w = Workspace(tmp_path, shared)
    args = case.make(w)
    res = CliRunner().invoke(CLIS[case.cli], args, catch_exceptions=False)
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output
    assert len(lines) == 1 and lines[0].startswith("error: "), res.output
    assert case.expect in lines[0], lines[0]
    assert not list(tmp_path.rglob("PWNED")), "a checkpoint ran code"
