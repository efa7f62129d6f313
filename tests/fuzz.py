"""Property-based mutation of every parser's real input: one clear error or physical values, never anything else.

Each target starts from a real, valid file (the embedded test city's exports, files written by uavplace's own
writers, a built bundle, a trained-format checkpoint), applies one to four edits that hypothesis draws (bytes
replaced, deleted or inserted, tokens such as ``nan`` or ``1e400`` put in, lines repeated, the file cut short;
for bundles also array values replaced by extremes, hashes updated so that only the content checks can see it),
and calls the parser. The property: it returns (and what it returns passes the target's check), or it raises
``InputError``. Anything else (an internal error, a hang past the deadline, a ``MemoryError``) fails.

Run by ``tests/test_fuzz.py`` in child processes, one per target, under a memory limit, a few dozen examples each.
A long run (no memory limit here; ``--examples`` as many as you like)::

    python -m tests.fuzz --examples 5000            # every target
    python -m tests.fuzz p2m city --examples 20000  # some
"""

from __future__ import annotations

import argparse
import gzip
import hashlib
import io
import json
import resource
import shutil
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

from uavplace.schemas import InputError

REPO = Path(__file__).resolve().parents[1]
EMBEDDED = REPO / "data" / "raw" / "test"
#: Tokens an edit may insert: numbers a parser must refuse or bound, structure words, bytes text should not hold.
TOKENS = [b"nan", b"-inf", b"1e400", b"-1e308", b"99999999999999999999", b"-0", b"0x1F", b"1_000", b"\x00", b"\xff\xfe",
          b"\n", b"\r\n", b" ", b"-", b"begin_<", b"end_<", b"<!ENTITY a 'b'>", b"{", b"]", b'"', b"element vertex 2000000000",
          b"3 0 1 2", b"f 1 2 99", b"mtllib x.mtl"]  # fmt: skip
#: Values an array edit may put into a bundle.
EXTREMES = [np.nan, np.inf, -np.inf, 1e30, -1e30, 0.0, -1.0, 2.0**31 - 1, -(2.0**31)]


@st.composite
def edits(draw: st.DrawFn) -> list[tuple]:
    """One to four edits, positions as fractions of the current length."""
    out = []
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["replace", "delete", "insert", "truncate", "repeat"]))
        where = draw(st.floats(0, 1, exclude_max=True))
        if kind == "replace":
            out.append((kind, where, draw(st.binary(min_size=1, max_size=8))))
        elif kind == "delete":
            out.append((kind, where, draw(st.integers(1, 64))))
        elif kind == "insert":
            out.append((kind, where, draw(st.sampled_from(TOKENS) | st.binary(min_size=1, max_size=16))))
        else:
            out.append((kind, where, draw(st.integers(1, 50))))
    return out


def mutate(data: bytes, plan: list[tuple]) -> bytes:
    for kind, where, arg in plan:
        at = int(where * len(data)) if data else 0
        if kind == "replace":
            data = data[:at] + arg + data[at + len(arg) :]
        elif kind == "delete":
            data = data[:at] + data[at + arg :]
        elif kind == "insert":
            data = data[:at] + arg + data[at:]
        elif kind == "truncate":
            data = data[:at]
        else:  # repeat the line at ``at`` ``arg`` times
            start = data.rfind(b"\n", 0, at) + 1
            end = data.find(b"\n", at)
            end = len(data) if end < 0 else end + 1
            data = data[:end] + data[start:end] * arg + data[end:]
    return data


@dataclass
class Target:
    """A parser and its valid seed file: ``setup(folder)`` writes the inputs and returns the file to mutate;
    ``parse(path)`` reads it (after the mutation) and returns something ``check`` accepts."""

    setup: Callable[[Path], Path]
    parse: Callable[[Path], object]
    check: Callable[[object], None] = lambda _: None


def _copy(name: str, lines: int | None = None) -> Callable[[Path], Path]:
    def setup(folder: Path) -> Path:
        src = EMBEDDED / name
        data = gzip.decompress(src.read_bytes()) if name.endswith(".gz") else src.read_bytes()
        if lines is not None:
            data = b"".join(data.splitlines(keepends=True)[:lines])
        dst = folder / name.removesuffix(".gz")
        dst.write_bytes(data)
        return dst

    return setup


def _city(folder: Path) -> Path:
    """The embedded test city's first ten structures, a whole .city."""
    text = (EMBEDDED / "test.city").read_text()
    end = -1
    for _ in range(10):
        end = text.index("end_<structure>", end + 1)
    path = folder / "test.city"
    path.write_text(text[: end + len("end_<structure>\n")] + "end_<structure_group>\nend_<city>\n")
    return path


def _p2m(path: Path) -> object:
    from uavplace.ingest.wireless_insite.p2m import read_p2m
    from uavplace.ingest.wireless_insite.p2m_header import COHERENT_MARGIN_DB

    return read_p2m(path, max_gain_db=4.3 + COHERENT_MARGIN_DB, tx_power_dbm=20.0)


def _check_p2m(result: object) -> None:
    from uavplace.schemas.tables import RECEIVERS

    _, table = result  # type: ignore[misc]
    for name in table.column_names:
        if name in RECEIVERS.column_names and RECEIVERS.column(name).has_range:
            values = table.column(name).to_numpy(zero_copy_only=False).astype(float)
            column = RECEIVERS.column(name)
            assert column.first_out_of_range(values, ~np.isnan(values)) is None, f"{name} out of range"


def _geojson(folder: Path) -> Path:
    square = [[[0, 0], [20, 0], [20, 20], [0, 20], [0, 0]]]
    features = [{"type": "Feature", "geometry": {"type": "Polygon", "coordinates": square}, "properties": {"height": 12.5}}]
    path = folder / "b.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    return path


def _mesh(suffix: str) -> Callable[[Path], Path]:
    def setup(folder: Path) -> Path:
        import trimesh

        box = trimesh.creation.box(extents=(10, 10, 20))
        box.apply_translation((0, 0, 10))
        path = folder / f"b.{suffix}"
        if suffix == "ply":
            path.write_bytes(trimesh.exchange.ply.export_ply(box, encoding="ascii"))
        else:
            box.export(path)
        return path

    return setup


def _scene(folder: Path) -> Path:
    _mesh("ply")(folder)
    path = folder / "s.xml"
    path.write_text('<scene version="2.1.0"><shape type="ply" id="a"><string name="filename" value="b.ply"/></shape></scene>')
    return path


def _bundle(name: str) -> Callable[[Path], Path]:
    """A bundle of the small test city, built here; the file ``name`` is mutated and re-hashed by ``_load_bundle``."""

    def setup(folder: Path) -> Path:
        from tests.conftest import write_grid_city
        from uavplace.dataset.build import build_city
        from uavplace.ingest.pipeline import ingest_city
        from uavplace.schemas.bundle import BuildConfig

        ingest_city(write_grid_city(folder / "raw" / "city"), folder / "root")
        result = build_city("city", BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=-60.0), folder / "root")
        return result.path / name

    return setup


def _load_bundle(path: Path) -> object:
    """Re-hash the mutated file in the manifest (a forger's move), then load."""
    from uavplace.dataset.bundle import load_bundle

    folder = path.parent
    if path.name != "manifest.json":
        manifest = json.loads((folder / "manifest.json").read_text())
        manifest["files"][path.name] = hashlib.sha256(path.read_bytes()).hexdigest()
        (folder / "manifest.json").write_text(json.dumps(manifest))
    return load_bundle(str(folder))


def _check_bundle(bundle: object) -> None:
    assert np.isfinite(bundle.sinr_db).all() and np.isfinite(bundle.height_rel_m).all()  # type: ignore[attr-defined]
    assert (~bundle.blocked).any()  # type: ignore[attr-defined]


def _checkpoint(folder: Path) -> Path:
    import torch

    from uavplace.rl.agent.config import preset_config
    from uavplace.rl.agent.dqn import make_network

    config = preset_config("fast")
    env = config.env_config()
    net = make_network(config, env.num_channels, env.window)
    path = folder / "best.pt"
    torch.save({"online": net.state_dict(), "config": config.model_dump(mode="json"), "eval": {}}, path)
    return path


def _load_checkpoint(path: Path) -> object:
    from uavplace.infra.tensors import load_tensors

    return load_tensors(path)


def _reader(module: str, function: str) -> Callable[[Path], object]:
    def parse(path: Path) -> object:
        import importlib

        return getattr(importlib.import_module(module), function)(path)

    return parse


TARGETS: dict[str, Target] = {
    "p2m": Target(_copy("test.power.t001_01.r002.p2m.gz", lines=400), _p2m, _check_p2m),
    "setup": Target(_copy("test.setup"), _reader("uavplace.ingest.wireless_insite.setup", "read_setup")),
    "txrx": Target(_copy("test.txrx"), _reader("uavplace.ingest.wireless_insite.txrx", "read_txrx")),
    "city": Target(_city, _reader("uavplace.ingest.wireless_insite.city", "read_city")),
    "geojson": Target(_geojson, _reader("uavplace.ingest.geojson", "read_geojson")),
    "ply": Target(_mesh("ply"), _reader("uavplace.ingest.mesh", "read_mesh")),
    "obj": Target(_mesh("obj"), _reader("uavplace.ingest.mesh", "read_mesh")),
    "gltf": Target(_mesh("gltf"), _reader("uavplace.ingest.mesh", "read_mesh")),
    "mitsuba": Target(_scene, _reader("uavplace.ingest.mitsuba", "read_mitsuba")),
    "bundle-manifest": Target(_bundle("manifest.json"), _load_bundle, _check_bundle),
    "bundle-users": Target(_bundle("users.parquet"), _load_bundle, _check_bundle),
    "bundle-maps": Target(_bundle("maps.npz"), _load_bundle, _check_bundle),
    "checkpoint": Target(_checkpoint, _load_checkpoint),
}


def _array_edits(path: Path, plan: list[tuple[str, float, float]]) -> None:
    """Replace values of ``maps.npz``'s arrays (by name, at a fraction of their size) and rewrite it."""
    with np.load(path) as npz:
        arrays = {k: npz[k].copy() for k in npz.files}
    for name, where, value in plan:
        a = arrays[name]
        index = int(where * a.size)
        with np.errstate(invalid="ignore", over="ignore"):
            a.flat[index] = np.asarray(value).astype(a.dtype) if a.dtype.kind != "f" or np.isfinite(value) else value
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    path.write_bytes(buffer.getvalue())


ARRAYS = ["x_m", "y_m", "height_rel_m", "blocked", "building_id", "sinr_db", "dead", "num_rx", "provenance"]


def run(name: str, examples: int, seed_value: int) -> None:
    """Mutate ``name``'s seed ``examples`` times; raise at the first example whose outcome breaks the property."""
    target = TARGETS[name]
    with tempfile.TemporaryDirectory(prefix=f"uavplace-fuzz-{name}-") as tmp:
        pristine = Path(tmp) / "pristine"
        pristine.mkdir()
        seed_path = target.setup(pristine)
        target.check(target.parse(seed_path))  # the seed itself is valid
        work = Path(tmp) / "work"
        array_plan = st.lists(st.tuples(st.sampled_from(ARRAYS), st.floats(0, 1, exclude_max=True), st.sampled_from(EXTREMES)),
                              min_size=0, max_size=2) if name == "bundle-maps" else st.just([])  # fmt: skip

        @seed(seed_value)
        @settings(max_examples=examples, deadline=timedelta(seconds=10), database=None,
                  suppress_health_check=list(HealthCheck), print_blob=True)  # fmt: skip
        @given(plan=edits(), values=array_plan)
        def example(plan: list[tuple], values: list[tuple]) -> None:
            shutil.rmtree(work, ignore_errors=True)
            shutil.copytree(pristine, work)
            path = work / seed_path.relative_to(pristine)
            if values:
                _array_edits(path, values)
            else:
                path.write_bytes(mutate(path.read_bytes(), plan))
            try:
                result = target.parse(path)
            except InputError:
                return
            target.check(result)

        example()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("targets", nargs="*", help=f"targets (default: all): {', '.join(TARGETS)}")
    parser.add_argument("--examples", type=int, default=50, help="examples per target")
    parser.add_argument("--seed", type=int, default=0, help="hypothesis seed")
    parser.add_argument("--max-gb", type=float, default=None, help="address-space limit of this process [GiB]")
    args = parser.parse_args(argv)
    unknown = sorted(set(args.targets) - set(TARGETS))
    if unknown:
        parser.error(f"unknown targets {unknown}; known: {', '.join(TARGETS)}")
    if args.max_gb:
        limit = int(args.max_gb * 2**30)
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    for name in args.targets or TARGETS:
        run(name, args.examples, args.seed)
        peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        print(f"{name}: {args.examples} examples passed; peak resident {peak_kb / 2**20:.2f} GiB", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
