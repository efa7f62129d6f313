"""Where the arithmetic runs (infra/device.py): one rule for torch and for Mitsuba's variant, ``cuda`` refused
without a GPU, the belief products in torch on a device (checked here on the CPU's torch against numpy), the agents'
networks moved where the report says, and the ray tracer's variant recorded only when it is not the CPU's."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from uavplace.cli import uavdata, uavrl
from uavplace.infra.device import pick, torch_device
from uavplace.rl.belief.model import CandidateMaps, DeviceCopies, posterior_cover
from uavplace.rl.config import SearchConfig
from uavplace.simulate.config import Simulation
from uavplace.simulate.raytrace import VARIANTS, RayTraceConfig, mitsuba_variant, raytrace_record

NO_GPU = pytest.mark.skipif(torch.cuda.is_available(), reason="a GPU is here: cuda is not refused")


def test_the_device_is_chosen_by_one_rule():
    assert pick("auto", False, "x") == pick("cpu", True, "x") == "cpu"
    assert pick("auto", True, "x") == pick("cuda", True, "x") == "cuda"
    with pytest.raises(ValueError, match="no GPU that torch can use"):
        torch_device("cuda", cuda_available=False)
    with pytest.raises(ValueError, match="unknown device 'tpu'"):
        torch_device("tpu", cuda_available=True)
    assert torch_device("cuda:1", cuda_available=True) == torch.device("cuda:1")
    with pytest.raises(ValueError, match="no GPU"):
        torch_device("cuda:1", cuda_available=False)
    assert torch_device("auto", cuda_available=False) == torch.device("cpu")
    assert torch_device("auto") == torch.device("cuda" if torch.cuda.is_available() else "cpu")
    assert mitsuba_variant("auto", cuda_available=True) == VARIANTS["cuda"]
    assert mitsuba_variant("auto", cuda_available=False) == mitsuba_variant("cpu", cuda_available=True) == VARIANTS["cpu"]


def test_the_belief_product_in_torch_is_numpys():
    """``posterior_cover`` through ``DeviceCopies`` (torch, float64) against numpy: the same to 1e-12; the copy of a
    map is made once while the map lives and never served for another array."""
    rng = np.random.default_rng(3)
    cover = rng.random((300, 700)).astype(np.float32)
    maps = CandidateMaps(np.zeros((300, 2), np.int64), np.zeros((700, 2), np.int64), np.zeros((1, 1)), cover, cover, cover)
    log_b = rng.normal(0, 30, (9, 300))
    copies = DeviceCopies(torch.device("cpu"))
    np.testing.assert_allclose(posterior_cover(log_b, maps, copies), posterior_cover(log_b, maps), rtol=1e-12, atol=1e-15)
    single = log_b.astype(np.float32)  # a float32 belief: its product in float32 on either side
    on_torch = posterior_cover(single, maps, copies)
    assert on_torch.dtype == posterior_cover(single, maps).dtype == np.float32
    np.testing.assert_allclose(on_torch, posterior_cover(single, maps), rtol=1e-5, atol=1e-7)
    first = copies(cover, np.float64)
    assert copies(cover, np.float64) is first and len(copies._held) == 2  # float64 and float32 copies of one array
    other = cover * 0.5
    assert copies(other, np.float64) is not first and torch.equal(copies(other, np.float64), torch.from_numpy(other).double())
    del other
    copies(cover.copy(), np.float64)  # another array: the dead one's copy is dropped
    assert len(copies._held) == 3


def test_the_belief_product_in_bfloat16_is_near_float32s_and_each_rows_own():
    """``posterior_cover(..., precision="bfloat16")`` (the hybrid's channel): within 3 x 2^-8 of the float32 product's
    value (a belief, a cover and a sum each rounded once); a row's values the same in a batch of any other rows and
    with one torch thread or two (a report cuts its episodes into pieces: ``eval.parallel``); any other name refused."""
    rng = np.random.default_rng(5)
    cover = rng.random((400, 900)).astype(np.float32)
    maps = CandidateMaps(np.zeros((400, 2), np.int64), np.zeros((900, 2), np.int64), np.zeros((1, 1)), cover, cover, cover)
    log_b = rng.normal(0, 3, (64, 400)).astype(np.float32)
    exact, low = posterior_cover(log_b, maps), posterior_cover(log_b, maps, precision="bfloat16")
    assert low.dtype == np.float32 and low.shape == exact.shape
    assert (np.abs(low - exact) <= 3 * 2.0**-8 * exact).all() and not np.array_equal(low, exact)
    threads = torch.get_num_threads()
    try:
        for n in (1, 2):
            torch.set_num_threads(n)
            for rows in (slice(0, 1), slice(5, 7), slice(10, 47), slice(0, 64)):
                assert np.array_equal(posterior_cover(log_b[rows], maps, precision="bfloat16"), low[rows])
    finally:
        torch.set_num_threads(threads)
    with pytest.raises(ValueError, match="not 'float16'"):
        posterior_cover(log_b, maps, precision="float16")


def test_the_searcher_plays_the_same_episodes_with_its_products_in_torch(tiny):
    from uavplace.rl.predictor import load_predictor
    from uavplace.rl.tasks.placement.config import EnvConfig
    from uavplace.rl.tasks.placement.rollout import run_episodes
    from uavplace.rl.tasks.placement.searcher import MapSearchPolicy
    from uavplace.rl.world.maps import MapSet

    maps = MapSet.load("tiny", EnvConfig(t_max=60, rotate=False), root=str(tiny))
    episodes = maps.episode_list(16, 2)
    own = SearchConfig(precision="belief")  # numpy's float32 product against torch's
    numpy_side = MapSearchPolicy(load_predictor(), own, device="cpu")
    torch_side = MapSearchPolicy(load_predictor(), own, device="cpu")
    torch_side.on_device = DeviceCopies(torch.device("cpu"))  # the GPU's code path, on the CPU
    a, b = (run_episodes(maps, p, episodes) for p in (numpy_side, torch_side))
    np.testing.assert_array_equal(a["steps"].to_numpy(), b["steps"].to_numpy())
    copy = pickle.loads(pickle.dumps(torch_side))  # a Ray task's copy: its device's products made anew there
    assert copy.device == "cpu" and copy.on_device is None


def test_the_agents_network_goes_to_the_reports_device():
    from uavplace.eval.evaluate import default_agents, load_agent

    agent = load_agent(default_agents()[0], 0.096, 0, device="cpu")
    assert {p.device for p in agent.policy.net.parameters()} == {torch.device("cpu")} == {agent.policy.device}
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="no GPU"):
            load_agent(default_agents()[0], 0.096, 0, device="cuda")


def test_the_ray_tracers_variant_is_recorded_only_off_the_cpu():
    """The CPU's variant leaves simulation.json's record (and a trace cache's key) as it was; another one names it."""
    cpu = Simulation(name="t", device="cpu").raytrace()
    assert cpu.variant == VARIANTS["cpu"] and "variant" not in raytrace_record(cpu)
    assert raytrace_record(RayTraceConfig(variant=VARIANTS["cuda"]))["variant"] == VARIANTS["cuda"]


@NO_GPU
def test_cuda_without_a_gpu_is_refused_by_every_command(tmp_path):
    for command, args in (
        (uavrl, ["report", "--device", "cuda", "--dataset", "tiny", "--out", str(tmp_path / "r")]),
        (uavrl, ["robustness", "--device", "cuda", "--out", str(tmp_path / "r")]),
        (uavdata, ["simulate", "procedural:tiny", "--name", "t", "--out", str(tmp_path), "--device", "cuda"]),
    ):
        res = CliRunner().invoke(command, args)
        assert res.exit_code == 2 and "--device" in res.output and "no GPU" in res.output, res.output
        assert not any(tmp_path.iterdir())


def test_the_searcher_plans_on_the_product_in_its_settings_precision(tiny, monkeypatch):
    """``SearchConfig.precision``: the map searcher multiplies in its belief's own precision by default ('belief') and in
    bfloat16 when told (the product it is handed each step says which), as the tracking and fleet searchers' settings
    tell theirs; it finds every tiny user either way."""
    import uavplace.rl.tasks.placement.searcher as placement
    from uavplace.rl.predictor import load_predictor
    from uavplace.rl.tasks.fleet.config import fleet_search
    from uavplace.rl.tasks.placement.config import EnvConfig
    from uavplace.rl.tasks.placement.rollout import run_episodes
    from uavplace.rl.tasks.tracking.config import tracking_search
    from uavplace.rl.world.maps import MapSet

    assert SearchConfig().precision == "belief" and tracking_search().precision == fleet_search().precision == "bfloat16"
    maps = MapSet.load("tiny", EnvConfig(t_max=60, rotate=False), root=str(tiny))
    episodes = maps.episode_list(24, 4)
    asked: list[str] = []

    def told(log_b, maps, on_device=None, precision="belief"):  # noqa: ANN001, ANN202 - posterior_cover's signature
        asked.append(precision)
        return posterior_cover(log_b, maps, on_device, precision)

    monkeypatch.setattr(placement, "posterior_cover", told)
    for precision in ("belief", "bfloat16"):
        asked.clear()
        played = run_episodes(maps, placement.MapSearchPolicy(load_predictor(), SearchConfig(precision=precision)), episodes)
        assert set(asked) == {precision} and played["success"].all()
