"""The radio-map community's formats (dataset/export.py, `uavdata export`): a bundle round-trips through a
RadioMapSeer-style folder within the PNG's quantisation, the DeepMIMO-style file's arrays are the bundle's in their
documented units and frame, a damaged folder is refused naming the file, and the predictor trains on such a folder."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from uavplace.cli import uavdata, uavrl
from uavplace.dataset.bundle import load_bundle
from uavplace.dataset.export import read_radiomapseer, write_deepmimo, write_radiomapseer
from uavplace.dataset.trainmaps import STEP_DB
from uavplace.schemas import InputError


def test_radiomapseer_folder_round_trips_within_the_quantisation(tiny, tmp_path):
    bundle = load_bundle("tiny", root=tiny)
    folder = write_radiomapseer(bundle, tmp_path)
    assert folder == tmp_path / "tiny" and (folder / "png" / "buildings_complete" / "tiny.png").is_file()
    maps = read_radiomapseer(folder)
    np.testing.assert_array_equal(maps.blocked, bundle.blocked)
    np.testing.assert_array_equal(maps.dead, bundle.dead)
    assert np.abs(maps.sinr_db - bundle.sinr_db)[~bundle.dead].max() <= STEP_DB / 2 + 1e-4
    np.testing.assert_allclose(maps.height_rel_m, bundle.height_rel_m, atol=0.005 + 1e-6)
    table = bundle.users.set_index("user")
    np.testing.assert_array_equal(maps.users, table.loc[bundle.user_indices(), ["iy", "ix"]].to_numpy())
    # row 0 of every image is the north: the building map's first row is the grid's last
    from PIL import Image

    with Image.open(folder / "png" / "buildings_complete" / "tiny.png") as im:
        image = np.asarray(im)
    np.testing.assert_array_equal(image[0] > 127, bundle.blocked[-1])
    scale = json.loads((folder / "scale.json").read_text())
    assert scale["sinr"]["step_db"] == STEP_DB and "row 0 is the northernmost" in scale["frame"]


def test_uavdata_ingests_a_radiomapseer_folder_as_a_city(tiny, tmp_path):
    """Export, ingest, build: the same maps (the SINR to the PNG's quantisation, the rest exactly; heights to the cm),
    the same users, and a build that says where its values came from ("not recorded": the folder records nothing)."""
    bundle = load_bundle("tiny", root=tiny)
    folder = write_radiomapseer(bundle, tmp_path / "raw")
    root = tmp_path / "processed"
    res = CliRunner().invoke(uavdata, ["ingest", str(folder), "--name", "tiny-again", "--out", str(root)])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(uavdata, ["build", "--city", "tiny-again", "--grid", "4m", "--alt", "10", "--root", str(root)])
    assert res.exit_code == 0, res.output
    again = load_bundle("tiny-again", root=root)
    assert again.blocked.shape == bundle.blocked.shape and np.allclose(
        [again.x_m[0], again.y_m[0]], [bundle.x_m[0], bundle.y_m[0]]
    )
    np.testing.assert_array_equal(again.blocked, bundle.blocked)
    np.testing.assert_array_equal(again.dead, bundle.dead)
    live = ~bundle.dead
    assert np.abs(again.sinr_db - bundle.sinr_db)[live].max() <= STEP_DB / 2 + 1e-4
    ground = lambda b: np.maximum(b.height_rel_m + b.altitude_m, 0)  # noqa: E731 - what the folder keeps: heights above the ground
    np.testing.assert_allclose(ground(again), ground(bundle), atol=0.005 + 1e-6)
    cells = lambda b: b.users.set_index("user").loc[b.user_indices(), ["iy", "ix"]].to_numpy()  # noqa: E731
    np.testing.assert_array_equal(cells(again), cells(bundle))
    assert set(again.cell_sources()) <= {"unreached", "not recorded"}


def test_a_damaged_radiomapseer_folder_is_refused_naming_the_file(tiny, tmp_path):
    folder = write_radiomapseer(load_bundle("tiny", root=tiny), tmp_path)
    (folder / "gain" / "tiny_1.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match="tiny_1.png: not a readable PNG"):
        read_radiomapseer(folder)
    res = CliRunner().invoke(uavdata, ["ingest", str(folder), "--out", str(tmp_path / "p")])  # one line, nothing written
    assert res.exit_code == 2 and "tiny_1.png: not a readable PNG" in res.output and not (tmp_path / "p" / "tiny").exists()
    folder = write_radiomapseer(load_bundle("tiny", root=tiny), tmp_path)  # replaced: it is one of these folders
    from PIL import Image

    Image.fromarray(np.zeros((3, 3), np.uint8)).save(folder / "gain" / "tiny_0.png")
    with pytest.raises(InputError, match="tiny_0.png: shape: 3 x 3 pixels"):
        read_radiomapseer(folder)
    (folder / "scale.json").write_text('{"format": "other"}')
    with pytest.raises(InputError, match="scale.json"):
        read_radiomapseer(folder)
    mine = tmp_path / "mine" / "tiny"
    mine.mkdir(parents=True)
    (mine / "notes.txt").write_text("x")
    with pytest.raises(InputError, match="refusing to replace"):
        write_radiomapseer(load_bundle("tiny", root=tiny), tmp_path / "mine")


def test_a_radiomapseer_folder_is_read_inside_itself_and_its_numbers_checked(tiny, tmp_path):
    """What a RadioMapSeer-style folder names is data: a city that is a path, a raster that is a link out, a palette or
    16-bit gain map (which would be read as indices or cut to a byte), numbers that are not finite or far out of
    range, settings out of range, a step that would decode SINR past 400 dB, a user off the grid: each refused naming
    the file and field, nothing outside the folder read."""
    from PIL import Image

    outside = tmp_path / "outside"
    outside.mkdir()

    def fresh() -> tuple:
        folder = write_radiomapseer(load_bundle("tiny", root=tiny), tmp_path / "f")
        return folder, json.loads((folder / "scale.json").read_text())

    def refused(folder, match: str) -> None:  # noqa: ANN001
        with pytest.raises(InputError, match=match):
            read_radiomapseer(folder)

    folder, scale = fresh()
    (folder / "scale.json").write_text(json.dumps(scale | {"city": "../../outside/x"}))
    refused(folder, r"scale.json: city: .* is not a safe name")
    folder, _ = fresh()
    gain = folder / "gain" / "tiny_0.png"
    Image.open(gain).save(outside / "g.png")
    gain.unlink()
    gain.symlink_to(outside / "g.png")
    refused(folder, "tiny_0.png: a link or a path that leads out of")
    for image, mode in ((Image.open(outside / "g.png").convert("P"), "P"), (Image.new("I;16", (24, 20)), "I;16")):
        folder, _ = fresh()
        image.save(folder / "gain" / "tiny_1.png")
        refused(folder, f"tiny_1.png: mode: PNG mode {mode}, expected L")
    for field, value in (("floor_db", float("nan")), ("spacing_m", 1e-300), ("spacing_m", float("inf")), ("altitude_m", -50.0)):
        folder, scale = fresh()
        where = "sinr" if field == "floor_db" else "grid" if field == "spacing_m" else "settings"
        scale[where][field] = value
        (folder / "scale.json").write_text(json.dumps(scale))
        refused(folder, f"scale.json: {field}: .* is not a finite number")
    for where, field, value, says in (("settings", "frequency_hz", -1.0, r"settings: frequency_hz -1.0: expected a number"),
                                      ("sinr", "step_db", 10.0, r"tiny_0.png: sinr: SINR up to .* dB .* over 400 dB")):  # fmt: skip
        folder, scale = fresh()
        scale[where][field] = value
        (folder / "scale.json").write_text(json.dumps(scale))
        refused(folder, says)
    folder, _ = fresh()
    users = (folder / "users.csv").read_text().splitlines()
    head, first = users[0].split(","), users[1].split(",")
    first[head.index("x_m")] = "1e9"
    (folder / "users.csv").write_text("\n".join([users[0], ",".join(first), *users[2:]]) + "\n")
    refused(folder, "users.csv:2: x_m: 1000000000.0 is not on the grid")


def test_a_radiomapseer_folder_with_an_export_beside_it_is_refused(tiny, tmp_path):
    """An InSite export dropped beside a scale.json would be neither read nor named: one error line, nothing written."""
    import shutil

    from tests.conftest import REPO

    folder = write_radiomapseer(load_bundle("tiny", root=tiny), tmp_path / "f")
    shutil.copy(next((REPO / "data" / "raw" / "tiny").glob("*.txrx")), folder)
    res = CliRunner().invoke(uavdata, ["ingest", str(folder), "--out", str(tmp_path / "p")])
    assert res.exit_code == 2 and "is a RadioMapSeer-style folder and also holds 1 file(s) of other formats" in res.output
    assert not (tmp_path / "p" / "tiny").exists()


def test_deepmimo_file_holds_the_bundles_maps_in_its_units(tiny, tmp_path):
    bundle = load_bundle("tiny", root=tiny)
    with np.load(write_deepmimo(bundle, tmp_path)) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(arrays.pop("meta").tobytes())
    u, m = bundle.num_users, bundle.blocked.size
    assert arrays["rx_power_dbm"].shape == (u, m) and arrays["tx_positions_m"].shape == (u, 3)
    sinr = bundle.sinr_db.reshape(u, -1)
    live = ~bundle.dead.reshape(u, -1)
    np.testing.assert_allclose(arrays["sinr_db"][live], sinr[live], atol=1e-5)
    assert np.isnan(arrays["sinr_db"][~live]).all()
    settings = meta["settings"]
    np.testing.assert_allclose(arrays["rx_power_dbm"][live], sinr[live] + settings["noise_dbm"], atol=1e-4)
    np.testing.assert_allclose(arrays["path_loss_db"][live], settings["tx_power_dbm"] - arrays["rx_power_dbm"][live], atol=1e-4)
    ix = 3  # the rx cells in row-major order, x fastest, at the altitude
    np.testing.assert_allclose(arrays["rx_positions_m"][ix], [bundle.x_m[ix], bundle.y_m[0], bundle.altitude_m])
    assert meta["units"]["rx_power_dbm"] == "dBm" and "x east, y north" in meta["frame"]


def test_export_command_and_training_on_an_exported_folder(tiny, tmp_path):
    out = tmp_path / "exports"
    res = CliRunner().invoke(uavdata, ["export", "tiny", "--root", str(tiny), "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert (out / "tiny" / "scale.json").is_file() and (out / "tiny.deepmimo.npz").is_file()
    from tests.test_learned import _constants

    constants = tmp_path / "predictor.json"
    constants.write_text(_constants().model_dump_json())
    res = CliRunner().invoke(uavrl, ["train-predictor", "--maps", str(out / "tiny"), "--constants", str(constants),
                                     "--out", str(tmp_path / "unet"), "--steps", "2", "--batch", "2", "--widths", "4,8",
                                     "--threads", "1", "--quiet", "--root", str(tiny)])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "trained on" in res.output
    mine = tmp_path / "mine"  # a folder of the user's that holds a model.json: refused before any training
    mine.mkdir()
    (mine / "model.json").write_text("{}")
    (mine / "thesis.tex").write_text("years of work")
    res = CliRunner().invoke(uavrl, ["train-predictor", "--maps", str(out / "tiny"), "--constants", str(constants),
                                     "--out", str(mine), "--steps", "2", "--batch", "2", "--widths", "4,8",
                                     "--threads", "1", "--quiet", "--root", str(tiny)])  # fmt: skip
    assert res.exit_code == 2 and "thesis.tex" in res.output and "trained on" not in res.output, res.output
    assert (mine / "thesis.tex").read_text() == "years of work"


def test_export_and_pack_never_replace_a_users_own_files(tiny, tmp_path):
    """`uavdata export` and `uavdata pack` replace what they wrote before, never a user's: a RadioMapSeer-style
    folder with the user's notes in it, a file of the user's named like the DeepMIMO export or a pack. Each is
    refused with one error line, the user's file as it was."""
    out = tmp_path / "exports"
    run = CliRunner().invoke
    assert run(uavdata, ["export", "tiny", "--root", str(tiny), "--out", str(out)]).exit_code == 0
    assert run(uavdata, ["export", "tiny", "--root", str(tiny), "--out", str(out)]).exit_code == 0  # its own: replaced
    res = run(uavdata, ["export", "tiny", "nosuch", "--root", str(tiny), "--out", str(tmp_path / "o2")])
    assert res.exit_code == 2 and "nosuch" in res.output and not (tmp_path / "o2").exists()  # refused before tiny
    (out / "tiny" / "notes.txt").write_text("mine")
    res = run(uavdata, ["export", "tiny", "--root", str(tiny), "--out", str(out), "--format", "radiomapseer"])
    assert res.exit_code == 2 and "notes.txt" in res.output and (out / "tiny" / "notes.txt").read_text() == "mine"
    (tmp_path / "o3").mkdir()
    (tmp_path / "o3" / "tiny").write_text("a file where the folder would go")
    res = run(uavdata, ["export", "tiny", "--root", str(tiny), "--out", str(tmp_path / "o3"), "--format", "radiomapseer"])
    assert res.exit_code == 2 and "exists and is not a RadioMapSeer-style folder: refusing" in res.output, res.output
    (out / "tiny.deepmimo.npz").write_bytes(b"my own arrays")
    res = run(uavdata, ["export", "tiny", "--root", str(tiny), "--out", str(out), "--format", "deepmimo"])
    assert res.exit_code == 2 and "is not a DeepMIMO-style export uavplace wrote" in res.output, res.output
    assert (out / "tiny.deepmimo.npz").read_bytes() == b"my own arrays"
    packs = tmp_path / "packs"
    packs.mkdir()
    (packs / "tiny.npz").write_bytes(b"PK my own zip")
    res = run(uavdata, ["pack", "tiny", "--root", str(tiny), "--out", str(packs)])
    assert res.exit_code == 2 and "is not a training-maps pack uavplace wrote" in res.output, res.output
    assert (packs / "tiny.npz").read_bytes() == b"PK my own zip"
    (packs / "tiny.npz").unlink()
    assert run(uavdata, ["pack", "tiny", "--root", str(tiny), "--out", str(packs)]).exit_code == 0
