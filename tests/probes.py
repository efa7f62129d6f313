"""A probe pass over the real command lines: hostile inputs, each run in a child process, every outcome classified.

An independent pass: probes written from classes of hostile input and from each command's own options
(read from click, so a new option is probed without editing this file), not from ``tests/bad_inputs/``. Families:

- ``opt``: every numeric option of ``uavdata build|show|simulate`` and ``uavrl train|report|baselines`` given -1,
  nan, inf, 1e300 and 1e-300;
- ``set``: every numeric setting of ``uavrl train --set`` given nan and 1e12;
- ``raw``: edits of the embedded tiny city's exports (header and row values, sizes, compression bombs, files that
  are not regular files, names);
- ``bundle``: a built bundle's arrays, tables, manifest and ``latest`` edited, hashes updated where the edit would
  otherwise be caught by them;
- ``run``: a trained run's weights, ``run.json``, ``checkpoint.json`` and archives edited;
- ``race``: two commands at once on the same output (trains of one name, ingest beside build, two builds, two
  reports);
- ``fs``: outputs that are files, read-only folders, missing roots;
- ``round3``: sweeps and the folders under their ``--out``, sweep specs that are FIFOs or
  devices, Ray settings that would wait forever, two ensembles at once, ``--markdown`` a FIFO, device or link,
  records that are FIFOs, Mitsuba instances, routes files, the limits on products, duplicated runs and groups,
  a run folder named as mathtext. A probe marked ``always_check`` is checked after a refusal too (what the refused
  command must have left as it was).

Outcomes: ``accepted`` (exit 0 and the result's check passed), ``refused`` (exit 2, ``error:`` lines only, one per
bad input: ``uavdata build`` of several cities says each city's, no internal error), and the failures ``internal`` (an internal error or a traceback), ``hang`` (past ``--timeout``), ``blowup``
(peak memory of the command and its children past 2 GiB, or a MemoryError), ``silent`` (exit 0 with a result that
fails its check: non-finite or unphysical values), ``lost`` (a race that exits 0 twice and keeps one result, or a
result inconsistent with its record) and ``unclear`` (any other exit, or an error that is not one line).

    python -m tests.probes --out runs/probes                # all (about an hour on 2 cores)
    python -m tests.probes --out runs/probes --only raw,run  # some families
    python -m tests.probes --out runs/probes --list          # the probes, without running them

``pytest --probes`` runs every probe as a test case (``tests/test_probes.py``); the default suite leaves them out.

Writes ``OUT/probes.csv`` (one row a probe: family, id, outcome, exit status, seconds, peak MiB, the error line) and
``OUT/probes.md`` (counts by family and outcome, then every failure).
"""

from __future__ import annotations

import argparse
import contextlib
import gzip
import hashlib
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

REPO = Path(__file__).resolve().parents[1]
TINY = REPO / "data" / "raw" / "tiny"
#: The training city of the base run: the tiny city's twin with routes (a report on tiny is then an unseen city).
TWIN = REPO / "data" / "raw" / "tiny-routes"
CLI = [sys.executable, "-m", "uavplace.cli"]
PEAK_LIMIT_MIB = 2048
#: The address-space cap of a probe: a runaway allocation fails inside it (a MemoryError) instead of starving the machine.
ADDRESS_CAP = 24 * 2**30
BAD = ("internal", "hang", "blowup", "silent", "lost", "unclear")
VALUES = ["-1", "nan", "inf", "1e300", "1e-300"]


@dataclass
class Result:
    rc: int | None
    seconds: float
    peak_mib: float
    stderr: str
    stdout: str = ""


@dataclass
class Probe:
    family: str
    id: str
    #: makes the inputs in the probe's folder and returns one command (a list) or several to run at once
    make: Callable[[Path], list[str] | list[list[str]]]
    #: for an accepted command: None, or what is wrong with its result (a silent or lost outcome)
    check: Callable[[Path, list[Result]], str | None] | None = None
    timeout: float | None = None
    #: a control: the unspoiled command of a family, which must be accepted (else its probes prove nothing)
    control: bool = False
    #: run ``check`` after a refusal too: what a refused command must have left as it was (a data-loss probe)
    always_check: bool = False
    outcome: str = ""
    detail: str = ""
    results: list[Result] = field(default_factory=list)


# -- running ----------------------------------------------------------------------------------------------------------
def _cap() -> None:
    os.setsid()
    resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_CAP, ADDRESS_CAP))


#: The probes' commands running now, each the leader of its own session: what a stopped pass kills (``_stop``).
RUNNING: set[int] = set()


def start(args: list[str], cwd: Path) -> subprocess.Popen:
    env = os.environ | {"UAVPLACE_QUIET": "1", "PYTHONWARNINGS": "ignore", "RAY_AUTH_MODE": "disabled"}
    env.pop("UAVPLACE_DEBUG", None)
    command = [sys.executable, *args[1:]] if args[0] == "python" else [*CLI, *args]  # a script, or a command line
    proc = subprocess.Popen(command, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                            preexec_fn=_cap, text=True, errors="replace")  # fmt: skip
    RUNNING.add(proc.pid)
    return proc


def _stop(signum: int, frame: object) -> None:
    """A pass stopped (SIGTERM, Ctrl-C) kills the probes' commands it started: in their own sessions, they would
    otherwise run on (a million training steps writing where the probe pointed them)."""
    for pid in list(RUNNING):
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(pid, signal.SIGKILL)
    raise SystemExit(128 + signum)


def finish(proc: subprocess.Popen, t0: float, timeout: float) -> Result:
    """Wait for ``proc`` (killing its session past ``timeout``); its exit status, time and peak memory (``wait4``'s
    maximum resident size covers the children it waited for)."""
    out, err = [], []
    readers = [threading.Thread(target=lambda s=s, b=b: b.append(s.read())) for s, b in ((proc.stdout, out), (proc.stderr, err))]
    for r in readers:
        r.start()
    rc, peak = None, 0.0
    while True:
        pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            rc = os.waitstatus_to_exitcode(status)
            peak = usage.ru_maxrss / 1024
            break
        if time.monotonic() - t0 > timeout:
            os.killpg(proc.pid, signal.SIGKILL)
            _, status, usage = os.wait4(proc.pid, 0)
            peak = usage.ru_maxrss / 1024
            break
        time.sleep(0.05)
    RUNNING.discard(proc.pid)
    proc.returncode = rc if rc is not None else -9
    for r in readers:
        r.join(timeout=5)
    return Result(rc, time.monotonic() - t0, peak, "".join(err), "".join(out))


def classify(probe: Probe, folder: Path, timeout: float) -> None:
    made = probe.make(folder)
    commands = made if made and isinstance(made[0], list) else [made]
    t0 = time.monotonic()
    procs = []
    for k, c in enumerate(commands):
        procs.append(start(c, folder))
        if k + 1 < len(commands):
            time.sleep(0.3)  # the second command starts while the first works
    probe.results = [finish(p, t0, probe.timeout or timeout) for p in procs]
    outcomes = []
    for r in probe.results:
        lines = [x for x in r.stderr.splitlines() if x.strip()]
        last = lines[-1] if lines else ""
        if r.rc is None:
            outcomes.append(("hang", f"killed after {r.seconds:.0f} s"))
        elif r.peak_mib > PEAK_LIMIT_MIB or "MemoryError" in r.stderr:
            outcomes.append(("blowup", f"peak {r.peak_mib:.0f} MiB: {last[:200]}"))
        elif "internal error" in r.stderr or "Traceback" in r.stderr:
            outcomes.append(("internal", (last or r.stderr)[:300]))
        elif r.rc == 0:
            outcomes.append(("accepted", ""))
        elif r.rc == 2 and last.startswith("error:") and all(x.startswith("error:") for x in lines if "error:" in x):
            outcomes.append(("refused", last[:300]))
        else:
            outcomes.append(("unclear", f"exit {r.rc}: {(last or r.stderr)[:300]}"))
    worst = next((o for o in outcomes if o[0] in BAD), None)
    if worst is not None:
        probe.outcome, probe.detail = worst
        return
    if probe.check is not None and (probe.always_check or any(o[0] == "accepted" for o in outcomes)):
        try:
            problem = probe.check(folder, probe.results)
        except Exception as exc:  # noqa: BLE001 - a result the check cannot read is itself the finding
            problem = f"the result cannot be read back: {type(exc).__name__}: {str(exc)[:200]}"
        if problem:
            probe.outcome = "lost" if probe.family == "race" else "silent"
            probe.detail = problem
            return
    probe.outcome = "accepted" if all(o[0] == "accepted" for o in outcomes) else "refused"
    probe.detail = next((o[1] for o in outcomes if o[0] == "refused"), "")
    if probe.control and probe.outcome != "accepted":
        probe.outcome, probe.detail = "setup", f"the control was refused: {probe.detail}"


# -- the shared inputs: the tiny city ingested and built, and a short training run --------------------------------------
class Base:
    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.raw = folder / "raw" / "tiny"
        self.root = folder / "root"
        self.run = folder / "runs" / "r0"
        self.run1 = folder / "runs" / "r1"  # seed 1: with r0, the members of an ensemble

    def make(self, timeout: float) -> None:
        if (self.folder / "ready").is_file():
            return
        shutil.rmtree(self.folder, ignore_errors=True)
        self.raw.parent.mkdir(parents=True)
        shutil.copytree(TINY, self.raw)
        shutil.copytree(TWIN, self.raw.parent / TWIN.name)
        steps = [
            ["uavdata", "ingest", str(self.raw), str(self.raw.parent / TWIN.name), "--out", str(self.root)],
            ["uavdata", *build_args(self.root)],
            ["uavrl", *train_args(self.root, self.folder / "runs", "r0", dataset=TWIN.name)],
            ["uavrl", *train_args(self.root, self.folder / "runs", "r1", "--seed", "1", dataset=TWIN.name)],
        ]
        for args in steps:
            r = finish(start(args, self.folder), time.monotonic(), 600)
            if r.rc != 0:
                raise SystemExit(f"probe base: {' '.join(args)} failed: {r.stderr[-2000:]}")
        (self.folder / "ready").write_text("ok\n")

    def copy_root(self, dst: Path) -> Path:
        shutil.copytree(self.root, dst / "root", symlinks=True)
        return dst / "root"

    def copy_raw(self, dst: Path) -> Path:
        shutil.copytree(self.raw, dst / "tiny")
        return dst / "tiny"

    def copy_run(self, dst: Path) -> Path:
        shutil.copytree(self.run, dst / "r0")
        return dst / "r0"


def train_args(root: Path, out: Path, name: str, *extra: str, dataset: str = "tiny") -> list[str]:
    return ["train", "--dataset", dataset, "--root", str(root), "--preset", "fast", "--steps", "256", "--eval-every", "128",
            "--out", str(out), "--name", name, "--set", "buffer_size=512", "--set", "learning_starts=64",
            "--set", "eval_episodes=8", "--set", "eval_split=null", *extra]  # fmt: skip


def build_args(root: Path, *extra: str) -> list[str]:
    return ["build", "--root", str(root), "--grid", "4m", "--alt", "10", *extra]


def report_args(root: Path, run: Path, out: Path, *extra: str) -> list[str]:
    """A short report of one run on the tiny city (valid as it is: the control probes check it)."""
    return ["report", "--dataset", "tiny", "--root", str(root), "--run", str(run), "--episodes", "8", "--bootstrap", "100",
            "--trajectories", "0", "--predictor", "none", "--out", str(out), "--quiet", *extra]  # fmt: skip


def tracking_args(root: Path, *extra: str) -> list[str]:
    """A tracking report on the tiny city's twin with routes."""
    return ["report", "--task", "tracking", "--dataset", TWIN.name, "--root", str(root), "--quiet", *extra]


def inflating_npz(path: Path, member: str, dtype: type, nbytes: int) -> Path:
    """A zip archive whose one ``.npy`` member inflates to ``nbytes`` of zeros (a few MB on disk), written as a stream."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z, z.open(member, "w", force_zip64=True) as f:
        header = np.lib.format.header_data_from_array_1_0(np.zeros(0, dtype))
        header["shape"] = (nbytes // np.dtype(dtype).itemsize,)
        np.lib.format.write_array_header_1_0(f, header)
        chunk = bytes(1 << 26)
        for _ in range(nbytes >> 26):
            f.write(chunk)
    return path


# -- checks of accepted results ----------------------------------------------------------------------------------------
def finite_npz(path: Path) -> str | None:
    with np.load(path, allow_pickle=False) as z:
        for k in z.files:
            a = z[k]
            if a.dtype.kind == "f" and not np.isfinite(a).all():
                return f"{path.name}: {k} holds non-finite values"
    return None


def bundle_check(root: Path) -> str | None:
    """Every bundle under ``root``: finite arrays, SINR within the floor and 400 dB, finite manifest numbers."""
    for manifest in root.glob("*/[0-9a-f]*/manifest.json"):
        problem = finite_npz(manifest.parent / "maps.npz")
        if problem:
            return f"{manifest.parent.name}: {problem}"
        with np.load(manifest.parent / "maps.npz") as z:
            sinr = z["sinr_db"]
            if sinr.size and (sinr.max() > 400 or sinr.min() < -400):
                return f"SINR from {sinr.min():g} to {sinr.max():g} dB"
        numbers = json.loads(manifest.read_text(), parse_constant=lambda c: float("nan"))
        bad = [k for k, v in _numbers(numbers) if not np.isfinite(v)]
        if bad:
            return f"manifest holds non-finite {', '.join(bad[:3])}"
    return None


def _numbers(doc: object, prefix: str = "") -> list[tuple[str, float]]:
    if isinstance(doc, dict):
        return [x for k, v in doc.items() for x in _numbers(v, f"{prefix}{k}.")]
    if isinstance(doc, list):
        return [x for v in doc for x in _numbers(v, prefix)]
    if isinstance(doc, float):
        return [(prefix.rstrip("."), doc)]
    return []


def run_check(out: Path) -> str | None:
    import torch

    for pt in out.rglob("*.pt"):
        state = torch.load(pt, map_location="cpu", weights_only=True)
        tensors = [v for v in _tensors(state)]
        if any(not torch.isfinite(t).all() for t in tensors if t.is_floating_point()):
            return f"{pt.relative_to(out)} holds non-finite weights"
    for record in out.rglob("run.json"):
        bad = [
            k for k, v in _numbers(json.loads(record.read_text(), parse_constant=lambda c: float("nan"))) if not np.isfinite(v)
        ]
        if bad:
            return f"{record.relative_to(out)} records non-finite {', '.join(bad[:3])}"
    return None


def _tensors(state: object):  # noqa: ANN202
    import torch

    if isinstance(state, torch.Tensor):
        yield state
    elif isinstance(state, dict):
        for v in state.values():
            yield from _tensors(v)
    elif isinstance(state, list | tuple):
        for v in state:
            yield from _tensors(v)


def report_check(out: Path) -> str | None:
    for summary in out.rglob("summary.csv"):
        t = pd.read_csv(summary)
        if "success" in t and not t["success"].between(0, 1).all():
            return f"{summary.name}: success outside 0..1"
    return None


def ingest_check(root: Path) -> str | None:
    for table in root.glob("*/ingested/receivers.parquet"):
        t = pd.read_parquet(table)
        for c in ("x_m", "y_m", "z_m"):
            if c in t and not np.isfinite(t[c]).all():
                return f"receivers.{c} holds non-finite values"
        for c in ("power_dbm", "path_loss_db", "path_gain_db"):
            if c in t:
                v = t[c].to_numpy(dtype=float)
                v = v[np.isfinite(v)]
                if v.size and (v.max() > 100 or v.min() < -400):
                    return f"receivers.{c} from {v.min():g} to {v.max():g}"
    return None


# -- the probes ---------------------------------------------------------------------------------------------------------
def option_probes(base: Base) -> list[Probe]:
    """Every numeric option of the commands a user runs on a city, with each of ``VALUES``."""
    import click

    from uavplace.cli import uavdata, uavrl

    numeric = (click.types.FloatParamType, click.types.IntParamType)
    skip = {"--root", "--out", "--ray-address", "--cpus-per-city", "--cpus-per-trial", "--trace-cache", "--name"}

    def contexts(w: Path) -> dict[tuple[str, str], list[str]]:
        root = base.copy_root(w)
        return {
            ("uavdata", "build"): build_args(root),
            ("uavdata", "show"): ["show", "tiny", "--root", str(root), "--out", str(w / "show")],
            ("uavdata", "simulate"): [
                "simulate",
                "procedural:tiny",
                "--name",
                "t",
                "--out",
                str(w / "sim"),
                "--users",
                "1",
                "--samples",
                "1e3",
            ],  # fmt: skip
            ("uavrl", "train"): train_args(root, w / "runs", "p"),
            ("uavrl", "report"): report_args(root, base.run, w / "rep"),
            ("uavrl", "baselines"): ["baselines", "--dataset", "tiny", "--root", str(root), "--episodes", "8"],
        }

    checks = {"build": lambda w, r: bundle_check(w / "root"), "train": lambda w, r: run_check(w / "runs"),
              "report": lambda w, r: report_check(w / "rep")}  # fmt: skip
    probes = []
    for group in (uavdata, uavrl):
        ctx = click.Context(group)
        for name in ("build", "show", "simulate", "train", "report", "baselines"):
            cmd = group.get_command(ctx, name)
            if cmd is None:
                continue
            # the control: the context itself must be accepted, or every probe of it is refused for the wrong reason
            probes.append(Probe("opt", f"{group.name} {name} (control)", lambda w, key=(group.name, name): [key[0], *contexts(w)[key]],
                                checks.get(name), control=True))  # fmt: skip
            for p in cmd.params:
                opt, kind = (p.opts[-1] if p.opts else ""), type(p.type).__name__
                if not isinstance(p, click.Option) or p.is_flag or opt in skip:
                    continue
                if not (isinstance(p.type, numeric) or type(p.type).__name__ in ("Metres", "Bounds", "Point")):
                    continue
                for value in VALUES:

                    def make(w: Path, key=(group.name, name), opt=opt, value=value, multi=kind) -> list[str]:
                        args = contexts(w)[key]
                        v = ",".join([value] * 4) if multi == "Bounds" else ",".join([value] * 2) if multi == "Point" else value
                        if opt in args:
                            args = list(args)
                            args[args.index(opt) + 1] = v
                            return [key[0], *args]
                        return [key[0], *args, opt, v]

                    probes.append(Probe("opt", f"{group.name} {name} {opt} {value}", make, checks.get(name)))
    return probes


def set_probes(base: Base) -> list[Probe]:
    from uavplace.rl.agent.config import DQNConfig
    from uavplace.rl.tasks.placement.config import EnvConfig

    keys = [k for k, f in DQNConfig.model_fields.items() if f.annotation in (int, float) and k != "seed"]
    keys += [f"env.{k}" for k, f in EnvConfig.model_fields.items() if f.annotation in (int, float)]
    probes = [Probe("set", "train (control)", lambda w: ["uavrl", *train_args(base.copy_root(w), w / "runs", "p")],
                    lambda w, r: run_check(w / "runs"), control=True)]  # fmt: skip
    for key in keys:
        for value in ("nan", "1e12"):

            def make(w: Path, key=key, value=value) -> list[str]:
                return ["uavrl", *train_args(base.copy_root(w), w / "runs", "p", "--set", f"{key}={value}")]

            probes.append(Probe("set", f"train --set {key}={value}", make, lambda w, r: run_check(w / "runs")))
    return probes


def _ingest(w: Path, city: Path) -> list[str]:
    return ["uavdata", "ingest", str(city), "--out", str(w / "root"), "--quiet"]


def _edit_text(rel: str, fn: Callable[[str], str]) -> Callable[[Path, Path], None]:
    def edit(city: Path, w: Path) -> None:
        path = city / rel
        if path.suffix == ".gz":
            text = gzip.decompress(path.read_bytes()).decode()
            path.write_bytes(gzip.compress(fn(text).encode()))
        else:
            path.write_text(fn(path.read_text()))

    return edit


def _set_word(line_no: int, word: int, value: str) -> Callable[[str], str]:
    def fn(text: str) -> str:
        lines = text.splitlines()
        words = lines[line_no].split()
        words[word] = value
        lines[line_no] = " ".join(words)
        return "\n".join(lines) + "\n"

    return fn


def _cut_row(line_no: int, words: int) -> Callable[[str], str]:
    def fn(text: str) -> str:
        lines = text.splitlines()
        lines[line_no] = " ".join(lines[line_no].split()[:words])
        return "\n".join(lines) + "\n"

    return fn


def raw_probes(base: Base) -> list[Probe]:
    P1 = "tiny.power.t001_01.r002.p2m.gz"
    edits: dict[str, Callable[[Path, Path], None]] = {}
    for col, name in ((1, "x"), (2, "y"), (3, "z"), (4, "distance"), (5, "power")):
        for value in ("nan", "inf", "-inf", "1e308", "-1e308", "", "1,5", "0x10", "1e-400"):
            edits[f"p2m row 1 {name}={value or 'missing'}"] = _edit_text(
                P1, _set_word(3, col, value) if value else _cut_row(3, col)
            )
    edits["p2m receiver number 2^63"] = _edit_text(P1, _set_word(3, 0, str(2**63)))
    edits["p2m receiver number 0"] = _edit_text(P1, _set_word(3, 0, "0"))
    edits["p2m duplicate receiver"] = _edit_text(P1, lambda t: t + t.splitlines()[3] + "\n")
    edits["p2m header 5 MB"] = _edit_text(P1, lambda t: "# " + "x" * 5_000_000 + "\n" + t)
    edits["p2m row 5 MB"] = _edit_text(P1, lambda t: t + "1 " * 2_500_000 + "\n")
    edits["p2m 200k rows"] = _edit_text(P1, lambda t: t + "".join(f"{k} 2 2 10 90 -70 0\n" for k in range(1000, 201_000)))
    edits["p2m only header"] = _edit_text(P1, lambda t: "\n".join(t.splitlines()[:3]) + "\n")
    edits["p2m empty"] = _edit_text(P1, lambda t: "")
    edits["p2m NUL bytes"] = _edit_text(P1, lambda t: t.replace("\n", "\x00\n", 5))
    edits["p2m CRLF"] = _edit_text(P1, lambda t: t.replace("\n", "\r\n"))
    edits["p2m columns shuffled"] = _edit_text(P1, lambda t: t.replace("<X(m)> <Y(m)>", "<Y(m)> <X(m)>"))
    edits["p2m unknown column"] = _edit_text(P1, lambda t: t.replace("<Phase(deg)>", "<Foo(bar)>"))

    def gz_bomb(rows: bool) -> Callable[[Path, Path], None]:
        def edit(city: Path, w: Path) -> None:
            text = gzip.decompress((city / P1).read_bytes()) if rows else b""
            with gzip.open(city / P1, "wb", compresslevel=9) as f:
                f.write(text)
                chunk = b" " * 2**20
                for _ in range(3000):  # 3 GiB of blanks (after the rows)
                    f.write(chunk)

        return edit

    edits["p2m gzip bomb 3 GiB after the rows"] = gz_bomb(True)
    edits["p2m gzip bomb 3 GiB alone"] = gz_bomb(False)
    edits["p2m truncated gzip"] = lambda city, w: (city / P1).write_bytes((city / P1).read_bytes()[:500])
    edits["p2m not gzip"] = lambda city, w: (city / P1).write_bytes(b"plain text, not gzip\n")
    edits["p2m is a folder"] = lambda city, w: ((city / P1).unlink(), (city / P1).mkdir())
    edits["p2m is a FIFO"] = lambda city, w: ((city / P1).unlink(), os.mkfifo(city / P1))
    edits["p2m symlink to /dev/zero"] = lambda city, w: ((city / P1).unlink(), (city / P1).symlink_to("/dev/zero"))
    edits["p2m symlink loop"] = lambda city, w: ((city / P1).unlink(), (city / P1).symlink_to(city / P1))
    edits["p2m unreadable"] = lambda city, w: (city / P1).chmod(0)
    edits["p2m name with newline"] = lambda city, w: (city / P1).rename(city / "tiny.power.t001_01.r002\n.p2m.gz")
    edits["p2m set name unknown"] = lambda city, w: (city / P1).rename(city / "tiny.power.t001_09.r002.p2m.gz")
    edits["p2m tx point 999"] = lambda city, w: (city / P1).rename(city / "tiny.power.t999_01.r002.p2m.gz")
    edits["p2m rx set 9"] = lambda city, w: (city / P1).rename(city / "tiny.power.t001_01.r009.p2m.gz")
    edits["p2m 2000 copies"] = lambda city, w: [
        shutil.copy(city / P1, city / f"tiny.power.t001_01.r002.c{k}.p2m.gz") for k in range(2000)
    ]
    txrx = "tiny.txrx"
    for old, new, name in (("spacing 4.000000", "spacing 0", "spacing 0"), ("spacing 4.000000", "spacing -4", "spacing -4"),
                           ("spacing 4.000000", "spacing nan", "spacing nan"), ("spacing 4.000000", "spacing 1e-9", "spacing 1e-9"),
                           ("side1 92.000000", "side1 1e12", "side 1e12"), ("side1 92.000000", "side1 -92", "side negative"),
                           ("nVertices 4", "nVertices 2000000000", "points claimed 2e9"), ("nVertices 4", "nVertices 3", "points fewer"),
                           ("nVertices 4", "nVertices 5", "points more"), ("73.075312 59.328244 1.500000", "nan 59.3 1.5", "point nan"),
                           ("73.075312 59.328244 1.500000", "1e300 59.3 1.5", "point 1e300"), ("power 20.00000", "power nan", "power nan"),
                           ("power 20.00000", "power 1e9", "power 1e9"), ("power 20.00000", "power -1e9", "power -1e9"),
                           ("project_id 1", "project_id 2", "set ids twice"), ("end_<grid>", "", "grid not ended"),
                           ("begin_<points> User", "begin_<points> User\nbegin_<points> Inner", "nested set"),
                           ("is_transmitter yes", "is_transmitter maybe", "bad yes/no"),
                           ("2.000000 2.000000 10.000000", "2 2 1e400", "grid corner 1e400")):  # fmt: skip
        edits[f"txrx {name}"] = _edit_text(txrx, lambda t, old=old, new=new: t.replace(old, new, 1))
    setup = "tiny.setup"
    for old, new, name in (("CarrierFrequency 800000000.000", "CarrierFrequency 0", "frequency 0"),
                           ("CarrierFrequency 800000000.000", "CarrierFrequency nan", "frequency nan"),
                           ("CarrierFrequency 800000000.000", "CarrierFrequency -8e8", "frequency negative"),
                           ("CarrierFrequency 800000000.000", "CarrierFrequency 1e300", "frequency 1e300"),
                           ("bandwidth 1000000.000", "bandwidth 0", "bandwidth 0"), ("type HalfWaveDipole", "type Yagi", "antenna unknown"),
                           ("filename tiny.city", "filename ../../../etc/passwd", "feature outside"),
                           ("filename tiny.city", "filename /dev/zero", "feature /dev/zero"),
                           ("filename tiny.city", "filename missing.city", "feature missing"),
                           ("power_threshold -250", "power_threshold nan", "threshold nan")):  # fmt: skip
        edits[f"setup {name}"] = _edit_text(setup, lambda t, old=old, new=new: t.replace(old, new, 1))
    city = "tiny.city"
    for old, new, name in (("46.654262 8.136910 37.000000", "nan 8.1 37", "vertex nan"),
                           ("46.654262 8.136910 37.000000", "1e300 8.1 37", "vertex 1e300"),
                           ("46.654262 8.136910 37.000000", "46.654262 8.136910 37000000", "roof 37000 km"),
                           ("46.654262 8.136910 37.000000", "46.654262 8.136910 -37", "roof below ground"),
                           ("nVertices 4", "nVertices 2000000000", "vertices claimed 2e9"), ("nVertices 4", "nVertices 2", "face of 2"),
                           ("nVertices 4", "nVertices -4", "vertices negative"), ("end_<city>", "", "city not ended"),
                           ("begin_<face> ", "begin_<face> \n" * 50000, "50000 faces begun")):  # fmt: skip
        edits[f"city {name}"] = _edit_text(city, lambda t, old=old, new=new: t.replace(old, new, 1))
    edits["city 20000 buildings"] = _edit_text(
        city,
        lambda t: t.replace(
            "end_<city>",
            "".join(
                f"begin_<structure> b{k}\nbegin_<sub_structure> 1\nbegin_<face> \nMaterial 1\nnVertices 4\n"
                f"{x} {y} 10\n{x + 1} {y} 10\n{x + 1} {y + 1} 10\n{x} {y + 1} 10\nend_<face>\nend_<sub_structure>\nend_<structure>\n"
                for k, (x, y) in enumerate((1000 + 2 * (i % 150), 1000 + 2 * (i // 150)) for i in range(20000))
            )
            + "end_<city>",
        ),
    )
    edits["simulation.json garbage"] = lambda city, w: (city / "simulation.json").write_bytes(b"\xff\xfe{[")
    edits["simulation.json 50 MB"] = lambda city, w: (city / "simulation.json").write_text('{"a": "' + "x" * 50_000_000 + '"}')
    edits["geojson beside, bad"] = lambda city, w: (city / "b.geojson").write_text(
        '{"type": "FeatureCollection", "features": [{}]}'
    )
    edits["ply beside, 2e9 vertices"] = lambda city, w: (city / "b.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 2000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n"
    )
    edits["obj beside, faces out of range"] = lambda city, w: (city / "b.obj").write_text("v 0 0 0\nv 1 0 0\nf 1 2 99\n")
    edits["xml beside, billion laughs"] = lambda city, w: (city / "scene.xml").write_text(
        '<?xml version="1.0"?><!DOCTYPE s [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">]><scene version="2.1.0">&b;</scene>'
    )
    edits["routes table, nan time"] = lambda city, w: (city / "tiny.routes.csv").write_text(
        "route,order,time_s,tx_set,tx_point,x_m,y_m,kind,speed_mps\n0,0,nan,1,1,73.075312,59.328244,pedestrian,1.4\n"
    )
    edits["(control) the city as it is"] = lambda city, w: None
    edits["folder empty"] = lambda city, w: [p.unlink() for p in city.iterdir()]
    edits["folder is a file"] = lambda city, w: (shutil.rmtree(city), city.write_text("x"))

    probes = []
    for name, edit in edits.items():

        def make(w: Path, edit=edit) -> list[str]:
            city = base.copy_raw(w)
            edit(city, w)
            return _ingest(w, city)

        probes.append(Probe("raw", name, make, lambda w, r: ingest_check(w / "root"), control=name.startswith("(control)")))
    return probes


def _bundle_dir(root: Path) -> Path:
    return root / "tiny" / (root / "tiny" / "latest").read_text().strip()


def _rehash(folder: Path, name: str) -> None:
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["files"][name] = hashlib.sha256((folder / name).read_bytes()).hexdigest()
    (folder / "manifest.json").write_text(json.dumps(manifest))


def _edit_array(name: str, fn: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path], None]:
    def edit(folder: Path) -> None:
        with np.load(folder / "maps.npz") as z:
            arrays = {k: z[k] for k in z.files}
        arrays[name] = fn(arrays[name])
        np.savez(folder / "maps.npz", **arrays)
        _rehash(folder, "maps.npz")

    return edit


def _edit_manifest(path: list[str], value: object) -> Callable[[Path], None]:
    def edit(folder: Path) -> None:
        manifest = json.loads((folder / "manifest.json").read_text())
        node = manifest
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = value
        (folder / "manifest.json").write_text(json.dumps(manifest))

    return edit


def _edit_users(fn: Callable[[pd.DataFrame], pd.DataFrame]) -> Callable[[Path], None]:
    def edit(folder: Path) -> None:
        t = pd.read_parquet(folder / "users.parquet")
        fn(t).to_parquet(folder / "users.parquet", index=False)
        _rehash(folder, "users.parquet")

    return edit


def bundle_probes(base: Base) -> list[Probe]:
    edits: dict[str, Callable[[Path], None]] = {}
    for array in ("sinr_db", "height_rel_m", "blocked", "dead", "x_m", "y_m", "building_id"):
        for name, fn in (("nan", lambda a: np.where(np.arange(a.size).reshape(a.shape) == 0, np.nan, a) if a.dtype.kind == "f" else a),
                         ("1e30", lambda a: np.full_like(a, 1e30) if a.dtype.kind == "f" else a),
                         ("one value short", lambda a: a.ravel()[:-1]),
                         ("float16", lambda a: a.astype(np.float16)),
                         ("object", lambda a: a.astype(object)),
                         ("all max", lambda a: np.full_like(a, np.iinfo(a.dtype).max if a.dtype.kind in "iu" else True if a.dtype == bool else 1e4)),
                         ("shuffled", lambda a: np.random.default_rng(0).permutation(a.ravel()).reshape(a.shape))):  # fmt: skip
            if name == "object":
                edits[f"{array} {name}"] = lambda f, array=array: (
                    np.savez(f / "maps.npz", **{array: np.array([{"a": 1}], dtype=object)}),
                    _rehash(f, "maps.npz"),
                )
            else:
                edits[f"{array} {name}"] = _edit_array(array, fn)
    for path, value in ((["grid", "spacing_m"], 0), (["grid", "spacing_m"], -4), (["grid", "num_x"], 10**9), (["grid", "num_x"], 0),
                        (["grid", "x_min_m"], 1e308), (["config", "noise_dbm"], 1e400), (["config", "p_t_db"], -1e300),
                        (["num_users"], 10**9), (["version"], "../../x"), (["city"], "../etc"), (["files", "maps.npz"], "0" * 64),
                        (["schema_version"], 999), (["config", "grid_m"], "four")):  # fmt: skip
        edits[f"manifest {'.'.join(path)}={value}"] = _edit_manifest(path, value)
    edits["manifest not JSON"] = lambda f: (f / "manifest.json").write_text("{")
    edits["manifest 100 MB"] = lambda f: (f / "manifest.json").write_text('{"x": "' + "y" * 100_000_000 + '"}')
    edits["manifest deeply nested"] = lambda f: (f / "manifest.json").write_text("[" * 100_000 + "]" * 100_000)
    edits["users ids shifted"] = _edit_users(lambda t: t.assign(user=t["user"] + 100) if "user" in t else t.iloc[::-1])
    edits["users duplicated"] = _edit_users(lambda t: pd.concat([t, t]))
    edits["users none"] = _edit_users(lambda t: t.iloc[:0])
    edits["users x nan"] = _edit_users(lambda t: t.assign(x_m=np.nan))
    edits["users split unknown"] = _edit_users(lambda t: t.assign(split="holdout"))
    edits["users parquet garbage"] = lambda f: (
        (f / "users.parquet").write_bytes(b"PAR1garbagePAR1"),
        _rehash(f, "users.parquet"),
    )
    edits["maps zip bomb header"] = lambda f: _huge_header(f)
    edits["latest points outside"] = lambda f: (f.parent / "latest").write_text("../../../../tmp")
    edits["latest empty"] = lambda f: (f.parent / "latest").write_text("")
    edits["latest 10 MB"] = lambda f: (f.parent / "latest").write_text("a" * 10_000_000)
    edits["bundle folder a symlink outside"] = lambda f: (shutil.rmtree(f), f.symlink_to("/etc"))
    edits["maps.npz a FIFO"] = lambda f: ((f / "maps.npz").unlink(), os.mkfifo(f / "maps.npz"))
    edits["(control) the bundle as it is"] = lambda f: None
    probes = []
    for name, edit in edits.items():

        def make(w: Path, edit=edit) -> list[str]:
            root = base.copy_root(w)
            edit(_bundle_dir(root))
            return ["uavrl", "baselines", "--dataset", "tiny", "--root", str(root), "--episodes", "8"]

        probes.append(Probe("bundle", name, make, control=name.startswith("(control)")))
    return probes


def _huge_header(folder: Path) -> None:
    buf = Path(tempfile.mkstemp(suffix=".npy")[1])
    header = {"descr": "<f4", "fortran_order": False, "shape": (1000, 1000, 1000, 1000)}
    with open(buf, "wb") as f:
        np.lib.format.write_array_header_1_0(f, header)
        f.write(b"\0" * 64)
    with np.load(folder / "maps.npz") as z:
        arrays = {k: z[k] for k in z.files}
    with zipfile.ZipFile(folder / "maps.npz", "w") as zf:
        for k, a in arrays.items():
            if k == "sinr_db":
                zf.write(buf, "sinr_db.npy")
            else:
                with zf.open(f"{k}.npy", "w") as f:
                    np.lib.format.write_array(f, a)
    buf.unlink()
    _rehash(folder, "maps.npz")


def _edit_run_json(fn: Callable[[dict], None]) -> Callable[[Path], None]:
    def edit(run: Path) -> None:
        doc = json.loads((run / "run.json").read_text())
        fn(doc)
        (run / "run.json").write_text(json.dumps(doc))

    return edit


def _edit_weights(fn: Callable[[dict], dict], name: str = "best.pt") -> Callable[[Path], None]:
    def edit(run: Path) -> None:
        import torch

        path = run / "checkpoints" / name
        state = torch.load(path, map_location="cpu", weights_only=True)
        torch.save(fn(state), path)

    return edit


def _first_tensor(state: dict, fn: Callable) -> dict:  # noqa: ANN001
    import torch

    for k, v in state.items():
        if isinstance(v, torch.Tensor) and v.is_floating_point():
            state[k] = fn(v)
            return state
        if isinstance(v, dict):
            _first_tensor(v, fn)
            return state
    return state


def run_probes(base: Base) -> list[Probe]:
    import torch

    edits: dict[str, Callable[[Path], None]] = {
        "weights nan": _edit_weights(lambda s: _first_tensor(s, lambda t: t * float("nan"))),
        "weights inf": _edit_weights(lambda s: _first_tensor(s, lambda t: t + float("inf"))),
        "weights 1e38": _edit_weights(lambda s: _first_tensor(s, lambda t: torch.full_like(t, 1e38))),
        "weights wrong shape": _edit_weights(lambda s: _first_tensor(s, lambda t: t.ravel()[:-1])),
        "weights float64": _edit_weights(lambda s: _first_tensor(s, lambda t: t.double())),
        "weights empty dict": _edit_weights(lambda s: {}),
        "weights a list": _edit_weights(lambda s: [1, 2, 3]),
        "weights not torch": lambda r: (r / "checkpoints" / "best.pt").write_bytes(b"not a checkpoint"),
        "weights empty file": lambda r: (r / "checkpoints" / "best.pt").write_bytes(b""),
        "weights missing": lambda r: (r / "checkpoints" / "best.pt").unlink(),
        "weights a FIFO": lambda r: ((r / "checkpoints" / "best.pt").unlink(), os.mkfifo(r / "checkpoints" / "best.pt")),
    }
    for key, value in (("hidden", 10**9), ("hidden", 0), ("conv_channels", [100000, 100000, 100000]), ("fovea", 10**6),
                       ("network", "resnet"), ("agent", "oracle"), ("window", 10**6), ("total_steps", -5), ("dropout", float("nan")),
                       ("ensemble", 10**6), ("buffer_size", 10**13), ("batch_size", 10**9), ("eval_episodes", 10**9)):  # fmt: skip

        def set_config(doc: dict, key=key, value=value) -> None:
            target = doc["config"]["env"] if key == "window" else doc["config"]
            target[key] = value

        edits[f"run.json {key}={value}"] = _edit_run_json(set_config)
    edits["run.json not JSON"] = lambda r: (r / "run.json").write_text("{")
    edits["run.json datasets test city renamed"] = _edit_run_json(lambda d: d.update(datasets={"TINY": "0" * 12}))
    edits["run.json extra field"] = _edit_run_json(lambda d: d.update(extra=1))
    probes = []
    for name, edit in edits.items():

        def make(w: Path, edit=edit) -> list[str]:
            root = base.copy_root(w)
            run = base.copy_run(w)
            edit(run)
            return ["uavrl", *report_args(root, run, w / "rep")]

        probes.append(Probe("run", f"report of {name}", make, lambda w, r: report_check(w / "rep")))
    probes.insert(0, Probe("run", "report of the run (control)", lambda w: ["uavrl", *report_args(base.copy_root(w), base.copy_run(w), w / "rep")],
                           lambda w, r: report_check(w / "rep"), control=True))  # fmt: skip
    for key, value in ((None, None), ("step", -1), ("step", 10**12), ("step", "nan"), ("updates", -1),
                       ("losses", [float("nan")] * 3), ("rng", {"x": 1}), ("best_score", [2.0, -1.0])):  # fmt: skip

        def make(w: Path, key=key, value=value) -> list[str]:
            root = base.copy_root(w)
            out = w / "runs"
            r = finish(start(["uavrl", *train_args(root, out, "p", "--until", "128")], w), time.monotonic(), 300)
            if r.rc != 0:
                raise RuntimeError(r.stderr[-500:])
            if key is not None:
                path = out / "p" / "checkpoints" / "last" / "checkpoint.json"
                doc = json.loads(path.read_text())
                doc[key] = value
                path.write_text(json.dumps(doc))
            return ["uavrl", "train", "--resume", str(out / "p"), "--root", str(root)]

        name = "resume (control)" if key is None else f"resume with checkpoint.json {key}={value}"
        probes.append(Probe("run", name, make, lambda w, r: run_check(w / "runs"), timeout=180, control=key is None))
    for archive in ("replay.npz", "env.npz"):

        def make(w: Path, archive=archive) -> list[str]:
            root = base.copy_root(w)
            out = w / "runs"
            r = finish(start(["uavrl", *train_args(root, out, "p", "--until", "128")], w), time.monotonic(), 300)
            if r.rc != 0:
                raise RuntimeError(r.stderr[-500:])
            path = out / "p" / "checkpoints" / "last" / archive
            with np.load(path) as z:
                arrays = {k: z[k] for k in z.files}
            k0 = (
                next(k for k, a in arrays.items() if a.dtype.kind == "f")
                if any(a.dtype.kind == "f" for a in arrays.values())
                else next(iter(arrays))
            )
            arrays[k0] = np.full_like(arrays[k0], np.nan) if arrays[k0].dtype.kind == "f" else arrays[k0][:1]
            np.savez(path, **arrays)
            return ["uavrl", "train", "--resume", str(out / "p"), "--root", str(root)]

        probes.append(Probe("run", f"resume with {archive} edited", make, lambda w, r: run_check(w / "runs"), timeout=180))
    return probes


def race_probes(base: Base) -> list[Probe]:
    def two_trains(w: Path) -> list[list[str]]:
        root = base.copy_root(w)
        return [["uavrl", *train_args(root, w / "runs", "same", "--seed", "0")],
                ["uavrl", *train_args(root, w / "runs", "same", "--seed", "1")]]  # fmt: skip

    def trains_check(w: Path, results: list[Result]) -> str | None:
        if all(r.rc == 0 for r in results):
            return "both trainings of one name exited 0"
        return run_check(w / "runs")

    def ingest_and_build(w: Path) -> list[list[str]]:
        root = base.copy_root(w)
        city = base.copy_raw(w)
        (city / "tiny.power.t004_01.r002.p2m.gz").unlink()  # the new ingest has 3 users, the old 4
        return [["uavdata", "ingest", str(city), "--out", str(root), "--quiet"],
                ["uavdata", "build", "--root", str(root), "--grid", "4m", "--alt", "10", "--force"]]  # fmt: skip

    def consistent(w: Path, results: list[Result]) -> str | None:
        """Every bundle's users table holds as many users as its manifest, and its recorded inputs are the ingest's
        files it was built from (a rebuild of the same version gives the same users)."""
        root = w / "root"
        for manifest in root.glob("tiny/[0-9a-f]*/manifest.json"):
            m = json.loads(manifest.read_text())
            users = pd.read_parquet(manifest.parent / "users.parquet")
            if len(users) != m.get("num_users", len(users)):
                return f"{manifest.parent.name}: {len(users)} users in the table, {m.get('num_users')} in the manifest"
        check_root = w / "check"
        shutil.copytree(root, check_root)
        for manifest in check_root.glob("tiny/[0-9a-f]*/manifest.json"):
            shutil.rmtree(manifest.parent)
        r = finish(start(["uavdata", "build", "--root", str(check_root), "--grid", "4m", "--alt", "10"], w),
                   time.monotonic(), 120)  # fmt: skip
        if r.rc != 0:
            return None
        for fresh in check_root.glob("tiny/[0-9a-f]*/users.parquet"):
            held = root / "tiny" / fresh.parent.name / "users.parquet"
            if held.is_file() and not pd.read_parquet(held).equals(pd.read_parquet(fresh)):
                return f"bundle {fresh.parent.name}: its users are not those of the ingest its version names"
        return bundle_check(root)

    def two_builds(w: Path) -> list[list[str]]:
        root = base.copy_root(w)
        args = ["uavdata", *build_args(root, "--force")]
        return [args, args]

    def two_reports(w: Path) -> list[list[str]]:
        root = base.copy_root(w)
        args = ["uavrl", *report_args(root, base.run, w / "rep")]
        return [args, [*args, "--seed", "1"]]

    def two_ingests(w: Path) -> list[list[str]]:
        city = base.copy_raw(w)
        return [_ingest(w, city), _ingest(w, city)]

    def two_resumes(w: Path) -> list[list[str]]:
        root = base.copy_root(w)
        out = w / "runs"
        r = finish(start(["uavrl", *train_args(root, out, "p", "--until", "128")], w), time.monotonic(), 300)
        if r.rc != 0:
            raise RuntimeError(r.stderr[-500:])
        return [["uavrl", "train", "--resume", str(out / "p"), "--root", str(root)]] * 2

    def resumes_check(w: Path, results: list[Result]) -> str | None:
        if all(r.rc == 0 for r in results):
            return "two resumes of one run both exited 0"
        return run_check(w / "runs")

    return [
        Probe("race", "two trainings of one name", two_trains, trains_check, timeout=240),
        Probe("race", "ingest beside build --force", ingest_and_build, consistent, timeout=180),
        Probe("race", "two builds --force", two_builds, consistent, timeout=180),
        Probe("race", "two reports into one folder", two_reports, lambda w, r: report_check(w / "rep"), timeout=180),
        Probe("race", "two ingests of one city", two_ingests, lambda w, r: ingest_check(w / "root"), timeout=120),
        Probe("race", "two resumes of one run", two_resumes, resumes_check, timeout=300),
    ]


def fs_probes(base: Base) -> list[Probe]:
    def readonly(w: Path) -> Path:
        d = w / "ro"
        d.mkdir()
        d.chmod(0o555)
        return d

    def a_file(w: Path) -> Path:
        (w / "f").write_text("x")
        return w / "f"

    def readonly_root(w: Path) -> list[str]:
        root = base.copy_root(w)
        shutil.rmtree(_bundle_dir(root))
        _chmod_tree(root, 0o555)
        return ["uavdata", *build_args(root)]

    def report(w: Path, out: Path, *extra: str) -> list[str]:
        return ["uavrl", *report_args(base.copy_root(w), base.run, out, *extra)]

    def ensemble(w: Path, *runs: Path) -> list[str]:
        return ["uavrl", "ensemble", *map(str, runs), "--out", str(w / "e"), "--root", str(base.copy_root(w))]

    # As root (these machines), permissions do not stop a write: the read-only probes are then accepted.
    cases: dict[str, Callable[[Path], list[str]]] = {
        "ingest --out a file": lambda w: _ingest_to(base, w, a_file(w)),
        "ingest --out read-only": lambda w: _ingest_to(base, w, readonly(w) / "root"),
        "build --root missing": lambda w: ["uavdata", *build_args(w / "none")],
        "build --root read-only": readonly_root,
        "report --out a file": lambda w: report(w, a_file(w)),
        "report --markdown a folder": lambda w: report(w, w / "rep", "--markdown", str(w)),
        "train --out read-only": lambda w: ["uavrl", *train_args(base.copy_root(w), readonly(w), "p")],
        "train --resume not a run": lambda w: ["uavrl", "train", "--resume", str(w), "--root", str(base.copy_root(w))],
        "show --out read-only": lambda w: [
            "uavdata",
            "show",
            "tiny",
            "--root",
            str(base.copy_root(w)),
            "--out",
            str(readonly(w) / "x"),
        ],
        "show city ../..": lambda w: ["uavdata", "show", "../..", "--root", str(base.copy_root(w)), "--out", str(w / "x")],
        "train --dataset ../tiny": lambda w: ["uavrl", *train_args(base.copy_root(w), w / "runs", "p"), "--dataset", "../tiny"],
        "train --name ../escape": lambda w: ["uavrl", *train_args(base.copy_root(w), w / "runs", "../escape")],
        "ensemble of nothing": lambda w: ensemble(w, w / "none"),
        "ensemble of one run twice": lambda w: ensemble(w, base.run, base.run),
        "sweep spec missing": lambda w: ["uavrl", "sweep", str(w / "none.toml"), "--out", str(w / "s")],
        "sweep spec binary": lambda w: ["uavrl", "sweep", str(_binary(w / "s.toml")), "--out", str(w / "s")],
        "limit unknown": lambda w: ["uavdata", "--limit", "nope=1", "list"],
        "limit nan": lambda w: ["uavdata", "--limit", "grid_cells=nan", "list"],
        "limit below a bundle's grid": lambda w: [
            "uavdata",
            "--limit",
            "grid_cells=10",
            *build_args(base.copy_root(w), "--force"),
        ],
    }
    return [Probe("fs", name, make) for name, make in cases.items()]


def _binary(path: Path) -> Path:
    path.write_bytes(b"\xff\x00" * 100)
    return path


def _ingest_to(base: Base, w: Path, out: Path) -> list[str]:
    return ["uavdata", "ingest", str(base.copy_raw(w)), "--out", str(out), "--quiet"]


def _chmod_tree(root: Path, mode: int) -> None:
    for p in sorted(root.rglob("*"), reverse=True):
        if p.is_dir():
            p.chmod(mode)
    root.chmod(mode)


#: A sweep of one short trial on the base's training city (valid as it is: the third round's control runs it).
SWEEP = """datasets = ["tiny-routes"]
cities = ["tiny"]
episodes = 8
[[trials]]
name = "t"
preset = "fast"
seeds = [0]
steps = 128
eval_every = 64
settings = {num_envs = 8, buffer_size = 512, batch_size = 16, train_every = 4, learning_starts = 64, eval_episodes = 8, hidden = 16, conv_channels = [4, 8, 8], "env.t_max" = 30, eval_split = "null"}
"""


def _node(path: Path, kind: str) -> Path:
    """A FIFO or a character device (1, 5: like /dev/zero) of the probe's own, in its folder; never the machine's."""
    if kind == "fifo":
        os.mkfifo(path)
    else:
        os.mknod(path, 0o666 | 0o020000, os.makedev(1, 5))
    return path


def _unchanged(path: Path, mode: int, data: bytes | None = None) -> Callable[[Path, list[Result]], str | None]:
    """A check that ``path`` is still the kind of file it was (and holds ``data``)."""

    def check(w: Path, results: list[Result]) -> str | None:
        if not os.path.lexists(path) or os.lstat(path).st_mode != mode:
            return f"{path.name} was replaced or removed"
        if data is not None and path.read_bytes() != data:
            return f"{path.name} was rewritten"
        return None

    return check


def round3_probes(base: Base) -> list[Probe]:
    """Issue 50's classes: sweeps and their output folders, ensembles at once, outputs that are devices, FIFOs or
    links, records that are FIFOs, Mitsuba instances, routes, the limits on products, duplicated runs and groups."""
    probes: list[Probe] = []

    def spec(w: Path, text: str = SWEEP) -> Path:
        (w / "s.toml").write_text(text)
        return w / "s.toml"

    def sweep(w: Path, *extra: str, path: Path | None = None) -> list[str]:
        return ["uavrl", "sweep", str(path or spec(w)), "--out", str(w / "O"), "--root", str(base.copy_root(w)), *extra]

    def thesis(w: Path) -> list[str]:
        (w / "O" / "t-s0").mkdir(parents=True)
        (w / "O" / "t-s0" / "thesis.tex").write_text("x")
        return sweep(w)

    def kept_thesis(w: Path, results: list[Result]) -> str | None:
        thesis = w / "O" / "t-s0" / "thesis.tex"
        return None if thesis.is_file() and thesis.read_text() == "x" else "the user's thesis.tex was removed"

    probes += [
        Probe("round3", "control: a sweep of one trial", lambda w: sweep(w), timeout=600, control=True),
        Probe("round3", "sweep: a user's folder named like a trial", thesis, kept_thesis, always_check=True),
        Probe("round3", "sweep: spec a FIFO", lambda w: sweep(w, path=_node(w / "f.toml", "fifo"))),
        Probe("round3", "sweep: --cpus-per-trial 100000", lambda w: sweep(w, "--cpus-per-trial", "100000")),
        Probe("round3", "sweep: --ray-address nothing answers", lambda w: sweep(w, "--ray-address", "127.0.0.1:1")),
        Probe("round3", "sweep: --ray-address not an address", lambda w: sweep(w, "--ray-address", "head")),
        Probe(
            "round3",
            "sweep: a million seeds",
            lambda w: sweep(w, path=spec(w, SWEEP.replace("seeds = [0]", f"seeds = [{', '.join(map(str, range(1_000_000)))}]"))),
        ),  # fmt: skip
        Probe("round3", "sweep: nested 100000 deep", lambda w: sweep(w, path=spec(w, "a = " + "[" * 100_000 + "]" * 100_000))),
    ]
    if os.geteuid() == 0:
        probes.append(Probe("round3", "sweep: spec a character device", lambda w: sweep(w, path=_node(w / "z.toml", "char"))))

    def markdown(kind: str) -> Probe:
        def make(w: Path) -> list[str]:
            if kind == "link":
                (w / "target.md").write_text("mine")
                (w / "out.md").symlink_to(w / "target.md")
            else:
                _node(w / "out.md", kind)
            probe.check = _unchanged(w / "out.md", os.lstat(w / "out.md").st_mode)
            return ["uavrl", *report_args(base.copy_root(w), base.run, w / "rep", "--markdown", str(w / "out.md"))]

        probe = Probe("round3", f"report --markdown a {kind}", make, always_check=True)
        return probe

    probes += [markdown("fifo"), markdown("link")] + ([markdown("char")] if os.geteuid() == 0 else [])

    def two_ensembles(w: Path) -> list[list[str]]:
        root = base.copy_root(w)
        args = ["uavrl", "ensemble", str(base.run), str(base.run1), "--out", str(w / "E"), "--root", str(root)]
        return [args, args]

    def one_ensemble(w: Path, results: list[Result]) -> str | None:
        if all(r.rc == 0 for r in results):
            return "both ensembles into one folder exited 0"
        return None if (w / "E" / "run.json").is_file() else "no ensemble was kept"

    probes.append(Probe("round3", "two ensembles into one folder", two_ensembles, one_ensemble, timeout=300))

    def fifo_manifest(command: str) -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            root = base.copy_root(w)
            manifest = _bundle_dir(root) / "manifest.json"
            manifest.unlink()
            _node(manifest, "fifo")
            if command == "list":
                return ["uavdata", "list", "--root", str(root)]
            if command == "baselines":
                return ["uavrl", "baselines", "--dataset", "tiny", "--root", str(root), "--episodes", "4"]
            return ["uavrl", *report_args(root, base.run, w / "rep")]

        return make

    probes += [Probe("round3", f"{c}: a bundle's manifest.json a FIFO", fifo_manifest(c), timeout=60)
               for c in ("list", "baselines", "report")]  # fmt: skip

    def fifo_run_json(w: Path) -> list[str]:
        run = base.copy_run(w)
        (run / "run.json").unlink()
        _node(run / "run.json", "fifo")
        return ["uavrl", *report_args(base.copy_root(w), run, w / "rep")]

    probes.append(Probe("round3", "report: run.json a FIFO", fifo_run_json, timeout=60))

    def scene(group: str) -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            import trimesh

            (w / "meshes").mkdir()
            trimesh.creation.box(extents=(10, 10, 20)).export(w / "meshes" / "a.ply")
            shape = '<shape type="ply" id="a"><string name="filename" value="meshes/a.ply"/></shape>'
            body = {"instance": shape + '<shape type="instance" id="i"><ref id="a"/><transform name="to_world">'
                                        '<translate x="500"/></transform></shape>',
                    "shapegroup": f'<shape type="shapegroup" id="g">{shape}</shape><shape type="instance" id="i">'
                                  '<ref id="g"/><transform name="to_world"><translate x="500"/></transform></shape>'}[group]  # fmt: skip
            (w / "scene.xml").write_text(f'<scene version="2.1.0">{body}</scene>')
            return ["uavdata", "simulate", str(w / "scene.xml"), "--name", "s", "--out", str(w / "raw")]

        return make

    probes += [
        Probe("round3", f"simulate: a Mitsuba scene with a {g}", scene(g), timeout=120) for g in ("instance", "shapegroup")
    ]

    def routes(edit: Callable[[list[str]], list[str]]) -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            city = w / TWIN.name
            shutil.copytree(TWIN, city)
            path = next(city.glob("*.routes.csv"))
            path.write_text("\n".join(edit(path.read_text().splitlines())) + "\n")
            return _ingest(w, city)

        return make

    probes += [
        Probe("round3", "routes: a field over 128 kB", routes(lambda r: [*r[:2], r[2] + "," + "9" * 200_000, *r[3:]])),
        Probe(
            "round3",
            "routes: a byte-order mark",
            routes(lambda r: ["\ufeff" + r[0], *r[1:]]),
            lambda w, res: ingest_check(w / "root"),
        ),  # fmt: skip
        Probe(
            "round3",
            "routes: a pedestrian at 100 m/s",
            routes(lambda r: [r[0], *(x.replace(",pedestrian,1.4", ",pedestrian,100") for x in r[1:])]),
        ),  # fmt: skip
    ]

    def report(w: Path, *extra: str, run: Path | None = None) -> list[str]:
        return ["uavrl", *report_args(base.copy_root(w), run or base.run, w / "rep", *extra)]

    probes += [
        Probe("round3", "report: --episodes 1e6", lambda w: report(w, "--episodes", "1000000")),
        Probe(
            "round3",
            "report: tracking --horizon 100000",
            lambda w: ["uavrl", *tracking_args(base.copy_root(w), "--horizon", "100000")],
        ),
        # fmt: skip
        Probe("round3", "report: a run twice", lambda w: report(w, "--run", str(base.run) + "/")),
        Probe(
            "round3",
            "report: a run and a link to it",
            lambda w: (w / "link").symlink_to(base.run) or report(w, "--run", str(w / "link")),
        ),  # fmt: skip
        Probe("round3", "report: --group g=X,X", lambda w: report(w, "--group", f"g={base.run},{base.run}")),
        Probe("round3", "report: --group genie=X", lambda w: report(w, "--group", f"genie={base.run}")),
        Probe(
            "round3",
            "report: a run folder named as mathtext",
            lambda w: report(w, run=shutil.copytree(base.run, w / "$\\frac{a}{$")),
        ),  # fmt: skip
    ]
    return probes + cache_probes()


def cache_probes() -> list[Probe]:
    """``uavdata simulate --trace-cache``: a cache entry truncated, random, altered (its sha256 kept) or a FIFO. The
    damaged entries must be traced again (never a crash, the city written whole and the record saying so); the FIFO
    refused before any tracing."""
    args = ["procedural:tiny", "--name", "c", "--users", "2", "--samples", "1e5", "--seed", "1"]

    def simulate(w: Path) -> list[str]:
        return ["uavdata", "simulate", *args, "--out", str(w / "raw"), "--trace-cache", str(w / "cache"), "--quiet"]

    def damaged(edit: Callable[[Path], None]) -> Callable[[Path], list[str]]:
        def make(w: Path) -> list[str]:
            r = finish(start(simulate(w), w), time.monotonic(), 300)
            if r.rc != 0:
                raise RuntimeError(r.stderr[-500:])
            shutil.rmtree(w / "raw")
            edit(w / "cache" / "c.npz")
            return simulate(w)

        return make

    def traced_again(w: Path, results: list[Result]) -> str | None:
        record = json.loads((w / "raw" / "c" / "simulation.json").read_text())
        return (
            None if str(record.get("trace_cache", "")).startswith("traced again") else f"trace_cache: {record.get('trace_cache')}"
        )

    def altered(path: Path) -> None:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        first = next(k for k in arrays if k not in ("key", "sha256"))
        arrays[first] = arrays[first] * 2
        np.savez_compressed(path.with_name("x.npz"), **arrays)
        path.with_name("x.npz").replace(path)

    def fifo(w: Path) -> list[str]:
        (w / "cache").mkdir()
        _node(w / "cache" / "c.npz", "fifo")
        return simulate(w)

    return [
        Probe("round3", "control: simulate with a trace cache", simulate, timeout=300, control=True),
        Probe(
            "round3",
            "trace cache: an entry truncated",
            damaged(lambda p: p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])),
            traced_again,
            timeout=600,
        ),  # fmt: skip
        Probe(
            "round3",
            "trace cache: an entry of random bytes",
            damaged(lambda p: p.write_bytes(os.urandom(p.stat().st_size))),
            traced_again,
            timeout=600,
        ),  # fmt: skip
        Probe("round3", "trace cache: an entry altered, its sha256 kept", damaged(altered), traced_again, timeout=600),
        Probe("round3", "trace cache: the entry a FIFO", fifo, timeout=120),
    ]


FAMILIES = {"opt": option_probes, "set": set_probes, "raw": raw_probes, "bundle": bundle_probes, "run": run_probes,
            "race": race_probes, "fs": fs_probes, "round3": round3_probes}  # fmt: skip


def all_families() -> dict[str, Callable[[Base], list[Probe]]]:
    """These families and the fourth and fifth rounds', a surface each (tests/probes_round4.py and
    tests/probes_round5.py, which import this module's helpers: imported here, when the pass starts, not beside
    them)."""
    from tests.probes_round4 import FAMILIES as round4
    from tests.probes_round5 import FAMILIES as round5

    return FAMILIES | round4 | round5


# -- the pass -----------------------------------------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("runs/probes"), help="folder of the tables and the shared inputs")
    ap.add_argument(
        "--only",
        default="",
        help="families to run, comma-separated (" + ", ".join(all_families()) + "); also ID substrings after a colon: raw:gzip",
    )
    ap.add_argument(
        "--timeout", type=float, default=60.0, help="seconds a probe may run (race and resume probes state their own)"
    )
    ap.add_argument("--list", action="store_true", help="print the probes and exit")
    args = ap.parse_args(argv)
    family, _, pattern = args.only.partition(":")
    families = all_families()
    chosen = [f for f in (family.split(",") if family else families) if f]
    base = Base(args.out.resolve() / "base")
    probes = [p for f in chosen for p in families[f](base) if pattern in p.id]
    if args.list:
        for p in probes:
            print(f"{p.family}\t{p.id}")
        print(f"{len(probes)} probes")
        return 0
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, _stop)
    base.make(600)
    suffix = "" if not args.only else "-" + args.only.replace(",", "-").replace(":", "-").replace(" ", "_")
    partial = args.out / f"probes{suffix}.partial.csv"
    rows = pd.read_csv(partial, keep_default_na=False).to_dict("records") if partial.is_file() else []
    done = {(r["family"], r["id"]) for r in rows}
    for k, probe in enumerate(probes, 1):
        if (probe.family, probe.id) in done:
            continue
        work = Path(tempfile.mkdtemp(prefix="probe-", dir=args.out.resolve()))
        try:
            classify(probe, work, args.timeout)
        except Exception as exc:  # noqa: BLE001 - a probe that cannot be set up is reported, not fatal
            probe.outcome, probe.detail = "setup", f"{type(exc).__name__}: {str(exc)[:300]}"
        finally:
            _chmod_tree(work, 0o755) if work.exists() else None
            shutil.rmtree(work, ignore_errors=True)
        r = probe.results
        rows.append({"family": probe.family, "id": probe.id, "outcome": probe.outcome,
                     "exit": ";".join(str(x.rc) for x in r), "seconds": round(max((x.seconds for x in r), default=0), 1),
                     "peak_mib": round(max((x.peak_mib for x in r), default=0)), "detail": probe.detail})  # fmt: skip
        print(f"[{k}/{len(probes)}] {probe.outcome:9s} {rows[-1]['seconds']:6.1f} s {rows[-1]['peak_mib']:5d} MiB  {probe.family}: "
              f"{probe.id}" + (f"\n      {probe.detail}" if probe.outcome in (*BAD, "setup") else ""), flush=True)  # fmt: skip
        pd.DataFrame(rows).to_csv(partial, index=False)  # a pass stopped here continues from the next probe
    table = pd.DataFrame(rows)
    table.to_csv(args.out / f"probes{suffix}.csv", index=False)
    partial.unlink(missing_ok=True)
    write_markdown(table, args.out / f"probes{suffix}.md")
    counts = table["outcome"].value_counts().to_dict()
    print(f"{len(table)} probes: " + ", ".join(f"{v} {k}" for k, v in counts.items()))
    print(f"slowest {table['seconds'].max():.1f} s, peak {table['peak_mib'].max()} MiB")
    return 1 if table["outcome"].isin([*BAD, "setup"]).any() else 0


def write_markdown(table: pd.DataFrame, path: Path) -> None:
    counts = table.pivot_table(index="family", columns="outcome", values="id", aggfunc="count", fill_value=0)
    lines = ["# Probe pass", "", f"{len(table)} probes by `python -m tests.probes`; slowest "
             f"{table['seconds'].max():.1f} s, largest peak {table['peak_mib'].max()} MiB.", "",
             "| family | " + " | ".join(counts.columns) + " |", "|---|" + "---|" * len(counts.columns)]  # fmt: skip
    lines += [f"| {f} | " + " | ".join(str(int(v)) for v in row) + " |" for f, row in counts.iterrows()]
    bad = table[table["outcome"].isin([*BAD, "setup"])]
    lines += ["", f"## Failures ({len(bad)})", ""]
    lines += [f"- **{r.outcome}** `{r.family}: {r.id}` ({r.seconds} s, {r.peak_mib} MiB): {r.detail}" for r in bad.itertuples()]
    path.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    sys.exit(main())
