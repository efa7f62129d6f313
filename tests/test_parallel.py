"""The report's methods as Ray tasks, each in pieces of its episodes, give the same episodes, to the bit, as one after
the other in this process: every method (the shipped agents, the hybrid that reads the searcher's belief, the
searchers, the baselines), the recorded paths, the progress (each method's episodes counted to the end)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.evaluate import ReportConfig, blanked_agents, blanked_results, evaluate, load_agent
from uavplace.infra.files import shipped


@pytest.fixture(scope="module")
def local_ray():
    ray = pytest.importorskip("ray")
    from uavplace.infra.cluster import start_ray

    started = start_ray(None, 1, "--workers")
    yield
    if started:
        ray.shutdown()


def test_a_method_is_cut_into_contiguous_pieces():
    from uavplace.eval.parallel import MIN_PIECE, pieces

    assert pieces(1000, 2) == [(0, 500), (500, 1000)]
    assert pieces(MIN_PIECE, 8) == [(0, MIN_PIECE)] and pieces(7, 3) == [(0, 7)]  # never below MIN_PIECE episodes
    cut = pieces(1001, 3)
    assert cut[0][0] == 0 and cut[-1][1] == 1001 and all(a[1] == b[0] for a, b in zip(cut[:-1], cut[1:], strict=True))


def test_methods_on_ray_play_the_same_episodes(tiny, tmp_path, local_ray, monkeypatch):
    import uavplace.eval.parallel as parallel

    monkeypatch.setattr(parallel, "MIN_PIECE", 5)  # every method in pieces, even on a few episodes
    config = ReportConfig(dataset="tiny", episodes=24, seed=3)
    bundle = load_bundle("tiny", root=tiny)
    agents = lambda: [load_agent(shipped(f"data/agents/{n}"), config.test_epsilon, config.seed) for n in ("best", "hybrid")]  # noqa: E731
    serial = evaluate(config, bundle, agents())
    seen: dict[str, int] = {}
    on_ray = evaluate(config, bundle, agents(), lambda m, done, total: seen.update({m: done}), parallel=True)
    assert list(on_ray) == list(serial)  # the methods in the report's order
    for name in serial:
        pd.testing.assert_frame_equal(on_ray[name], serial[name], check_exact=True)
        paths, expected = on_ray[name].attrs.get("paths") or {}, serial[name].attrs.get("paths") or {}
        assert paths.keys() == expected.keys() and all((paths[e] == expected[e]).all() for e in paths)
    assert all(seen[name] == 24 for name in serial)  # each method's progress reached its last episode
    readers = blanked_agents(config, agents())
    pd.testing.assert_frame_equal(
        pd.concat(blanked_results(config, bundle, readers, None, parallel=True)),
        pd.concat(blanked_results(config, bundle, blanked_agents(config, agents()), None)),
        check_exact=True,
    )


def test_the_report_is_the_same_on_one_worker_and_on_two(tiny, tmp_path, local_ray):
    """`uavrl report --workers 2` (on the local Ray) writes the same tables and episodes as `--workers 1`."""
    args = ["report", "--dataset", "tiny", "--root", str(tiny), "--episodes", "16", "--bootstrap", "100"]
    _reports_on_one_and_two_workers(tmp_path, args, ["results.csv", "episodes.parquet"])


def test_a_policy_in_a_task_finds_the_prediction_cache_from_another_folder(tmp_path, monkeypatch):
    """A Ray worker runs in a folder of its own: the searcher's cache is kept by its absolute path, so the copy in a
    task reads the maps the report made instead of predicting them again."""
    import copy

    from tests.test_searcher import _constants
    from uavplace.rl.belief import PredictionCache
    from uavplace.rl.tasks.placement.searcher import MapSearchPolicy

    monkeypatch.chdir(tmp_path)
    policy = MapSearchPolicy(_constants(), cache=PredictionCache("data/processed/.predictions"))
    monkeypatch.chdir("/")
    policy._canvases[("v", 0, 5.0)] = "maps held in memory"
    moved = copy.deepcopy(policy)  # what travels: __getstate__, as Ray's serialiser takes it
    assert moved.cache.folder == tmp_path / "data" / "processed" / ".predictions" and moved._canvases == {}


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    """Two grid cities with two routes each (``tests.test_tracking``'s ``walk`` and another drawn alike, ``stroll``),
    ingested and built: the tracking task's worlds."""
    from tests.test_tracking import build_walk

    tmp = tmp_path_factory.mktemp("walk")
    build_walk(tmp, "stroll", seed=5)
    return build_walk(tmp)


def _reports_on_one_and_two_workers(tmp_path, args: list[str], files: list[str]) -> None:
    """`uavrl report ARGS --workers 1` and `--workers 2` write ``files`` alike, to the bit."""
    from click.testing import CliRunner

    from uavplace.cli import uavrl

    read = {"csv": pd.read_csv, "parquet": pd.read_parquet}
    written = {}
    for workers in ("1", "2"):
        out = tmp_path / f"w{workers}"
        res = CliRunner().invoke(uavrl, [*args, "--quiet", "--workers", workers, "--out", str(out)])
        assert res.exit_code == 0, res.output
        written[workers] = [read[f.rsplit(".", 1)[1]](out / f) for f in files]
    for name, one, two in zip(files, written["1"], written["2"], strict=True):
        assert len(one) > 0, name
        pd.testing.assert_frame_equal(one, two, check_exact=True)


def test_the_tracking_report_is_the_same_on_one_worker_and_on_two(walk, tmp_path, local_ray, monkeypatch):
    """`uavrl report --task tracking --workers 2`: every method (a placement agent, the hybrid that carries the
    searcher's belief, the tracking searcher, the baselines whose draws are keyed by an episode's place in the list)
    in pieces of its episodes plays every episode as `--workers 1` does; two cities' methods, of the same names,
    played in one go."""
    import uavplace.eval.parallel as parallel

    monkeypatch.setattr(parallel, "MIN_PIECE", 5)  # every method in pieces, even on a few episodes
    agents = [a for n in ("proposed", "hybrid") for a in ("--run", str(shipped(f"data/agents/{n}")))]
    args = ["report", "--task", "tracking", "--dataset", "walk", "--dataset", "stroll", "--root", str(walk), "--episodes",
            "12", "--horizon", "20", "--bootstrap", "100", *agents]  # fmt: skip
    _reports_on_one_and_two_workers(tmp_path, args, ["tracking.csv", "walk-episodes.parquet", "stroll-episodes.parquet"])


def test_the_fleet_report_is_the_same_on_one_worker_and_on_two(tiny, tmp_path, local_ray, monkeypatch):
    """`uavrl report --task fleet --workers 2`: the fleet searcher, the agents on every UAV and the baselines in
    pieces play every episode as `--workers 1` does."""
    import uavplace.eval.parallel as parallel

    monkeypatch.setattr(parallel, "MIN_PIECE", 5)
    args = ["report", "--task", "fleet", "--dataset", "tiny", "--root", str(tiny), "--episodes", "12", "--users", "2",
            "--bootstrap", "100"]  # fmt: skip
    _reports_on_one_and_two_workers(tmp_path, args, ["results.csv", "differences.csv", "episodes.parquet"])


def test_a_learned_tiers_planes_made_by_ray_tasks_give_the_same_predictions(tiny, local_ray, monkeypatch):
    """In the driver of a joined Ray, the learned tier's input planes are Ray tasks a few batches ahead of the network:
    the predictions are those made in this process alone, to the bit, batch by batch in order."""
    import torch

    import uavplace.rl.predictor.learned as learned
    from uavplace.dataset.bundle import load_bundle
    from uavplace.rl.config import UNetConfig
    from uavplace.rl.predictor import PhysicsConstants, Scene

    bundle = load_bundle("tiny", root=tiny)
    scene = Scene.of(bundle)
    constants = PhysicsConstants(intercept_db=-20, log_d_db=-23, wall_db=-9, diffraction_weight=0.1, dead_level_db=-13,
                                 dead_scale_db=4, error_db=10, max_walls=3)  # fmt: skip
    config = UNetConfig(widths=[4, 8], steps=1)
    model = learned.LearnedModel(weights_sha256="0" * 64, config=config, constants=constants, error_db=9.0, users=1,
                                 train_seconds=0.0, final_loss=0.0)  # fmt: skip
    torch.manual_seed(0)
    net = learned.MapUNet(config.widths)
    for p in net.parameters():  # not the physics tier's zero head: the network's own numbers show in the maps
        torch.nn.init.normal_(p, std=0.1)
    predictor = learned.LearnedPredictor(model, net, batch=3)
    users, cells = np.argwhere(scene.ground_height_m <= 0)[:11], np.argwhere(~bundle.blocked)
    assert learned.ray_driver()
    on_ray = predictor.predict(scene, users, cells)
    monkeypatch.setattr(learned, "ray_driver", lambda: False)
    alone = predictor.predict(scene, users, cells)
    for a, b in zip(on_ray, alone, strict=True):
        assert np.array_equal(a, b)
    assert not np.array_equal(alone[0][0], alone[0][1])  # the users' maps differ: an order mixed up would show
