"""The embedded default cities in data/raw/: small enough for git, and they ingest and build as documented."""

from __future__ import annotations

import json

import gymnasium as gym
import pytest
from gymnasium.utils.env_checker import check_env

import rl  # noqa: F401  (registers the environments)
from dataset.build import build_city
from dataset.bundle import load_bundle
from ingest.pipeline import ingest_city
from schemas.bundle import BuildConfig
from tests.conftest import REPO

RAW = REPO / "data" / "raw"
#: city -> (users, grid cells x, grid cells y) as made by the commands in the README.
EMBEDDED = {"train": (27, 138, 125), "test": (25, 100, 125), "tiny": (4, 24, 20)}
#: The noise-plus-interference level the README's main job builds them with [dBm].
CALIBRATED_NOISE_DBM = -68.0


def test_embedded_data_is_small():
    size = sum(p.stat().st_size for p in RAW.rglob("*") if p.is_file())
    assert size <= 25e6, f"data/raw holds {size / 1e6:.1f} MB, more than the 25 MB budget"


@pytest.mark.parametrize("city", sorted(EMBEDDED))
def test_embedded_city_ingests_and_builds(tmp_path, city):
    users, nx, ny = EMBEDDED[city]
    record = json.loads((RAW / city / "simulation.json").read_text())
    assert record["spec"]["name"] == city and len(record["users_m"]) == users
    ingest_city(RAW / city, tmp_path)
    b = load_bundle(build_city(city, BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=CALIBRATED_NOISE_DBM), tmp_path).path)
    assert b.num_users == users and b.shape == (ny, nx)
    assert b.manifest.counts["buildings"] == record["num_buildings"]
    d = b.manifest.difficulty
    assert 0 < d["target_share"] < 1 and d["num_starts"] > 0
    env = gym.make("uavplace/UavPlacement-v0", dataset=city, root=str(tmp_path), rotate=True)
    check_env(env.unwrapped)
    assert env.reset(seed=0)[0].shape == (2, 61, 61)
