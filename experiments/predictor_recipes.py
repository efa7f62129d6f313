"""Learned-predictor recipes judged by the searcher they serve, each on several training seeds, on validation cities.

Each ``--recipe NAME=OPTIONS`` (options of `uavrl train-predictor`, e.g. ``--maps data/trainmaps --steps 4000``) is
trained once per ``--seeds`` seed on the 22 training cities (corpus-000..015, oldtown-000..004, train) into
OUT/NAME-sSEED (a folder whose model.json was made by the same command, from the same bundles, packs and training code,
is kept: the script resumes), scored on the validation cities' users (model.json), then played by the map searcher (the
shipped settings) beside the shipped predictor's searcher and the genie on the same episodes of each validation city. A
recipe is worth keeping where it beats the shipped tier by more than its own seeds spread: the table gives each recipe's
mean over seeds and their range, per city, for SPL and median steps, and the predictor's scores the same way.

With ``--calibrate PACKS`` each trained tier is first calibrated on the packs in PACKS, cities none was trained on
(`uavrl calibrate-predictor`, into OUT/NAME-sSEED-cal), and judged so: the shipped tier's calibration was fitted so.

    python experiments/predictor_recipes.py --recipe 'packs4k=--maps data/trainmaps --steps 4000' --seeds 0 1 2
        [--episodes 300] [--city etoile-val] [--out runs/predictor/recipes] [--train-only] [--calibrate PACKS]

Validation cities only: a test city is refused. Each city's outcome is written to OUT/judged-<city>.json once its
episodes are played (the same predictors, episodes and seed are not played again).
"""

from __future__ import annotations

import importlib
import json
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
from common import VALIDATION, validation_parser

from uavplace.dataset.bundle import load_bundle, resolve
from uavplace.dataset.trainmaps import select_packs
from uavplace.eval.evaluate import ReportConfig, evaluate
from uavplace.eval.metrics import bootstrap_table
from uavplace.infra.console import markdown_table
from uavplace.infra.files import atomic_write_text, sha256_file
from uavplace.rl.belief import PREDICTIONS, PredictionCache
from uavplace.rl.config import DEFAULT_PREDICTOR, SearchConfig
from uavplace.rl.predictor import code_digest, load_predictor
from uavplace.rl.tasks.placement.policies import GeniePolicy
from uavplace.rl.tasks.placement.searcher import SEARCHER, MapSearchPolicy

#: The training cities of every recipe (the shipped tier's), before the recipe's own options.
TRAINING = [
    *(f"--dataset=corpus-{i:03d}" for i in range(16)),
    *(f"--dataset=oldtown-{i:03d}" for i in range(5)),
    "--dataset=train",
]
#: The cities every tier is scored on (model.json's scores, the table's error columns).
SCORED = [f"--val-dataset={c}" for c in VALIDATION]
#: What a model folder's record says made it.
COMMAND_FILE = "recipe-command.json"
SHIPPED = "shipped"


#: The code that trains and calibrates a tier beside the predictor family's own (``rl.predictor.code_digest``, which
#: covers its commands too): part of what made a model folder.
TRAINING_CODE = ("uavplace.rl.config", "uavplace.dataset.trainmaps")


def _option_values(command: list[str], name: str) -> list[str]:
    """Every value ``command`` gives option ``name`` (``--name value`` or ``--name=value``)."""
    values = [a.split("=", 1)[1] for a in command if a.startswith(name + "=")]
    return values + [command[i + 1] for i, a in enumerate(command[:-1]) if a == name]


def made_by(command: list[str], root: Path) -> dict:
    """What made a model folder: ``command``, the content of what it reads (each city's bundle version, which hashes the
    bundle's inputs and config; the packs its ``--maps`` and ``--packs`` select; the version of the ``--predictor`` it
    starts from) and the code. A folder whose record differs (more packs since, a rebuilt city, changed code) is made
    again."""
    packs = select_packs(_option_values(command, "--maps"), _option_values(command, "--packs"))
    return {
        "command": command,
        "bundles": {c: resolve(c, root=root).name for o in ("--dataset", "--val-dataset") for c in _option_values(command, o)},
        "packs": {str(p): sha256_file(p) for p in packs},
        "predictors": {f: load_predictor(Path(f)).version() for f in _option_values(command, "--predictor")},
        "code": {"predictor": code_digest()} | {m: sha256_file(importlib.import_module(m).__file__) for m in TRAINING_CODE},
    }


def made(folder: Path, command: list[str], root: Path) -> Path:
    """``folder`` made by ``command``, run unless a finished folder made by the same command, from the same inputs and
    code (``made_by``), is there already."""
    record, key = folder / COMMAND_FILE, made_by(command, root)
    if (folder / "model.json").is_file() and record.is_file() and json.loads(record.read_text()) == key:
        print(f"{folder}: made already, kept", flush=True)
        return folder
    print("$ " + shlex.join(command), flush=True)
    subprocess.run(command, check=True)
    atomic_write_text(record, json.dumps(key, indent=1))
    return folder


def train(name: str, options: str, seed: int, out: Path, root: Path) -> Path:
    """Train recipe ``name`` at ``seed`` into ``out/name-sSEED``."""
    folder = out / f"{name}-s{seed}"
    return made(folder, ["uavrl", "train-predictor", *TRAINING, *shlex.split(options), "--seed", str(seed), "--root",
                         str(root), *SCORED, "--out", str(folder), "--quiet"], root)  # fmt: skip


def calibrate(folder: Path, packs: Path, root: Path) -> Path:
    """``folder``'s network calibrated on the packs in ``packs`` (cities it was not trained on) into ``folder``-cal, as
    the shipped tier was (docs/predictor.md, "Calibration of the dead-cell probability")."""
    out = folder.with_name(folder.name + "-cal")
    return made(out, ["uavrl", "calibrate-predictor", "--predictor", str(folder), "--maps", str(packs), "--root", str(root),
                      *SCORED, "--out", str(out)], root)  # fmt: skip


def judge(city: str, tiers: dict[str, Path], args, out: Path) -> dict:  # noqa: ANN001 - the parsed arguments
    """The genie and a searcher per tier on the same ``args.episodes`` episodes of ``city``: each method's success,
    median steps and SPL (written to OUT/judged-<city>.json; read back when it holds the same tiers, by their versions:
    weights, calibration and code, and the same episodes)."""
    predictors = {n: load_predictor(p) for n, p in tiers.items()}
    key = {"tiers": {n: t.version() for n, t in predictors.items()}, "episodes": args.episodes, "seed": args.seed}
    path = out / f"judged-{city}.json"
    if path.is_file() and (held := json.loads(path.read_text())).get("key") == key:
        return held["methods"]
    bundle = load_bundle(city, root=args.root)
    if bundle.manifest.config.role == "test":
        sys.exit(f"{city} is a test city: release numbers come from `uavrl report`, never a choice")
    cache = PredictionCache(args.root / PREDICTIONS)
    policies = [GeniePolicy()] + [
        MapSearchPolicy(t, SearchConfig(), cache, name=f"{SEARCHER} [{n}]") for n, t in predictors.items()
    ]
    config = ReportConfig(dataset=city, episodes=args.episodes, seed=args.seed, predictor=None)
    table = bootstrap_table(evaluate(config, bundle, [], baselines=policies), n_boot=200, seed=args.seed)
    methods = {
        r["method"].removeprefix(f"{SEARCHER} [").removesuffix("]"): {k: float(r[k]) for k in ("success", "median_steps", "spl")}
        for r in table.to_dict("records")
    }
    atomic_write_text(path, json.dumps({"key": key, "methods": methods}, indent=1))
    return methods


def spread(values: list[float], digits: int) -> str:
    """Mean over seeds, with their range where there are several."""
    mean = f"{np.mean(values):.{digits}f}"
    return mean if len(values) == 1 else f"{mean} [{min(values):.{digits}f}, {max(values):.{digits}f}]"


def main() -> None:
    ap = validation_parser(__doc__, episodes=300)
    ap.add_argument("--recipe", action="append", required=True, help="NAME=OPTIONS of `uavrl train-predictor` (repeatable)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="Training seeds of every recipe")
    ap.add_argument("--out", type=Path, default=Path("runs/predictor/recipes"), help="Where the trained tiers go")
    ap.add_argument("--root", type=Path, default=Path("data/processed"))
    ap.add_argument("--shipped", type=Path, default=DEFAULT_PREDICTOR, help="The tier the recipes are set against")
    ap.add_argument("--train-only", action="store_true", help="Train (or resume training) and stop before the episodes")
    ap.add_argument(
        "--calibrate",
        type=Path,
        help="A folder of packs of cities no recipe trained on: every tier is "
        "calibrated on them (into NAME-sSEED-cal) and judged so, as the shipped tier was",
    )
    args = ap.parse_args()
    recipes = dict(r.split("=", 1) for r in args.recipe)
    if SHIPPED in recipes or len(recipes) != len(args.recipe):
        ap.error(f"--recipe: one NAME each, none called {SHIPPED!r}")
    args.out.mkdir(parents=True, exist_ok=True)
    tiers = {SHIPPED: args.shipped}
    for name, options in recipes.items():
        for seed in args.seeds:
            folder = train(name, options, seed, args.out, args.root)
            tiers[f"{name}-s{seed}"] = calibrate(folder, args.calibrate, args.root) if args.calibrate else folder
    if args.train_only:
        return
    groups = {SHIPPED: [SHIPPED]} | {n: [f"{n}-s{s}" for s in args.seeds] for n in recipes}
    rows = [["recipe", "city", "success", "median steps", "SPL", "median |error| [dB]", "p90 [dB]", "dead/live", "ECE"]]
    for city in args.city or VALIDATION:
        methods = judge(city, tiers, args, args.out)
        print(f"{city}: genie median {methods[GeniePolicy.name]['median_steps']:g} steps", flush=True)
        for group, members in groups.items():
            played = [methods[m] for m in members]
            scores = [json.loads((tiers[m] / "model.json").read_text())["scores"].get(city) for m in members]
            scores = [s for s in scores if s]
            cells = [spread([s[f"learned_{k}"] for s in scores], d) if scores else "" for k, d in
                     (("median_error_db", 1), ("p90_error_db", 1), ("dead_live_agreement", 3), ("calibration_error", 3))]  # fmt: skip
            rows.append([group, city, spread([100 * p["success"] for p in played], 1),
                         spread([p["median_steps"] for p in played], 1), spread([p["spl"] for p in played], 3), *cells])  # fmt: skip
    print(markdown_table(rows), flush=True)


if __name__ == "__main__":
    main()
