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


def test_the_searcher_plays_the_same_episodes_with_its_products_in_torch(tiny):
    from uavplace.rl.predictor import load_predictor
    from uavplace.rl.tasks.placement.config import EnvConfig
    from uavplace.rl.tasks.placement.rollout import run_episodes
    from uavplace.rl.tasks.placement.searcher import MapSearchPolicy
    from uavplace.rl.world.maps import MapSet

    maps = MapSet.load("tiny", EnvConfig(t_max=60, rotate=False), root=str(tiny))
    episodes = maps.episode_list(16, 2)
    numpy_side = MapSearchPolicy(load_predictor(), device="cpu")
    torch_side = MapSearchPolicy(load_predictor(), device="cpu")
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
