"""Exact paths for the cells Sionna's radio map missed (``uavdata simulate --complete-missed``), a Ray task per user.

The radio map's rays miss cells that only a few paths reach (a reflection that then diffracts into a side street);
the fill estimates them. Completing a city traces Sionna's ``PathSolver`` at the centre of every open cell the radio
map missed, every path found as InSite finds them, so that those cells carry exact values ("exact paths" in
``schemas.provenance``) instead of estimates. Each user's missed cells are one Ray task (a local Ray by default, a
cluster by address), in child processes of ``CELLS_PER_CALL`` cells (the path buffer grows with the receivers); Mitsuba
runs on a GPU where it finds one. ``simulate_city`` keeps each user's result in the trace cache as it arrives, so an
interrupted completion resumes at the users not yet done.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from uavplace.infra.cluster import start_ray
from uavplace.simulate.raytrace import RadioMapJob, RayTraceConfig, point_path_gains_isolated

#: Missed cells a child process traces at once (``exact_path_maps``' batch: its path buffer holds them all).
CELLS_PER_CALL = 128


def missed_cells(traced: np.ndarray, open_cells: np.ndarray) -> np.ndarray:
    """The cells to complete [U, ny, nx]: open (no building at or above the plane) and missed by the radio map's rays
    (``traced``, the raw path gains [U, ny, nx], 0 where no ray hit)."""
    return (traced == 0) & np.broadcast_to(open_cells, traced.shape)


def _user_paths(job: RadioMapJob, config: RayTraceConfig, points_m: np.ndarray) -> tuple[np.ndarray, float]:
    """One user's exact path gains at ``points_m`` [n, 3] (linear; 0 where no path) and the seconds they took."""
    start = time.perf_counter()
    parts = [
        point_path_gains_isolated(job, points_m[i : i + CELLS_PER_CALL], config)[0]
        for i in range(0, len(points_m), CELLS_PER_CALL)
    ]
    return (np.concatenate(parts) if parts else np.zeros(0)), time.perf_counter() - start


def complete_users(
    job: RadioMapJob,
    config: RayTraceConfig,
    missed: np.ndarray,
    users: list[int],
    on_user: Callable[[int, np.ndarray, float], None],
    *,
    address: str | None = None,
    cpus_per_user: float = 2.0,
) -> None:
    """Trace exact paths at ``missed[u]``'s cell centres for each of ``users`` (indices of ``job.users_m``), a Ray task
    each; ``on_user(u, gains [missed[u].sum()], seconds)`` as each finishes. ``config.samples_per_tx`` is PathSolver's
    rays per user. ``address``: a Ray cluster (None: a local Ray, or the running one inside a Ray task)."""
    try:
        import ray
    except ImportError:
        raise RuntimeError("Ray is not installed: pip install -e '.[raytrace]'") from None
    if not users:
        return
    centres = job.cell_centres()
    started = start_ray(address, cpus_per_user, "--cpus-per-city")
    try:
        task = ray.remote(num_cpus=cpus_per_user, max_retries=0)(_user_paths)
        pending = {task.remote(replace(job, users_m=(job.users_m[u],)), config, centres[missed[u].ravel()]): u for u in users}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            u = pending.pop(ready[0])
            try:
                gains, seconds = ray.get(ready[0])
            except ray.exceptions.RayError as err:
                raise RuntimeError(
                    f"user {u + 1}'s exact paths failed: {str(err).splitlines()[0]} (the users done so far "
                    "are kept in the trace cache; run again to resume)"
                ) from None
            on_user(u, gains, seconds)
    finally:
        if started:
            ray.shutdown()
