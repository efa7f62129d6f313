"""The probe families of the fifth round (issue 89): the surfaces added since the fourth, a family each.

- ``rms``: a RadioMapSeer-style folder (``uavdata export``'s) ingested after an edit: its city a path out, a raster
  that is a link out, palette, 16-bit and RGB gain maps, a grid of 2000 x 2000 cells, a PNG header of 20000 x 20000
  pixels, numbers of ``scale.json`` and ``users.csv`` that are not finite or far out of range, an InSite export
  beside it.
- ``export``: ``uavdata export`` over a user's own folder ``OUT/<city>`` that holds a ``scale.json``, over a user's
  ``OUT/<city>.deepmimo.npz``, and of a city that does not exist after one that does (nothing written).
- ``pack``: ``uavdata pack`` over a user's own ``OUT/<city>.npz``, with a ``simulation.json`` that is a link out of
  the city's raw folder, and over a pack whose meta was edited (packed again, not kept).
- ``packs``: ``uavrl train-predictor --maps`` over packs that are links out, inflate to 2.5 GB, carry a meta of
  NaN floor, -1 Hz, a 10 dB step or no spacing, are encrypted or of an unknown compression, or are given twice.
- ``predictor``: ``train-predictor`` / ``calibrate-predictor --out`` a user's folder holding a ``model.json``, ``--out``
  a copy of the shipped predictor holding a user's file too (refused before any training), U-Nets of 4096 channels
  and of 100000.
- ``search``: ``uavrl report --search`` with infinities, a boolean for a number, a setting no searcher plays.
- ``workers``: ``--workers`` past the CPUs, ``--ray-address`` at a port that accepts and never answers, and at an
  HTTP server (report and sweep).
- ``views``: a script plays a policy that writes its view's public maps, or reads the env, the route or the user's
  point through its view, in each task: the write changes nothing the env reads (accepted, checked), the reads fail
  (refused).

Each is refused in one line within the probe's time, or accepted with a result its check passes; a data-loss probe
also checks, after a refusal, that the user's files are as they were.
"""

from __future__ import annotations

import json
import shutil
import socket
import sys
import threading
import zipfile
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, HTTPServer
from pathlib import Path

import numpy as np

from tests.probes import REPO, SWEEP, TWIN, Base, Probe, Result, inflating_npz, ingest_check, report_args
from tests.probes_round4 import _run

PREDICTOR = REPO / "data" / "agents" / "searcher" / "unet"
MINE = "a user's own words\n"


def _export(base: Base, w: Path, fmt: str = "radiomapseer") -> Path:
    """The tiny city exported into ``w/exp`` (the folder, or the file for deepmimo)."""
    _run(["uavdata", "export", "tiny", "--root", str(base.root), "--out", str(w / "exp"), "--format", fmt], w)
    return w / "exp" / "tiny"


def _kept(*names: str) -> Callable[[Path, list[Result]], str | None]:
    """A check: each of ``names`` (under the probe's folder) still holds ``MINE``."""

    def check(w: Path, results: list[Result]) -> str | None:
        for name in names:
            path = w / name
            if not path.is_file() or path.read_text() != MINE:
                return f"{name}, a user's own file, was replaced or removed"
        return None

    return check


# -- rms ----------------------------------------------------------------------------------------------------------------
def rms_probes(base: Base) -> list[Probe]:
    def edited(edit: Callable[[Path, Path], None]) -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            folder = _export(base, w)
            edit(folder, w)
            return ["uavdata", "ingest", str(folder), "--out", str(w / "p")]

        return make

    def scale(fn: Callable[[dict], None]) -> Callable[[Path, Path], None]:
        def edit(folder: Path, w: Path) -> None:
            doc = json.loads((folder / "scale.json").read_text())
            fn(doc)
            (folder / "scale.json").write_text(json.dumps(doc))

        return edit

    def setter(where: str, key: str, value: object) -> Callable[[dict], None]:
        def fn(doc: dict) -> None:
            (doc if where == "" else doc[where])[key] = value

        return fn

    def gain_image(mode: str, size: tuple[int, int] | None = None) -> Callable[[Path, Path], None]:
        def edit(folder: Path, w: Path) -> None:
            from PIL import Image

            gain = folder / "gain" / "tiny_0.png"
            with Image.open(gain) as im:
                image = im.convert(mode) if size is None else Image.new(mode, size)
            image.save(gain)

        return edit

    def link_out(folder: Path, w: Path) -> None:
        gain = folder / "gain" / "tiny_0.png"
        (w / "outside").mkdir()
        shutil.copy(gain, w / "outside" / "g.png")
        gain.unlink()
        gain.symlink_to(w / "outside" / "g.png")

    def huge_grid(folder: Path, w: Path) -> None:
        from PIL import Image

        scale(lambda d: d["grid"].update(num_x=2000, num_y=2000))(folder, w)
        for png in folder.rglob("*.png"):
            Image.new(Image.open(png).mode, (2000, 2000)).save(png)  # a few kB each: zeros compress

    def huge_header(folder: Path, w: Path) -> None:
        """A PNG whose header says 20000 x 20000 pixels (its rows a few kB of zeros)."""
        from PIL import Image

        Image.new("L", (20000, 20000)).save(folder / "gain" / "tiny_0.png")

    def user_value(column: str, value: str) -> Callable[[Path, Path], None]:
        def edit(folder: Path, w: Path) -> None:
            lines = (folder / "users.csv").read_text().splitlines()
            head, first = lines[0].split(","), lines[1].split(",")
            first[head.index(column)] = value
            (folder / "users.csv").write_text("\n".join([lines[0], ",".join(first), *lines[2:]]) + "\n")

        return edit

    def insite_beside(folder: Path, w: Path) -> None:
        shutil.copy(next((REPO / "data" / "raw" / "tiny").glob("*.txrx")), folder)

    def ingested(w: Path, results: list[Result]) -> str | None:
        return ingest_check(w / "p")

    probes = [Probe("rms", "control: an export ingested", edited(lambda f, w: None), ingested, control=True)]
    probes += [
        Probe("rms", "scale.json city: a path out", edited(scale(setter("", "city", "../../outside/x")))),
        Probe("rms", "a gain PNG that is a link out", edited(link_out)),
        Probe("rms", "a palette gain PNG", edited(gain_image("P"))),
        Probe("rms", "a 16-bit gain PNG", edited(gain_image("I;16", (24, 20)))),
        Probe("rms", "an RGB gain PNG", edited(gain_image("RGB"))),
        Probe("rms", "a grid of 2000 x 2000 cells", edited(huge_grid), timeout=120),
        Probe("rms", "a PNG header of 20000 x 20000 pixels", edited(huge_header), timeout=120),
        Probe("rms", "an InSite export beside it", edited(insite_beside)),
        Probe("rms", "users.csv: x_m 1e9", edited(user_value("x_m", "1e9"))),
        Probe("rms", "users.csv: y_m nan", edited(user_value("y_m", "nan"))),
    ]
    for where, key, value in (("sinr", "floor_db", float("nan")), ("grid", "spacing_m", 1e-300),
                              ("grid", "spacing_m", float("inf")), ("settings", "altitude_m", -50.0),
                              ("sinr", "step_db", 10.0), ("settings", "frequency_hz", -1.0)):  # fmt: skip
        probes.append(Probe("rms", f"scale.json {where}.{key} {value}", edited(scale(setter(where, key, value)))))
    return probes


# -- export -------------------------------------------------------------------------------------------------------------
def export_probes(base: Base) -> list[Probe]:
    def export(*cities: str, fmt: str = "radiomapseer") -> list[str]:
        return ["uavdata", "export", *cities, "--root", str(base.root), "--out", "out", "--format", fmt]

    def users_folder(w: Path) -> list[str]:
        (w / "out" / "tiny").mkdir(parents=True)
        (w / "out" / "tiny" / "scale.json").write_text(MINE)
        (w / "out" / "tiny" / "notes.txt").write_text(MINE)
        return export("tiny")

    def users_file(w: Path) -> list[str]:
        (w / "out").mkdir()
        (w / "out" / "tiny.deepmimo.npz").write_text(MINE)
        return export("tiny", fmt="deepmimo")

    def nothing(w: Path, results: list[Result]) -> str | None:
        return "tiny was written before nosuch was refused" if (w / "out" / "tiny").exists() else None

    def exported(w: Path, results: list[Result]) -> str | None:
        return None if (w / "out" / "tiny" / "scale.json").is_file() else "no scale.json written"

    return [
        Probe("export", "control: an export", lambda w: export("tiny"), exported, control=True),
        Probe(
            "export",
            "over a user's folder with a scale.json",
            users_folder,
            _kept("out/tiny/scale.json", "out/tiny/notes.txt"),
            always_check=True,
        ),
        Probe("export", "over a user's .deepmimo.npz", users_file, _kept("out/tiny.deepmimo.npz"), always_check=True),
        Probe("export", "a city, then one that does not exist", lambda w: export("tiny", "nosuch"), nothing, always_check=True),
    ]


# -- pack ---------------------------------------------------------------------------------------------------------------
def pack_probes(base: Base) -> list[Probe]:
    def pack(w: Path, *extra: str) -> list[str]:
        return ["uavdata", "pack", "tiny", "--root", str(base.root), "--out", str(w / "m"), *extra]

    def users_file(w: Path) -> list[str]:
        (w / "m").mkdir()
        (w / "m" / "tiny.npz").write_text(MINE)
        return pack(w)

    def linked_record(w: Path) -> list[str]:
        raw = w / "raw" / "tiny"
        raw.mkdir(parents=True)
        (w / "outside.json").write_text(json.dumps({"secret": "outside the city folder"}))
        (raw / "simulation.json").symlink_to(w / "outside.json")
        return pack(w, "--raw", str(w / "raw"))

    def not_read(w: Path, results: list[Result]) -> str | None:
        pack_file = w / "m" / "tiny.npz"
        if pack_file.is_file() and b"outside the city folder" in _meta_bytes(pack_file):
            return "the pack copied a simulation.json from outside the city folder"
        return None

    def edited_meta(w: Path) -> list[str]:
        _run(pack(w), w)
        _rewrite_meta(w / "m" / "tiny.npz", lambda meta: meta.update(simulation={"edited": True}))
        return pack(w)

    def packed_again(w: Path, results: list[Result]) -> str | None:
        if "packed already" in results[0].stdout:
            return "a pack whose meta was edited was kept as packed already"
        return None if b"edited" not in _meta_bytes(w / "m" / "tiny.npz") else "the edited meta is still there"

    return [
        Probe("pack", "control: a pack", lambda w: pack(w), control=True),
        Probe("pack", "over a user's own tiny.npz", users_file, _kept("m/tiny.npz"), always_check=True),
        Probe("pack", "simulation.json a link out of the city folder", linked_record, not_read, always_check=True),
        Probe("pack", "over a pack whose meta was edited", edited_meta, packed_again),
    ]


def _meta_bytes(path: Path) -> bytes:
    with np.load(path, allow_pickle=False) as z:
        return z["meta"].tobytes()


def _rewrite_meta(path: Path, fn: Callable[[dict], None]) -> None:
    """Edit a pack's meta, its arrays (and their sha256) kept."""
    with np.load(path, allow_pickle=False) as z:
        members = {k: z[k] for k in z.files}
    meta = json.loads(members["meta"].tobytes())
    fn(meta)
    members["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    np.savez(path, **members)


# -- packs --------------------------------------------------------------------------------------------------------------
def packs_probes(base: Base) -> list[Probe]:
    def train(w: Path, *maps: Path) -> list[str]:
        folders = [a for m in maps for a in ("--maps", str(m))]
        return ["uavrl", "train-predictor", *folders, "--root", str(base.root), "--steps", "2", "--batch", "2",
                "--widths", "4,8", "--threads", "1", "--out", str(w / "unet"), "--quiet"]  # fmt: skip

    def with_pack(edit: Callable[[Path, Path], None] | None = None, twice: bool = False) -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            _run(["uavdata", "pack", "tiny", "tiny-routes", "--root", str(base.root), "--out", str(w / "m")], w)
            if edit is not None:
                edit(w / "m" / "tiny.npz", w)
            return train(w, w / "m", *([w / "m"] if twice else []))

        return make

    def meta(fn: Callable[[dict], None]) -> Callable[[Path, Path], None]:
        return lambda path, w: _rewrite_meta(path, fn)

    def link_out(path: Path, w: Path) -> None:
        (w / "outside").mkdir()
        path.rename(w / "outside" / "tiny.npz")
        path.symlink_to(w / "outside" / "tiny.npz")

    def inflating(path: Path, w: Path) -> None:
        path.unlink()
        inflating_npz(path, "sinr.npy", np.uint8, int(2.5 * 2**30))

    def flag(bits: int, method: int | None = None) -> Callable[[Path, Path], None]:
        """Set a general-purpose flag (1: encrypted) or the compression method of every member's headers."""

        def edit(path: Path, w: Path) -> None:
            data = bytearray(path.read_bytes())
            with zipfile.ZipFile(path) as z:
                infos = z.infolist()
            central = data.find(b"PK\x01\x02")
            for info in infos:
                local = info.header_offset
                data[local + 6] |= bits
                if method is not None:
                    data[local + 8 : local + 10] = method.to_bytes(2, "little")
            while central != -1:
                data[central + 8] |= bits
                if method is not None:
                    data[central + 10 : central + 12] = method.to_bytes(2, "little")
                central = data.find(b"PK\x01\x02", central + 4)
            path.write_bytes(bytes(data))

        return edit

    def trained(w: Path, results: list[Result]) -> str | None:
        return None if (w / "unet" / "model.json").is_file() else "no model.json written"

    def once(w: Path, results: list[Result]) -> str | None:
        record = json.loads((w / "unet" / "model.json").read_text())
        fitted = record.get("fitted_on", [])
        return None if len(fitted) == len(set(fitted)) else f"a pack given twice is counted twice: {fitted}"

    def settings(key: str, value: object) -> Callable[[dict], None]:
        return lambda m: m["settings"].update({key: value})

    return [
        Probe("packs", "control: train on packs", with_pack(), trained, control=True, timeout=180),
        Probe("packs", "a pack that is a link out", with_pack(link_out)),
        Probe("packs", "a member inflating to 2.5 GB", with_pack(inflating), timeout=120),
        Probe("packs", "meta floor_db NaN", with_pack(meta(settings("floor_db", float("nan"))))),
        Probe("packs", "meta frequency -1 Hz", with_pack(meta(settings("frequency_hz", -1.0)))),
        Probe("packs", "meta step 10 dB", with_pack(meta(lambda m: m.update(step_db=10.0)))),
        Probe("packs", "meta without spacing_m", with_pack(meta(lambda m: m["settings"].pop("spacing_m")))),
        Probe("packs", "encrypted members", with_pack(flag(1))),
        Probe("packs", "an unknown compression method", with_pack(flag(0, 99))),
        Probe("packs", "one folder of packs given twice", with_pack(twice=True), once, timeout=180),
    ]


# -- predictor commands -------------------------------------------------------------------------------------------------
def predictor_probes(base: Base) -> list[Probe]:
    def train(out: str | Path, *extra: str) -> list[str]:
        return ["uavrl", "train-predictor", "--dataset", TWIN.name, "--root", str(base.root), "--steps", "2", "--batch", "2",
                "--widths", "4,8", "--threads", "1", "--out", str(out), "--quiet", *extra]  # fmt: skip

    def users_folder(command: Callable[[Path], list[str]]) -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            (w / "mine").mkdir()
            (w / "mine" / "model.json").write_text(MINE)
            (w / "mine" / "thesis.tex").write_text(MINE)
            return command(w)

        return make

    def calibrate(w: Path) -> list[str]:
        _run(["uavdata", "pack", "tiny", "--root", str(base.root), "--out", str(w / "m")], w)
        _run(train(w / "unet"), w)
        return ["uavrl", "calibrate-predictor", "--predictor", str(w / "unet"), "--maps", str(w / "m"), "--root",
                str(base.root), "--out", str(w / "mine")]  # fmt: skip

    def quick(w: Path, results: list[Result]) -> str | None:
        return f"refused after {results[0].seconds:.0f} s: after the training" if results[0].seconds > 30 else None

    def shipped_and_mine(w: Path) -> list[str]:
        """A copy of the shipped predictor's folder with a user's file beside it: refused before a million steps."""
        shutil.copytree(PREDICTOR, w / "mine")
        (w / "mine" / "thesis.tex").write_text(MINE)
        return train(w / "mine", "--steps", "1000000")

    return [
        Probe("predictor", "control: train-predictor", lambda w: train(w / "unet"), control=True, timeout=120),
        Probe(
            "predictor",
            "train-predictor --out a folder with model.json",
            users_folder(lambda w: train(w / "mine")),
            _kept("mine/model.json", "mine/thesis.tex"),
            always_check=True,
            timeout=120,
        ),
        Probe(
            "predictor",
            "calibrate-predictor --out a folder with model.json",
            users_folder(calibrate),
            _kept("mine/model.json", "mine/thesis.tex"),
            always_check=True,
            timeout=240,
        ),
        Probe(
            "predictor",
            "--out a shipped predictor's copy with a user's file, a million steps",
            shipped_and_mine,
            lambda w, r: quick(w, r) or _kept("mine/thesis.tex")(w, r),
            always_check=True,
        ),
        Probe("predictor", "--widths 4096 x 5", lambda w: train(w / "u", "--widths", "4096,4096,4096,4096,4096")),
        Probe("predictor", "--widths 100000", lambda w: train(w / "u", "--widths", "100000")),
    ]


# -- search -------------------------------------------------------------------------------------------------------------
def search_probes(base: Base) -> list[Probe]:
    def report(*pairs: str, predictor: str = str(PREDICTOR)) -> Callable[[Path], list[str]]:
        search = [a for p in pairs for a in ("--search", p)]  # the last --predictor given is the one taken
        return lambda w: ["uavrl", *report_args(base.root, base.run, w / "rep", *search, "--predictor", predictor)]

    probes = [Probe("search", "control: a report with the searcher", report("stride=2"), control=True, timeout=180)]
    for pair in ("reach_cells=Infinity", "min_sigma_db=1e999", "stride=true", "info_weight=nan", "stride=1e300"):
        probes.append(Probe("search", f"--search {pair}", report(pair)))
    probes.append(Probe("search", "--search with --predictor none", report("stride=4", predictor="none")))
    return probes


# -- workers ------------------------------------------------------------------------------------------------------------
class _Silent(threading.Thread):
    """A TCP listener that accepts and never answers (the probe pass's own, on a free local port)."""

    def __init__(self) -> None:
        super().__init__(daemon=True)
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.held: list[socket.socket] = []

    def run(self) -> None:
        while True:
            conn, _ = self.sock.accept()
            self.held.append(conn)


class _Hello(BaseHTTPRequestHandler):
    def do_GET(self) -> None:  # noqa: N802 - the http.server name
        self.send_response(200)
        self.end_headers()
        self.wfile.write(b"hello")

    def log_message(self, *args: object) -> None:
        pass


def _http_port() -> int:
    server = HTTPServer(("127.0.0.1", 0), _Hello)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server.server_address[1]


def workers_probes(base: Base) -> list[Probe]:
    def report(*extra: str) -> Callable[[Path], list[str]]:
        return lambda w: ["uavrl", *report_args(base.root, base.run, w / "rep", *extra)]

    def at(kind: str, command: str) -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            if kind == "silent":
                listener = _Silent()
                listener.start()
                port = listener.port
            else:
                port = _http_port()
            address = f"127.0.0.1:{port}"
            if command == "report":
                return report("--ray-address", address)(w)
            (w / "s.toml").write_text(SWEEP)
            return ["uavrl", "sweep", str(w / "s.toml"), "--ray-address", address, "--out", str(w / "O"), "--root",
                    str(base.root)]  # fmt: skip

        return make

    return [
        Probe("workers", "control: a report on 2 workers", report("--workers", "2"), control=True, timeout=180),
        Probe("workers", "report --workers 64", report("--workers", "64")),
        Probe("workers", "report --ray-address: a listener that never answers", at("silent", "report"), timeout=90),
        Probe("workers", "report --ray-address: an HTTP server", at("http", "report"), timeout=90),
        Probe("workers", "sweep --ray-address: a listener that never answers", at("silent", "sweep"), timeout=90),
    ]


# -- views --------------------------------------------------------------------------------------------------------------
VIEWS = """
import sys

import numpy as np

from uavplace.dataset.bundle import load_bundle

root, task, act = sys.argv[1], sys.argv[2], sys.argv[3]


class Policy:
    name = "probe"

    def reset(self, rows, num_envs, *uavs):
        pass

    def act(self, obs, mask, view):
        if act == "write":
            for a in (view.public.blocked, view.public.height):
                a.flags.writeable = True
            view.public.blocked[...] = False
            return np.zeros(len(mask), np.int64)
        getattr(view, act)  # what a view does not hold: the env's own
        return np.zeros(len(mask), np.int64)


try:
    if task == "placement":
        from uavplace.rl.tasks.placement.config import EnvConfig
        from uavplace.rl.tasks.placement.rollout import run_episodes
        from uavplace.rl.world.maps import MapSet

        maps = MapSet([load_bundle("tiny", root=root)], EnvConfig(t_max=30, rotate=False))
        blocked = maps.blocked.copy()
        episodes = maps.episode_list(4, 0)
        table = run_episodes(maps, Policy(), episodes, record=np.arange(4))
        for k in range(4):
            path = table.attrs["paths"][k] + maps.pad
            assert not maps.blocked[maps.view_map[int(episodes[k, 0])], path[:, 0], path[:, 1]].any(), "entered a building"
    else:
        from uavplace.rl.tasks.tracking import RouteSet, TrackingConfig, run_tracking

        routes = RouteSet([load_bundle("tiny-routes", root=root)], TrackingConfig(horizon=20))
        blocked = routes.maps.blocked.copy()
        episodes = routes.sample_episodes(4, np.random.default_rng(0))
        played = run_tracking(routes, Policy(), episodes, record=True)
        canvas = routes.canvas[episodes[:, 0].astype(int)]
        assert not routes.maps.blocked[canvas[:, None], played.path[:, :, 0], played.path[:, :, 1]].any(), "entered a building"
        maps = routes.maps
    assert np.array_equal(maps.blocked, blocked), "the env's blocked cells changed"
except AttributeError as err:
    print(f"error: the view holds no {act}: {err}", file=sys.stderr)
    sys.exit(2)
except AssertionError as err:
    print(f"the write reached the env: {err}")
    sys.exit(0)
print("ok")
"""


def views_probes(base: Base) -> list[Probe]:
    def script(task: str, act: str) -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            (w / "views.py").write_text(VIEWS)
            return ["python", str(w / "views.py"), str(base.root), task, act]

        return make

    def intact(w: Path, results: list[Result]) -> str | None:
        return None if results[0].stdout.strip().endswith("ok") else results[0].stdout.strip()[-200:]

    probes = []
    for task in ("placement", "tracking"):
        probes.append(Probe("views", f"{task}: write the public maps", script(task, "write"), intact))
        reads = ("maps", "env", "sinr_here") if task == "placement" else ("routes", "point", "route", "sinr_here")
        probes += [Probe("views", f"{task}: read {name} through the view", script(task, name)) for name in reads]
    return probes


FAMILIES = {
    "rms": rms_probes,
    "export": export_probes,
    "pack": pack_probes,
    "packs": packs_probes,
    "predictor": predictor_probes,
    "search": search_probes,
    "workers": workers_probes,
    "views": views_probes,
}

if __name__ == "__main__":
    sys.exit("run these with python -m tests.probes --only " + ",".join(FAMILIES))
