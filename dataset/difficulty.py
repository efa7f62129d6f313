"""How hard a bundle's search problem is: target share, dead share, shortest-path steps (the genie's).

``steps_to_target`` is one multi-source breadth-first search per user over
the legal (not blocked) cells, from every target cell (SINR >= P_T) at once,
done as a frontier expansion on whole arrays: ``[num_users, ny, nx]`` in, the
number of 4-neighbour moves from every cell to the nearest target out.
"""

from __future__ import annotations

import numpy as np

from uavplace.schemas.constants import P_T_DB, reaches_target

#: Steps value of a cell from which no target can be reached (and of blocked cells).
UNREACHABLE = np.iinfo(np.int32).max


def steps_to_target(legal: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Shortest number of 4-neighbour moves over ``legal`` cells to any ``target`` cell.

    ``legal``: ``[ny, nx]`` or broadcastable to ``target``'s ``[..., ny, nx]``; ``target``
    cells must be legal to count. Returns int32 ``[..., ny, nx]``, ``UNREACHABLE`` where
    no target can be reached or the cell is not legal.
    """
    legal = np.broadcast_to(legal, target.shape)
    dist = np.full(target.shape, UNREACHABLE, dtype=np.int32)
    frontier = target & legal
    seen = frontier.copy()
    d = 0
    while frontier.any():
        dist[frontier] = d
        grown = np.zeros_like(frontier)
        grown[..., 1:, :] |= frontier[..., :-1, :]
        grown[..., :-1, :] |= frontier[..., 1:, :]
        grown[..., :, 1:] |= frontier[..., :, :-1]
        grown[..., :, :-1] |= frontier[..., :, 1:]
        frontier = grown & legal & ~seen
        seen |= frontier
        d += 1
    return dist


def valid_starts(
    blocked: np.ndarray, dead: np.ndarray, sinr_db: np.ndarray, p_t_db: float, steps: np.ndarray | None = None
) -> np.ndarray:
    """Cells an episode may start in: legal, not dead, below the target, and with a target reachable from them.

    ``[num_users, ny, nx]`` (or any ``[..., ny, nx]``). A start in a courtyard closed by
    buildings above the altitude can never succeed, so it is not a start: the genie
    succeeds in every episode by construction. ``steps``: the ``steps_to_target`` of
    these maps, when already computed.
    """
    if steps is None:
        steps = steps_to_target(~blocked, reaches_target(sinr_db, p_t_db, dead, ~blocked))
    return _candidate_starts(blocked, dead, sinr_db, p_t_db) & (steps != UNREACHABLE)


def _candidate_starts(blocked: np.ndarray, dead: np.ndarray, sinr_db: np.ndarray, p_t_db: float) -> np.ndarray:
    """Legal, live cells below the target: starts before the reachability rule."""
    return ~blocked & ~dead & ~reaches_target(sinr_db, p_t_db)


def difficulty(blocked: np.ndarray, dead: np.ndarray, sinr_db: np.ndarray, p_t_db: float = P_T_DB) -> dict[str, float | None]:
    """Summary of the search problem over all users at target ``p_t_db``.

    ``target_share``: legal, live cells at or above P_T, over legal cells; ``dead_share``:
    legal cells no path reached, over legal cells; ``excluded_start_share``: legal, live
    cells below P_T from which no target can be reached (closed courtyards), over all
    such cells: they are not starts (``valid_starts``); ``bfs_median_steps`` /
    ``bfs_mean_steps``: over every valid start of every user, the shortest legal path to
    a target cell. A figure that does not exist (no start) is None.
    """
    legal = ~blocked
    target = reaches_target(sinr_db, p_t_db, dead, legal)
    steps = steps_to_target(legal, target)
    candidates = _candidate_starts(blocked, dead, sinr_db, p_t_db)
    starts = valid_starts(blocked, dead, sinr_db, p_t_db, steps)
    s = steps[starts].astype(float)
    n_legal = legal.sum() * sinr_db.shape[0]
    out = {
        "p_t_db": float(p_t_db),
        "target_share": float(target.sum() / n_legal),
        "dead_share": float((dead & legal).sum() / n_legal),
        "blocked_share": float(blocked.mean()),
        "num_starts": int(starts.sum()),
        "excluded_start_share": float(1 - starts.sum() / candidates.sum()) if candidates.any() else float("nan"),
        "bfs_median_steps": float(np.median(s)) if s.size else float("nan"),
        "bfs_mean_steps": float(s.mean()) if s.size else float("nan"),
    }
    return {k: (v if np.isfinite(v) else None) for k, v in out.items()}
