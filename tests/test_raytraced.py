"""The ray-traced tier of the predictor (rl/predictor/raytraced.py): the UAV's 3D map as prisms, the variant chosen by
device, the calibration, the version that keys its cache, the loader reading the tier from the model card, and (with
Sionna RT) a map searcher on it that reads no user's map and is served its maps from the cache the second time."""

from __future__ import annotations

import json

import numpy as np
import pytest
import shapely

from tests.test_simulate import needs_sionna
from uavplace.rl.predictor import Scene, load_constants, load_predictor
from uavplace.rl.predictor.raytraced import (
    TRACES,
    RayTracedModel,
    RayTracedPredictor,
    calibrate,
    cell_centres_m,
    map_blocks,
    save_raytraced,
)
from uavplace.schemas import InputError
from uavplace.simulate.raytrace import VARIANTS, mitsuba_variant


def _scene(heights: np.ndarray, spacing_m: float = 4.0) -> Scene:
    return Scene(np.asarray(heights, np.float32), spacing_m, 10.0, 8e8, 20.0, -75.0, -30.0)


def _model(**update) -> RayTracedModel:
    return RayTracedModel(constants=load_constants(), **update)


def test_the_variant_is_chosen_by_device():
    assert mitsuba_variant("cpu", cuda_available=True) == VARIANTS["cpu"] == "llvm_ad_mono_polarized"
    assert mitsuba_variant("auto", cuda_available=False) == VARIANTS["cpu"]
    assert mitsuba_variant("auto", cuda_available=True) == VARIANTS["cuda"] == "cuda_ad_mono_polarized"
    assert mitsuba_variant("cuda", cuda_available=True) == VARIANTS["cuda"]
    with pytest.raises(ValueError, match="no GPU"):
        mitsuba_variant("cuda", cuda_available=False)
    with pytest.raises(ValueError, match="unknown device"):
        mitsuba_variant("tpu", cuda_available=False)
    assert mitsuba_variant("auto") in VARIANTS.values()  # what this machine has, asked of Dr.Jit


def test_the_map_becomes_prisms_of_its_cells_and_heights():
    """Every building cell's centre lies in exactly one prism of its own height, no open cell's in any; cells of one
    height that touch are one prism."""
    rng = np.random.default_rng(4)
    h = np.where(rng.random((9, 7)) < 0.4, rng.choice([6.0, 12.5, 30.0], (9, 7)), 0.0)
    h[0, :3] = 6.0  # a run of one height: one prism
    blocks = map_blocks(_scene(h))
    centres = cell_centres_m(np.argwhere(np.ones(h.shape, bool)), 4.0)
    inside = np.array([[b.footprint.contains(shapely.Point(x, y)) for b in blocks] for x, y in centres])  # [cells, blocks]
    roof = np.array([b.roof_z_m for b in blocks])
    np.testing.assert_array_equal(inside.sum(axis=1), (h.ravel() > 0).astype(int))
    np.testing.assert_array_equal(np.where(inside.any(axis=1), roof[inside.argmax(axis=1)], 0.0), h.ravel())
    assert all(b.base_z_m == 0.0 for b in blocks)
    assert len(blocks) < (h > 0).sum()


def test_calibration_fits_the_spread_and_the_dead_logistics():
    """On cells whose truth is the trace plus 3 dB noise, dead below -10 dB: the spread is about 3 dB and a reached
    cell of a low trace is called dead; an unreached cell takes the physics tier's value, and its own logistic (here
    dead below 0 dB of the physics tier's SINR)."""
    rng = np.random.default_rng(0)
    traced = rng.uniform(-40, 40, 20_000)
    physics = rng.uniform(-40, 40, traced.size)
    measured = traced + rng.normal(0, 3, traced.size)
    low = measured < -10
    traced[:5000] = -np.inf  # unreached: the truth is the physics tier's plus noise, dead below 0 dB
    measured[:5000] = physics[:5000] + rng.normal(0, 3, 5000)
    low[:5000] = measured[:5000] < 0
    model = calibrate(_model(spread_estimator="std"), traced, physics, measured, low)
    assert 2.7 < model.error_db < 3.3
    heavy = measured.copy()
    heavy[-2000:] += rng.choice([-40, 40], 2000)  # a tail: the std grows, the robust spread stays the core's
    assert calibrate(_model(spread_estimator="std"), traced, physics, heavy, low).error_db > 8
    assert 2.7 < calibrate(_model(spread_estimator="robust"), traced, physics, heavy, low).error_db < 3.6
    assert -12 < model.dead_level_db < -8 and model.dead_scale_db < 3
    assert -2 < model.unreached_level_db < 2 and model.unreached_scale_db < 3
    mu, p_dead = RayTracedPredictor(model).combine(np.array([[-30.0, 20.0, -np.inf, -np.inf]]), np.array([[1.0, 2.0, -9.0, 9.0]]))
    np.testing.assert_allclose(mu, [[-30.0, 20.0, -9.0, 9.0]])
    assert p_dead[0, 0] > 0.99 and p_dead[0, 1] < 0.01 and p_dead[0, 2] > 0.9 and p_dead[0, 3] < 0.1
    with pytest.raises(ValueError, match="too few"):
        calibrate(_model(), traced[:5], physics[:5], measured[:5], low[:5])


def test_the_version_keys_settings_and_calibration_not_scores():
    base = RayTracedPredictor(_model()).version()
    assert RayTracedPredictor(_model(samples=200_000)).version() != base
    assert RayTracedPredictor(_model(error_db=7.0)).version() != base
    physics = RayTracedPredictor(_model(fallback="physics"))
    assert RayTracedPredictor(_model()).fallback.tier == "learned" and physics.fallback.tier == "physics"
    assert physics.version() != base  # the fallback's weights or constants in the key
    assert RayTracedPredictor(_model(scores={"x": {"median_error_db": 1.0}}, made_by=["uavrl x"])).version() == base
    assert RayTracedPredictor(_model(device="cpu")).version() == RayTracedPredictor(_model(device="auto")).version() or (
        mitsuba_variant("auto") == VARIANTS["cuda"]
    )  # the key is the variant that traces, not the setting


def test_the_loader_reads_the_tier_from_the_model_card(tmp_path):
    save_raytraced(tmp_path / "rt", _model(samples=50_000))
    loaded = load_predictor(tmp_path / "rt")
    assert isinstance(loaded, RayTracedPredictor) and loaded.model.samples == 50_000
    (tmp_path / "odd").mkdir()
    (tmp_path / "odd" / "model.json").write_text(json.dumps({"tier": "oracle"}))
    with pytest.raises(InputError, match="tier 'oracle'"):
        load_predictor(tmp_path / "odd")
    (tmp_path / "odd" / "model.json").write_text("{not json")
    with pytest.raises(InputError, match="not JSON"):
        load_predictor(tmp_path / "odd")


def test_the_learned_weights_are_bounded_by_the_network(tmp_path):
    """The learned tier's weights file may not be larger than its network's parameters allow: refused unread."""
    import shutil

    from tests.conftest import REPO

    folder = tmp_path / "unet"
    shutil.copytree(REPO / "data" / "agents" / "searcher" / "unet", folder)
    with open(folder / "weights.pt", "ab") as f:
        f.truncate(64 << 20)  # sparse: 64 MB of nothing past the weights
    with pytest.raises(InputError, match="parameters of float32"):
        load_predictor(folder)


@needs_sionna
def test_a_searcher_on_the_traced_tier_reads_no_users_map_and_caches_its_maps(tiny, tmp_path):
    """The map searcher on the ray-traced tier (few rays, the tiny city) moves the same when the user's map is
    scrambled off its route (the tier traced the public map only), and a second searcher with the same settings is
    served the maps from the cache (no ray traced)."""
    from tests import scramble
    from tests.test_information import EPISODES, T_MAX
    from uavplace.rl.belief import PredictionCache
    from uavplace.rl.config import SearchConfig
    from uavplace.rl.tasks.placement.config import EnvConfig
    from uavplace.rl.tasks.placement.searcher import MapSearchPolicy
    from uavplace.rl.world.maps import MapSet

    maps = MapSet.load("tiny", EnvConfig(t_max=T_MAX, rotate=False), root=str(tiny))
    traced: list[int] = []
    predictor = RayTracedPredictor(_model(samples=20_000, users_per_call=64, device="cpu"))
    predictor.on_batch = lambda done, total: traced.append(done)
    cache = PredictionCache(tmp_path / "cache")
    policy = MapSearchPolicy(predictor, SearchConfig(), cache)
    same, _ = scramble.replay_placement(maps, policy, maps.episode_list(EPISODES, 1), np.random.default_rng(3))
    assert all(same), f"moves changed when cells the searcher never visited changed ({same})"
    assert traced and len(list((tmp_path / "cache").glob("*.npz"))) == 1
    traced.clear()
    TRACES.clear()  # this process's traces too: only the cache on disk may serve the second searcher
    again = MapSearchPolicy(predictor, SearchConfig(), PredictionCache(tmp_path / "cache"))
    again.canvas_maps(again_public := _public(maps), 0)
    assert not traced, "the second searcher traced again instead of reading the cache"
    assert again_public.settings[0]["city"] == "tiny"


def _public(maps):  # noqa: ANN001, ANN202
    from uavplace.rl.world.view import PublicMaps

    return PublicMaps.of(maps)


def test_parts_are_whole_solver_calls():
    from uavplace.rl.predictor.raytraced import parts

    assert parts(100, 1, 32) == [(0, 100)]
    assert parts(100, 2, 32) == [(0, 64), (64, 100)]
    assert parts(129, 3, 32) == [(0, 64), (64, 128), (128, 129)]
    assert parts(10, 4, 32) == [(0, 10)]
    for n, w in ((1000, 7), (33, 2), (64, 64)):
        runs = parts(n, w, 16)
        assert runs[0][0] == 0 and runs[-1][1] == n and len(runs) <= w
        assert all(a % 16 == 0 and b == c for (a, b), (c, _) in zip(runs, runs[1:] + [(n, n)], strict=True))


@needs_sionna
@pytest.mark.slow
def test_candidates_traced_as_ray_tasks_are_the_maps_of_one_run(tiny):
    """Two Ray tasks on a local Ray trace the same maps, to the bit, as one run in this process (whole solver calls,
    the seeds of the whole set's)."""
    import ray

    from uavplace.dataset.bundle import load_bundle
    from uavplace.infra.cluster import start_ray
    from uavplace.rl.predictor.raytraced import traced_gain

    b = load_bundle("tiny", root=tiny)
    scene = Scene.of(b)
    users = np.argwhere(b.height_rel_m < -b.altitude_m + 1)[::37][:6]
    model = _model(samples=5_000, users_per_call=2, device="cpu")
    one = traced_gain(scene, users, model)
    started = start_ray(None, 1.0, "--workers", num_cpus=2)
    try:
        two = traced_gain(scene, users, model, workers=2)
    finally:
        if started:
            ray.shutdown()
    assert (one > 0).any()
    np.testing.assert_array_equal(one, two)


@needs_sionna
def test_trace_predictor_calibrates_on_a_pack_and_writes_its_card(tiny, tmp_path):
    """`uavrl trace-predictor` on a shipped training pack (one user, few rays): a model card of the ray-traced tier
    that the loader reads, calibrated on that pack; a line a pack as it goes. A pack without a dead cell (the tiny
    city) is refused in one line naming --maps."""
    from click.testing import CliRunner

    from tests.conftest import REPO
    from uavplace.cli import uavrl
    from uavplace.dataset.bundle import load_bundle
    from uavplace.dataset.trainmaps import TrainingMaps, write_pack

    common = ["--users", "1", "--samples", "5000", "--device", "cpu", "--fallback", "physics", "--root", str(tiny)]
    args = ["trace-predictor", "--maps", str(REPO / "data" / "trainmaps"), "--packs", "tt-000", *common]
    result = CliRunner().invoke(uavrl, [*args, "--out", str(tmp_path / "rt")])
    assert result.exit_code == 0, result.output
    assert "tt-000 traced (1/1" in result.output and "wrote" in result.output
    loaded = load_predictor(tmp_path / "rt")
    assert isinstance(loaded, RayTracedPredictor) and loaded.model.calibrated_on[0].startswith("tt-000@")
    assert loaded.model.samples == 5000 and loaded.model.calibration_users == 1 and loaded.model.made_by
    (tmp_path / "maps").mkdir()
    write_pack(tmp_path / "maps" / "tiny.npz", TrainingMaps.of_bundle(load_bundle("tiny", root=tiny)))
    refused = ["trace-predictor", "--maps", str(tmp_path / "maps"), *common, "--out", str(tmp_path / "rt2")]
    result = CliRunner().invoke(uavrl, refused)
    assert result.exit_code == 2 and "--maps" in result.output and "too few" in result.output, result.output
    assert not (tmp_path / "rt2").exists()
