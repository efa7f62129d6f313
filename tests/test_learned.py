"""The learned tier of the radio-map predictor: an untrained network is the physics tier, training lowers its loss,
its files are data (weights only, bound to their description by a hash), and `uavrl train-predictor` writes them."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from pydantic import ValidationError

from uavplace.cli import uavrl
from uavplace.dataset.bundle import load_bundle
from uavplace.dataset.trainmaps import TrainingMaps
from uavplace.infra.files import CONTENTS
from uavplace.rl.belief import PredictionCache
from uavplace.rl.config import SearchConfig
from uavplace.rl.predictor import PhysicsConstants, PhysicsPredictor, Scene, load_predictor
from uavplace.rl.predictor.learned import (
    MODEL_CARD,
    MODEL_JSON,
    WEIGHTS,
    LearnedModel,
    LearnedPredictor,
    MapUNet,
    UNetConfig,
    _batch,
    _loss,
    load_learned,
    save_learned,
    train_learned,
    training_examples,
)
from uavplace.rl.tasks.placement.searcher import MapSearchPolicy
from uavplace.schemas import InputError

SMALL = UNetConfig(widths=[4, 8], crop=16, batch=4, steps=40, lr=5e-3, threads=1)


def _constants() -> PhysicsConstants:
    return PhysicsConstants(intercept_db=-20, log_d_db=-23, wall_db=-9, diffraction_weight=0.1, dead_level_db=-13,
                            dead_scale_db=4, error_db=10, max_walls=3)  # fmt: skip


def _fields(constants: PhysicsConstants, config: UNetConfig) -> dict:
    return {"config": config, "constants": constants, "error_db": 9.0, "users": 1, "train_seconds": 0.0,
            "final_loss": 0.0}  # fmt: skip


def _trained_and_saved(bundle, folder):  # noqa: ANN001, ANN202
    """(network, folder): three training steps on ``bundle``'s users, saved as a learned tier in ``folder``."""
    net, facts = train_learned([TrainingMaps.of_bundle(bundle)], _constants(), SMALL.model_copy(update={"steps": 3}))
    folder.mkdir()
    save_learned(folder, net, {"config": SMALL, "constants": _constants(), **facts})
    return net, folder


def test_untrained_network_is_the_physics_tier(tiny):
    """The head starts at zero: before training the learned tier predicts the physics tier's maps exactly."""
    bundle = load_bundle("tiny", root=tiny)
    scene, constants = Scene.of(bundle), _constants()
    model = LearnedModel(weights_sha256="0" * 64, **_fields(constants, SMALL))
    learned = LearnedPredictor(model, MapUNet(SMALL.widths))
    users = np.argwhere(scene.ground_height_m <= 0)[:5]
    cells = np.argwhere(~bundle.blocked)
    mu, p_dead = learned.predict(scene, users, cells)
    want_mu, want_dead = PhysicsPredictor(constants).predict(scene, users, cells)
    np.testing.assert_allclose(mu, want_mu, atol=1e-3)
    np.testing.assert_allclose(p_dead, want_dead, atol=1e-4)


def test_training_lowers_the_loss_and_is_seeded(tiny):
    bundle = load_bundle("tiny", root=tiny)
    maps = [TrainingMaps.of_bundle(bundle)]
    examples = training_examples(maps, _constants())
    fixed = _batch(examples, SMALL.model_copy(update={"batch": 16}), np.random.default_rng(123))
    before = _loss(MapUNet(SMALL.widths), fixed, 1.0)[0].item()
    net, facts = train_learned(maps, _constants(), SMALL)
    after = _loss(net, fixed, 1.0)[0].item()
    assert after < before
    again, _ = train_learned(maps, _constants(), SMALL)
    for a, b in zip(net.state_dict().values(), again.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b)
    assert facts["users"] == bundle.num_users and facts["error_db"] > 0


def test_learned_files_round_trip_and_refuse_foreign_weights(tiny, tmp_path):
    bundle = load_bundle("tiny", root=tiny)
    net, folder = _trained_and_saved(bundle, tmp_path / "unet")
    loaded = load_predictor(folder)
    scene = Scene.of(bundle)
    users, cells = np.array([[2, 3], [5, 5]]), np.argwhere(~bundle.blocked)
    for a, b in zip(loaded.predict(scene, users, cells), LearnedPredictor(loaded.model, net).predict(scene, users, cells),
                    strict=True):  # fmt: skip
        np.testing.assert_allclose(a, b, atol=1e-6)
    other = MapUNet(SMALL.widths)  # weights that are not the ones model.json names
    torch.save(other.state_dict(), folder / WEIGHTS)
    with pytest.raises(InputError, match="sha256"):
        load_learned(folder)
    (folder / MODEL_JSON).write_text(json.dumps({"config": {"widths": []}}))
    with pytest.raises(InputError, match="model.json"):
        load_learned(folder)


def test_searcher_with_the_learned_tier_finds_the_tiny_users(tiny, tmp_path):
    from uavplace.rl.tasks.placement.config import EnvConfig
    from uavplace.rl.tasks.placement.rollout import run_episodes
    from uavplace.rl.world.maps import MapSet

    bundle = load_bundle("tiny", root=tiny)
    _, folder = _trained_and_saved(bundle, tmp_path / "unet")
    maps = MapSet.load("tiny", EnvConfig(t_max=100), root=str(tiny))
    cache = PredictionCache(tmp_path / "cache")
    policy = MapSearchPolicy(load_predictor(folder), SearchConfig(), cache)
    df = run_episodes(maps, policy, maps.episode_list(16, 0), num_envs=8)
    assert df["success"].mean() >= 0.9
    warm = run_episodes(
        maps, MapSearchPolicy(load_predictor(folder), SearchConfig(), cache), maps.episode_list(16, 0), num_envs=8
    )
    np.testing.assert_array_equal(df["steps"], warm["steps"])  # the cached maps play as the computed ones


def test_train_predictor_cli_writes_weights_model_and_card(tiny, tmp_path):
    import shutil

    from tests.conftest import REPO
    from uavplace.dataset.build import build_city
    from uavplace.ingest.pipeline import ingest_city
    from uavplace.schemas.bundle import BuildConfig

    root = tmp_path / "root"  # tiny, and tiny again under another name to validate on (a training city may not be)
    shutil.copytree(tiny, root)
    ingest_city(REPO / "data" / "raw" / "tiny", root, name="tiny-val")
    build_city("tiny-val", BuildConfig(grid_m=4.0, altitude_m=10.0), root)
    constants = tmp_path / "predictor.json"
    constants.write_text(_constants().model_dump_json())
    out = tmp_path / "unet"
    args = ["train-predictor", "--dataset", "tiny", "--val-dataset", "tiny-val", "--constants", str(constants), "--out",
            str(out), "--steps", "2", "--batch", "2", "--threads", "1", "--quiet", "--root", str(root)]  # fmt: skip
    result = CliRunner().invoke(uavrl, args)
    assert result.exit_code == 0, result.output
    assert {p.name for p in out.iterdir()} == {MODEL_JSON, WEIGHTS, MODEL_CARD, CONTENTS}  # and what uavplace wrote there
    model = load_learned(out).model
    assert set(model.scores) == {"tiny-val"} and model.scores["tiny-val"]["learned_ms_per_map"] > 0
    assert "uavrl train-predictor" in (out / MODEL_CARD).read_text()
    (out / MODEL_JSON).unlink()
    (out / "notes.txt").write_text("mine")  # a folder that is not a learned predictor's is never replaced
    result = CliRunner().invoke(uavrl, args)
    assert result.exit_code != 0 and (out / "notes.txt").read_text() == "mine"


def test_shipped_learned_tier_loads_and_says_how_it_was_made():
    from tests.conftest import REPO
    from uavplace.rl.config import DEFAULT_PREDICTOR

    predictor = load_predictor(REPO / DEFAULT_PREDICTOR)
    assert predictor.tier == "learned" and predictor.error_db > 0
    assert predictor.model.users > 0 and predictor.model.scores  # trained on users, scored on validation cities
    card = (REPO / DEFAULT_PREDICTOR / MODEL_CARD).read_text()
    assert predictor.model.weights_sha256 in card


def test_shipped_calibration_command_selects_the_packs_it_was_calibrated_on():
    """The shipped card's `uavrl calibrate-predictor` line, run on today's data/trainmaps, reads exactly the packs
    ``calibrated_on`` names, with their versions: more packs landing there does not change what it reproduces."""
    import shlex

    from tests.conftest import REPO
    from uavplace.dataset.trainmaps import read_pack, select_packs
    from uavplace.rl.config import DEFAULT_PREDICTOR

    model = load_predictor(REPO / DEFAULT_PREDICTOR).model
    [line] = [shlex.split(c) for c in model.made_by if "calibrate-predictor" in c]
    values = {o: [line[i + 1] for i, a in enumerate(line[:-1]) if a == o] for o in ("--maps", "--packs")}
    paths = select_packs([REPO / m for m in values["--maps"]], values["--packs"])
    assert len(select_packs([REPO / m for m in values["--maps"]], ["tt-*"])) > len(paths)  # others there, not read
    assert [f"{m.city}@{m.version}" for m in map(read_pack, paths)] == model.calibrated_on
    assert shlex.join(line) in (REPO / DEFAULT_PREDICTOR / MODEL_CARD).read_text()


def test_reliability_by_hand():
    """Ten equal-width bins; the error is the count-weighted |frequency - mean probability|."""
    from uavplace.rl.predictor import reliability

    p = np.array([0.05, 0.05, 0.95, 0.95, 0.95, 0.55])
    outcome = np.array([False, True, True, True, True, False])
    ece, rows = reliability(p, outcome)
    assert [r[2] for r in rows] == [2, 1, 3]
    np.testing.assert_allclose([r[1] for r in rows], [0.5, 0.0, 1.0])
    assert ece == pytest.approx((2 * 0.45 + 1 * 0.55 + 3 * 0.05) / 6)
    assert reliability(np.array([1.0, 0.0]), np.array([True, False]))[0] == 0  # p = 1 falls in the last bin


def test_platt_scaling_recovers_a_known_miscalibration():
    from uavplace.rl.predictor import platt_scaling, reliability

    rng = np.random.default_rng(0)
    z = rng.normal(0, 3, 200_000)
    y = rng.random(z.size) < 1 / (1 + np.exp(-(0.5 * z - 1.0)))  # the events follow 0.5 z - 1, not z
    scale, bias = platt_scaling(z, y)
    assert scale == pytest.approx(0.5, abs=0.02) and bias == pytest.approx(-1.0, abs=0.03)
    before = reliability(1 / (1 + np.exp(-z)), y)[0]
    after = reliability(1 / (1 + np.exp(-(scale * z + bias))), y)[0]
    assert after < 0.01 < before


def test_training_holds_out_users_to_calibrate(tiny):
    """With a calibration share, the held-out users are left out of the gradient steps and fit the dead logit's scale
    and bias, which the predictor then applies."""
    bundle = load_bundle("tiny", root=tiny)
    maps = [TrainingMaps.of_bundle(bundle)]
    config = SMALL.model_copy(update={"steps": 5, "calibration_share": 0.5})
    net, facts = train_learned(maps, _constants(), config)
    assert facts["calibration_users"] == bundle.num_users // 2 and facts["users"] == bundle.num_users - facts["calibration_users"]
    scale, bias = facts["calibration"]
    assert (scale, bias) != (1.0, 0.0) and np.isfinite([scale, bias]).all()
    model = LearnedModel(weights_sha256="0" * 64, **{**_fields(_constants(), config), "calibration": (scale, bias)})
    plain = LearnedModel(weights_sha256="0" * 64, **_fields(_constants(), config))
    scene, cells = Scene.of(bundle), np.argwhere(~bundle.blocked)
    users = np.array([[2, 3]])
    _, p_cal = LearnedPredictor(model, net).predict(scene, users, cells)
    _, p_raw = LearnedPredictor(plain, net).predict(scene, users, cells)
    logit = np.log(p_raw) - np.log1p(-p_raw)
    np.testing.assert_allclose(p_cal, 1 / (1 + np.exp(-(scale * logit + bias))), atol=2e-4)
    assert LearnedPredictor(model, net).version() != LearnedPredictor(plain, net).version()


def test_calibrate_predictor_fits_platt_scaling_on_packs_it_was_not_trained_on(tiny, tmp_path):
    """`uavrl calibrate-predictor`: the Platt scaling of the uncalibrated dead logit on every user of the packs (by
    hand: ``platt_scaling`` of ``dead_logits``), the same weights, a card saying where it was fitted; fitting the
    calibrated folder again gives the same numbers; a pack of a city the network was trained on is refused and nothing
    is written."""
    from uavplace.cli import uavdata
    from uavplace.dataset.trainmaps import read_pack
    from uavplace.rl.predictor import platt_scaling

    packs = tmp_path / "packs"
    assert CliRunner().invoke(uavdata, ["pack", "tiny", "--root", str(tiny), "--out", str(packs)]).exit_code == 0
    net, folder = _trained_and_saved(load_bundle("tiny", root=tiny), tmp_path / "unet")  # fitted_on names no city
    out = tmp_path / "calibrated"
    args = ["calibrate-predictor", "--predictor", str(folder), "--maps", str(packs), "--root", str(tiny)]
    result = CliRunner().invoke(uavrl, [*args, "--out", str(out)])
    assert result.exit_code == 0, result.output
    maps = read_pack(packs / "tiny.npz")
    scene, cells = Scene.from_settings(maps.settings, maps.height_rel_m), np.argwhere(~maps.blocked)
    raw = load_learned(folder).dead_logits(scene, maps.users, cells)
    low = maps.dead[:, cells[:, 0], cells[:, 1]] | (maps.sinr_db[:, cells[:, 0], cells[:, 1]] <= scene.floor_db + 1e-3)
    expected = platt_scaling(raw.astype(np.float64).ravel(), low.ravel())
    calibrated = load_learned(out)
    assert calibrated.model.calibration == pytest.approx(expected, rel=1e-9) and expected != pytest.approx((1.0, 0.0))
    assert calibrated.model.calibrated_on == [f"tiny@{maps.version}"]
    assert calibrated.model.weights_sha256 == load_learned(folder).model.weights_sha256
    scale, bias = expected
    _, p_dead = calibrated.predict(scene, maps.users, cells)
    np.testing.assert_allclose(p_dead, 1 / (1 + np.exp(-(scale * raw + bias))), atol=1e-6)
    card = (out / MODEL_CARD).read_text()
    assert "uavrl calibrate-predictor" in card and f"tiny@{maps.version}" in card
    again = CliRunner().invoke(uavrl, [*args[:2], str(out), *args[3:], "--out", str(tmp_path / "again")])
    assert again.exit_code == 0, again.output
    assert load_learned(tmp_path / "again").model.calibration == pytest.approx(expected, rel=1e-9)
    model = json.loads((folder / MODEL_JSON).read_text())
    (folder / MODEL_JSON).write_text(json.dumps({**model, "fitted_on": [f"tiny@{maps.version}"]}))
    refused = CliRunner().invoke(uavrl, [*args, "--out", str(tmp_path / "refused")])
    assert refused.exit_code != 0 and "trained on it" in refused.output and not (tmp_path / "refused").exists()
    for pattern in ("tt-*", "tin"):  # a pattern matches the whole name: "tin" is not a prefix of "tiny"
        none = CliRunner().invoke(uavrl, [*args, "--packs", pattern, "--out", str(tmp_path / "none")])
        assert none.exit_code != 0 and "--packs" in none.output and not (tmp_path / "none").exists()


def test_a_training_step_too_large_for_memory_is_refused_before_any_map_is_read(tiny):
    """`--batch 1024` (inside UNetConfig's range) would hold about 4 GB of activations a step: refused by the limit
    predictor_step_bytes before any training map is read, naming --batch, --crop and --widths (any of them may be
    what is too large); a level over 1024 channels is refused by the settings."""
    from uavplace.rl.predictor.learned import step_bytes

    assert step_bytes(UNetConfig(batch=1024)) > 2 * 2**30 > step_bytes(UNetConfig())
    maps = [TrainingMaps.of_bundle(load_bundle("tiny", root=tiny))]
    for config in (UNetConfig(batch=1024), UNetConfig(widths=[1000, 1000])):
        with pytest.raises(InputError, match=r"--batch x --crop x --widths \[bytes\]: .* predictor_step_bytes"):
            train_learned(maps, _constants(), config)
    with pytest.raises(ValidationError, match="less than or equal to 1024"):
        UNetConfig(widths=[16, 4096])
