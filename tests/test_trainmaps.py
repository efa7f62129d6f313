"""Training-maps packs (dataset/trainmaps.py, `uavdata pack`): the maps of a bundle round-trip within the quantisation,
a damaged or foreign pack is refused naming the file and the field, and `uavrl train-predictor --maps` trains on them
and refuses a validation city it trains on."""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest
from click.testing import CliRunner

from uavplace.cli import uavdata, uavrl
from uavplace.dataset.bundle import load_bundle
from uavplace.dataset.trainmaps import STEP_DB, TrainingMaps, dequantise, pack_bytes, quantise, read_pack, write_pack
from uavplace.infra import limits as lim
from uavplace.schemas import InputError


def test_pack_round_trips_a_bundle_within_half_a_step(tiny, tmp_path):
    bundle = load_bundle("tiny", root=tiny)
    path = tmp_path / "tiny.npz"
    meta = write_pack(path, TrainingMaps.of_bundle(bundle), {"spec": {"seed": 3}})
    maps = read_pack(path)
    assert (maps.city, maps.version, meta.num_users, meta.simulation) == (
        "tiny",
        bundle.version,
        bundle.num_users,
        {"spec": {"seed": 3}},
    )
    np.testing.assert_array_equal(maps.dead, bundle.dead)
    np.testing.assert_array_equal(maps.blocked, bundle.blocked)
    np.testing.assert_array_equal(maps.provenance, bundle.provenance)
    np.testing.assert_allclose(maps.height_rel_m, bundle.height_rel_m, atol=0.05 + 1e-6)
    live = ~bundle.dead
    assert np.abs(maps.sinr_db - bundle.sinr_db)[live].max() <= STEP_DB / 2 + 1e-4
    assert (maps.sinr_db[bundle.dead] == bundle.sinr_floor_db).all()
    table = bundle.users.set_index("user")
    np.testing.assert_array_equal(maps.users, table.loc[bundle.user_indices(), ["iy", "ix"]].to_numpy())
    assert maps.settings["floor_db"] == bundle.sinr_floor_db


def test_quantise_marks_dead_cells_and_counts_clipped_ones():
    sinr = np.array([-40.0, -39.74, 10.26, 200.0], np.float32)
    dead = np.array([True, False, False, False])
    q, clipped = quantise(sinr, dead, floor_db=-40.0)
    assert q.tolist() == [0, 2, 102, 255] and clipped == 1
    back, back_dead = dequantise(q, -40.0, STEP_DB)
    assert back_dead.tolist() == [True, False, False, False]
    np.testing.assert_allclose(back[1:3], [-39.5, 10.5])


def _rewritten(data: bytes, name: str, array: np.ndarray) -> bytes:
    """``data`` (a pack) with member ``name`` replaced by ``array``."""
    out = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(data)) as src, zipfile.ZipFile(out, "w") as dst:
        for info in src.infolist():
            if info.filename == f"{name}.npy":
                with dst.open(info.filename, "w") as f:
                    np.lib.format.write_array(f, array)
            else:
                dst.writestr(info, src.read(info))
    return out.getvalue()


def test_damaged_or_foreign_packs_are_refused_naming_the_field(tiny, tmp_path, monkeypatch):
    bundle = load_bundle("tiny", root=tiny)
    data, _ = pack_bytes(TrainingMaps.of_bundle(bundle))
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        sinr = np.load(io.BytesIO(z.read("sinr.npy")))
    altered = sinr.copy()
    altered[0, 0, 0] ^= 1
    cases = {
        "sinr": _rewritten(data, "sinr", altered),  # one value changed: its sha256 differs
        "users": _rewritten(data, "users", np.zeros((1, 2), np.int16)),  # a shape the meta does not say
        "meta": _rewritten(data, "meta", np.frombuffer(b'{"format": "other"}', np.uint8)),
    }
    for field, bad in cases.items():
        path = tmp_path / f"{field}.npz"
        path.write_bytes(bad)
        with pytest.raises(InputError) as err:
            read_pack(path)
        assert err.value.field == field and str(path) in str(err.value)
    import json

    with zipfile.ZipFile(io.BytesIO(data)) as z:
        meta = json.loads(np.load(io.BytesIO(z.read("meta.npy"))).tobytes())
    settings = meta["settings"]
    for change, said in (
        ({"settings": settings | {"floor_db": float("nan")}}, "floor_db nan: expected a number"),
        ({"settings": settings | {"frequency_hz": -1.0}}, "frequency_hz -1.0: expected a number"),
        ({"settings": {k: v for k, v in settings.items() if k != "spacing_m"}}, "spacing_m None: expected a number"),
        ({"step_db": 10.0}, "10 dB: this format's step is 0.5 dB"),
    ):  # settings a pack's maps are read by: refused, never read as good
        path = tmp_path / "settings.npz"
        path.write_bytes(_rewritten(data, "meta", np.frombuffer(json.dumps(meta | change).encode(), np.uint8)))
        with pytest.raises(InputError, match=said) as err:
            read_pack(path)
        assert err.value.field == "meta"
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="unreadable"):
        read_pack(tmp_path / "cut.npz")
    header = io.BytesIO()  # an array header that claims a terabyte, over a few bytes of data
    np.lib.format.write_array_header_1_0(header, {"descr": "|u1", "fortran_order": False, "shape": (10**12,)})
    out = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(data)) as src, zipfile.ZipFile(out, "w") as dst:
        for info in src.infolist():
            dst.writestr(info.filename, header.getvalue() + b"\0" * 8 if info.filename == "sinr.npy" else src.read(info))
    (tmp_path / "huge.npz").write_bytes(out.getvalue())
    with pytest.raises(InputError, match="unreadable"):
        read_pack(tmp_path / "huge.npz")
    for name, (local, central, value) in {"encrypted": (6, 8, 1), "method": (8, 10, 99)}.items():
        flipped = bytearray(data)  # the encrypted flag set, or a compression method zipfile lacks, on every member
        at = 0
        while (at := flipped.find(b"PK\x03\x04", at)) >= 0:
            flipped[at + local] |= value
            at += 4
        at = 0
        while (at := flipped.find(b"PK\x01\x02", at)) >= 0:
            flipped[at + central] |= value
            at += 4
        (tmp_path / f"{name}.npz").write_bytes(bytes(flipped))
        with pytest.raises(InputError, match="unreadable"):
            read_pack(tmp_path / f"{name}.npz")
    (tmp_path / "whole.npz").write_bytes(data)
    monkeypatch.setattr(lim, "_current", None)
    monkeypatch.setenv(lim.ENV, "map_bytes=1000")  # a pack that inflates past the limit is refused before it is read
    with pytest.raises(InputError, match="map_bytes"):
        read_pack(tmp_path / "whole.npz")
    monkeypatch.setattr(lim, "_current", None)


def test_pack_cli_and_train_predictor_on_packs(tiny, tmp_path):
    out = tmp_path / "packs"
    result = CliRunner().invoke(uavdata, ["pack", "tiny", "--root", str(tiny), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert (out / "tiny.npz").is_file() and "kB a user" in result.output
    bundle, packed = load_bundle("tiny", root=tiny), read_pack(out / "tiny.npz")  # what it wrote, not only its name
    source = TrainingMaps.of_bundle(bundle)
    assert packed.version == bundle.version and np.array_equal(packed.users, source.users)
    np.testing.assert_array_equal(packed.dead, source.dead)
    assert np.abs(packed.sinr_db - source.sinr_db)[~source.dead].max() <= STEP_DB / 2 + 1e-6
    again = CliRunner().invoke(uavdata, ["pack", "tiny", "--root", str(tiny), "--out", str(out)])
    assert again.exit_code == 0 and "packed already" in again.output
    whole = (out / "tiny.npz").read_bytes()
    with np.load(out / "tiny.npz", allow_pickle=False) as z:  # its meta edited, its arrays and their sha256 kept
        members = {k: z[k] for k in z.files}
    meta = json.loads(members["meta"].tobytes())
    meta["simulation"] = {"edited": True}
    members["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    np.savez(out / "tiny.npz", **members)
    read_pack(out / "tiny.npz")  # still a readable pack: only packing it again can tell
    third = CliRunner().invoke(uavdata, ["pack", "tiny", "--root", str(tiny), "--out", str(out)])
    assert third.exit_code == 0 and "packed already" not in third.output and (out / "tiny.npz").read_bytes() == whole
    constants = tmp_path / "predictor.json"
    from tests.test_learned import _constants

    constants.write_text(_constants().model_dump_json())
    common = ["--constants", str(constants), "--steps", "2", "--batch", "2", "--threads", "1", "--widths", "4,8",
              "--quiet", "--root", str(tiny)]  # fmt: skip
    trained = CliRunner().invoke(uavrl, ["train-predictor", "--maps", str(out), "--out", str(tmp_path / "unet"), *common])
    assert trained.exit_code == 0, trained.output
    assert f"trained on {load_bundle('tiny', root=tiny).num_users} users of 1 cities" in trained.output
    overlap = CliRunner().invoke(
        uavrl, ["train-predictor", "--maps", str(out), "--val-dataset", "tiny", "--out", str(tmp_path / "u2"), *common]
    )
    assert overlap.exit_code != 0 and "also a training city" in overlap.output and not (tmp_path / "u2").exists()
    nothing = CliRunner().invoke(uavrl, ["train-predictor", "--out", str(tmp_path / "u3"), *common])
    assert nothing.exit_code != 0 and "--maps" in nothing.output
    # --packs selects among the packs by whole name: "tiny" reads the pack, "tin" none (refused, nothing written)
    picked = CliRunner().invoke(uavrl, ["train-predictor", "--maps", str(out), "--packs", "tiny", "--out", str(tmp_path / "u4"),
                                        *common])  # fmt: skip
    assert picked.exit_code == 0 and "users of 1 cities" in picked.output, picked.output
    for extra in (["--maps", str(out), "--packs", "tin"], ["--dataset", "tiny", "--packs", "tiny"]):
        none = CliRunner().invoke(uavrl, ["train-predictor", *extra, "--out", str(tmp_path / "u5"), *common])
        assert none.exit_code != 0 and "--packs" in none.output and not (tmp_path / "u5").exists(), none.output


def test_shipped_training_maps_are_valid_small_and_of_training_cities_only():
    """data/trainmaps (experiments/training_maps.sh): every pack reads and checks, the folder is within its 40 MB
    budget, and no pack is of a validation or test city (nor of any city with a declared role): each is of the
    training-map corpora, tm-* (the mixed styles) or tt-* (tiered), or the real-layout training crops of data/geometry/
    (delfshaven-0*, denhaag-0*; docs/raytraced.md)."""
    from tests.conftest import REPO
    from uavplace.dataset.catalog import ROLES_FILE, read_roles
    from uavplace.dataset.trainmaps import list_packs

    folder = REPO / "data" / "trainmaps"
    packs = list_packs(folder)
    size = sum(p.stat().st_size for p in folder.iterdir() if p.is_file())
    assert size <= 40e6, f"data/trainmaps holds {size / 1e6:.1f} MB, over its 40 MB budget"
    roles = read_roles(REPO / "data" / "raw" / ROLES_FILE)
    declared = {*roles.train, *roles.val, *roles.test, *roles.crop}
    for path in packs:
        maps = read_pack(path)
        corpora = ("tm-", "tt-", "delfshaven-0", "denhaag-0")
        assert path.stem == maps.city and maps.city not in declared and maps.city.startswith(corpora)
        assert maps.provenance.size and maps.users.shape[0] >= 1


def test_packs_and_records_are_read_from_their_folders_only(tiny, tmp_path):
    """A pack in --maps that is a link out of its folder is refused, not trained on; a city's simulation.json that
    is a link out of the city folder is refused, not copied into the pack; a folder given twice counts its packs once."""
    from uavplace.dataset.trainmaps import select_packs, simulation_record

    packs = tmp_path / "packs"
    packs.mkdir()
    write_pack(packs / "tiny.npz", TrainingMaps.of_bundle(load_bundle("tiny", root=tiny)))
    assert select_packs([packs, packs]) == [packs / "tiny.npz"]
    from uavplace.rl.predictor.learned import training_maps

    assert len(training_maps([], [], (packs, packs, tmp_path / "." / "packs"))) == 1  # what train-predictor reads
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (packs / "tiny.npz").rename(elsewhere / "tiny.npz")
    (packs / "tiny.npz").symlink_to(elsewhere / "tiny.npz")
    with pytest.raises(InputError, match="tiny.npz: a link or a path that leads out of"):
        select_packs([packs])
    raw = tmp_path / "raw" / "tiny"
    raw.mkdir(parents=True)
    (elsewhere / "simulation.json").write_text('{"spec": {"secret": 1}}')
    (raw / "simulation.json").symlink_to(elsewhere / "simulation.json")
    with pytest.raises(InputError, match="simulation.json: a link or a path that leads out of"):
        simulation_record(raw)
    res = CliRunner().invoke(
        uavdata, ["pack", "tiny", "--root", str(tiny), "--raw", str(tmp_path / "raw"), "--out", str(tmp_path / "o")]
    )
    assert res.exit_code == 2 and "leads out of" in res.output and not (tmp_path / "o" / "tiny.npz").exists()
    for text, said in (("{not json", "not JSON"), ("[1, 2]", "not a JSON object")):  # `list --table` reads it too
        (raw / "simulation.json").unlink()
        (raw / "simulation.json").write_text(text)
        res = CliRunner().invoke(uavdata, ["list", "--table", "--root", str(tiny), "--raw", str(tmp_path / "raw")])
        assert res.exit_code == 2 and f"simulation.json: {said}: a simulation record" in res.output, res.output
