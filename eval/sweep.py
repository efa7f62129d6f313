"""``uavrl sweep SPEC``: training runs as Ray Tune trials, then one table on the validation cities.

A sweep is a TOML file that ``SweepSpec`` validates: the training cities, families of trials (a preset,
settings that override it, seeds) and ensembles of finished trials. Each trial is a normal run folder
``OUT/<family>-s<seed>/`` made by the same code as ``uavrl train`` (``rl.agent.train.start_run``):
``uavrl report --run`` plays it, ``uavrl train --resume`` continues it. Ray Tune schedules the trials
(a local Ray by default, a cluster with ``--ray-address``; ``--cpus-per-trial`` CPUs each, the torch
threads of the trial); resuming is the run folders' own: running the sweep again continues every
unfinished trial from its last checkpoint and skips the finished ones. Tune's own state goes to
``OUT/.tune/`` and is never read back.

At the end every trial and ensemble is played on the validation cities with the report's evaluation
(``eval.evaluate.evaluate``: 1000 fixed episodes a city, t_max 500, test epsilon 0.096, the genie beside
it), never on a test city, and the table is written to ``OUT/sweep.md`` and ``OUT/sweep.csv``, next to
the spec it came from (``OUT/sweep.toml``).
"""

from __future__ import annotations

import datetime as dt
import json
import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Literal

import pandas as pd
from pydantic import Field, field_validator, model_validator

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.cities import development_cities
from uavplace.eval.evaluate import ReportConfig, evaluate, load_agent
from uavplace.eval.metrics import bootstrap_table, difference_table
from uavplace.infra.cluster import start_ray
from uavplace.infra.files import atomic_write_text, check_name, read_model_toml
from uavplace.infra.limits import check_limit
from uavplace.rl.agent.config import DQNConfig, parse_settings, preset_config
from uavplace.rl.tasks.placement.policies import GeniePolicy
from uavplace.rl.world.stats import format_stat
from uavplace.schemas import InputError
from uavplace.schemas.base import MAX_SEED, Contract, repeated

#: The spec, as it was given, beside the runs it made.
SPEC_COPY = "sweep.toml"


class TrialSpec(Contract):
    """A family of trials: one run per seed, named ``<name>-s<seed>``."""

    name: str = Field(description="Family name; its runs are OUT/<name>-s<seed>/")
    preset: Literal["paper", "fast", "best", "best-pqn", "best-dqn"] = Field(
        default="best", description="rl/agent/config.py PRESETS"
    )
    agent: Literal["dqn", "blind"] = Field(default="dqn", description="dqn: height map + SINR memory; blind: SINR memory only")
    seeds: list[int] = Field(default=[0], min_length=1, description="One run per seed")
    steps: int | None = Field(default=None, ge=1, description="Environment steps (default: the preset's)")
    eval_every: int | None = Field(default=None, ge=1, description="Steps between validation evaluations (default: the preset's)")
    settings: dict[str, str | int | float | bool | list[int | float]] = Field(
        default_factory=dict, description="Fields of DQNConfig to override, env fields as 'env.FIELD' (as `uavrl train --set`)"
    )

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        return check_name(v, "trial name")

    @field_validator("settings")
    @classmethod
    def _not_a_trial_field(cls, v: dict) -> dict:
        own = {"agent": "agent", "seed": "seeds", "total_steps": "steps", "eval_every": "eval_every"}
        clash = [f"{k} (use the trial's {own[k]})" for k in v if k in own]
        if clash:
            raise ValueError(f"{', '.join(clash)}: these have their own trial fields")
        return v

    @field_validator("seeds")
    @classmethod
    def _unique(cls, v: list[int]) -> list[int]:
        if len(set(v)) != len(v):
            raise ValueError(f"seeds {v} repeat a seed")
        return v

    def configs(self) -> dict[str, DQNConfig]:
        """Run name -> its config, as ``uavrl train --preset ... --set ... --seed ...`` would make it."""
        settings = parse_settings([f"{k}={v if isinstance(v, str) else json.dumps(v)}" for k, v in self.settings.items()])
        extra = ({"total_steps": self.steps} if self.steps else {}) | ({"eval_every": self.eval_every} if self.eval_every else {})
        return {
            f"{self.name}-s{s}": preset_config(self.preset, **settings, **extra, agent=self.agent, seed=s) for s in self.seeds
        }


class EnsembleSpec(Contract):
    """Finished trials played as one agent (``uavrl ensemble``), into ``OUT/<name>/``."""

    name: str
    members: list[str] = Field(min_length=2, description="Run names of the sweep (<family>-s<seed>)")

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        return check_name(v, "ensemble name")


class SweepSpec(Contract):
    """A sweep file (TOML): what to train, on which cities, and where to compare it."""

    datasets: list[str] = Field(min_length=1, description="Training cities or corpora, as `uavrl train --dataset`")
    val_datasets: list[str] = Field(default_factory=list, description="Extra cities best.pt is selected on (`--val-dataset`)")
    cities: list[str] = Field(
        default_factory=list, description="Validation cities of the final table (default: every built city with the val role)"
    )
    episodes: int = Field(default=1000, ge=1, description="Episodes per city in the final table")
    seed: int = Field(default=0, ge=0, le=MAX_SEED, description="Seed of the final table's episodes and random moves")
    trials: list[TrialSpec] = Field(min_length=1)
    ensembles: list[EnsembleSpec] = Field(default_factory=list)

    @model_validator(mode="after")
    def _names(self) -> SweepSpec:
        runs = self.run_names()
        if len(set(runs)) != len(runs):
            raise ValueError(f"two trials share a run name: {repeated(runs)[0]}")
        for e in self.ensembles:
            unknown = [m for m in e.members if m not in runs]
            if unknown:
                raise ValueError(f"ensemble {e.name}: {unknown[0]} is not a run of the sweep (runs: {', '.join(runs)})")
            if e.name in runs:
                raise ValueError(f"ensemble {e.name} has a run's name")
        return self

    def run_names(self) -> list[str]:
        return [f"{t.name}-s{s}" for t in self.trials for s in t.seeds]

    def configs(self) -> dict[str, DQNConfig]:
        return {name: config for t in self.trials for name, config in t.configs().items()}


def read_spec(path: str | Path) -> SweepSpec:
    """A sweep file, validated (every config made once, so that a bad setting is refused before Ray starts);
    ``InputError`` naming the file and the field."""
    path = Path(path)
    spec = read_model_toml(path, SweepSpec, "a sweep file", missing="no such sweep file")
    check_limit("sweep_runs", len(spec.run_names()), path, "runs (trials x seeds)", field="trials")
    try:
        spec.configs()
    except InputError as err:
        raise InputError(path, err.message, field=f"settings.{err.field}" if err.field else "settings") from None
    return spec


#: What a training run writes in its folder: a trial's folder holding anything else is not one the sweep made.
RUN_ENTRIES = frozenset({"run.json", "metrics.parquet", "eval.parquet", "checkpoints"})


def _remove_unstarted(run_dir: Path, config: DQNConfig, remove: bool = True) -> None:
    """Remove a trial's folder that a sweep started but never checkpointed (nothing to continue), and only that: a
    folder that is not a training run of ``config`` (no ``run.json``, another config, or other files beside the run's)
    is refused (``InputError``), never removed. ``remove=False``: only the refusal."""
    from uavplace.rl.agent.runs import read_run_json

    if run_dir.is_symlink() or not run_dir.is_dir() or not (run_dir / "run.json").is_file():
        raise InputError(
            run_dir, "exists and is not a training run: a sweep removes only what it made; move it away, or rename the trial"
        )
    if read_run_json(run_dir).config.model_dump() != config.model_dump():
        raise InputError(run_dir, "holds a run of other settings than the sweep's: move it away, or rename the trial")
    strangers = sorted(p.name for p in run_dir.iterdir() if p.name not in RUN_ENTRIES)
    if strangers:
        raise InputError(
            run_dir,
            f"holds files a run does not write ({', '.join(strangers[:3])}): a sweep removes only what it made; move them away",
        )
    if remove:
        shutil.rmtree(run_dir)  # started but never checkpointed: nothing to continue


def check_held_out(spec: SweepSpec, path: Path, root: Path) -> None:
    """Refuse (``InputError`` naming the sweep file) a validation city of the sweep (``val_datasets``, ``cities``)
    that is also one of its training cities: the table would score the runs where they learnt."""
    from uavplace.dataset.catalog import expand_datasets

    trained = set(expand_datasets(spec.datasets, root))
    for field in ("val_datasets", "cities"):
        both = sorted(trained & set(expand_datasets(getattr(spec, field), root)))
        if both:
            raise InputError(
                path,
                f"{', '.join(both)}: a training city of the sweep is also a validation city: the "
                "table would score the runs where they learnt",
                field=field,
            )


def _trial(tune_config: dict) -> None:
    """One Ray Tune trial (``{"trial": params}``): train (or continue, or skip) the run ``params["run"]`` under the run
    folder's lock, then report its last validation evaluation to Tune."""
    import torch
    from ray import tune

    from uavplace.infra.files import exclusive_folder
    from uavplace.rl.agent.runs import run_finished
    from uavplace.rl.agent.train import start_run

    params = tune_config["trial"]
    config = DQNConfig.model_validate_json(params["config"])
    run_dir = Path(params["out"]) / params["run"]
    torch.set_num_threads(max(1, int(params["cpus"])))
    with exclusive_folder(run_dir, "training run"):
        if not run_finished(run_dir):
            resume = (run_dir / "checkpoints" / "last").is_dir()
            if run_dir.exists() and not resume:
                _remove_unstarted(run_dir, config)
            trainer = start_run(
                run_dir,
                config,
                params["datasets"],
                params["val_datasets"],
                params["root"],
                resume=resume,
                command=params["command"],
            )
            trainer.run(resume=resume)
    last = pd.read_parquet(run_dir / "eval.parquet").iloc[-1]
    tune.report({"success": float(last["success"]), "median_steps": float(last["median_steps"])})


def run_sweep(
    spec: SweepSpec,
    out: Path,
    *,
    root: Path,
    address: str | None = None,
    cpus_per_trial: float = 1.0,
    command: str = "",
    on_line: Callable[[str], None] = print,
) -> list[str]:
    """Train every trial of ``spec`` into ``out`` on Ray Tune, then build its ensembles; the run names that failed.

    Unfinished trials continue from their last checkpoint; finished ones are skipped (so a second call resumes).
    """
    os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")  # Tune's older reporter, which verbose=0 silences
    try:
        import ray
        from ray import tune
    except ImportError:
        raise RuntimeError("Ray Tune is not installed: pip install -e '.[sweep]'") from None
    from uavplace.dataset.catalog import expand_datasets
    from uavplace.rl.agent.ensemble import build_ensemble
    from uavplace.rl.agent.runs import run_finished

    out, root = out.resolve(), root.resolve()  # trials run in Tune's working folders
    configs = spec.configs()
    todo = [name for name in configs if not run_finished(out / name)]
    for name in todo:  # refused before Ray starts: a trial's folder that the sweep did not make
        if (out / name).exists() and not (out / name / "checkpoints" / "last").is_dir():
            _remove_unstarted(out / name, configs[name], remove=False)
    on_line(
        f"sweep: {len(configs)} trials, {len(configs) - len(todo)} finished before"
        + (f"; training {', '.join(todo)}" if todo else "")
    )
    failed: list[str] = []
    if todo:
        started = start_ray(address, cpus_per_trial, "--cpus-per-trial")
        try:
            # corpus names (``corpus`` -> corpus-000, ...) expanded here, as ``uavrl train`` does
            common = {
                "out": str(out),
                "root": str(root),
                "datasets": expand_datasets(spec.datasets, root),
                "val_datasets": expand_datasets(spec.val_datasets, root),
                "command": command,
                "cpus": cpus_per_trial,
            }
            space = [common | {"run": name, "config": configs[name].model_dump_json()} for name in todo]
            trainable = tune.with_resources(_trial, {"cpu": cpus_per_trial})
            stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%d-%H%M%S")
            tuner = tune.Tuner(
                trainable,
                param_space={"trial": tune.grid_search(space)},
                tune_config=tune.TuneConfig(reuse_actors=False),
                run_config=tune.RunConfig(name=f"sweep-{stamp}", storage_path=str(out / ".tune"), verbose=0),
            )
            t0 = time.monotonic()
            results = tuner.fit()
            for r in results:
                name = r.config["trial"]["run"]
                if r.error is not None:
                    failed.append(name)
                    on_line(f"sweep: {name} failed: {str(r.error).strip().splitlines()[-1][:300]}")
                else:
                    on_line(f"sweep: {name}: validation {_scores(r.metrics)}")
            on_line(f"sweep: trials done in {time.monotonic() - t0:.0f} s")
        finally:
            if started:
                ray.shutdown()
    for e in spec.ensembles:
        folder = out / e.name
        if folder.exists() or any(m in failed for m in e.members):
            continue
        row = build_ensemble([out / m for m in e.members], folder, root, command=command)
        on_line(f"sweep: ensemble {e.name}: validation {_scores(row)}")
    return failed


def _scores(row: dict) -> str:
    return f"{format_stat('success', row['success'])} success, median {format_stat('median_steps', row['median_steps'])} steps"


def changed_settings(config: DQNConfig) -> str:
    """The fields of ``config`` (and its env) that differ from its preset, as ``--set`` would write them."""
    base = preset_config(config.preset, seed=config.seed).model_dump()  # the agent (dqn or blind) shows as a change
    mine = config.model_dump()
    out = [f"{k}={v}" for k, v in mine.items() if k not in ("env", "total_steps", "eval_every", "seed") and v != base[k]]
    out += [f"env.{k}={v}" for k, v in mine["env"].items() if v != base["env"][k]]
    return ", ".join(out) or "(preset)"


def validation_table(
    folders: list[Path],
    cities: list[str] | None,
    *,
    root: Path,
    episodes: int = 1000,
    seed: int = 0,
    release: bool = False,
    on_progress: Callable[[str, int, int], None] | None = None,
    played: dict[str, dict[str, pd.DataFrame]] | None = None,
) -> pd.DataFrame:
    """Every agent folder on ``cities`` (default: every built validation city; a test city only with ``release``),
    each city's episodes played by all of them and the genie (``eval.evaluate.evaluate``). One row per agent: its
    settings, the validation that chose its ``best.pt``, its wall time, and per city the success and median steps
    with 95 % intervals over users then episodes, and the ratio of its median to the genie's. ``played``, when
    given, receives each city's episodes (city -> the folder's name, or the genie's -> ``run_episodes`` frame), for
    paired differences."""
    cities = development_cities(cities, root, release=release)
    agents = [load_agent(folder, 0.096, seed) for folder in folders]
    for a in agents:  # the folders' names tell agents of one preset apart
        a.name = a.policy.name = a.folder.name
    rows = {a.name: {"run": a.name, "settings": changed_settings(a.config)} for a in agents}
    for a in agents:
        evals = pd.read_parquet(a.folder / "eval.parquet")
        chosen, last = evals[evals["best"]].iloc[-1], evals["step"].max()
        rows[a.name] |= {
            "steps": int(last) if pd.notna(last) else a.config.ensemble * a.config.total_steps,
            "chosen val success": float(chosen["success"]),
            "chosen val median": float(chosen["median_steps"]),
            "wall_s": float(evals["wall_s"].iloc[-1])
            if "wall_s" in evals and pd.notna(evals["wall_s"].iloc[-1])
            else float("nan"),
        }
    for city in cities:
        config = ReportConfig(dataset=city, episodes=episodes, t_max=500, seed=seed, trajectories=0)
        results = evaluate(config, load_bundle(city, root=root), agents, baselines=[GeniePolicy()], on_progress=on_progress)
        if played is not None:
            played[city] = results
        table = bootstrap_table(results, seed=seed).set_index("method")
        genie = table.loc[GeniePolicy.name, "median_steps"]
        for a in agents:
            r = table.loc[a.name]
            rows[a.name] |= {
                f"{city} {k}": float(r[k])
                for k in ("success", "success_lo", "success_hi", "median_steps", "median_steps_lo", "median_steps_hi")
            }
            rows[a.name][f"{city} x genie"] = float(r["median_steps"] / max(genie, 1))
    return pd.DataFrame(list(rows.values())).assign(cities=", ".join(cities))


def paired_differences(played: dict[str, dict[str, pd.DataFrame]], against: str, seed: int) -> dict[str, pd.DataFrame]:
    """Per city, then for the cities pooled (when more than one), every run minus ``against`` (the genie left out)."""
    runs = [name for name in next(iter(played.values())) if name != GeniePolicy.name]
    by_city = dict(played)
    if len(played) > 1:
        by_city[f"{len(played)} cities pooled"] = {r: pd.concat([p[r] for p in played.values()], ignore_index=True) for r in runs}
    return {city: difference_table({r: results[r] for r in runs}, [against], seed=seed) for city, results in by_city.items()}


def markdown(table: pd.DataFrame, t_max: int = 500) -> str:
    """``validation_table`` as a Markdown table (intervals in brackets)."""
    cities = table["cities"].iloc[0].split(", ")
    head = ["run", "settings", "steps", "chosen on val", *(f"{c}: success, median, x genie" for c in cities), "wall"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in table.to_dict("records"):
        cells = [
            r["run"],
            r["settings"],
            f"{r['steps']:,}",
            f"{100 * r['chosen val success']:.1f} % / {r['chosen val median']:g}",
        ]
        for c in cities:
            cells.append(
                f"{format_stat('success', r[f'{c} success'], r[f'{c} success_lo'], r[f'{c} success_hi'])}, "
                f"{format_stat('median_steps', r[f'{c} median_steps'], r[f'{c} median_steps_lo'], r[f'{c} median_steps_hi'], t_max)}, "
                f"{r[f'{c} x genie']:.2f}"
            )
        cells.append("-" if pd.isna(r["wall_s"]) else f"{r['wall_s']:.0f} s")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_table(table: pd.DataFrame, out: Path, spec_path: Path | None = None) -> Path:
    """``OUT/sweep.md`` and ``OUT/sweep.csv`` (and the spec as ``OUT/sweep.toml``), each written atomically."""
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "sweep.md", markdown(table))
    atomic_write_text(out / "sweep.csv", table.to_csv(index=False))
    if spec_path is not None:
        atomic_write_text(out / SPEC_COPY, spec_path.read_text(encoding="utf-8"))
    return out / "sweep.md"
