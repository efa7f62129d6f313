"""The embedded default cities in data/raw/: small enough for git, and they ingest and build as documented."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import uavplace.rl  # noqa: F401  (registers the environments)
from tests.conftest import REPO
from uavplace.dataset.build import build_city
from uavplace.dataset.bundle import load_bundle
from uavplace.ingest.pipeline import ingest_city
from uavplace.schemas.bundle import EMBEDDED_NOISE_DBM, BuildConfig
from uavplace.schemas.provenance import NOT_RECORDED, SIDE_FILE_SUFFIX

RAW = REPO / "data" / "raw"
#: Every embedded city: a folder of data/raw made by the commands in the README.
CITIES = sorted(p.name for p in RAW.iterdir() if (p / "simulation.json").is_file())


def test_embedded_data_is_small_and_complete():
    size = sum(p.stat().st_size for p in RAW.rglob("*") if p.is_file())
    # 100 MB for the placement cities and the tracking task's test routes, 10 MB more for its training corpus and
    # validation city (trk-000 ... trk-003, trk-val: 12.5 MB; docs/tracking.md), and 5 MB for the real-layout
    # validation cities traced from data/geometry/ (delfshaven-val, denhaag-val: about 4 MB; docs/raytraced.md)
    assert size <= 115e6, f"data/raw holds {size / 1e6:.1f} MB, more than the 115 MB budget"
    corpus = [c for c in CITIES if c.startswith("corpus-")]
    assert len(corpus) >= 18 and {"train", "test", "tiny", "etoile", "florence"} <= set(CITIES)


def test_the_roles_file_declares_the_embedded_cities():
    """data/raw/cities.toml (what `uavdata build` reads): valid, naming embedded cities only, and its crop list is
    exactly the cities whose grid covers part of their scene (simulated with an extent)."""
    from uavplace.dataset.catalog import ROLES_FILE, read_roles

    roles = read_roles(RAW / ROLES_FILE)
    named = {*roles.train, *roles.val, *roles.test, *roles.crop}
    assert named <= {p.name for p in RAW.iterdir() if p.is_dir()}
    windowed = {c for c in CITIES if json.loads((RAW / c / "simulation.json").read_text())["spec"].get("extent_m")}
    assert set(roles.crop) == windowed
    assert {"test", "etoile", "florence"} <= set(roles.test) and roles.val_users == 3


@pytest.mark.parametrize("city", CITIES)
def test_embedded_city_ingests_builds_and_is_faithful(tmp_path, city):
    """As documented: the users and grid of its simulation.json, no mosaic above the SINR floor, a genie that
    always succeeds, a valid Gymnasium environment."""
    from uavplace.rl.tasks.placement.config import EnvConfig
    from uavplace.rl.tasks.placement.policies import GeniePolicy
    from uavplace.rl.tasks.placement.rollout import run_episodes
    from uavplace.rl.world.maps import MapSet
    from uavplace.simulate.fidelity import lattice_boundary_shares, lattice_step_ratios
    from uavplace.simulate.raytrace import constant_patch_share

    record = json.loads((RAW / city / "simulation.json").read_text())
    assert record["spec"]["name"] == city
    ingest_city(RAW / city, tmp_path)
    window = record["spec"].get("extent_m") is not None  # a grid on part of the scene: `crop` in data/raw/cities.toml
    config = BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=EMBEDDED_NOISE_DBM, crop=window)
    b = load_bundle(build_city(city, config, tmp_path).path)
    assert b.num_users == len(record["users_m"]) and b.shape == (record["grid"]["num_y"], record["grid"]["num_x"])
    assert b.manifest.counts["buildings"] == record.get("num_buildings")
    # Every shipped map says where its values came from (docs/simulate.md, "Provenance"): a side file whose codes leave at
    # most half the live receivers "not recorded" (experiments/embedded_provenance.py's rule), as the cells show.
    assert (RAW / city / f"{city}{SIDE_FILE_SUFFIX}").is_file()
    live_open = ~b.dead & ~b.blocked[None]
    assert (b.provenance[live_open] == NOT_RECORDED).mean() <= 0.5
    d = b.manifest.difficulty
    assert 0 < d["target_share"] < 1 and d["num_starts"] > 0
    if city == "test":  # the calibration: at the documented level the genie needs the paper's 14 +- 3 moves
        assert abs(d["bfs_median_steps"] - 14) <= 3, d["bfs_median_steps"]
    live = ~b.dead & ~b.blocked[None] & (b.sinr_db > b.sinr_floor_db)
    assert constant_patch_share(b.sinr_db, live) <= 0.01
    # No lattice of the coarse maps once used to fill gaps (docs/fidelity.md): dead regions follow the city, about 1 in
    # 16 (1 in 4) of their boundaries on the 64 m (16 m) lines, and the SINR steps as much across those lines as elsewhere.
    # A city of exact paths at every cell (`--solver paths`, the twin of docs/fidelity.md) has no fill, so no lattice to
    # look for: its 32 x 32 cells hold one 64 m line each way, and physics alone gives it a step ratio of 1.2 there.
    if record["raytrace"].get("solver", "radio-map") == "radio-map":
        shares = lattice_boundary_shares(~b.dead, ~b.blocked)
        if not np.isnan(shares["64 m"]):  # (a city with no dead cell has no boundary)
            assert shares["64 m"] <= 0.10 and shares["16 m"] <= 0.30, shares
        steps = lattice_step_ratios(b.sinr_db, ~b.dead, ~b.blocked)
        assert steps["64 m"] <= 1.1 and steps["16 m"] <= 1.1, steps
    maps = MapSet([b], EnvConfig(t_max=500, rotate=False))
    episodes = maps.sample_episodes(200, np.random.default_rng(0))
    assert run_episodes(maps, GeniePolicy(), episodes)["success"].all()
    env = gym.make("uavplace/UavPlacement-v0", dataset=city, root=str(tmp_path), rotate=True)
    check_env(env.unwrapped)
    assert env.reset(seed=0)[0].shape == (2, 61, 61)
    if record.get("routes", {}).get("count"):  # the tracking task: every route point in the bundle, the oracle on top
        from uavplace.rl.tasks.tracking import OraclePolicy, ReplanningGenie, RouteSet, TrackingConfig, run_tracking

        assert (
            b.manifest.num_route_points == record["routes"]["points"] and b.routes["route"].nunique() == record["routes"]["count"]
        )
        routes = RouteSet([b], TrackingConfig(horizon=60))
        episodes = routes.sample_episodes(24, np.random.default_rng(0))
        oracle, genie = (run_tracking(routes, p, episodes).table["covered_share"] for p in (OraclePolicy(), ReplanningGenie()))
        assert (oracle >= genie).all() and oracle.mean() > 0.5
        check_env(
            gym.make("uavplace/UavTracking-v0", dataset=city, root=str(tmp_path), horizon=60).unwrapped, skip_render_check=True
        )
