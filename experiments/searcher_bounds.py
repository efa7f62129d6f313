"""Bounds on the map searcher's steps, on validation cities: its excess over the genie split without an order.

On the episodes ``uavrl report`` draws for a city, these play the same episodes:

- the genie (the user's true map and position);
- the map searcher (predicted maps of every candidate cell, the position unknown);
- *the searcher told where the user is, within R cells*: the same searcher whose belief starts on the candidates
  within ``--radius`` cells (Chebyshev) of the user's cell instead of all of them, and is updated by its own
  measurements as the searcher's is: its steps above the genie's are what the predicted maps cost once the position
  is (nearly) known;
- with ``--true-maps``, *the searcher given the true maps*: the same searcher whose candidates are the city's users,
  each with its ray-traced map instead of a prediction, the position unknown: its steps above the genie's are what
  localisation costs with perfect maps. It needs a city whose users cover its open ground (every candidate traced),
  such as the dense validation crop this script's docstring names below;
- with ``--ceiling data/ceiling``, *the ceiling*: the searcher whose candidates are its own stride-2 lattice, each with
  the map ray-traced at that cell at the city's own settings (``experiments/ceiling_traces.py``, every candidate),
  the position unknown, and the same told where the user is: what prediction alone can reach, and what the planner
  leaves when the maps are true and the position nearly known.

Each share is measured against the searcher itself, so neither depends on the order in which they are taken:
localisation's share is searcher - told where; the maps' share is searcher - true maps; what is left of the excess
is their interaction.

The dense validation crop (a 120 x 120 m piece of etoile-val's region, 160 users sampled over its open ground; about
25 minutes of the 2 cores) and its bounds:

    uavdata simulate sionna:etoile --crop=260,-60,380,60 --name etoile-val-dense --users 160 --seed 11 \\
        --samples 1.6e7 --gap-fill-walk 4-neighbour --out runs/bounds/raw --trace-cache runs/traces
    uavdata ingest runs/bounds/raw/etoile-val-dense/ --out runs/bounds/processed
    uavdata build --grid 4m --alt 10 --root runs/bounds/processed --city etoile-val-dense
    python experiments/searcher_bounds.py --root runs/bounds/processed --city etoile-val-dense --true-maps [--p-t-db 20]

A built-up one, 120 x 120 m of florence-val's region where buildings above the UAV cover half the cells (51 %), the
same way (66 minutes of tracing on 2 cores shared with other work; docs/searcher.md has its bounds):

    uavdata simulate sionna:florence --crop=322,32,442,152 --name florence-val-dense --users 160 --seed 12 \
        --samples 1.6e7 --gap-fill-walk 4-neighbour --out runs/bounds/raw --trace-cache runs/traces

    python experiments/searcher_bounds.py [--city etoile-val] [--episodes 300] [--radius 2]
    python experiments/searcher_bounds.py --city etoile-val --ceiling data/ceiling

Test cities are refused: nothing is learnt from them.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pandas as pd
from common import VALIDATION, validation_parser
from searcher_steps import user_cells

from uavplace.dataset.bundle import Bundle, load_bundle
from uavplace.dataset.trainmaps import read_pack, select_packs
from uavplace.eval.evaluate import ReportConfig, evaluate
from uavplace.eval.metrics import resample_counts
from uavplace.infra.console import markdown_table
from uavplace.rl.belief import PREDICTIONS, CandidateMaps, PredictionCache, candidate_cells
from uavplace.rl.config import DEFAULT_PREDICTOR, SearchConfig
from uavplace.rl.predictor import load_predictor
from uavplace.rl.tasks.placement.policies import GeniePolicy
from uavplace.rl.tasks.placement.searcher import SEARCHER, MapSearchPolicy
from uavplace.rl.world.view import AgentView, PublicMaps, public_maps
from uavplace.schemas.constants import P_T_DB

TOLD = "searcher told where (within R cells)"
TRUE_MAPS = "searcher given the true maps"
CEILING = "searcher given the true maps (ceiling)"
CEILING_TOLD = "told where, given the true maps (ceiling)"


class OracleSearch(MapSearchPolicy):
    """The searcher told more than the UAV knows (an oracle: it reads the env): with ``radius``, where the user is (its
    belief starts on the candidates within ``radius`` cells, Chebyshev, of the user's cell, the nearest where none is
    that near, then is updated by its own measurements); with ``truth``, the true maps of its candidates instead of
    predictions (``(cells [C, 2], SINR [C, ny, nx], dead [C, ny, nx])``, unturned maps only, as the report plays
    them). Both: what the planner leaves with perfect maps and the position nearly known."""

    privileged = True

    def __init__(
        self,
        *args: object,
        name: str,
        radius: int | None = None,
        truth: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
        **kwargs: object,
    ) -> None:
        super().__init__(*args, name=name, **kwargs)
        self.radius, self.truth = radius, truth
        self._users: dict[int, np.ndarray] = {}
        self._row_users = np.zeros((0, 2), np.int64)

    def act(self, obs: np.ndarray, mask: np.ndarray, env: object) -> np.ndarray:
        if self.radius is not None:
            self._row_users = user_cells(env, self._users)
        return super().act(obs, mask, AgentView(env, public_maps(env)))

    def prior(self, maps: CandidateMaps, row: int) -> np.ndarray:
        if self.radius is None:
            return super().prior(maps, row)
        gap = np.abs(maps.cells - self._row_users[row]).max(axis=1)
        near = gap <= max(self.radius, int(gap.min()))
        return np.where(near, 0.0, -1e30).astype(np.float32)

    def canvas_maps(self, public: PublicMaps, canvas: int) -> CandidateMaps:
        if self.truth is None:
            return super().canvas_maps(public, canvas)
        key = ("true", canvas)
        if key not in self._canvases:
            if public.symmetry_of(canvas) != 0:
                raise ValueError("the true-maps searcher plays unturned maps only")
            cells, sinr_db, dead = self.truth
            legal = np.argwhere(public.legal(canvas))
            index = np.full(sinr_db.shape[1:], -1, np.int64)
            index[legal[:, 0], legal[:, 1]] = np.arange(len(legal))
            mu = sinr_db[:, legal[:, 0], legal[:, 1]].astype(np.float32)
            p_dead = dead[:, legal[:, 0], legal[:, 1]].astype(np.float32)
            cover = self.cover(mu, p_dead, public.config.p_t_db)
            self._canvases[key] = CandidateMaps(cells, legal, index, mu, p_dead, cover)
        return self._canvases[key]


def bundle_truth(bundle: Bundle) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The true maps of ``bundle``'s users, as ``OracleSearch`` takes them."""
    users = bundle.user_indices()
    return bundle.user_cells(users), bundle.sinr_db[users], bundle.dead[users]


def ceiling_truth(bundle: Bundle, folder: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The true maps of every stride-2 candidate of ``bundle``'s city from the ceiling's packs in ``folder``
    (``experiments/ceiling_traces.py``), checked to be the city's grid and heights and to hold every candidate."""
    paths = sorted(select_packs([folder], [f"{bundle.city}-ceil-*"]))
    packs = [read_pack(p) for p in paths]
    expected = candidate_cells(np.maximum(bundle.height_rel_m + bundle.altitude_m, 0), SearchConfig().stride, True)
    cells = np.concatenate([p.users for p in packs]) if packs else np.zeros((0, 2), np.int64)
    for path, pack in zip(paths, packs, strict=True):
        if pack.height_rel_m.shape != bundle.height_rel_m.shape or not np.array_equal(pack.blocked, bundle.blocked):
            raise SystemExit(f"{path}: not {bundle.city}'s grid and buildings")
    if len(cells) != len(expected) or not np.array_equal(np.unique(cells, axis=0), np.unique(expected, axis=0)):
        raise SystemExit(f"{folder}: {len(cells)} of {bundle.city}'s {len(expected)} candidates traced: the ceiling needs all")
    return cells, np.concatenate([p.sinr_db for p in packs]), np.concatenate([p.dead for p in packs])


def mean_with_interval(diff: pd.Series, users: np.ndarray, n_boot: int = 2000, seed: int = 0) -> str:
    """The mean of a paired per-episode difference and its 95 % interval, resampling users then their episodes (as
    the report's intervals, ``eval.metrics.resample_counts``): ``"12.3 [8.1, 16.0]"``."""
    counts = resample_counts(users, len(diff), n_boot, seed)
    means = counts @ diff.to_numpy(np.float64) / counts.sum(axis=1)
    lo, hi = np.quantile(means, [0.025, 0.975])
    return f"{diff.mean():.1f} [{lo:.1f}, {hi:.1f}]"


def main() -> None:
    ap = validation_parser(__doc__, episodes=300)
    ap.add_argument("--radius", type=int, default=2, help="Cells (Chebyshev) of the told-where oracle's first belief")
    ap.add_argument("--true-maps", action="store_true", help="Also the searcher given every user's true map")
    ap.add_argument(
        "--ceiling",
        type=Path,
        help="Also the searcher given every candidate's true map from the ceiling's packs here (data/ceiling), and told "
        "where with them",
    )
    ap.add_argument("--p-t-db", type=float, default=P_T_DB, help="The SINR target P_T [dB] (a harder target on an easy crop)")
    ap.add_argument("--root", type=Path, default=Path("data/processed"))
    args = ap.parse_args()
    predictor = load_predictor(DEFAULT_PREDICTOR)
    cache = PredictionCache(args.root / PREDICTIONS)
    truths = ([TRUE_MAPS] if args.true_maps else []) + ([CEILING, CEILING_TOLD] if args.ceiling else [])
    head = ["city", "genie", "map searcher", TOLD, *truths]
    head += ["mean excess [95 % interval, users resampled]", "localisation: searcher - told where"]
    head += ["predicted maps: told where - genie"]
    head += ["maps: searcher - true maps", "interaction"] if args.true_maps else []
    head += ["maps: searcher - ceiling", "planner: ceiling told where - genie"] if args.ceiling else []
    rows = [
        head
        + [f"success ({' / '.join(['searcher', 'told', *truths])})", f"median / genie's ({' / '.join(['searcher', *truths])})"]
    ]
    for city in args.city or VALIDATION:
        bundle = load_bundle(city, root=args.root)
        if bundle.manifest.config.role == "test":
            ap.error(f"{city} is a test city: nothing is learnt from it")
        methods = [GeniePolicy(), MapSearchPolicy(predictor, cache=cache),
                   OracleSearch(predictor, cache=cache, name=TOLD, radius=args.radius)]  # fmt: skip
        if args.true_maps:
            methods.append(OracleSearch(predictor, cache=cache, name=TRUE_MAPS, truth=bundle_truth(bundle)))
        if args.ceiling:
            ceiling = ceiling_truth(bundle, args.ceiling)
            methods.append(OracleSearch(predictor, cache=cache, name=CEILING, truth=ceiling))
            methods.append(OracleSearch(predictor, cache=cache, name=CEILING_TOLD, truth=ceiling, radius=args.radius))
        config = ReportConfig(dataset=city, episodes=args.episodes, seed=args.seed, predictor=None, p_t_db=args.p_t_db)
        t0 = time.perf_counter()
        res = evaluate(config, bundle, [], baselines=methods)
        steps = pd.DataFrame({m.name: res[m.name]["steps"] for m in methods})
        ok = {m.name: 100 * res[m.name]["success"].mean() for m in methods}
        genie, search, told = steps["genie"], steps[SEARCHER], steps[TOLD]
        users = res[SEARCHER]["user"].to_numpy()  # every method plays the same episodes: one user each
        row = [city, f"{genie.median():g}", f"{search.median():g}", f"{told.median():g}"]
        row += [f"{steps[name].median():g}" for name in truths]
        row += [mean_with_interval(search - genie, users), mean_with_interval(search - told, users)]
        row += [mean_with_interval(told - genie, users)]
        if args.true_maps:
            row += [mean_with_interval(search - steps[TRUE_MAPS], users)]
            row += [mean_with_interval(steps[TRUE_MAPS] + told - genie - search, users)]
        if args.ceiling:
            row += [mean_with_interval(search - steps[CEILING], users), mean_with_interval(steps[CEILING_TOLD] - genie, users)]
        success = [f"{ok[name]:.1f}" for name in (SEARCHER, TOLD, *truths)]
        ratios = [f"{steps[name].median() / genie.median():.2f}" for name in (SEARCHER, *truths)]
        rows.append(row + [" / ".join(success), " / ".join(ratios)])
        print(f"{city}: {time.perf_counter() - t0:.0f} s", flush=True)
    print(markdown_table(rows))


if __name__ == "__main__":
    main()
