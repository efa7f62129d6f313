"""The probe families of the fourth round (issue 66): one a surface added since the third.

- ``predcache``: the searcher's predicted-maps cache (``ROOT/.predictions``) damaged between two reports of the same
  episodes: altered with its sha256 kept, made NaN, out of range, truncated, random, another canvas's, a link out of
  the data root, a FIFO, a folder, sparse gigabytes, a zip bomb. Every one must give the clean report's episodes to
  the bit (predicted again), a link must stay a link to its untouched target.
- ``sidefile``: the provenance side file beside a simulated export: another simulation's, a gzip of newlines, a long
  line, a truncated gzip, a code that is none, rows that overlap, a FIFO, sparse gigabytes.
- ``roles``: the cities' roles file of ``uavdata build --roles``: 1.3 M names (the duplicate check must be linear),
  a name twice, a city of two roles, a FIFO, sparse gigabytes, not TOML.
- ``zoo``: the PettingZoo env (``uavplace.rl.tasks.fleet.zoo``; and the Gymnasium placement env's overrides) driven by a script:
  actions outside the space, steps before
  ``reset`` and after the end, overrides out of range or unknown. A refusal is a ``ValueError`` or ``InputError``
  (the script prints it as one ``error:`` line, exit 2); anything else is a traceback, an internal error.
- ``weights``: every weights file a command reads (a run's ``best.pt`` and ``networks.pt``, ``--set init``'s,
  an ensemble member's, the learned predictor's ``weights.pt`` and ``model.json``) as a FIFO, sparse gigabytes or a
  pickle payload (which must not run); the shipped agents found from another working folder.
- ``limits``: work bounded before it starts: a simulated grid of 25 M cells, 1000 users at 0.5 m, 100,000
  footprints in a GeoJSON, a ``.city`` or a Mitsuba scene, sparse 2 GB text exports, a million 50-step episodes,
  ``train-predictor --batch 1024``, a trace-cache entry that inflates to 2 GB, a tracking report whose P_T no route
  meets, a validation city that is a training city.

Each is refused in one line within the probe's time, or accepted with a result its check passes.
"""

from __future__ import annotations

import gzip
import json
import os
import shutil
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from tests.conftest import sparse_file
from tests.probes import (
    REPO,
    TINY,
    Base,
    Probe,
    Result,
    _ingest,
    _node,
    finish,
    inflating_npz,
    ingest_check,
    report_args,
    report_check,
    run_check,
    start,
    tracking_args,
    train_args,
)

PREDICTOR = REPO / "data" / "agents" / "searcher" / "unet"
#: A sparse file's size: past every text and record limit, no disk taken.
SPARSE = 2 * 2**30


def _sparse(path: Path) -> Path:
    return sparse_file(path, SPARSE)


def _replace_by_fifo(path: Path) -> Path:
    path.unlink()
    return _node(path, "fifo")


def _run(args: list[str], cwd: Path, timeout: float = 300) -> None:
    """A setup command that must succeed."""
    r = finish(start(args, cwd), time.monotonic(), timeout)
    if r.rc != 0:
        raise RuntimeError(f"{' '.join(args[:3])}: {r.stderr[-500:]}")


# -- predcache ----------------------------------------------------------------------------------------------------------
def _episodes(rep: Path) -> pd.DataFrame:
    return pd.concat([pd.read_parquet(p) for p in sorted(rep.rglob("episodes.parquet"))], ignore_index=True)


def predcache_probes(base: Base) -> list[Probe]:
    """A report with the searcher (the shipped predictor) caches its predicted maps; every entry is then damaged and
    the same report played again: its episodes must be the clean report's, to the bit."""

    def report(w: Path, root: Path) -> list[str]:
        return ["uavrl", *report_args(root, base.run, w / "rep", "--predictor", str(PREDICTOR))]

    def damaged(edit: Callable[[Path, Path], None]) -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            root = base.copy_root(w)
            _run(report(w, root), w)
            (w / "rep").rename(w / "clean")
            entries = sorted((root / ".predictions").glob("*.npz"))
            if not entries:
                raise RuntimeError("the clean report cached no predicted maps")
            for entry in entries:
                edit(entry, w)
            return report(w, root)

        return make

    def same_episodes(w: Path, results: list[Result]) -> str | None:
        clean, again = _episodes(w / "clean"), _episodes(w / "rep")
        if not clean.equals(again):
            return "the report's episodes differ from the clean report's: a damaged entry was used"
        outside = w / "outside"
        if outside.is_dir():
            for target in outside.iterdir():
                if target.read_bytes() != (w / "kept" / target.name).read_bytes():
                    return f"the link's target {target.name} outside the data root was rewritten"
            links = [p for p in (w / "root" / ".predictions").iterdir() if p.is_symlink()]
            if len(links) != len(list(outside.iterdir())):
                return "a link in the cache was replaced or removed"
        return None

    def arrays(entry: Path) -> dict[str, np.ndarray]:
        with np.load(entry, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}

    def rewrite(fn: Callable[[dict], None], meta: str) -> Callable[[Path, Path], None]:
        """Edit the arrays; ``meta``: ``kept`` (the sha256 of the original arrays) or ``made`` (recomputed, so that
        only the range and finiteness checks stand between the entry and the searcher)."""

        def edit(entry: Path, w: Path) -> None:
            a = arrays(entry)
            fn(a)
            a["mu"], a["p_dead"] = a["mu"].astype(np.float16), a["p_dead"].astype(np.float16)
            if meta == "made":
                from uavplace.rl.belief.cache import _entry_meta

                key = bytes(a["meta"]).decode().split(":")[0]
                a["meta"] = np.frombuffer(_entry_meta(key, a["mu"], a["p_dead"]), np.uint8)
            np.savez(entry.with_name("x.npz"), **a)
            entry.with_name("x.npz").replace(entry)

        return edit

    def plus_30(a: dict) -> None:
        a["mu"] = a["mu"] + 30

    def nan(a: dict) -> None:
        a["mu"] = np.full_like(a["mu"], np.nan)

    def all_dead(a: dict) -> None:
        a["p_dead"] = np.ones_like(a["p_dead"])

    def link_out(entry: Path, w: Path) -> None:
        """The entry a link to an altered copy outside the data root."""
        (w / "outside").mkdir(exist_ok=True)
        (w / "kept").mkdir(exist_ok=True)
        target = w / "outside" / entry.name
        shutil.copy(entry, target)
        rewrite(plus_30, "kept")(target, w)
        shutil.copy(target, w / "kept" / entry.name)
        entry.unlink()
        entry.symlink_to(target)

    def swapped(entry: Path, w: Path) -> None:
        """Another canvas's entry (a valid entry of another key) under this one's name."""
        others = sorted(p for p in entry.parent.glob("*.npz") if p != entry)
        if others:
            shutil.copy(others[0], entry.with_name("x.npz"))
            entry.with_name("x.npz").replace(entry)
        else:
            rewrite(plus_30, "kept")(entry, w)

    def bomb(entry: Path, w: Path) -> None:
        """A member that inflates to 2 GB of zeros (a few MB on disk)."""
        entry.unlink()
        inflating_npz(entry, "mu.npy", np.float16, SPARSE)

    edits: dict[str, Callable[[Path, Path], None]] = {
        "every SINR +30 dB, its sha256 kept": rewrite(plus_30, "kept"),
        "every dead probability 1, its sha256 kept": rewrite(all_dead, "kept"),
        "NaN SINR, its sha256 made anew": rewrite(nan, "made"),
        "SINR 1000 dB, its sha256 made anew": rewrite(lambda a: a.update(mu=np.full_like(a["mu"], 1000)), "made"),
        "dead probability 2, its sha256 made anew": rewrite(lambda a: a.update(p_dead=a["p_dead"] * 0 + 2), "made"),
        "a link to an altered copy outside the data root": link_out,
        "another canvas's entry": swapped,
        "truncated": lambda p, w: p.write_bytes(p.read_bytes()[: p.stat().st_size // 2]),
        "random bytes": lambda p, w: p.write_bytes(os.urandom(p.stat().st_size)),
        "empty": lambda p, w: p.write_bytes(b""),
        "a FIFO": lambda p, w: _replace_by_fifo(p),
        "a folder": lambda p, w: (p.unlink(), p.mkdir()),
        "sparse 2 GB": lambda p, w: _sparse(p),
        "a member inflating to 2 GB": bomb,
    }
    probes = [
        Probe(
            "predcache",
            "control: the report played again on its cache",
            damaged(lambda p, w: None),
            same_episodes,
            timeout=300,
            control=True,
        )
    ]
    probes += [Probe("predcache", f"entry {name}", damaged(edit), same_episodes, timeout=300) for name, edit in edits.items()]
    return probes


def simulation(out: Path, seed: int, *extra: str) -> list[str]:
    """A small simulated city ``c`` (the tiny procedural city, 2 users, 1e5 rays: seconds) into ``out``."""
    small = "procedural:tiny --name c --users 2 --samples 1e5".split()
    return ["uavdata", "simulate", *small, "--seed", str(seed), "--out", str(out), "--quiet", *extra]


# -- sidefile -----------------------------------------------------------------------------------------------------------
def _simulated(base: Base, seed: int) -> Path:
    """A small simulated city with its provenance side file (made once per seed, kept beside the base)."""
    folder = base.folder / f"sim-{seed}"
    if not (folder / "ready").is_file():
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        args = simulation(folder / "raw", seed)
        _run(args, folder, 600)
        (folder / "ready").write_text("ok\n")
    return folder / "raw" / "c"


def sidefile_probes(base: Base) -> list[Probe]:
    def ingest(edit: Callable[[Path, Path], None]) -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            city = shutil.copytree(_simulated(base, 1), w / "c")
            edit(city / "c.provenance.csv.gz", w)
            return ["uavdata", "ingest", str(city), "--out", str(w / "root"), "--quiet"]

        return make

    def lines(fn: Callable[[list[str]], list[str]]) -> Callable[[Path, Path], None]:
        def edit(path: Path, w: Path) -> None:
            text = gzip.decompress(path.read_bytes()).decode().splitlines()
            path.write_bytes(gzip.compress(("\n".join(fn(text)) + "\n").encode()))

        return edit

    def other(path: Path, w: Path) -> None:
        shutil.copy(_simulated(base, 2) / "c.provenance.csv.gz", path)

    def header_row(text: list[str]) -> int:
        return next(i for i, line in enumerate(text) if not line.startswith("#"))

    def code(text: list[str]) -> list[str]:
        i = header_row(text) + 1
        return [*text[:i], ",".join([*text[i].split(",")[:-1], "99"]), *text[i + 1 :]]

    def overlap(text: list[str]) -> list[str]:
        i = header_row(text) + 1
        return [*text[: i + 1], text[i], *text[i + 1 :]]

    def newlines(path: Path, w: Path) -> None:
        path.write_bytes(gzip.compress(b"\n" * (1 << 30), 9))

    def accepted_other(w: Path, results: list[Result]) -> str | None:
        return "another simulation's side file was accepted with this export"

    probes = [
        Probe(
            "sidefile",
            "control: a simulated city's side file",
            ingest(lambda p, w: None),
            lambda w, r: ingest_check(w / "root"),
            timeout=120,
            control=True,
        ),
        Probe("sidefile", "another simulation's side file", ingest(other), accepted_other, timeout=120),
    ]
    edits: dict[str, Callable[[Path, Path], None]] = {
        "a gzip of a GB of newlines": newlines,
        "a line of 1 MB": lines(lambda t: [*t[:1], "#" + "x" * (1 << 20), *t[1:]]),
        "a code that is none": lines(code),
        "a row twice (overlap)": lines(overlap),
        "the header only": lines(lambda t: t[: header_row(t) + 1]),
        "truncated": lambda p, w: p.write_bytes(p.read_bytes()[: p.stat().st_size // 2]),
        "random bytes": lambda p, w: p.write_bytes(os.urandom(4096)),
        "a FIFO": lambda p, w: _replace_by_fifo(p),
        "sparse 2 GB": lambda p, w: _sparse(p),
    }
    probes += [
        Probe("sidefile", name, ingest(edit), lambda w, r: ingest_check(w / "root"), timeout=120) for name, edit in edits.items()
    ]
    return probes


# -- roles --------------------------------------------------------------------------------------------------------------
def roles_probes(base: Base) -> list[Probe]:
    def build(text: str | Callable[[Path], Path]) -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            path = w / "cities.toml"
            if callable(text):
                text(path)
            else:
                path.write_text(text)
            return [
                "uavdata",
                "build",
                "--root",
                str(base.copy_root(w)),
                "--grid",
                "4m",
                "--alt",
                "10",
                "--roles",
                str(path),
                "--quiet",
            ]

        return make

    many = "train = [" + ",".join(f'"c{i}"' for i in range(1_300_000)) + "]\n"
    probes = [
        Probe(
            "roles",
            "control: tiny-routes train, tiny test",
            build('train = ["tiny-routes"]\ntest = ["tiny"]\n'),
            control=True,
            timeout=120,
        ),
        Probe("roles", "1.3 M names (15 MB)", build(many), timeout=60),
        Probe("roles", "1.3 M names, the last twice", build(many.replace("]\n", ',"c0"]\n')), timeout=60),
        Probe("roles", "a name twice", build('train = ["tiny-routes", "tiny-routes"]\n')),
        Probe("roles", "a city of two roles", build('train = ["tiny"]\ntest = ["tiny"]\n')),
        Probe("roles", "a name that is a path", build('train = ["../x"]\n')),
        Probe("roles", "an unknown role", build('holdout = ["tiny"]\n')),
        Probe("roles", "not TOML", build("train = [\n")),
        Probe("roles", "a FIFO", build(lambda p: _node(p, "fifo"))),
        Probe("roles", "sparse 2 GB", build(_sparse)),
    ]
    return probes


# -- zoo ----------------------------------------------------------------------------------------------------------------
#: The probe's script: builds the env on the base's root, runs ``BODY`` (``env``, ``np`` in scope), and turns the
#: env's refusals (ValueError, pydantic's included, and InputError) into one ``error:`` line and exit 2.
ZOO = """
import sys
import numpy as np
from uavplace.schemas import InputError
try:
    from uavplace.rl.tasks.placement.gym import UavPlacementEnv
    from uavplace.rl.tasks.fleet.zoo import parallel_env
    make = parallel_env if sys.argv[3] == "fleet" else UavPlacementEnv
    env = make("tiny", root=sys.argv[1], **eval(sys.argv[2]))
{body}
except (ValueError, InputError) as exc:
    print("error: " + str(exc).splitlines()[0], file=sys.stderr)
    sys.exit(2)
"""

#: A whole episode of legal random actions: the control.
EPISODE = """    env.reset(seed=0)
    rng = np.random.default_rng(0)
    while env.agents:
        env.step({a: int(rng.integers(0, 5)) for a in env.agents})"""


def zoo_probes(base: Base) -> list[Probe]:
    def script(body: str, overrides: str = "{}", task: str = "fleet") -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            (w / "zoo.py").write_text(ZOO.format(body=body))
            return ["python", str(w / "zoo.py"), str(base.copy_root(w)), overrides, task]

        return make

    def action(value: str) -> str:
        return f"    env.reset(seed=0)\n    env.step({{env.agents[0]: {value}}})"

    probes = [Probe("zoo", "control: an episode of legal actions", script(EPISODE), control=True)]
    for value in ("-1", "5", "-6", "2**70", "1e300", "2.7", "-0.5", "'3'", "True", "None", "np.float64(1.0)"):
        probes.append(Probe("zoo", f"action {value}", script(action(value))))
    probes += [
        Probe("zoo", "a step before reset()", script("    env.step({'uav_0': 0})")),
        Probe("zoo", "a step after the end", script(EPISODE + "\n    env.step({'uav_0': 0})")),
        Probe("zoo", "an action for an unknown agent", script("    env.reset(seed=0)\n    env.step({'uav_9': 0})")),
    ]
    for overrides in (
        "{'uavs': 99}",
        "{'uavs': 0}",
        "{'users': 0}",
        "{'users': 10**6}",
        "{'t_max': 10**12}",
        "{'p_t_db': float('nan')}",
        "{'colour': 1}",
    ):
        probes.append(Probe("zoo", f"overrides {overrides}", script(EPISODE, overrides)))
    # the Gymnasium placement env's overrides, validated the same way
    placement = "    env.reset(seed=0)\n    env.step(0)"
    probes.append(Probe("zoo", "placement: control", script(placement, "{'window': 31}", "placement"), control=True))
    for overrides in ("{'window': 2}", "{'t_max': 0}", "{'p_t_db': float('nan')}", "{'colour': 1}"):
        probes.append(Probe("zoo", f"placement: overrides {overrides}", script(placement, overrides, "placement")))
    return probes


# -- weights ------------------------------------------------------------------------------------------------------------
#: A pickle that would create the file ``RAN`` in the working folder if it were unpickled by pickle's full loader.
RAN = "payload-ran"


def _payload(path: Path) -> Path:
    import pickle

    class Payload:
        def __reduce__(self) -> tuple:
            return (os.system, (f"touch {RAN}",))

    import torch

    torch.save({"online": Payload()}, path, pickle_protocol=pickle.HIGHEST_PROTOCOL)
    return path


def _not_run(w: Path, results: list[Result]) -> str | None:
    return f"a pickle payload ran ({RAN} exists)" if (w / RAN).exists() else None


def weights_probes(base: Base) -> list[Probe]:
    def report(edit: Callable[[Path], object], *extra: str) -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            run = base.copy_run(w)
            edit(run / "checkpoints" / "best.pt")
            return ["uavrl", *report_args(base.copy_root(w), run, w / "rep", *extra)]

        return make

    def resume(edit: Callable[[Path], object]) -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            root = base.copy_root(w)
            _run(["uavrl", *train_args(root, w / "runs", "p", "--until", "128")], w)
            edit(w / "runs" / "p" / "checkpoints" / "last" / "networks.pt")
            return ["uavrl", "train", "--resume", str(w / "runs" / "p"), "--root", str(root)]

        return make

    def init(edit: Callable[[Path], object]) -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            run = base.copy_run(w)
            edit(run / "checkpoints" / "best.pt")
            return ["uavrl", *train_args(base.copy_root(w), w / "runs", "p", "--set", f"init={run}")]

        return make

    def ensemble(edit: Callable[[Path], object]) -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            run = base.copy_run(w)
            edit(run / "checkpoints" / "best.pt")
            return ["uavrl", "ensemble", str(run), str(base.run1), "--out", str(w / "E"), "--root", str(base.copy_root(w))]

        return make

    def predictor(name: str, edit: Callable[[Path], object]) -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            folder = shutil.copytree(PREDICTOR, w / "unet")
            edit(folder / name)
            return ["uavrl", *report_args(base.copy_root(w), base.run, w / "rep", "--predictor", str(folder))]

        return make

    def shipped(w: Path) -> list[str]:
        """The report's defaults (the shipped agents and predictor) from a working folder outside the project."""
        return [
            "uavrl",
            "report",
            "--dataset",
            "tiny",
            "--root",
            str(base.copy_root(w)),
            "--episodes",
            "4",
            "--bootstrap",
            "100",
            "--trajectories",
            "0",
            "--out",
            str(w / "rep"),
            "--quiet",
        ]

    kinds: dict[str, Callable[[Path], object]] = {
        "a FIFO": _replace_by_fifo,
        "sparse 2 GB": _sparse,
        "a pickle payload": _payload,
    }
    probes = [
        Probe(
            "weights",
            "control: the shipped agents from another folder",
            shipped,
            lambda w, r: report_check(w / "rep"),
            timeout=300,
            control=True,
        ),
        Probe(
            "weights",
            "control: --set init from a run",
            init(lambda p: None),
            lambda w, r: run_check(w / "runs"),
            timeout=180,
            control=True,
        ),
    ]
    for kind, edit in kinds.items():
        probes += [
            Probe("weights", f"report: best.pt {kind}", report(edit), _not_run, always_check=True),
            Probe("weights", f"resume: networks.pt {kind}", resume(edit), _not_run, timeout=180, always_check=True),
            Probe("weights", f"train --set init: best.pt {kind}", init(edit), _not_run, timeout=120, always_check=True),
            Probe("weights", f"ensemble: a member's best.pt {kind}", ensemble(edit), _not_run, timeout=120, always_check=True),
            Probe(
                "weights",
                f"report --predictor: weights.pt {kind}",
                predictor("weights.pt", edit),
                _not_run,
                timeout=120,
                always_check=True,
            ),
        ]
    probes += [
        Probe("weights", "report --predictor: model.json a FIFO", predictor("model.json", _replace_by_fifo)),
        Probe("weights", "report --predictor: model.json sparse 2 GB", predictor("model.json", _sparse)),
    ]
    return probes


# -- limits -------------------------------------------------------------------------------------------------------------
def limits_probes(base: Base) -> list[Probe]:
    def simulate(source: str | Callable[[Path], Path], *extra: str) -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            src = source(w) if callable(source) else source
            return ["uavdata", "simulate", str(src), "--name", "x", "--out", str(w / "raw"), "--quiet", *extra]

        return make

    square = {"type": "Polygon", "coordinates": [[[0, 0], [4, 0], [4, 4], [0, 4], [0, 0]]]}

    def footprints(w: Path) -> Path:
        features = [
            {
                "type": "Feature",
                "properties": {"height": 10},
                "geometry": {
                    **square,
                    "coordinates": [[[x + 6 * (i % 300), y + 6 * (i // 300)] for x, y in square["coordinates"][0]]],
                },
            }
            for i in range(100_000)
        ]
        (w / "many.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": features}))
        return w / "many.geojson"

    def mitsuba(w: Path) -> Path:
        import trimesh

        (w / "meshes").mkdir()
        trimesh.creation.box(extents=(4, 4, 10)).export(w / "meshes" / "a.ply")
        shapes = "".join(
            f'<shape type="ply" id="s{i}"><string name="filename" value="meshes/a.ply"/></shape>' for i in range(100_000)
        )
        (w / "scene.xml").write_text(f'<scene version="2.1.0">{shapes}</scene>')
        return w / "scene.xml"

    def city_file(w: Path) -> Path:
        text = (TINY / "tiny.city").read_text()
        head, _, rest = text.partition("begin_<structure> ")
        structure = "begin_<structure> " + rest.partition("end_<structure>")[0] + "end_<structure>\n"
        tail = rest.partition("end_<structure>")[2]
        (w / "many.city").write_text(head + structure * 100_000 + tail.lstrip("\n"))
        return w / "many.city"

    def sparse_export(suffix: str) -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            city = shutil.copytree(TINY, w / "tiny")
            _sparse(city / f"tiny{suffix}")
            return _ingest(w, city)

        return make

    def sparse_geojson(w: Path) -> list[str]:
        return simulate(lambda v: _sparse(v / "big.geojson"))(w)

    def report(*extra: str) -> Callable[[Path], list[str]]:
        return lambda w: ["uavrl", *report_args(base.copy_root(w), base.run, w / "rep", *extra)]

    def tracking(p_t: str) -> Callable[[Path], list[str]]:
        return lambda w: ["uavrl", *tracking_args(base.copy_root(w), "--p-t-db", p_t, "--episodes", "4", "--out", str(w / "rep"))]

    def train_predictor(*extra: str) -> Callable[[Path], list[str]]:
        return lambda w: [
            "uavrl",
            "train-predictor",
            "--dataset",
            "tiny-routes",
            "--root",
            str(base.copy_root(w)),
            "--steps",
            "2",
            "--out",
            str(w / "unet"),
            "--quiet",
            *extra,
        ]

    def inflating_trace(w: Path) -> list[str]:
        args = simulation(w / "raw", 1, "--trace-cache", str(w / "cache"))
        (w / "cache").mkdir()
        # an entry of a 2 GB array of zeros (a few MB on disk), where the simulation makes a few kB
        inflating_npz(w / "cache" / "c.npz", "sinr.npy", np.float32, SPARSE)
        return args

    def traced_again(w: Path, results: list[Result]) -> str | None:
        record = json.loads((w / "raw" / "c" / "simulation.json").read_text())
        cache = str(record.get("trace_cache", ""))
        return None if cache.startswith("traced again") or cache == "traced" else f"trace_cache: {cache}"

    return [
        Probe(
            "limits",
            "simulate: 5 x 5 km at 1 m (25 M cells)",
            simulate("procedural:mixed", "--users", "1", "--grid", "1m", "--extent", "0,0,5000,5000"),
        ),
        Probe("limits", "simulate: 1000 users at 0.5 m", simulate("procedural:mixed", "--users", "1000", "--grid", "0.5m")),
        Probe("limits", "simulate: a GeoJSON of 100,000 footprints", simulate(footprints)),
        Probe("limits", "simulate: a Mitsuba scene of 100,000 shapes", simulate(mitsuba)),
        Probe("limits", "simulate: a .city of 100,000 structures", simulate(city_file)),
        Probe("limits", "simulate: a sparse 2 GB GeoJSON", sparse_geojson),
        *[Probe("limits", f"ingest: a sparse 2 GB {s}", sparse_export(s)) for s in (".city", ".txrx", ".setup")],
        Probe("limits", "report: a million 50-step episodes", report("--episodes", "1000000", "--t-max", "50")),
        Probe("limits", "report: 10,000 episodes of 10,000 steps", report("--episodes", "10000", "--t-max", "10000")),
        Probe("limits", "tracking report: P_T 100 dB", tracking("100")),
        Probe("limits", "tracking report: P_T -100 dB", tracking("-100")),
        Probe("limits", "control: train-predictor of 2 steps", train_predictor(), control=True, timeout=120),
        Probe("limits", "train-predictor: --batch 1024", train_predictor("--batch", "1024")),
        Probe("limits", "train-predictor: --val-dataset a training city", train_predictor("--val-dataset", "tiny-routes")),
        Probe("limits", "trace cache: an entry inflating to 2 GB", inflating_trace, traced_again, timeout=300),
    ]


FAMILIES = {
    "predcache": predcache_probes,
    "sidefile": sidefile_probes,
    "roles": roles_probes,
    "zoo": zoo_probes,
    "weights": weights_probes,
    "limits": limits_probes,
}

if __name__ == "__main__":
    sys.exit("run these with python -m tests.probes --only " + ",".join(FAMILIES))
