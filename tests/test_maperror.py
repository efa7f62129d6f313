"""The UAV's 3D map when it errs (rl/world/maperror.py, ``MapErrorSettings`` of every task): per-building height
errors, small buildings missing, a registration shift; what policies and their predictors read of the buildings
errs, which cells may be entered, the users' maps and the genie never do."""

from __future__ import annotations

import numpy as np

from tests import scramble
from uavplace.dataset.bundle import load_bundle
from uavplace.rl.config import MapErrorSettings, SearchConfig
from uavplace.rl.tasks.placement.config import EnvConfig
from uavplace.rl.tasks.placement.policies import GeniePolicy
from uavplace.rl.tasks.placement.rollout import run_episodes
from uavplace.rl.world.maperror import seen_heights
from uavplace.rl.world.maps import MapSet
from uavplace.rl.world.view import PublicMaps

MODERATE = MapErrorSettings(height_sigma_m=2.0, missing_share=0.1, shift_m=1.0, seed=3)


def test_each_building_errs_by_one_draw_and_never_below_the_ground(tiny):
    bundle = load_bundle("tiny", root=tiny)
    assert seen_heights(bundle, MapErrorSettings()) is bundle.height_rel_m  # the exact map: the bundle's own
    seen = seen_heights(bundle, MapErrorSettings(height_sigma_m=3.0, seed=1))
    ground = -bundle.altitude_m
    assert (seen >= ground - 1e-5).all() and np.array_equal(
        seen[bundle.building_id < 0], bundle.height_rel_m[bundle.building_id < 0]
    )
    errors = []
    for seed in range(1, 31):  # the tiny city's 4 buildings, under 30 seeds
        seen_k = seen_heights(bundle, MapErrorSettings(height_sigma_m=3.0, seed=seed))
        for b in np.unique(bundle.building_id[bundle.building_id >= 0]):
            cells = bundle.building_id == b
            d = (seen_k - bundle.height_rel_m)[cells]
            if (seen_k[cells] > ground + 1e-5).all():  # one error a building (where not clipped at the ground)
                assert np.ptp(d) < 1e-4
                errors.append(d[0])
    assert len(errors) >= 60 and 2.4 < np.std(errors) < 3.6 and abs(np.mean(errors)) < 1.0
    again = seen_heights(bundle, MapErrorSettings(height_sigma_m=3.0, seed=1))
    other = seen_heights(bundle, MapErrorSettings(height_sigma_m=3.0, seed=2))
    assert np.array_equal(seen, again) and not np.array_equal(seen, other)


def test_small_buildings_go_missing_and_the_shift_moves_the_map_its_distance(tiny):
    bundle = load_bundle("tiny", root=tiny)
    ground, on = -bundle.altitude_m, bundle.building_id >= 0
    gone = seen_heights(bundle, MapErrorSettings(missing_share=1.0, missing_area_m2=1e6))
    assert np.allclose(gone, ground)  # every building small, every one missing
    kept = seen_heights(bundle, MapErrorSettings(missing_share=1.0, missing_area_m2=1.0))
    np.testing.assert_array_equal(kept, bundle.height_rel_m)  # none under 1 m2: none missing
    yy, xx = np.mgrid[: bundle.shape[0], : bundle.shape[1]]

    def centre(h: np.ndarray) -> np.ndarray:  # the centroid of the heights above the ground [cells]
        w = np.maximum(h - ground, 0)
        return np.array([(w * yy).sum(), (w * xx).sum()]) / w.sum()

    for shift in (4.0, 8.0):
        moved = seen_heights(bundle, MapErrorSettings(shift_m=shift, seed=5))
        distance = np.hypot(*(centre(moved) - centre(bundle.height_rel_m))) * bundle.spacing_m
        assert abs(distance - shift) < 0.35 * shift, (shift, distance)
    assert on.any()


def test_the_error_reaches_the_policies_map_and_never_the_world(tiny):
    """With a map error, the height channel and the public maps (the searcher's input, its version naming the error)
    hold the erring map; the legal moves, the users' maps and the genie's episodes are the traced city's."""
    exact = MapSet.load("tiny", EnvConfig(t_max=60, rotate=False), root=str(tiny))
    erring = MapSet.load("tiny", EnvConfig(t_max=60, rotate=False, map_error=MODERATE), root=str(tiny))
    for name in ("blocked", "sinr", "dead", "steps", "memory0"):
        np.testing.assert_array_equal(getattr(exact, name), getattr(erring, name), err_msg=name)
    assert not np.array_equal(exact.height, erring.height)
    a, b = PublicMaps.of(exact), PublicMaps.of(erring)
    assert not np.array_equal(a.bundle_heights[0], b.bundle_heights[0]) and np.array_equal(a.blocked, b.blocked)
    assert b.settings[0]["version"].startswith(a.settings[0]["version"] + "~map-")
    episodes = exact.episode_list(30, 0)
    genie = [run_episodes(m, GeniePolicy(), episodes) for m in (exact, erring)]
    np.testing.assert_array_equal(genie[0]["steps"].to_numpy(), genie[1]["steps"].to_numpy())


def test_the_searcher_on_an_erring_map_reads_only_what_it_measured(tiny):
    from uavplace.rl.predictor import load_predictor
    from uavplace.rl.tasks.placement.searcher import MapSearchPolicy

    maps = MapSet.load("tiny", EnvConfig(t_max=60, rotate=False, map_error=MODERATE), root=str(tiny))
    episodes = maps.episode_list(8, 1)
    policy = MapSearchPolicy(load_predictor(), SearchConfig())
    same, _ = scramble.replay_placement(maps, policy, episodes, np.random.default_rng(7))
    assert all(same), f"moves changed off its path on an erring map ({same})"
