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


class Toy(Contract):
    count: int = Field(default=3, ge=1, le=9, description="How many.")
    rate: float = Field(default=0.5, gt=0, lt=1, description="A share.")
    mode: Literal["a", "b"] = Field(default="a", description="Which.")
    names: tuple[str, ...] = Field(default=(), description="Names (repeatable).")
    fast: bool = Field(default=False, description="Go fast.")
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


def test_the_evaluation_protocols_options_are_one_model():
    """``uavrl baselines`` and ``uavrl report`` take the episodes, t_max, P_T, split and seed from EpisodeSettings's
    fields (the report's config inherits them): one default, one bound, one help each."""
    from uavplace.eval.cli import report
    from uavplace.eval.evaluate import ReportConfig
    from uavplace.rl.cli import baselines
    from uavplace.rl.config import EpisodeSettings

    for command in (baselines, report):
        derived = {p.name: p for p in command.params if isinstance(p, FieldOption)}
        assert set(derived) >= {"episodes", "t_max", "p_t_db", "split", "seed"}
        for name in ("episodes", "t_max", "p_t_db", "split", "seed"):
            field = EpisodeSettings.model_fields[name]
            assert derived[name].field == f"EpisodeSettings.{name}"
            assert derived[name].default == field.default and derived[name].help == field.description
            assert repr(ReportConfig.model_fields[name]) == repr(field)  # inherited, not restated
    assert issubclass(ReportConfig, EpisodeSettings)


def test_the_build_settings_are_the_bundles_config():
    """``uavdata build``'s settings of every city (the altitude, its tolerance, noise, interference, power, floor,
    bounds, crop, seed and P_T) are ``BuildConfig``'s fields, as the manifest records them: one default, one bound,
    one help each; a value outside a field's bounds is refused by its option."""
    from uavplace.dataset.cli import build
    from uavplace.schemas.bundle import BuildConfig

    derived = {p.name: p for p in build.params if isinstance(p, FieldOption)}
    fields = ("altitude_m", "altitude_tol_m", "noise_dbm", "interference_std_db", "tx_dbm", "sinr_floor_db", "bounds")
    assert set(derived) == {*fields, "crop", "seed", "p_t_db"}
    for name, option in derived.items():
        field = BuildConfig.model_fields[name]
        assert option.field == f"BuildConfig.{name}" and option.help == field.description
        assert option.default == field.default or (option.is_flag and field.default is False)
    res = CliRunner().invoke(build, ["--noise-dbm", "101"])
    assert res.exit_code == 2 and "-250<=x<=100" in res.output
