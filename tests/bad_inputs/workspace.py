"""What the bad-input cases are made from: fresh copies of a small good city, built data and an agent, and mutators."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import torch

from tests.conftest import write_grid_city

#: The good city every ingest case starts from: 6 x 5 receivers at 4 m, 2 users, path loss (and power) outputs.
PL1 = "city.pl.t001_01.r002.p2m"
POWER1 = "city.power.t001_01.r002.p2m"
HEADER_LINES = 3


def row_line(row: int) -> int:
    """File line of receiver row ``row`` (1-based) of a synthetic .p2m."""
    return HEADER_LINES + row


class Workspace:
    """One case's folder, with makers of good inputs to spoil. ``shared`` holds the built data made once per session."""

    def __init__(self, tmp: Path, shared: Path) -> None:
        self.tmp, self.shared = tmp, shared
        self.proc = tmp / "proc"

    # -- raw cities -------------------------------------------------------------------------------
    def city(self, name: str = "city", outputs: tuple[str, ...] = ("pl",), gz: bool = False) -> Path:
        return write_grid_city(self.tmp / "raw" / name, outputs=outputs, gz=gz)

    def ingest(self, folder: Path, *extra: str) -> list[str]:
        return ["ingest", str(folder), "--out", str(self.proc), "--quiet", *extra]

    @staticmethod
    def replace(path: Path, old: str, new: str) -> Path:
        text = path.read_text()
        assert old in text, (path, old)
        path.write_text(text.replace(old, new, 1))
        return path

    @staticmethod
    def set_field(path: Path, row: int, column: int, value: str) -> Path:
        """Receiver row ``row`` (1-based), word ``column`` (0 = receiver number) set to ``value``."""
        lines = path.read_text().splitlines()
        words = lines[row_line(row) - 1].split()
        words[column] = value
        lines[row_line(row) - 1] = " ".join(words)
        path.write_text("\n".join(lines) + "\n")
        return path

    def p2m(self, row: int, column: int, value: str, outputs: tuple[str, ...] = ("pl",), file: str = PL1) -> list[str]:
        city = self.city(outputs=outputs)
        self.set_field(city / file, row, column, value)
        return self.ingest(city)

    def edit(self, file: str, old: str, new: str, outputs: tuple[str, ...] = ("pl",)) -> list[str]:
        city = self.city(outputs=outputs)
        self.replace(city / file, old, new)
        return self.ingest(city)

    def add_file(self, name: str, content: str | bytes) -> list[str]:
        city = self.city()
        path = city / name
        path.write_bytes(content if isinstance(content, bytes) else content.encode())
        return self.ingest(city)

    def geojson(self, doc: object | str | bytes) -> list[str]:
        if isinstance(doc, str | bytes):
            return self.add_file("b.geojson", doc)
        return self.add_file("b.geojson", json.dumps(doc))

    def gz_body(self, mutate) -> list[str]:  # noqa: ANN001
        city = self.city(gz=True)
        path = city / (PL1 + ".gz")
        path.write_bytes(mutate(path.read_bytes()))
        return self.ingest(city)

    # -- built data -------------------------------------------------------------------------------
    def root(self) -> Path:
        """A copy of the built root: city ``city`` ingested and built (latest), a test city for reports."""
        dst = self.tmp / "root"
        if not dst.exists():
            shutil.copytree(self.shared / "root", dst)
        return dst

    def bundle(self) -> Path:
        root = self.root()
        version = (root / "city" / "latest").read_text().strip()
        return root / "city" / version

    def forge(self, name: str, data: bytes) -> Path:
        """Replace a bundle file and its sha256 in the manifest, so that only the content checks can catch it."""
        folder = self.bundle()
        (folder / name).write_bytes(data)
        manifest = json.loads((folder / "manifest.json").read_text())
        manifest["files"][name] = hashlib.sha256(data).hexdigest()
        (folder / "manifest.json").write_text(json.dumps(manifest))
        return self.root()

    def agent(self, trained_on: str = "elsewhere", version: str = "0123456789ab") -> Path:
        """A copy of a valid agent folder (untrained weights of the fast preset) trained on ``trained_on@version``."""
        dst = self.tmp / "agent"
        k = 0
        while dst.exists():
            k += 1
            dst = self.tmp / f"agent-{k}"
        shutil.copytree(self.shared / "agent", dst)
        run = json.loads((dst / "run.json").read_text())
        run["datasets"] = {trained_on: version}
        (dst / "run.json").write_text(json.dumps(run))
        return dst

    def report(self, *extra: str) -> list[str]:
        out = self.tmp / "reports" / "r"
        has_out = "--out" in extra
        return ["report", "--dataset", "city", "--root", str(self.root()), "--episodes", "4", "--quiet",
                *(() if has_out else ("--out", str(out))), *extra]  # fmt: skip

    def payload(self, path: Path, *, key: str = "online") -> Path:
        """A .pt whose unpickling would create ``PWNED`` beside it: the code-execution probe of a checkpoint."""
        torch.save({key: RunsCode(str(path.parent / "PWNED")), "config": {}}, path)
        return path

    def run_folder(
        self, *, networks: bytes | None = None, payload: bool = False, old_last: bool = False, step: float = 0
    ) -> Path:
        """A training run folder to resume: run.json of the fast preset on the built city, and a checkpoint (whose
        ``checkpoint.json`` holds ``step``, empty random-generator states and no networks unless given)."""
        from uavplace.rl.agent.config import preset_config
        from uavplace.rl.agent.runs import RunRecord

        run = self.tmp / "run"
        (run / "checkpoints" / "last").mkdir(parents=True)
        config = preset_config("fast", total_steps=64, buffer_size=256, num_envs=4)
        record = RunRecord(config=config, datasets={"city": "x"}, train_split=None, eval_split=None, command="",
                           uavplace_version="0", torch_version="0", created_utc="")  # fmt: skip
        (run / "run.json").write_text(record.model_dump_json())
        last = run / "checkpoints" / "last"
        if old_last:
            shutil.rmtree(last)
            self.payload(run / "checkpoints" / "last.pt")
            return run
        state = {"step": step, "updates": 0, "best_score": None, "synced_at": 0, "losses": [], "episodes_started": 0,
                 "rng": {}, "env_rng": {}, "wall_s": None}  # fmt: skip
        (last / "checkpoint.json").write_text(json.dumps(state))
        if payload:
            self.payload(last / "networks.pt")
        elif networks is not None:
            (last / "networks.pt").write_bytes(networks)
        return run


class RunsCode:
    """Pickles to a call of ``open(path, "w")``: unpickling it creates a file. A stand-in for any code."""

    def __init__(self, path: str) -> None:
        self.path = path

    def __reduce__(self):  # noqa: ANN204
        return (open, (self.path, "w"))
