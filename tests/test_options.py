"""Options derived from pydantic models (``infra.options``): a setting declared once, as a field."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import click
import pytest
from click.testing import CliRunner
from pydantic import Field

from uavplace.infra.options import FieldOption, model_options
from uavplace.schemas.base import Contract
from uavplace.simulate.config import Simulation


class Toy(Contract):
    count: int = Field(default=3, ge=1, le=9, description="How many.")
    rate: float = Field(default=0.5, gt=0, lt=1, description="A share.")
    mode: Literal["a", "b"] = Field(default="a", description="Which.")
    names: tuple[str, ...] = Field(default=(), description="Names (repeatable).")
    fast: bool = Field(default=False, description="Go fast.")
    loud: bool = Field(default=True, description="Say it.")
    path: Path | None = Field(default=None, description="Where.")
    steps: int = Field(default=10, ge=1, description="Steps.", json_schema_extra={"limit": "episodes"})


@click.command()
@model_options(Toy, names={"fast": "--quick"})
def toy(**values: object) -> None:
    click.echo(Toy(**values).model_dump_json())


def _run(*args: str) -> click.testing.Result:
    return CliRunner().invoke(toy, list(args))


def test_the_options_are_the_fields():
    """Name, type, bounds, default and help come from the field: an option of every field, in its order."""
    res = _run()
    assert res.exit_code == 0, res.output
    assert Toy.model_validate_json(res.output) == Toy()
    res = _run("--count", "9", "--rate", "0.25", "--mode", "b", "--names", "x", "--names", "y", "--quick", "--path", "p")
    assert Toy.model_validate_json(res.output) == Toy(count=9, rate=0.25, mode="b", names=("x", "y"), fast=True, path="p")
    params = {p.name: p for p in toy.params}
    assert list(params) == list(Toy.model_fields)
    for name, field in Toy.model_fields.items():
        assert isinstance(params[name], FieldOption) and params[name].field == f"Toy.{name}"
        assert params[name].help == field.description
    assert params["fast"].opts == ["--quick"]
    assert params["loud"].opts == ["--loud"] and params["loud"].secondary_opts == ["--no-loud"]  # on by default
    assert Toy.model_validate_json(_run("--no-loud").output) == Toy(loud=False)
    assert Toy.model_validate_json(_run("--loud").output) == Toy()


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--count", "0"], "1<=x<=9"),
        (["--count", "10"], "1<=x<=9"),
        (["--rate", "1"], "0<x<1"),
        (["--rate", "nan"], "not a finite number"),
        (["--mode", "c"], "'c' is not one of 'a', 'b'"),
        (["--steps", "1e9"], "not a valid integer"),
        (["--steps", "2000000000"], "episodes"),
    ],
)
def test_the_fields_bounds_are_the_options(args, says):
    """A value outside the field's bounds (or the resource limit it names) is refused by the option, before the
    command runs."""
    res = _run(*args)
    assert res.exit_code == 2 and says in res.output, res.output


def _commands() -> list[tuple[str, str, str, tuple[str, ...]]]:
    """(command group, command, model, the fields its options derive from) of every command converted so far."""
    episode = ("episodes", "t_max", "p_t_db", "split", "seed")
    build = ("altitude_m", "altitude_tol_m", "noise_dbm", "interference_std_db", "tx_dbm", "sinr_floor_db", "bounds")
    return [
        ("uavrl", "baselines", "EpisodeSettings", episode),
        ("uavrl", "report", "EpisodeSettings", episode),
        ("uavrl", "report", "ReportConfig", ("test_epsilon", "n_boot", "trajectories")),
        ("uavdata", "build", "BuildConfig", (*build, "crop", "seed", "p_t_db", "grid_m")),
        ("uavdata", "build", "CityRoles", ("val_users",)),
        ("uavdata", "simulate", "Simulation", tuple(Simulation.model_fields)),
        ("uavrl", "train", "DQNConfig", ("agent", "total_steps", "seed", "eval_every")),
        ("uavrl", "levers", "EpisodeSettings", ("episodes", "seed")),
        ("uavrl", "train-predictor", "UNetConfig", ("widths", "steps", "batch", "seed", "threads")),
        ("uavrl", "report", "FleetConfig", ("uavs", "users")),
        ("uavrl", "report", "ReportSettings", ("predictor", "device", "network_precision")),
        ("uavrl", "report", "TrackingConfig", ("horizon",)),
        ("uavrl", "report", "TrackingReportConfig", ("hold",)),
    ]


@pytest.mark.parametrize(("group", "name", "model", "fields"), _commands(), ids=lambda v: v if isinstance(v, str) else "")
def test_a_commands_settings_are_its_models_fields(group, name, model, fields):
    """Each converted command's settings come from its model's fields (``FieldOption``): one default, one bound, one
    help each, written in the model only; the report's config inherits the evaluation protocol's fields."""
    from uavplace.cli import uavdata, uavrl
    from uavplace.eval.config import ReportConfig, ReportSettings
    from uavplace.eval.reports.tracking import TrackingReportConfig
    from uavplace.rl.agent.config import DQNConfig
    from uavplace.rl.config import EpisodeSettings, UNetConfig
    from uavplace.rl.tasks.fleet.config import FleetConfig
    from uavplace.rl.tasks.tracking.config import TrackingConfig
    from uavplace.schemas.bundle import BuildConfig, CityRoles

    command = {"uavdata": uavdata, "uavrl": uavrl}[group].get_command(None, name)
    cls = {
        "EpisodeSettings": EpisodeSettings,
        "ReportConfig": ReportConfig,
        "ReportSettings": ReportSettings,
        "BuildConfig": BuildConfig,
        "CityRoles": CityRoles,
        "Simulation": Simulation,
        "DQNConfig": DQNConfig,
        "UNetConfig": UNetConfig,
        "FleetConfig": FleetConfig,
        "TrackingConfig": TrackingConfig,
        "TrackingReportConfig": TrackingReportConfig,
    }[model]
    derived = {p.name: p for p in command.params if isinstance(p, FieldOption) and p.field.startswith(model + ".")}
    assert set(derived) == set(fields)
    for field_name, option in derived.items():
        field = cls.model_fields[field_name]
        if option.default is None and not option.required and field.default is not None:  # the value comes from elsewhere
            assert option.help.startswith(field.description.rstrip(".")) and "(default: " in option.help
            continue
        if field.is_required():
            assert option.required and option.help == field.description
            continue
        assert option.help == field.description
        listed = (field.json_schema_extra or {}).get("type") == "list"
        shown = ",".join(map(str, field.default or ())) or "none" if listed else None
        assert option.default in (field.default, shown) or (option.is_flag and field.default is False), field_name
        assert not option.is_flag or field.default is False or option.secondary_opts  # on by default: --no-x turns it off
    assert issubclass(ReportConfig, EpisodeSettings)
    assert all(repr(ReportConfig.model_fields[f]) == repr(EpisodeSettings.model_fields[f]) for f in EpisodeSettings.model_fields)


def test_an_option_refuses_what_its_field_refuses():
    """A value outside a field's bounds is refused by its option before the command runs."""
    from uavplace.cli import uavdata, uavrl

    res = CliRunner().invoke(uavdata, ["build", "--noise-dbm", "101"])
    assert res.exit_code == 2 and "-250<=x<=100" in res.output
    res = CliRunner().invoke(uavrl, ["train-predictor", "--seed", "-1"])
    assert res.exit_code == 2 and "--seed" in res.output


#: The options of each command that are no setting of a model: which inputs it reads, where it writes, how it runs,
#: which preset, task or role table it picks (a task's choices and a run's task are ``rl.tasks.registry``'s; a nested
#: model's fields as NAME=VALUE are checked by that model, ``infra.options.with_pairs``). Every other option of every
#: command is a model's field (``FieldOption``): a new option that restates a field by hand fails the test below, and
#: so does a switch declared for a command that has none of that name.
CLI_SWITCHES = {
    "uavdata build": {"cities", "crop_cities", "force", "quiet", "roles_file", "root", "splits"},
    "uavdata export": {"cities", "formats", "out", "root"},
    "uavdata ingest": {"folders", "name", "out_root", "quiet", "verbose"},
    "uavdata list": {"raw", "root", "table"},
    "uavdata pack": {"cities", "out", "raw", "root"},
    "uavdata schema": {"model", "out_dir"},
    "uavdata show": {"city", "out_path", "root", "user", "version"},
    "uavdata simulate": {"cpus_per_city", "out_root", "quiet", "ray_address", "sources", "trace_cache"},
    "uavrl baselines": {"datasets", "root"},
    "uavrl calibrate-predictor": {"map_folders", "out", "packs", "predictor", "root", "val_datasets"},
    "uavrl datasets": {"root"},
    "uavrl ensemble": {"out", "quiet", "root", "runs"},
    "uavrl fit-predictor": {"datasets", "out", "root", "val_datasets"},
    "uavrl levers": {"against", "cities", "release", "root", "runs"},
    "uavrl peer table": {"best", "cities", "markdown_path", "peers", "root"},
    "uavrl peer train": {"algo", "datasets", "match", "out", "root"},
    "uavrl report": {
        "agents_dir",
        "datasets",
        "groups",
        "map_error",
        "markdown",
        "measure",
        "out",
        "overwrite",
        "quiet",
        "ray_address",
        "root",
        "runs",
        "search",
        "strict",
        "task",
        "workers",
    },
    "uavrl robustness": {"datasets", "out", "root", "runs"},
    "uavrl sweep": {"cpus_per_trial", "out", "quiet", "ray_address", "root", "spec_file", "table_only"},
    "uavrl trace-predictor": {"constants", "map_folders", "out", "packs", "root", "users_per_pack", "val_datasets", "workers"},
    "uavrl train": {
        "datasets",
        "name",
        "preset",
        "quiet",
        "resume",
        "root",
        "runs",
        "settings",
        "strict",
        "task",
        "until",
        "val_datasets",
    },
    "uavrl train-predictor": {"constants", "datasets", "map_folders", "out", "packs", "quiet", "root", "val_datasets"},
}


def test_every_option_is_a_field_or_a_declared_switch():
    """Every option of every command derives from a model's field (its name, type, bounds, default and help written
    once, in the model), or is one of that command's declared switches, which are no setting: 0 options restate a
    field by hand, and no command declares a switch it has not."""
    from uavplace.cli import uavdata, uavrl

    hand, found = [], {}

    def walk(group: click.Group, prefix: str) -> None:
        for name in group.list_commands(None):
            command = group.get_command(None, name)
            if isinstance(command, click.Group):
                walk(command, f"{prefix} {name}")
                continue
            path = f"{prefix} {name}"
            found[path] = {p.name for p in command.params if p.name != "help" and not isinstance(p, FieldOption)}
            hand.extend(f"{path} --{n}" for n in sorted(found[path] - CLI_SWITCHES.get(path, set())))

    walk(uavdata, "uavdata")
    walk(uavrl, "uavrl")
    assert not hand, f"options written by hand, not derived from a model field: {hand}"
    assert {path: CLI_SWITCHES[path] - names for path, names in found.items() if CLI_SWITCHES.get(path, set()) - names} == {}
    assert set(CLI_SWITCHES) <= set(found)


def test_pairs_set_a_models_fields_checked_by_it():
    """``NAME=VALUE`` texts set a config's fields (JSON values, words as text, dashes for underscores), the rest kept;
    a text without '=', an unknown name or a value the model refuses is a usage error naming the option."""
    from uavplace.infra.options import with_pairs

    base = Toy(count=4)
    assert with_pairs(base, ["rate=0.25", "mode=b", "fast=true"], "--set") == Toy(count=4, rate=0.25, mode="b", fast=True)
    assert with_pairs(base, ["count=2", "count=7"], "--set").count == 7  # the last one wins
    assert with_pairs(base, [], "--set") == base
    for bad, says in (("rate", "expected NAME=VALUE"), ("speed=3", "NAME one of count, rate"), ("count=10", "count")):
        with pytest.raises(click.BadParameter, match=says) as err:
            with_pairs(base, [bad], "--set")
        assert "--set" in err.value.format_message() or err.value.param_hint == "'--set'"
