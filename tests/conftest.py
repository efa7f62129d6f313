"""Shared test helpers: where the real Wireless InSite fixtures are, and writers of synthetic exports."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest

from uavplace.simulate.insite import ReceiverGrid, write_p2m, write_setup, write_txrx

REPO = Path(__file__).resolve().parents[1]
#: ``uavdata`` in a child process of this interpreter (the console script without depending on PATH).
UAVDATA = [sys.executable, "-m", "uavplace.cli", "uavdata"]
FIXTURES = Path(os.environ.get("UAVPLACE_FIXTURES", REPO.parent / "shared" / "fixtures" / "wireless-insite"))


def pytest_configure(config: pytest.Config) -> None:
    """A first Ctrl-C ends the suite at once, during a training test too, and in the commands the tests start: the
    trainer's 'checkpoint, then stop' (``rl.agent.resume.interrupts``) is for users' runs; the tests of it unset it.

    One torch thread in the tests and the commands they start, unless OMP_NUM_THREADS says otherwise: on a machine
    shared with other jobs, two threads that cannot both have a core spin and burn CPU waiting for each other
    (``python benchmarks/shared_machine.py`` measures it; docs/testing.md)."""
    os.environ["UAVPLACE_CTRL_C"] = "end"
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    if "torch" in sys.modules:  # imported before this hook (a plugin): set what it read too late
        sys.modules["torch"].set_num_threads(int(os.environ["OMP_NUM_THREADS"]))


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--probes",
        action="store_true",
        help="Also run the probe suite (tests/probes.py, tests/probes_round4.py: about an hour on 2 cores).",
    )


#: The modules of ``pytest -m quick``: the parsers, schemas, ingest, build, the env and the searcher's units, about two
#: minutes on 2 cores (docs/testing.md); their tests marked ``slow`` stay out.
QUICK_MODULES = frozenset(
    {"test_schemas", "test_p2m", "test_geometry", "test_cityjson", "test_options", "test_information", "test_aggregate",
     "test_export", "test_trainmaps", "test_ingest_cli", "test_bad_inputs", "test_build", "test_env", "test_searcher"}
)  # fmt: skip


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark the tests of ``QUICK_MODULES`` ``quick`` (but those marked ``slow``)."""
    for item in items:
        if (
            item.module is not None
            and item.module.__name__.rpartition(".")[2] in QUICK_MODULES
            and not item.get_closest_marker("slow")
        ):
            item.add_marker(pytest.mark.quick)


def fixture_dir(name: str) -> Path:
    """A real fixture folder; the calling test skips, saying why, if it is absent."""
    path = FIXTURES / name
    if not path.is_dir():
        pytest.skip(f"real Wireless InSite fixture {path} not found (set UAVPLACE_FIXTURES to its folder)")
    return path


@pytest.fixture(scope="session")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The embedded tiny city ingested and built with the build's defaults (the embedded noise level): the root of its
    bundle (one build for the whole session; tests only read it)."""
    from uavplace.dataset.build import build_city
    from uavplace.ingest.pipeline import ingest_city
    from uavplace.schemas.bundle import BuildConfig

    root = tmp_path_factory.mktemp("tiny")
    ingest_city(REPO / "data" / "raw" / "tiny", root)
    build_city("tiny", BuildConfig(grid_m=4.0, altitude_m=10.0), root)
    return root


@pytest.fixture
def rosslyn() -> Path:
    return fixture_dir("lasse-2018-rosslyn")


@pytest.fixture
def deepmimo() -> Path:
    return fixture_dir("deepmimo-2025-grid")


@pytest.fixture
def boxes() -> Path:
    return fixture_dir("halosnoopy-2023-boxes")


def write_grid_city(
    folder: Path,
    *,
    nx: int = 6,
    ny: int = 5,
    spacing: float = 4.0,
    n_tx: int = 2,
    outputs: tuple[str, ...] = ("pl",),
    gz: bool = False,
    crlf: bool = False,
    seed: int = 0,
    z: float = 10.0,
    tx_power_dbm: float = 20.0,
    dead_share: float = 0.2,
    routes: list[np.ndarray] | None = None,
) -> Path:
    """A small InSite-like city: a .txrx (users + one receiver grid at ``z``), a .setup and receiver outputs.

    Path loss is 40 + 20 log10(distance + 1) plus uniform 0..10 dB; a ``dead_share`` of receivers is unreached.
    ``routes``: pedestrian routes (``[n, 2]`` points each), written as the .txrx points set ``Route``, one output
    per point and ``city.routes.csv``, as ``uavdata simulate --routes`` writes them.
    """
    from uavplace.simulate.routes import ROUTE_SET, Route, write_routes_csv

    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    grid = ReceiverGrid(x0_m=10.0, y0_m=-20.0, z_m=z, num_x=nx, num_y=ny, spacing_m=spacing)
    tx = np.array([(10.0 + 3.0 * i, -18.0, 1.5) for i in range(n_tx)])
    drawn = [Route(k, "pedestrian", np.asarray(r, float)) for k, r in enumerate(routes or [])]
    points = np.array([(x, y, 1.5) for r in drawn for x, y in r.points_m]).reshape(-1, 3)
    write_txrx(folder / "city.txrx", tx, grid, tx_power_dbm=tx_power_dbm, route_points_m=points)
    write_setup(folder / "city.setup", "synthetic")
    if drawn:
        write_routes_csv(folder / "city.routes.csv", drawn)
    pos = grid.points()
    sources = [((1, "User"), t + 1, tx[t]) for t in range(n_tx)] + [(ROUTE_SET, k + 1, p) for k, p in enumerate(points)]
    for tx_set, tx_point, where in sources:
        dist = np.hypot(pos[:, 0] - where[0], pos[:, 1] - where[1]) + 1.0
        pl = 40 + 20 * np.log10(dist) + rng.uniform(0, 10, dist.size)
        pl[rng.random(dist.size) < dead_share] = np.nan
        for output in outputs:
            write_p2m(
                folder,
                "city",
                output,
                tx_point=tx_point,
                tx_set=tx_set,
                rx_set=(2, "Drone_grid"),
                positions_m=pos,
                distance_m=dist,
                values=pl if output == "pl" else tx_power_dbm - pl,
                phase_deg=rng.uniform(-180, 180, dist.size),
                gz=gz,
                crlf=crlf,
            )
    return folder


def sparse_file(path: Path, size: int = 2 * 2**30) -> Path:
    """``path`` as a file of ``size`` bytes (2 GB by default) that takes no disk: past every size limit, never read."""
    path.unlink(missing_ok=True)
    with path.open("wb") as f:
        f.truncate(size)
    return path
