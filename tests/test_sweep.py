"""``uavrl sweep``: training runs as Ray Tune trials in run folders of their own, resumable, and one table on the
validation cities from the report's evaluation."""

from __future__ import annotations

import json
import re

import pandas as pd
import pytest
from click.testing import CliRunner

from tests.conftest import write_grid_city
from uavplace.cli import uavrl
from uavplace.dataset.build import build_city
from uavplace.ingest.pipeline import ingest_city
from uavplace.schemas.bundle import BuildConfig

pytest.importorskip("ray.tune", reason="Ray Tune missing (pip install -e '.[sweep]')")

#: A tiny schedule: 128 steps, a few small networks (the settings of tests/test_agent.py's tiny runs).
TINY = """
datasets = ["tiny"]
cities = ["tiny-val"]
episodes = 24

[[trials]]
name = "t"
preset = "fast"
seeds = [0, 1]
steps = 128
eval_every = 64
settings = {num_envs = 8, buffer_size = 512, batch_size = 16, train_every = 4, learning_starts = 64, eval_episodes = 16, hidden = 16, conv_channels = [4, 8, 8], "env.t_max" = 30}

[[ensembles]]
name = "t-e01"
members = ["t-s0", "t-s1"]
"""


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("sweep")
    for name, seed, role in (("tiny", 5, "train"), ("tiny-val", 6, "val")):
        ingest_city(
            write_grid_city(tmp / "raw" / name, nx=12, ny=10, n_tx=4, outputs=("power",), seed=seed), tmp / "p", name=name
        )
        build_city(
            name,
            BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=-58.0, role=role, val_users=1 if role == "train" else 0),
            tmp / "p",
        )
    return tmp / "p"


@pytest.mark.slow
def test_sweep_trains_resumes_and_tables(tmp_path, root):
    """Two trials and their ensemble: each trial a normal run folder (the config `uavrl train` makes from the same
    options), a trial stopped before the sweep is continued, not restarted; the table plays every run on the
    validation city; a second call trains nothing."""
    from uavplace.eval.sweep import paired_differences, read_spec, validation_table
    from uavplace.rl.agent.runs import read_run_json
    from uavplace.rl.agent.train import Trainer

    spec_file = tmp_path / "tiny.toml"
    spec_file.write_text(TINY)
    out = tmp_path / "runs"
    configs = read_spec(spec_file).configs()
    Trainer(configs["t-s1"], ["tiny"], root, out / "t-s1", command="uavrl train --until 64").run(stop_at=64)
    args = ["sweep", str(spec_file), "--out", str(out), "--root", str(root), "--quiet"]
    res = CliRunner().invoke(uavrl, args)
    assert res.exit_code == 0, res.output
    assert "2 trials, 0 finished before; training t-s0, t-s1" in res.output
    assert "ensemble t-e01: validation" in res.output
    for name in ("t-s0", "t-s1"):
        record = read_run_json(out / name)
        assert record.config == configs[name] and record.config.total_steps == 128 and record.config.env.t_max == 30
        assert pd.read_parquet(out / name / "eval.parquet").step.max() == 128
    assert read_run_json(out / "t-s0").resumed == []
    assert [r.split(" (from")[1] for r in read_run_json(out / "t-s1").resumed] == [" step 64)"]  # continued, not restarted
    table = pd.read_csv(out / "sweep.csv")
    assert table["run"].tolist() == ["t-s0", "t-s1", "t-e01"] and (table["cities"] == "tiny-val").all()
    assert table["tiny-val success"].between(0, 1).all() and (table["tiny-val success_lo"] <= table["tiny-val success"]).all()
    assert "| t-e01 |" in (out / "sweep.md").read_text() and (out / "sweep.toml").read_text() == TINY
    res = CliRunner().invoke(uavrl, args)
    assert res.exit_code == 0 and "2 trials, 2 finished before" in res.output and "training" not in res.output

    # The table's episodes, kept for paired differences: a run minus another on the same episodes.
    played = {}
    again = validation_table([out / "t-s0", out / "t-s1"], None, root=root, episodes=40, played=played)
    assert list(played) == ["tiny-val"] and set(played["tiny-val"]) == {"t-s0", "t-s1", "genie"}
    frames = played["tiny-val"]
    assert again.set_index("run").loc["t-s1", "tiny-val success"] == pytest.approx(frames["t-s1"]["success"].mean())
    diffs = paired_differences(played, "t-s0", seed=0)
    assert list(diffs) == ["tiny-val"]  # one city: nothing pooled
    row = diffs["tiny-val"].set_index("stat").loc["success"]
    assert row["method"] == "t-s1" and row["against"] == "t-s0" and row["lo"] <= row["difference"] <= row["hi"]
    assert row["difference"] == pytest.approx(frames["t-s1"]["success"].mean() - frames["t-s0"]["success"].mean())
    pooled = paired_differences({"a": frames, "b": frames}, "t-s0", seed=0)["2 cities pooled"].set_index("stat")
    assert pooled.loc["success", "difference"] == pytest.approx(row["difference"])  # the same episodes twice


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('datasets = ["tiny"]\n[[trials]]\nname = "a"\nseed = [1]\n', "trials.0.seed: Extra inputs are not permitted"),
        ('datasets = ["tiny"]\n[[trials]]\nname = "a"\nsettings = {gama = 0.5}\n', "settings.set: 'gama=0.5'"),
        (
            'datasets = ["tiny"]\n[[trials]]\nname = "a"\n[[ensembles]]\nname = "e"\nmembers = ["a-s0", "b-s0"]\n',
            "b-s0 is not a run of the sweep",
        ),  # fmt: skip
        ('datasets = ["tiny"]\n[[trials]]\nname = "a"\nseeds = [0, 0]\n', "repeat a seed"),
        ('datasets = ["tiny"\n', "not a TOML file"),
        ('datasets = ["tiny"]\n[[trials]]\nname = "a"\nsettings = {seed = 3}\n', "seed (use the trial's seeds)"),
        ("a = " + "[" * 100_000 + "]" * 100_000, "not a TOML file (maximum recursion depth exceeded)"),
    ],
    ids=["unknown-field", "unknown-setting", "unknown-member", "seed-twice", "not-toml", "seed-as-a-setting", "deep"],
)
def test_sweep_refuses_bad_specs(tmp_path, text, message):
    """A bad sweep file is one error line naming the file and the field, before Ray starts or anything is written."""
    spec = tmp_path / "bad.toml"
    spec.write_text(text)
    res = CliRunner().invoke(uavrl, ["sweep", str(spec), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2 and str(spec) in res.output and message in " ".join(res.output.split()), res.output
    assert not (tmp_path / "out").exists()


def test_shipped_sweep_files_validate():
    """The sweep files in experiments/sweeps/ validate, and the `best` one trains what train_agents.sh trained."""
    from pathlib import Path

    from uavplace.eval.sweep import read_spec
    from uavplace.rl.agent.config import preset_config

    files = sorted(Path(__file__).parents[1].joinpath("experiments", "sweeps").glob("*.toml"))
    assert files
    specs = {f.stem: read_spec(f) for f in files}
    best = specs["best"].configs()
    assert list(best) == [f"best-s{s}" for s in range(9)] and best["best-s4"] == preset_config("best", seed=4)
    assert json.loads(json.dumps([e.members for e in specs["best"].ensembles]))[1] == ["best-s3", "best-s4", "best-s5"]


def test_sweep_removes_only_what_it_made(tmp_path, root):
    """A folder under --out that bears a trial's name but is not a run the sweep started is refused before Ray
    starts, never removed; a run of the trial's settings that never checkpointed is removed (nothing to continue)."""
    from uavplace.eval.sweep import _remove_unstarted, read_spec
    from uavplace.infra.files import write_model_json
    from uavplace.rl.agent.runs import RunRecord
    from uavplace.schemas import InputError

    spec_file = tmp_path / "s.toml"
    spec_file.write_text(TINY)
    out = tmp_path / "O"
    (out / "t-s0").mkdir(parents=True)
    (out / "t-s0" / "thesis.tex").write_text("x")
    res = CliRunner().invoke(uavrl, ["sweep", str(spec_file), "--out", str(out), "--root", str(root)])
    assert res.exit_code != 0 and "a sweep removes only what it made" in res.output, res.output
    assert (out / "t-s0" / "thesis.tex").read_text() == "x"

    config = read_spec(spec_file).configs()["t-s0"]
    record = RunRecord(config=config, datasets={}, train_split=None, eval_split=None, command="", uavplace_version="0",
                       torch_version="0", created_utc="0")  # fmt: skip
    write_model_json(record, out / "t-s0" / "run.json")
    with pytest.raises(InputError, match="thesis.tex"):  # a run's folder with the user's file in it
        _remove_unstarted(out / "t-s0", config)
    assert (out / "t-s0" / "thesis.tex").is_file()
    (out / "t-s0" / "thesis.tex").unlink()
    with pytest.raises(InputError, match="other settings"):
        _remove_unstarted(out / "t-s0", read_spec(spec_file).configs()["t-s1"])
    _remove_unstarted(out / "t-s0", config)
    assert not (out / "t-s0").exists()


def test_sweep_refuses_what_would_wait_forever(tmp_path, root):
    """More CPUs a trial than the machine has, a Ray address nothing answers and one that is not an address: one
    line each, within seconds, before any trial starts."""
    import time

    spec_file = tmp_path / "s.toml"
    spec_file.write_text(TINY)
    base = ["sweep", str(spec_file), "--out", str(tmp_path / "O"), "--root", str(root)]
    for extra, message in (
        (["--cpus-per-trial", "100000"], "--cpus-per-trial: 100000: this machine has"),
        (["--ray-address", "127.0.0.1:1"], "--ray-address: 127.0.0.1:1: nothing answers there"),
        (["--ray-address", "head-without-port"], "expected HOST:PORT, ray://HOST:PORT or auto"),
    ):
        t0 = time.monotonic()
        res = CliRunner().invoke(uavrl, [*base, *extra])
        assert res.exit_code == 2 and message in res.output, res.output
        assert time.monotonic() - t0 < 30
    assert not any((tmp_path / "O").glob("t-*"))


def test_a_sweep_of_a_million_seeds_is_refused_by_the_limit(tmp_path):
    """The limits bound what costs memory: the runs of a sweep file (trials x seeds), refused before one config is
    made."""
    import resource

    from uavplace.eval.sweep import read_spec
    from uavplace.schemas import InputError

    spec_file = tmp_path / "s.toml"
    spec_file.write_text(TINY.replace("seeds = [0, 1]", f"seeds = [{', '.join(map(str, range(1_000_000)))}]"))
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(InputError, match="sweep_runs"):
        read_spec(spec_file)
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 2 * 2**20  # KiB: under 2 GB more at the peak


def test_a_sweep_validated_on_its_own_training_city_is_refused(tmp_path, root):
    spec_file = tmp_path / "s.toml"
    spec_file.write_text(TINY.replace('cities = ["tiny-val"]', 'cities = ["tiny-val", "tiny"]'))
    res = CliRunner().invoke(uavrl, ["sweep", str(spec_file), "--out", str(tmp_path / "O"), "--root", str(root)])
    assert res.exit_code == 2 and "cities: tiny: a training city of the sweep is also a validation city" in res.output
    assert not (tmp_path / "O").exists()


def test_a_ray_address_that_answers_but_is_not_ray_is_refused_at_once(monkeypatch):
    """A port that accepts and never answers, and a web server, are refused in one line within the timeout (ray.init
    would retry them for ever); a server that answers as gRPC does (a Ray head, whose answer the project checked
    against `ray start --head`) passes."""
    import socket
    import threading

    from uavplace.infra import cluster
    from uavplace.schemas import InputError

    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT_S", 0.5)

    def server(reply: bytes | None) -> tuple[str, int]:
        listener = socket.create_server(("127.0.0.1", 0))

        def serve() -> None:
            conn, _ = listener.accept()
            with conn:
                conn.recv(64)
                if reply is not None:
                    conn.sendall(reply)
                threading.Event().wait(2.0)  # hold the connection open, silent

        threading.Thread(target=serve, daemon=True).start()
        return listener.getsockname()[:2]

    silent, web = server(None), server(b"HTTP/1.1 400 Bad Request\r\n\r\n")
    grpc = server(bytes([0, 0, 0, 4, 0, 0, 0, 0, 0]))  # an empty HTTP/2 SETTINGS frame: what a gRPC server sends first
    for endpoint, said in ((silent, "no answer"), (web, "an answer that is not gRPC (b'HTTP/1.1 ')")):
        address = f"{endpoint[0]}:{endpoint[1]}"
        with pytest.raises(InputError, match=rf"{address}: not a Ray head \({re.escape(said)}"):
            cluster.check_ray_head(address, endpoint)
    cluster.check_ray_head("grpc", grpc)


def test_more_local_workers_than_cpus_are_refused_before_ray_starts():
    """`report --workers 64` on 2 cores would start 64 Ray workers (3.9 GB) to share two cores: refused in one line
    before Ray starts."""
    import os

    import ray

    from uavplace.infra.cluster import start_ray
    from uavplace.schemas import InputError

    have = os.cpu_count() or 1
    with pytest.raises(InputError, match=rf"--workers: {have + 1}: this machine has {have} CPUs: give at most {have}"):
        start_ray(None, 1.0, "--workers", have + 1)
    assert not ray.is_initialized()
