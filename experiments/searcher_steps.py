"""Where the map searcher's steps above the genie's go, on validation cities (issue 47's "why").

On the episodes ``uavrl report`` draws for a validation city, three methods play the same episodes:

- the genie (the user's true map and position);
- *the searcher told where the user is*: the map searcher's planner over the predicted map of a user at the user's
  true cell (an oracle: it reads the position, never the user's map). Its steps above the genie's are what the
  predictor's error costs;
- the map searcher itself. Its steps above the oracle's are what not knowing the position costs (localisation).

For the searcher, each episode also records the step at which its belief first holds at least half its mass within
``--near`` cells (Chebyshev) of the user: its steps split into searching (before) and approaching (after). The
position is read only to record this; the moves are the searcher's (its row ``map searcher`` is the report's).

    python experiments/searcher_steps.py [--city etoile-val] [--episodes 300] [--near 4]

Test cities are refused: nothing is learnt from them.
"""

from __future__ import annotations

import time

import numpy as np
import pandas as pd
from common import VALIDATION, validation_parser

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.evaluate import ReportConfig, evaluate
from uavplace.infra.console import markdown_table
from uavplace.rl.belief import PREDICTIONS, PredictionCache
from uavplace.rl.config import DEFAULT_PREDICTOR
from uavplace.rl.predictor import Scene, load_predictor
from uavplace.rl.tasks.placement.policies import GeniePolicy
from uavplace.rl.tasks.placement.searcher import MapSearchPolicy
from uavplace.rl.world.maps import transform
from uavplace.rl.world.view import AgentView, public_maps

KNOWN = "searcher told where the user is"


def user_cells(env: object, known: dict[int, np.ndarray]) -> np.ndarray:
    """[N, 2] each row's user cell in its (turned) map, read off the scenario (for the oracles of this script only) once
    per view and kept in ``known``."""
    maps = env.maps
    for v in set(env.view.tolist()) - known.keys():
        sc = maps.scenarios[int(maps.scenario_of(v))]
        b = maps.bundles[sc.bundle]
        row = b.users.loc[b.users["user"] == sc.user].iloc[0]
        one = np.zeros(b.sinr_db.shape[1:], bool)
        one[int(row["iy"]), int(row["ix"])] = True
        known[v] = np.argwhere(transform(one, int(maps.symmetry_of(v))))[0]
    return np.stack([known[v] for v in env.view.tolist()])


class KnownUserSearch(MapSearchPolicy):
    """The searcher's planner over the predicted map of a user at the true user cell: the predictor's share."""

    privileged = True

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, name=KNOWN, **kwargs)
        self._cover: dict[tuple, np.ndarray] = {}
        self._users: dict[int, np.ndarray] = {}

    def act(self, obs: np.ndarray, mask: np.ndarray, env: object) -> np.ndarray:
        public = public_maps(env)
        view = AgentView(env, public)
        users, p = user_cells(env, self._users), public.pad
        actions = np.zeros(len(mask), np.int64)
        for r in np.flatnonzero(~view.exhausted & mask.any(axis=1)):
            c = int(view.canvas[r])
            maps = self.canvas_maps(public, c)
            key = (c, *users[r])
            if key not in self._cover:
                settings = public.settings[public.bundle_of(c)]
                scene = Scene.from_settings(settings, public.map_heights(c))
                mu, p_dead = self.predictor.predict(scene, users[r][None], maps.legal)
                self._cover[key] = self.cover(mu, p_dead, public.config.p_t_db)[0]
            here = int(maps.index[view.pos[r, 0] - p, view.pos[r, 1] - p])
            seen = view.visits[r, maps.legal[:, 0] + p, maps.legal[:, 1] + p] > 0
            actions[r] = self.first_move(public, c, maps, here, self._cover[key], seen, mask[r])
        return actions


class RecordedSearch(MapSearchPolicy):
    """The map searcher, moving as it does, recording when its belief first holds half its mass near the user."""

    privileged = True

    def __init__(self, *args: object, near: int = 2, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)
        self.near = near
        self.located: dict[int, int] = {}
        self._users: dict[int, np.ndarray] = {}

    def act(self, obs: np.ndarray, mask: np.ndarray, env: object) -> np.ndarray:
        public = public_maps(env)
        actions = super().act(obs, mask, AgentView(env, public))
        users = user_cells(env, self._users)
        for r in np.flatnonzero(~env.exhausted):
            episode = int(env.episode_id[r])
            if episode in self.located or self.belief[r] is None:
                continue
            maps = self.canvas_maps(public, int(self.belief_canvas[r]))
            b = np.exp(self.belief[r] - self.belief[r].max())
            close = np.abs(maps.cells - users[r]).max(axis=1) <= self.near
            if b[close].sum() >= 0.5 * b.sum():
                self.located[episode] = int(env.t[r])
        return actions


def main() -> None:
    ap = validation_parser(__doc__, episodes=300)
    ap.add_argument("--near", type=int, default=4, help="Cells (Chebyshev) within which the belief's mass counts as located")
    ap.add_argument("--root", default="data/processed")
    args = ap.parse_args()
    predictor = load_predictor(DEFAULT_PREDICTOR)
    cache = PredictionCache(f"{args.root}/{PREDICTIONS}")
    rows = [["city", "genie", KNOWN, "map searcher", "mean excess", "of it: the predictor's", "of it: localisation",
             "located (median step)", "steps after located (median)", "excess in episodes > 50 over"]]  # fmt: skip
    for city in args.city or VALIDATION:
        bundle = load_bundle(city, root=args.root)
        if bundle.manifest.config.role == "test":
            ap.error(f"{city} is a test city: nothing is learnt from it")
        recorded = RecordedSearch(predictor, cache=cache, near=args.near)
        config = ReportConfig(dataset=city, episodes=args.episodes, seed=args.seed, predictor=None)
        t0 = time.perf_counter()
        res = evaluate(config, bundle, [], baselines=[GeniePolicy(), KnownUserSearch(predictor, cache=cache), recorded])
        df = pd.DataFrame({"genie": res["genie"]["steps"], "known": res[KNOWN]["steps"], "search": res["map searcher"]["steps"],
                           "ok": res["map searcher"]["success"]})  # fmt: skip
        df["located"] = pd.Series(recorded.located).reindex(range(len(df))).to_numpy()
        excess = df["search"] - df["genie"]
        big = excess > 50
        after = (df["search"] - df["located"])[df["located"].notna() & df["ok"]]
        rows.append([city, f"{df['genie'].median():g}", f"{df['known'].median():g}", f"{df['search'].median():g}",
                     f"{excess.mean():.1f}", f"{(df['known'] - df['genie']).mean():.1f}",
                     f"{(df['search'] - df['known']).mean():.1f}",
                     f"{100 * df['located'].notna().mean():.0f} % ({df['located'].median():g})",
                     f"{after.median():g}", f"{100 * excess[big].sum() / max(excess.sum(), 1):.0f} % ({100 * big.mean():.0f} % of episodes)"])  # fmt: skip
        print(f"{city}: {time.perf_counter() - t0:.0f} s", flush=True)
    print(markdown_table(rows))


if __name__ == "__main__":
    main()
