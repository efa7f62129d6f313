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
  such as the dense validation crop this script's docstring names below.

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
from uavplace.eval.evaluate import ReportConfig, evaluate
from uavplace.eval.metrics import resample_counts
from uavplace.infra.console import markdown_table
from uavplace.rl.belief import PREDICTIONS, CandidateMaps, PredictionCache
from uavplace.rl.config import DEFAULT_PREDICTOR
from uavplace.rl.predictor import load_predictor
from uavplace.rl.tasks.placement.policies import GeniePolicy
from uavplace.rl.tasks.placement.searcher import SEARCHER, MapSearchPolicy
from uavplace.rl.world.view import AgentView, PublicMaps, public_maps
from uavplace.schemas.constants import P_T_DB

TOLD = "searcher told where (within R cells)"
TRUE_MAPS = "searcher given the true maps"


class ToldWhereSearch(MapSearchPolicy):
    """The searcher whose belief starts on the candidates within ``radius`` cells of the user's cell (the nearest
    candidate where none is that near), then is updated by its own measurements. An oracle: it reads the position."""

    privileged = True

    def __init__(self, *args: object, radius: int = 2, **kwargs: object) -> None:
        super().__init__(*args, name=TOLD, **kwargs)
        self.radius = radius
        self._users: dict[int, np.ndarray] = {}
        self._row_users = np.zeros((0, 2), np.int64)

    def act(self, obs: np.ndarray, mask: np.ndarray, env: object) -> np.ndarray:
        self._row_users = user_cells(env, self._users)
        return super().act(obs, mask, AgentView(env, public_maps(env)))

    def prior(self, maps: CandidateMaps, row: int) -> np.ndarray:
        gap = np.abs(maps.cells - self._row_users[row]).max(axis=1)
        near = gap <= max(self.radius, int(gap.min()))
        return np.where(near, 0.0, -1e30).astype(np.float32)


class TrueMapsSearch(MapSearchPolicy):
    """The searcher whose candidates are ``bundle``'s users, each with its true map (SINR, and dead as probability 0 or
    1), the position unknown. An oracle: it reads every user's map. Unturned maps only (the report plays them so)."""

    privileged = True

    def __init__(self, bundle: Bundle, *args: object, **kwargs: object) -> None:
        super().__init__(*args, name=TRUE_MAPS, **kwargs)
        self.bundle = bundle

    def act(self, obs: np.ndarray, mask: np.ndarray, env: object) -> np.ndarray:
        return super().act(obs, mask, AgentView(env, public_maps(env)))

    def canvas_maps(self, public: PublicMaps, canvas: int) -> CandidateMaps:
        key = ("true", canvas)
        if key not in self._canvases:
            if public.symmetry_of(canvas) != 0:
                raise ValueError("the true-maps searcher plays unturned maps only")
            b = self.bundle
            users = b.user_indices()
            cells = b.user_cells(users)
            legal = np.argwhere(public.legal(canvas))
            index = np.full(b.blocked.shape, -1, np.int64)
            index[legal[:, 0], legal[:, 1]] = np.arange(len(legal))
            mu = b.sinr_db[users][:, legal[:, 0], legal[:, 1]].astype(np.float32)
            p_dead = b.dead[users][:, legal[:, 0], legal[:, 1]].astype(np.float32)
            cover = self.cover(mu, p_dead, public.config.p_t_db)
            self._canvases[key] = CandidateMaps(cells, legal, index, mu, p_dead, cover)
        return self._canvases[key]


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
    ap.add_argument("--p-t-db", type=float, default=P_T_DB, help="The SINR target P_T [dB] (a harder target on an easy crop)")
    ap.add_argument("--root", type=Path, default=Path("data/processed"))
    args = ap.parse_args()
    predictor = load_predictor(DEFAULT_PREDICTOR)
    cache = PredictionCache(args.root / PREDICTIONS)
    head = ["city", "genie", "map searcher", TOLD]
    head += [TRUE_MAPS] if args.true_maps else []
    head += ["mean excess [95 % interval, users resampled]", "localisation: searcher - told where"]
    head += ["predicted maps: told where - genie"]
    head += ["maps: searcher - true maps", "interaction"] if args.true_maps else []
    rows = [head + ["success (searcher / told / true)"]]
    for city in args.city or VALIDATION:
        bundle = load_bundle(city, root=args.root)
        if bundle.manifest.config.role == "test":
            ap.error(f"{city} is a test city: nothing is learnt from it")
        methods = [GeniePolicy(), MapSearchPolicy(predictor, cache=cache), ToldWhereSearch(predictor, cache=cache,
                                                                                           radius=args.radius)]  # fmt: skip
        if args.true_maps:
            methods.append(TrueMapsSearch(bundle, predictor, cache=cache))
        config = ReportConfig(dataset=city, episodes=args.episodes, seed=args.seed, predictor=None, p_t_db=args.p_t_db)
        t0 = time.perf_counter()
        res = evaluate(config, bundle, [], baselines=methods)
        steps = pd.DataFrame({m.name: res[m.name]["steps"] for m in methods})
        ok = {m.name: 100 * res[m.name]["success"].mean() for m in methods}
        genie, search, told = steps["genie"], steps[SEARCHER], steps[TOLD]
        users = res[SEARCHER]["user"].to_numpy()  # every method plays the same episodes: one user each
        row = [city, f"{genie.median():g}", f"{search.median():g}", f"{told.median():g}"]
        row += [f"{steps[TRUE_MAPS].median():g}"] if args.true_maps else []
        row += [mean_with_interval(search - genie, users), mean_with_interval(search - told, users)]
        row += [mean_with_interval(told - genie, users)]
        if args.true_maps:
            row += [mean_with_interval(search - steps[TRUE_MAPS], users)]
            row += [mean_with_interval(steps[TRUE_MAPS] + told - genie - search, users)]
        success = [f"{ok[SEARCHER]:.1f}", f"{ok[TOLD]:.1f}"] + ([f"{ok[TRUE_MAPS]:.1f}"] if args.true_maps else [])
        rows.append(row + [" / ".join(success)])
        print(f"{city}: {time.perf_counter() - t0:.0f} s", flush=True)
    print(markdown_table(rows))


if __name__ == "__main__":
    main()
