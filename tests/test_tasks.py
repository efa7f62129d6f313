"""A task is a folder and one line of the registry: a toy task added the way another package adds one (its entry
under the ``uavplace.tasks`` entry-point group), then trained and reported on the tiny city by the commands a user
runs, with no change to uavplace."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pandas as pd

from tests.probes import train_args

#: The toy task: placement's learner hook and env, its own settings model (``steps``: the budget of its report's
#: episodes), its own values of a finished training episode, and its own report.
TOY = {
    "__init__.py": """
        from uavplace.rl.tasks.entry import Task

        TASK = Task(name="toy", model="toytask.config:ToyTask", learning="toytask.learner:learning",
                    report="toytask.report:REPORT")
    """,
    "config.py": """
        from typing import ClassVar, Literal

        from pydantic import Field

        from uavplace.rl.tasks.entry import RunTask


        class ToyTask(RunTask):
            kind: Literal["toy"] = "toy"
            prefix: ClassVar[str | None] = "toy"
            tag: ClassVar[str] = "toy"
            ensembles: ClassVar[bool] = False
            steps: int = Field(default=25, ge=1, description="Toy: steps of a report's episode")
    """,
    "learner.py": """
        from dataclasses import replace

        from uavplace.rl.tasks.placement.learner import learning as placement


        def learning(run, cities):
            def values(info, row, terminated):
                return {"success": terminated, "toy_row": row}

            return replace(placement(run, cities), episode_values=values)
    """,
    "report.py": """
        import numpy as np

        from toytask.config import ToyTask
        from uavplace.eval.config import ReportConfig
        from uavplace.eval.reports.base import TaskReport


        def play(request, after):
            from uavplace.dataset.bundle import load_bundle
            from uavplace.eval.evaluate import load_agent
            from uavplace.rl.tasks.placement.rollout import run_episodes
            from uavplace.rl.world.maps import MapSet
            from uavplace.rl.world.stats import summarise

            request.out.mkdir(parents=True, exist_ok=True)
            for run in request.runs:
                agent = load_agent(run, request.test_epsilon, request.seed, task="toy")
                for city in request.datasets:
                    env = agent.config.env_config(evaluation=True).model_copy(update={"t_max": request.steps})
                    maps = MapSet([load_bundle(city, root=request.root)], env)
                    episodes = maps.sample_episodes(request.episodes, np.random.default_rng(request.seed))
                    table = run_episodes(maps, agent.policy, episodes)
                    table.assign(method=agent.name).to_csv(request.out / f"{city}.csv", index=False)
                    print(f"toy report {city}: success {summarise(table)['success']:.2f}")


        REPORT = TaskReport(
            play=play, summary="the toy task", budget=("steps", "--steps"), config=ReportConfig, searcher="uavplace.rl.tasks.placement.searcher:MapSearchPolicy",
            options=((ToyTask, ("steps",)),),
        )
    """,
}


def _install_toy(site: Path) -> None:
    """The toy task's package and the distribution record that registers it, on ``site`` (a folder on sys.path)."""
    package = site / "toytask"
    package.mkdir(parents=True)
    for name, text in TOY.items():
        (package / name).write_text(textwrap.dedent(text).lstrip())
    record = site / "toytask-0.1.dist-info"
    record.mkdir()
    (record / "METADATA").write_text("Metadata-Version: 2.1\nName: toytask\nVersion: 0.1\n")
    (record / "entry_points.txt").write_text("[uavplace.tasks]\ntoy = toytask:TASK\n")


def _uav(site: Path, *args: str) -> subprocess.CompletedProcess:
    env = os.environ | {"PYTHONPATH": os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")])}
    script = "import sys\nfrom uavplace.cli import uavrl\nuavrl(sys.argv[1:])"
    return subprocess.run([sys.executable, "-c", script, *args], capture_output=True, text=True, env=env, timeout=600)


def test_a_toy_task_from_its_folder_alone_trains_and_reports_on_the_tiny_city(tmp_path, tiny):
    site = tmp_path / "site"
    _install_toy(site)
    trained = _uav(site, *train_args(tiny, tmp_path / "runs", "toy", "--task", "toy", "--set", "toy.steps=30"))
    assert trained.returncode == 0, trained.stderr + trained.stdout
    run = tmp_path / "runs" / "toy"
    record = json.loads((run / "run.json").read_text())
    assert record["config"]["task"] == {"kind": "toy", "steps": 30}
    metrics = pd.read_parquet(run / "metrics.parquet")
    assert (
        "toy_row" in metrics.columns and metrics["toy_row"].between(0, record["config"]["num_envs"] - 1).all()
    )  # the task's own episode values
    assert not (run / "checkpoints" / "best.pt").is_symlink() and (run / "checkpoints" / "best.pt").is_file()

    out = tmp_path / "report"
    args = ["report", "--task", "toy", "--run", str(run), "--dataset", "tiny", "--root", str(tiny), "--episodes", "6"]
    reported = _uav(site, *args, "--steps", "12", "--out", str(out), "--predictor", "none")
    assert reported.returncode == 0, reported.stderr + reported.stdout
    assert "toy report tiny: success" in reported.stdout
    table = pd.read_csv(out / "tiny.csv")
    assert len(table) == 6 and table["steps"].max() <= 12 and set(table["method"]) == {"DQN (fast, toy)"}

    # uavplace itself knows no toy: without the distribution's record the task is unknown to both commands.
    (site / "toytask-0.1.dist-info" / "entry_points.txt").unlink()
    refused = _uav(site, *args)
    assert refused.returncode == 2 and "'toy' is not one of 'placement', 'tracking', 'fleet'" in refused.stderr
