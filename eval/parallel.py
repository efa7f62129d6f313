"""A report's methods played side by side as Ray tasks: local by default, a cluster by address.

Every method plays the same episode specs with its own policy and maps, and every random choice of an episode is
drawn from that episode and step (``rl.randomness``), never from what else runs: so the results are the same
frames, to the bit, whether the methods play one after the other in this process or at once on any number of
workers (``tests/test_parallel.py``). The searchers' predicted maps are made first, in this process, and kept in the
prediction cache; a task reads them from there (a policy travels without its in-memory maps).

Progress comes back from the tasks through a Ray queue, at most once a second a task, so a report's progress lines
name each method's episodes done as they pass, as they do without Ray.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import pandas as pd

from uavplace.rl.maps import MapSet
from uavplace.rl.policies import Policy
from uavplace.rl.rollout import run_episodes

#: Seconds between two progress messages of one task.
PROGRESS_EVERY_S = 1.0


def _play(maps: MapSet, policy: Policy, specs: np.ndarray, record: np.ndarray | None, name: str, queue) -> pd.DataFrame:  # noqa: ANN001
    """One method's rollouts in a Ray task: one torch thread (the task has one CPU), progress to ``queue``."""
    import torch

    torch.set_num_threads(1)
    last = [0.0]

    def tell(done: int, total: int) -> None:
        now = time.monotonic()
        if now - last[0] >= PROGRESS_EVERY_S or done >= total:
            last[0] = now
            queue.put((name, done, total))

    return run_episodes(maps, policy, specs, on_step=tell, record=record)


def play_on_ray(
    methods: list[tuple[str, Policy, MapSet]],
    specs: dict[str, np.ndarray],
    record: dict[str, np.ndarray | None],
    on_progress: Callable[[str, int, int], None] | None = None,
) -> dict[str, pd.DataFrame]:
    """``{name: run_episodes frame}`` of every method of ``methods`` (``(name, policy, maps)``) on its ``specs``,
    each a Ray task of one CPU on the Ray this process has joined (``infra.cluster.start_ray``), in ``methods``'
    order; ``record``: the episodes whose paths a method keeps (None: none)."""
    import ray
    from ray.util.queue import Empty, Queue

    queue = Queue()
    task = ray.remote(num_cpus=1, max_retries=0)(_play)
    shared: dict[int, ray.ObjectRef] = {}
    pending = {}
    for name, policy, maps in methods:
        ref = shared.setdefault(id(maps), ray.put(maps))  # one copy of each canvas set for all its methods
        pending[task.remote(ref, policy, specs[name], record[name], name, queue)] = name
    results: dict[str, pd.DataFrame] = {}

    def tell() -> None:
        while True:
            try:
                name, n, total = queue.get_nowait()
            except Empty:
                return
            if on_progress is not None:
                on_progress(name, n, total)

    try:
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1, timeout=0.5)
            tell()
            for ref in done:
                results[pending.pop(ref)] = ray.get(ref)
        tell()
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)
        ray.kill(queue.actor)
    return {name: results[name] for name, _, _ in methods}
