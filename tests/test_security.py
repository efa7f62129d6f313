"""Trust model: data files never run code, names never leave the project, outputs never replace what uavplace did not make."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

from tests.bad_inputs.workspace import Workspace
from tests.conftest import REPO, UAVDATA, sparse_file, write_grid_city
from tests.test_bad_inputs import shared  # noqa: F401 - the module-scoped fixture of built data
from uavplace.cli import uavdata, uavrl
from uavplace.eval.evaluate import ReportConfig
from uavplace.eval.report import make_report
from uavplace.schemas import InputError


def invoke(cli, *args: str):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False)


def snapshot(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_checkpoint_payloads_never_run(tmp_path, shared):  # noqa: F811
    """A best.pt or a resumable checkpoint carrying a pickle payload is refused and its code never runs; a checkpoint
    holding a FIFO is refused before anything of it is opened (np.load would block on it)."""
    w = Workspace(tmp_path, shared)
    agent = w.agent()
    w.payload(agent / "checkpoints" / "best.pt")
    res = invoke(uavrl, *w.report("--run", str(agent)))
    assert res.exit_code == 2 and "refused" in res.output and "io.open" in res.output
    for run in (w.run_folder(payload=True),):
        res = invoke(uavrl, "train", "--resume", str(run), "--root", str(w.root()))
        assert res.exit_code == 2 and "refused" in res.output
    fifo = Workspace(tmp_path / "fifo", shared).run_folder()  # a FIFO where the replay would be: refused, never opened
    os.mkfifo(fifo / "checkpoints" / "last" / "replay.npz")
    res = invoke(uavrl, "train", "--resume", str(fifo), "--root", str(w.root()))
    assert res.exit_code == 2 and "replay.npz: not a regular file" in res.output, res.output
    old = Workspace(tmp_path / "old", shared).run_folder(old_last=True)  # the pre-0.2 format: a pickled last.pt
    res = invoke(uavrl, "train", "--resume", str(old), "--root", str(w.root()))
    assert res.exit_code == 2 and "old pickled last.pt is not loaded" in res.output
    assert not list(tmp_path.rglob("PWNED"))


def test_names_never_leave_their_folder(tmp_path):
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "thesis.tex").write_text("years of work")
    before = snapshot(tmp_path)
    city = write_grid_city(tmp_path / "work" / "raw" / "city")
    out = tmp_path / "work" / "proc"
    for name in ("../../evil", "../victim", str(victim), "a/b", "..", "x" * 65, "city\n"):
        res = invoke(uavdata, "ingest", str(city), "--out", str(out), "--name", name, "--quiet")
        assert res.exit_code == 2 and "is not a safe name" in res.output, name
        res = invoke(uavdata, "simulate", "procedural:tiny", "--name", name, "--out", str(tmp_path / "work" / "raw"))
        assert res.exit_code == 2 and "is not a safe name" in res.output, name
        res = invoke(
            uavrl, "train", "--dataset", "city", "--root", str(out), "--out", str(tmp_path / "work" / "runs"), "--name", name
        )
        assert res.exit_code == 2 and "is not a safe name" in res.output, name
    assert not out.exists() and not (tmp_path / "work" / "runs").exists() and not (tmp_path / "evil").exists()
    after = snapshot(tmp_path)
    assert {k: v for k, v in after.items() if not k.startswith("work/")} == before


def test_outputs_replace_only_what_uavplace_made(tmp_path, shared):  # noqa: F811
    """`report --out` and `simulate --name` refuse a folder without their marker; the folder stays byte for byte."""
    w = Workspace(tmp_path, shared)
    data = tmp_path / "data"  # `--out data` must not wipe the raw data and the agents
    (data / "raw" / "city").mkdir(parents=True)
    (data / "raw" / "city" / "city.txrx").write_text("begin_<points> x\n")
    (data / "agents").mkdir()
    (data / "agents" / "notes.md").write_text("ours")
    thesis = tmp_path / "thesis"
    thesis.mkdir()
    (thesis / "thesis.tex").write_text("\\documentclass{article}")
    before = snapshot(tmp_path)
    for out in (data, thesis):
        res = invoke(uavrl, *w.report("--run", str(w.agent()), "--out", str(out)))
        assert res.exit_code == 2 and "is not a report made by uavplace" in res.output
    res = invoke(uavdata, "simulate", "procedural:tiny", "--name", "city", "--out", str(data / "raw"))
    assert res.exit_code == 2 and "is not a simulated city made by uavplace" in res.output
    after = snapshot(tmp_path)
    assert {k: after[k] for k in before} == before
    # a report folder is replaced by the next report
    agent = w.agent()
    res = invoke(uavrl, *w.report("--run", str(agent), "--out", str(tmp_path / "rep")))
    assert res.exit_code == 0, res.output
    res = invoke(uavrl, *w.report("--run", str(agent), "--out", str(tmp_path / "rep")))
    assert res.exit_code == 0 and (tmp_path / "rep" / "report.json").is_file()
    # a report of other agents is not replaced without --overwrite
    before = snapshot(tmp_path / "rep")
    other = w.agent()
    res = invoke(uavrl, *w.report("--run", str(other), "--out", str(tmp_path / "rep")))
    assert res.exit_code == 2 and "holds a report of other agents" in res.output and snapshot(tmp_path / "rep") == before
    res = invoke(uavrl, *w.report("--run", str(other), "--out", str(tmp_path / "rep"), "--overwrite"))
    assert res.exit_code == 0 and str(other) in (tmp_path / "rep" / "report.json").read_text()


def test_symlinks_out_of_the_city_are_not_read(tmp_path):
    secret = tmp_path / "elsewhere" / "secret.txt"
    secret.parent.mkdir()
    secret.write_text("not a p2m: reading it would fail\n")
    city = write_grid_city(tmp_path / "city")
    (city / "city.pl.t003_01.r002.p2m").symlink_to(secret)
    (city / "inside.txt").symlink_to(city / "city.setup")  # a link within the folder is fine
    res = invoke(uavdata, "ingest", str(city), "--out", str(tmp_path / "proc"))
    assert res.exit_code == 0, res.output
    assert "city.pl.t003_01.r002.p2m: symbolic link to" in res.output and "outside the city folder: not read" in res.output
    manifest = json.loads((tmp_path / "proc" / "city" / "ingested" / "manifest.json").read_text())
    link = next(s for s in manifest["sources"] if s["path"] == "city.pl.t003_01.r002.p2m")
    assert link["kind"] == "link" and link["sha256"] is None and link["size_bytes"] is None  # never opened nor stat'ed


def test_what_is_not_a_regular_file_is_listed_never_opened(tmp_path):
    """A FIFO named like an export (it would block), a link to a device, a looping link and a folder named like an
    export are each reported as not read, with a warning and in the manifest (never silently passed over)."""
    city = write_grid_city(tmp_path / "city")
    os.mkfifo(city / "city.pl.t003_01.r002.p2m")
    (city / "loop.p2m").symlink_to(city / "loop")
    (city / "loop").symlink_to(city / "loop.p2m")
    (city / "more.txrx").mkdir()
    res = invoke(uavdata, "ingest", str(city), "--out", str(tmp_path / "proc"))
    assert res.exit_code == 0, res.output
    manifest = json.loads((tmp_path / "proc" / "city" / "ingested" / "manifest.json").read_text())
    special = {s["path"]: s for s in manifest["sources"] if s["kind"] == "special"}
    assert set(special) == {"city.pl.t003_01.r002.p2m", "loop.p2m", "loop", "more.txrx"}
    assert all(s["sha256"] is None and s["status"] == "skipped" for s in special.values())
    assert "city.pl.t003_01.r002.p2m: not a regular file" in res.output and "more.txrx: a folder named like" in res.output


def test_concurrent_ingests_of_one_city_take_turns(tmp_path):
    """Three `uavdata ingest`, then three `uavdata build`, of one city at once: all succeed (a per-folder lock)."""
    city = write_grid_city(tmp_path / "city", nx=150, ny=120, n_tx=8, spacing=2.0, outputs=("pl", "power"))
    env = os.environ | {"PYTHONPATH": str(REPO)}
    cmd = [
        *UAVDATA,
        "ingest",
        str(city),
        "--out",
        str(tmp_path / "proc"),
        "--quiet",
    ]
    procs = [subprocess.Popen(cmd, env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT) for _ in range(3)]
    outputs = [p.communicate(timeout=120)[0].decode() for p in procs]
    assert [p.returncode for p in procs] == [0, 0, 0], outputs
    leftovers = sorted(p.name for p in (tmp_path / "proc" / "city").iterdir())
    assert leftovers == [".ingested.lock", "ingested"]
    build = [
        *UAVDATA,
        "build",
        "--root",
        str(tmp_path / "proc"),
        "--quiet",
        "--force",
    ]
    procs = [subprocess.Popen(build, env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT) for _ in range(3)]
    outputs = [p.communicate(timeout=120)[0].decode() for p in procs]
    assert [p.returncode for p in procs] == [0, 0, 0], outputs
    assert not [p.name for p in (tmp_path / "proc" / "city").iterdir() if ".tmp-" in p.name or p.name.endswith(".old")]


def test_report_checks_everything_before_the_first_episode(tmp_path, shared):  # noqa: F811
    w = Workspace(tmp_path, shared)
    played = []

    def on_progress(method, done, total):
        played.append(method)

    bad = ReportConfig(dataset="city", runs=[str(w.agent(trained_on="city"))], episodes=5)
    with pytest.raises(InputError, match="the test city"):
        make_report(bad, tmp_path / "r", root=w.root(), on_progress=on_progress)
    assert played == []
    # a training bundle that is not built here costs the upper bound only
    ok = ReportConfig(dataset="city", runs=[str(Workspace(tmp_path / "b", shared).agent(trained_on="elsewhere"))], episodes=5)
    report = make_report(ok, tmp_path / "r", root=w.root(), on_progress=on_progress)
    assert played and (report.out / "report.json").is_file()
    assert "elsewhere@0123456789ab" in (report.out / "report.json").read_text()


def test_checkpoint_payloads_are_named_whatever_torch_says(tmp_path):
    """A bare pickle of protocol 4 calling os.system: torch 2.13 refuses it as an "Unsupported operand", not a global;
    the refusal still says the file holds Python objects and names what it would call, and nothing runs."""
    import pickle

    from uavplace.infra.tensors import load_tensors

    marker = tmp_path / "PWNED"

    class Payload:
        def __reduce__(self):  # noqa: ANN204
            return (os.system, (f"touch {marker}",))

    path = tmp_path / "best.pt"
    path.write_bytes(pickle.dumps({"online": Payload()}, protocol=4))
    with pytest.raises(InputError, match=r"holds Python objects .*it names posix.system"):
        load_tensors(path)
    assert not marker.exists()


def test_non_finite_weights_are_refused_on_save_and_on_load(tmp_path):
    """NaN or inf weights (a diverged training, a tampered file) are never saved and never loaded: the error names
    the tensor; the file a refused save would have replaced is untouched."""
    import torch

    from uavplace.infra.tensors import load_tensors, save_tensors

    good = {"online": {"w": torch.ones(3), "steps": torch.tensor([1, 2])}, "config": {"lr": 1e-3}}
    path = tmp_path / "best.pt"
    save_tensors(good, path)
    before = path.read_bytes()
    bad = {"online": {"w": torch.tensor([1.0, float("nan"), 2.0]), "steps": torch.tensor([1, 2])}}
    with pytest.raises(InputError, match=r"online\.w holds NaN or inf: the training diverged"):
        save_tensors(bad, path)
    assert path.read_bytes() == before and load_tensors(path)["config"] == {"lr": 1e-3}
    torch.save({"online": {"w": torch.tensor([float("inf")])}}, tmp_path / "tampered.pt")
    with pytest.raises(InputError, match=r"tampered.pt: weights: online\.w holds NaN or inf: not usable weights"):
        load_tensors(tmp_path / "tampered.pt")


def _child(code: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh Python (the repository importable); killed after ``timeout`` s, so a hang fails the test."""
    env = os.environ | {"PYTHONPATH": str(REPO)}
    return subprocess.run([sys.executable, "-c", code], env=env, cwd=REPO, capture_output=True, text=True, timeout=timeout)


def test_mesh_references_that_are_not_regular_files_never_block(tmp_path):
    """An OBJ's material library and a glTF's buffer that are FIFOs: a read would block forever; they are refused."""
    os.mkfifo(tmp_path / "mat.mtl")
    os.mkfifo(tmp_path / "buf.bin")
    (tmp_path / "a.obj").write_text("mtllib mat.mtl\nv 0 0 0\nv 10 0 0\nv 0 10 20\nv 10 10 20\nf 1 2 3\nf 2 4 3\n")
    gltf = {
        "asset": {"version": "2.0"}, "buffers": [{"uri": "buf.bin", "byteLength": 36}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "max": [1, 1, 1], "min": [0, 0, 0]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}], "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}],
    }  # fmt: skip
    (tmp_path / "b.gltf").write_text(json.dumps(gltf))
    res = _child(
        "from pathlib import Path\nfrom uavplace.ingest.mesh import read_mesh\nfrom uavplace.schemas import InputError\n"
        f"print(len(read_mesh(Path({str(tmp_path / 'a.obj')!r}))[0]))\n"
        f"try:\n    read_mesh(Path({str(tmp_path / 'b.gltf')!r}))\nexcept InputError as e:\n    print(e)\n"
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines()[0] == "1"  # the OBJ without its materials: one building
    assert "buf.bin: not a regular file (a FIFO, device or folder): refused" in res.stdout


def test_a_mesh_of_many_bodies_stays_small(tmp_path):
    """20,000 separate boxes in one PLY (5 MB): read in seconds of CPU (the child's own CPU time, which a busy
    machine does not inflate) and well under 2 GB (it passed 8 GB once)."""
    import trimesh

    box = trimesh.creation.box(extents=(4, 4, 10))
    n, k = 20_000, 142
    offsets = np.stack([(np.arange(n) % k) * 8.0, (np.arange(n) // k) * 8.0, np.full(n, 5.0)], axis=1)
    vertices = (box.vertices[None] + offsets[:, None]).reshape(-1, 3)
    faces = (box.faces[None] + 8 * np.arange(n)[:, None, None]).reshape(-1, 3)
    trimesh.Trimesh(vertices, faces, process=False).export(tmp_path / "city.ply")
    res = _child(
        "import resource, time\nfrom pathlib import Path\nfrom uavplace.ingest.mesh import read_mesh\n"
        f"t = time.process_time(); records, _ = read_mesh(Path({str(tmp_path / 'city.ply')!r}))\n"
        "print(len(records), time.process_time() - t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n"
    )
    assert res.returncode == 0, res.stderr
    count, seconds, max_kb = res.stdout.split()
    assert int(count) == n
    assert float(seconds) < 60 and int(max_kb) < 2 * 2**20, res.stdout


@pytest.fixture
def small_disk(tmp_path):
    """A 24 kB file system (tmpfs), where every command runs out of space; skips where mounting is not allowed."""
    mount = tmp_path / "small"
    mount.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=24k", "tmpfs", str(mount)], capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here: {done.stderr.decode(errors='replace').strip()}")
    yield mount
    subprocess.run(["umount", str(mount)], capture_output=True)


def test_a_full_disk_is_one_line_and_leaves_nothing_half_written(tmp_path, small_disk):
    """ENOSPC in ingest and in training: exit 2, one `error:` line saying the disk is full, no traceback, and no
    temporary file or folder left on the full file system."""
    city = write_grid_city(tmp_path / "raw" / "city", nx=40, ny=40, n_tx=6)
    done = subprocess.run([*UAVDATA, "ingest", str(city), "--out", str(small_disk / "root")], capture_output=True, text=True)
    lines = [x for x in done.stderr.splitlines() if x.strip()]
    assert done.returncode == 2 and len(lines) == 1 and "no space left" in lines[0].lower(), done.stderr
    assert not [p for p in small_disk.rglob("*") if "tmp" in p.name or p.name.startswith(".")
                and not p.name.endswith(".lock")], list(small_disk.rglob("*"))  # fmt: skip
    subprocess.run([*UAVDATA, "ingest", str(city), "--out", str(tmp_path / "root"), "--quiet"], check=True)
    subprocess.run([*UAVDATA, "build", "--root", str(tmp_path / "root"), "--grid", "4m", "--alt", "10", "--noise-dbm", "-60",
                    "--quiet"], check=True)  # fmt: skip
    uavrl_cli = [sys.executable, "-m", "uavplace.cli", "uavrl"]
    done = subprocess.run([*uavrl_cli, "train", "--dataset", "city", "--root", str(tmp_path / "root"), "--preset", "fast",
                           "--steps", "64", "--eval-every", "32", "--out", str(small_disk / "runs"), "--name", "r", "--quiet",
                           "--set", "buffer_size=128", "--set", "learning_starts=16", "--set", "eval_episodes=4"],
                          capture_output=True, text=True)  # fmt: skip
    lines = [x for x in done.stderr.splitlines() if x.strip()]
    assert done.returncode == 2 and len(lines) == 1 and "no space left" in lines[0].lower(), done.stderr
    assert not [p for p in small_disk.rglob("*") if ".tmp" in p.name], list(small_disk.rglob("*"))


def test_an_output_file_path_that_is_not_a_regular_file_is_never_replaced(tmp_path, shared):  # noqa: F811
    """`--markdown` (and every file written whole) replaces a regular file or nothing: a FIFO, a folder, a link or a
    device node made here is refused in one line before any work, and stays what it was."""
    from uavplace.infra.files import atomic_write_text

    w = Workspace(tmp_path, shared)
    fifo, folder, link = tmp_path / "fifo", tmp_path / "folder", tmp_path / "link"
    os.mkfifo(fifo)
    folder.mkdir()
    (tmp_path / "target.md").write_text("mine")
    link.symlink_to(tmp_path / "target.md")
    paths = [fifo, folder, link]
    if os.geteuid() == 0:  # a character device of our own, in our folder (the machine's /dev/null is never touched)
        device = tmp_path / "null"
        os.mknod(device, 0o666 | 0o020000, os.makedev(1, 3))
        paths.append(device)
    for path in paths:
        kind = os.lstat(path).st_mode
        with pytest.raises(InputError, match="not a regular file"):
            atomic_write_text(path, "x")
        res = invoke(uavrl, *w.report("--run", str(w.agent()), "--out", str(tmp_path / "rep"), "--markdown", str(path)))
        assert res.exit_code == 2 and ("not a regular file" in res.output or "is a directory" in res.output), res.output
        assert os.lstat(path).st_mode == kind and not (tmp_path / "rep").exists()
    assert (tmp_path / "target.md").read_text() == "mine"


def _within(seconds: float, fn, *args):  # noqa: ANN001, ANN202
    """``fn(*args)``'s outcome (its result or the exception it raised), failing the test if it is still running after
    ``seconds`` (it would block forever)."""
    import threading

    box: list = []

    def run() -> None:
        try:
            box.append(fn(*args))
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            box.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), f"{fn.__name__} still blocks after {seconds} s"
    return box[0]


def test_records_that_are_fifos_or_devices_are_refused_at_once(tmp_path, tiny):
    """A bundle whose manifest.json is a FIFO, a sweep spec or a run.json that is a FIFO or an endless device: each is
    refused in one line within seconds (never waited on, never read to the end)."""
    import shutil

    from uavplace.dataset.bundle import read_manifest, resolve
    from uavplace.eval.sweep import read_spec
    from uavplace.rl.agent.runs import read_run_json

    root = tmp_path / "p"
    shutil.copytree(tiny, root)
    folder = resolve("tiny", root=root)
    (folder / "manifest.json").unlink()
    os.mkfifo(folder / "manifest.json")
    err = _within(10, read_manifest, folder)
    assert isinstance(err, InputError) and "not a regular file" in str(err)
    _within(30, invoke, uavdata, "list", "--root", str(root))  # lists what it can read, never waits on the FIFO
    res = _within(30, invoke, uavrl, "baselines", "--dataset", "tiny", "--root", str(root))
    assert res.exit_code == 2 and "manifest.json" in res.output and "not a regular file" in res.output, res.output
    os.mkfifo(tmp_path / "spec.toml")
    (tmp_path / "run").mkdir()
    os.mkfifo(tmp_path / "run" / "run.json")
    for fn, path in ((read_spec, tmp_path / "spec.toml"), (read_run_json, tmp_path / "run")):
        err = _within(10, fn, path)
        assert isinstance(err, InputError) and "not a regular file" in str(err), err
    if os.geteuid() == 0:  # an endless device of our own (like /dev/zero), in our folder
        os.mknod(tmp_path / "zero.toml", 0o666 | 0o020000, os.makedev(1, 5))
        err = _within(10, read_spec, tmp_path / "zero.toml")
        assert isinstance(err, InputError) and "not a regular file" in str(err)
    (tmp_path / "big.toml").write_bytes(b"#" * (17 * 2**20))
    err = _within(10, read_spec, tmp_path / "big.toml")
    assert isinstance(err, InputError) and "record_bytes" in str(err)


def test_names_are_drawn_as_they_are_never_as_mathtext(tmp_path, shared):  # noqa: F811
    """A run folder named like a broken TeX formula is a method's name in the figures, drawn as text."""
    w = Workspace(tmp_path, shared)
    weird = tmp_path / "$\\frac{a}{$"
    w.agent().rename(weird)
    res = invoke(uavrl, *w.report("--run", str(weird), "--out", str(tmp_path / "rep")))
    assert res.exit_code == 0, res.output
    assert (tmp_path / "rep" / "report.html").is_file()


def test_weights_files_that_are_fifos_are_refused_at_once(tmp_path):
    """Every weights file goes through one regular-file, size-bounded read (``load_tensors``): a FIFO as a resume's
    ``networks.pt`` or as ``--set init=DIR``'s ``best.pt`` is refused in one line, never waited on."""
    from uavplace.infra.tensors import load_tensors
    from uavplace.rl.agent.resume import start_from

    os.mkfifo(tmp_path / "networks.pt")
    err = _within(10, load_tensors, tmp_path / "networks.pt")
    assert isinstance(err, InputError) and "not a regular file" in str(err)
    init = tmp_path / "init"
    (init / "checkpoints").mkdir(parents=True)
    os.mkfifo(init / "checkpoints" / "best.pt")
    config = type("Config", (), {"init": str(init), "init_member": 0})()
    err = _within(10, start_from, None, config)
    assert isinstance(err, InputError) and "best.pt" in str(err) and "not a regular file" in str(err)
    err = _within(10, load_tensors, tmp_path / "absent.pt")
    assert isinstance(err, InputError) and "no such checkpoint" in str(err)
    # a run's best.pt that is there but a FIFO: "not a regular file", not "no checkpoints/best.pt"
    import shutil

    from uavplace.eval.evaluate import load_agent
    from uavplace.rl.agent.ensemble import read_member

    shutil.copy(REPO / "data" / "agents" / "best" / "run.json", init / "run.json")  # a run's record beside the FIFO
    for read in (lambda: load_agent(init, 0.0, 0), lambda: read_member(init)):
        err = _within(10, read)
        assert isinstance(err, InputError) and "not a regular file" in str(err), err


def test_predictor_weights_are_bounded_before_they_are_hashed(tmp_path):
    """The learned predictor's weights.pt of 2 GB (sparse) is refused by its size (its network's parameters), in one
    line naming the limit, before a byte of it is hashed (it had been hashed whole, 11 s, before the sha256 refused it)."""
    import shutil
    import time

    from uavplace.rl.config import DEFAULT_PREDICTOR
    from uavplace.rl.predictor.learned import load_learned

    folder = shutil.copytree(DEFAULT_PREDICTOR, tmp_path / "unet")
    sparse_file(folder / "weights.pt")
    cpu = time.process_time()
    err = _within(30, load_learned, folder)
    assert isinstance(err, InputError) and "parameters of float32" in str(err) and "weights.pt" in str(err), err
    assert time.process_time() - cpu < 2.0  # nothing of the 2 GB was read
    (folder / "weights.pt").write_bytes((DEFAULT_PREDICTOR / "weights.pt").read_bytes()[:-1] + b"x")
    err = _within(30, load_learned, folder)
    assert isinstance(err, InputError) and "do not belong together" in str(err), err


def test_sparse_text_exports_are_refused_by_their_size(tmp_path):
    """A sparse 2 GB .city, .txrx, .setup, GeoJSON or routes file is refused by its size (``text_bytes``) before any of
    it is read, in one line naming the limit; a FIFO in their place is refused at once."""
    from uavplace.ingest.geojson import read_geojson
    from uavplace.ingest.wireless_insite.keyword import read_text

    for name in ("big.city", "big.txrx", "big.setup", "big.geojson"):
        path = sparse_file(tmp_path / name)
        reader = read_text if not name.endswith("geojson") else read_geojson
        err = _within(10, reader, path, name)
        assert isinstance(err, InputError) and "text_bytes" in str(err), err
    os.mkfifo(tmp_path / "fifo.txrx")
    err = _within(10, read_text, tmp_path / "fifo.txrx", "fifo.txrx")
    assert isinstance(err, InputError) and "not a regular file" in str(err)


def test_work_is_bounded_before_it_starts(tmp_path, tiny):
    """Each command estimates its work before it starts and refuses in seconds, naming the limit: a simulated grid
    of 25 M cells (grid_cells), a GeoJSON of more features than the limit buildings, an evaluation of a million
    50-step episodes (episode_steps)."""
    import json

    from uavplace.ingest.geojson import read_geojson
    from uavplace.simulate.config import SimulationSpec
    from uavplace.simulate.raytrace import RayTraceConfig
    from uavplace.simulate.sources import check_simulation

    spec = SimulationSpec(source="procedural:mixed", name="x", num_users=1, grid_m=1.0, extent_m=(0.0, 0.0, 5000.0, 5000.0))
    err = _within(10, check_simulation, spec, RayTraceConfig())
    assert isinstance(err, InputError) and "grid_cells" in str(err)
    square = {"type": "Polygon", "coordinates": [[[0, 0], [1, 0], [1, 1], [0, 1], [0, 0]]]}
    feature = {"type": "Feature", "geometry": square, "properties": {"height": 10}}
    (tmp_path / "many.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": [feature] * 50_001}))
    err = _within(30, read_geojson, tmp_path / "many.geojson", "many.geojson")
    assert isinstance(err, InputError) and "buildings" in str(err)
    res = _within(60, invoke, uavrl, "report", "--dataset", "tiny", "--root", str(tiny), "--episodes", "1000000", "--t-max", "50")
    assert res.exit_code == 2 and "episode_steps" in res.output, res.output


def test_a_ray_that_does_not_start_is_one_line_saying_what_to_do(monkeypatch):
    """Ray's own startup failure (a node that timed out under load, a bare Exception) becomes one InputError naming
    what to do: run again, --ray-address, fewer CPUs."""
    import ray

    from uavplace.infra.cluster import start_ray

    def timed_out(**_kwargs):  # noqa: ANN202 - ray.init's failure as Ray raises it
        raise Exception(
            "The current node timed out during startup. This could happen because some of the Ray processes failed to startup."
        )  # noqa: TRY002

    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", timed_out)
    with pytest.raises(
        InputError, match=r"the local Ray did not start \(The current node timed out during startup.*--ray-address"
    ):
        start_ray(None, 1.0, "--cpus-per-city")
