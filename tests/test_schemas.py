"""The contracts: validation at the boundary, table declarations, JSON schema export."""

from __future__ import annotations

import pyarrow as pa
import pytest
from pydantic import ValidationError

from uavplace.schemas import RECEIVERS, SCHEMA_VERSION, Building, CityManifest, InputError, TxRxSet
from uavplace.schemas.export import SCHEMA_MODELS, json_schemas


def test_building_contract():
    ok = Building(building_id=0, footprint_wkt="POLYGON ((0 0, 4 0, 4 4, 0 4, 0 0))", base_z_m=0, roof_z_m=12, source="x:1")
    assert ok.height_m == 12
    with pytest.raises(ValidationError, match="not a valid polygon"):
        Building(building_id=0, footprint_wkt="POLYGON ((0 0, 4 4, 4 0, 0 4, 0 0))", base_z_m=0, roof_z_m=1, source="x")
    with pytest.raises(ValidationError, match="not a polygon"):
        Building(building_id=0, footprint_wkt="POINT (0 0)", base_z_m=0, roof_z_m=1, source="x")
    with pytest.raises(ValidationError, match="below base"):
        Building(building_id=0, footprint_wkt="POLYGON ((0 0, 4 0, 4 4, 0 0))", base_z_m=5, roof_z_m=1, source="x")
    with pytest.raises(ValidationError, match="Extra inputs"):
        Building(building_id=0, footprint_wkt="POLYGON ((0 0, 4 0, 4 4, 0 0))", base_z_m=0, roof_z_m=1, source="x", color="red")


def test_grid_set_contract():
    grid = TxRxSet(kind="grid", name="g", project_id=2, vertices_m=((0, 0, 10),), side1_m=8, side2_m=4, spacing_m=4, source="a:1")
    assert grid.grid_shape == (3, 2)
    with pytest.raises(ValidationError, match="needs side1"):
        TxRxSet(kind="grid", name="g", project_id=2, vertices_m=((0, 0, 10),), spacing_m=4, source="a:1")
    with pytest.raises(ValidationError, match="spacing 0.0"):
        TxRxSet(kind="grid", name="g", project_id=2, vertices_m=((0, 0, 10),), side1_m=8, side2_m=4, spacing_m=0, source="a:1")


def test_table_conform():
    n = 2
    cols = {c: pa.nulls(n, c.type) if c.nullable else pa.array([1] * n).cast(c.type) for c in RECEIVERS.columns}
    table = pa.table({c.name: v for c, v in cols.items()})
    out = RECEIVERS.conform(table)
    assert out.schema.field("power_dbm").metadata[b"unit"] == b"dBm"
    assert out.schema.metadata[b"schema_version"] == SCHEMA_VERSION.encode()
    with pytest.raises(InputError, match=r"missing columns \['reached'\]"):
        RECEIVERS.conform(table.drop_columns(["reached"]))
    with pytest.raises(InputError, match="x_m: table receivers has 2 nulls"):
        RECEIVERS.conform(table.set_column(4, "x_m", pa.nulls(n, pa.float64())))


def test_json_schemas_cover_every_contract():
    schemas = json_schemas()
    assert set(schemas) == set(SCHEMA_MODELS)
    assert all(s["x-schema-version"] == SCHEMA_VERSION for s in schemas.values())
    manifest = schemas["city_manifest"]
    assert "sources" in manifest["properties"] and manifest["additionalProperties"] is False
    assert CityManifest.model_config["frozen"]


def test_input_error_is_one_line():
    err = InputError("a/b.p2m", "bad value", line=12, field="x_m")
    assert str(err) == "a/b.p2m:12: x_m: bad value"
    assert str(InputError("f", "no rows")) == "f: no rows"


def test_input_error_survives_pickling():
    """Ray hands a trial's error to the driver by pickling it: the error must come back whole, not as a TypeError."""
    import pickle

    err = pickle.loads(pickle.dumps(InputError("a/b.p2m", "bad value", line=12, field="x_m")))
    assert isinstance(err, InputError) and (err.path, err.line, err.field) == ("a/b.p2m", 12, "x_m")
    assert str(err) == "a/b.p2m:12: x_m: bad value"


def test_every_limit_is_documented_with_its_default():
    """docs/security.md's table of resource limits lists each limit of ``Limits`` with its default (no drift)."""
    from pathlib import Path

    from uavplace.infra.limits import Limits, shown

    doc = (Path(__file__).resolve().parents[1] / "docs" / "security.md").read_text()
    for name, field in Limits.model_fields.items():
        assert f"| `{name}` | {shown(field.default)} |" in doc, name


def test_limits_parse_override_and_name_the_option(monkeypatch):
    """--limit NAME=VALUE and UAVPLACE_LIMITS set the limits of this process and its children; a value past a limit is
    one InputError naming the limit and how to raise it; bad pairs are refused."""
    from uavplace.infra import limits as lim

    monkeypatch.setattr(lim, "_current", None)
    monkeypatch.setenv(lim.ENV, "grid_cells=100")
    assert lim.limits().grid_cells == 100
    lim.set_limits(["mesh_bytes=2e3"])
    assert lim.limits().grid_cells == 100 and lim.limits().mesh_bytes == 2000
    assert "mesh_bytes=2000" in __import__("os").environ[lim.ENV]
    lim.check_limit("grid_cells", 100, "x", "cells")
    with pytest.raises(InputError, match=r"101 is over the limit grid_cells = 100; raise it with `--limit grid_cells=VALUE`"):
        lim.check_limit("grid_cells", 101, "--grid", "cells")
    with pytest.raises(InputError, match="is over the limit"):
        lim.check_limit("grid_cells", float("nan"), "--grid", "cells")
    for bad in ("nope=3", "grid_cells", "grid_cells=abc", "grid_cells=-1"):
        with pytest.raises(InputError):
            lim.set_limits([bad])
    monkeypatch.setattr(lim, "_current", None)


def test_atomic_outputs_take_the_umask_not_a_private_mode(tmp_path):
    """Files and folders written atomically get the mode a plain write would: 0644 / 0755 under umask 022, 0600 /
    0700 under 077 (mkstemp's and mkdtemp's private modes must not leak into reports and runs)."""
    import os

    from uavplace.infra.files import atomic_directory, atomic_write_text

    old = os.umask(0o022)
    try:
        for mask, file_mode, dir_mode in ((0o022, 0o644, 0o755), (0o077, 0o600, 0o700)):
            os.umask(mask)
            atomic_write_text(tmp_path / f"f{mask}.txt", "x")
            with atomic_directory(tmp_path / f"d{mask}") as d:
                (d / "a").write_text("y")
            assert (tmp_path / f"f{mask}.txt").stat().st_mode & 0o777 == file_mode
            assert (tmp_path / f"d{mask}").stat().st_mode & 0o777 == dir_mode
    finally:
        os.umask(old)


def test_an_output_folder_is_replaced_only_when_nothing_of_a_user_would_be_lost(tmp_path):
    """A folder with the marker but a user's file in it is refused, before the work when uavplace listed what it
    wrote there, after it when the folder has no list (made before the lists): the user's file stays either way, and
    the old output too. An output uavplace wrote, whatever it held, is replaced."""
    from pathlib import Path

    from uavplace.infra.files import CONTENTS, atomic_directory

    def write(folder: Path, *names: str) -> None:
        with atomic_directory(folder, marker="model.json", what="learned predictor") as d:
            for name in ("model.json", *names):
                (d / name).write_text(name)

    out = tmp_path / "out"
    write(out, "weights.pt", "extra.png")
    write(out, "weights.pt")  # uavplace's own folder: replaced, extra.png with it
    assert sorted(p.name for p in out.iterdir()) == sorted([CONTENTS, "model.json", "weights.pt"])
    (out / "thesis.tex").write_text("years of work")
    worked = []
    with pytest.raises(InputError, match=r"holds 1 entry that uavplace did not write there \(thesis.tex\)"):
        with atomic_directory(out, marker="model.json", what="learned predictor"):
            worked.append(True)
    assert not worked and (out / "thesis.tex").read_text() == "years of work"
    mine = tmp_path / "mine"  # a user's folder that only looks like an output: no list
    mine.mkdir()
    (mine / "model.json").write_text("{}")
    (mine / "thesis.tex").write_text("years of work")
    with pytest.raises(InputError, match=r"holds 1 entry that this output does not write \(thesis.tex\)"):
        write(mine, "weights.pt")
    assert sorted(p.name for p in mine.iterdir()) == ["model.json", "thesis.tex"]
    assert not list(tmp_path.glob(".mine.tmp-*"))
    legacy = tmp_path / "legacy"  # made before the lists, holding only what the new output writes: replaced
    legacy.mkdir()
    (legacy / "model.json").write_text("old")
    write(legacy, "weights.pt")
    assert (legacy / "model.json").read_text() == "model.json"


@pytest.mark.parametrize(
    ("command", "model"),
    [
        ("uavplace.dataset.cli:build", "uavplace.schemas.bundle:BuildConfig"),
        ("uavplace.eval.cli:report", "uavplace.eval.evaluate:ReportConfig"),
        ("uavplace.simulate.cli:simulate", "uavplace.simulate.config:Simulation"),
        ("uavplace.simulate.cli:simulate", "uavplace.simulate.config:SimulationSpec"),
        ("uavplace.simulate.cli:simulate", "uavplace.simulate.raytrace:RayTraceConfig"),
    ],  # fmt: skip
    ids=["build", "report", "simulate", "simulate-spec", "simulate-raytrace"],
)
def test_options_default_to_their_models_fields(command, model):
    """An option named like a field of the model it fills defaults to that field's default: the two cannot drift
    (as the noise level once did between `uavdata build` and BuildConfig)."""
    import importlib

    from pydantic_core import PydanticUndefined

    def load(ref: str):  # noqa: ANN202
        module, _, name = ref.partition(":")
        return getattr(importlib.import_module(module), name)

    import dataclasses

    cmd, kind = load(command), load(model)
    if dataclasses.is_dataclass(kind):
        fields = {f.name: f.default for f in dataclasses.fields(kind) if f.default is not dataclasses.MISSING}
    else:
        fields = {k: f.default for k, f in kind.model_fields.items() if f.default is not PydanticUndefined}
    compared = 0
    for param in cmd.params:
        if param.name not in fields or param.multiple:
            continue
        field_default = fields[param.name]
        if param.default is None and field_default is not None:  # taken from elsewhere (a roles file), said in its help
            assert "[default:" in (param.help or "") or "(default: " in (param.help or ""), param.name
            continue
        default = param.default if param.default is not None else None
        if param.is_flag:
            default = bool(param.default) if isinstance(param.default, bool) else False
        elif isinstance(default, str) and not isinstance(field_default, str):
            default = param.type.convert(default, param, None)
        if isinstance(field_default, tuple) and isinstance(default, list | str):
            default = () if default == "none" else tuple(default.split(",") if isinstance(default, str) else default)
        assert default == field_default or str(default) == str(field_default), (param.name, default, field_default)
        compared += 1
    assert compared >= 5


def test_simulate_ranges_live_in_its_settings_model_bounded_by_the_limits():
    """`uavdata simulate`'s settings are one pydantic model (simulate/config.py, Simulation), as every stage's are; each
    numeric setting has a lower bound, and one without an upper bound names the resource limit that bounds it."""
    from uavplace.infra.limits import Limits
    from uavplace.infra.options import field_bounds
    from uavplace.simulate.config import Simulation

    numeric = {n: f for n, f in Simulation.model_fields.items() if f.annotation in (int, float)}
    assert len(numeric) >= 12
    for name, info in numeric.items():
        bounds = field_bounds(info)
        assert "min" in bounds, name
        limit = (info.json_schema_extra or {}).get("limit")
        assert "max" in bounds or limit in Limits.model_fields, name


def test_duplicate_names_are_found_in_linear_time():
    """A roles file's lists are checked for repeats with a count of each name, not a scan per name: 300,000 names
    (which a scan per name takes hours on) validate at once, and a repeat is named."""
    from pydantic import ValidationError

    from uavplace.schemas.base import repeated
    from uavplace.schemas.bundle import CityRoles

    assert repeated(["b", "a", "b", "c", "a", "b"]) == ["a", "b"] and repeated([]) == []
    names = [f"city-{i}" for i in range(300_000)]
    assert len(CityRoles(val=names).val) == 300_000
    with pytest.raises(ValidationError, match="city-7 is listed twice"):
        CityRoles(val=[*names[:10], "city-7"])
