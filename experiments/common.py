"""What the experiment scripts share: the validation cities and the options every one of them takes."""

from __future__ import annotations

import argparse

#: The validation cities: every choice is made on them, never on a test city.
VALIDATION = ("corpus-016", "corpus-017", "oldtown-005", "etoile-val", "florence-val", "delfshaven-val", "denhaag-val")


def validation_parser(doc: str, episodes: int) -> argparse.ArgumentParser:
    """A parser described by ``doc``'s first line with ``--city`` (repeatable; default ``VALIDATION``), ``--episodes``
    and ``--seed``."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument(
        "--city", action="append", default=None, help=f"Validation city (repeatable; default: {', '.join(VALIDATION)})"
    )
    ap.add_argument("--episodes", type=int, default=episodes, help="Episodes a city, the same for every method")
    ap.add_argument("--seed", type=int, default=0, help="Seed of the episodes and of every random move")
    return ap


def agent_parser(doc: str, episodes: int = 1000) -> argparse.ArgumentParser:
    """A parser described by ``doc``'s first line for an agent's episodes: ``--run`` (default: the shipped best),
    ``--city`` (repeatable; default: every validation city), ``--release`` (test cities allowed, for release numbers
    only), ``--episodes`` and ``--root``."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--run", default="data/agents/best", help="Agent folder (default: the shipped best)")
    ap.add_argument("--city", action="append", default=None, help="City to play (repeatable; default: every validation city)")
    ap.add_argument("--release", action="store_true", help="Allow test cities (release numbers only, never to choose)")
    ap.add_argument("--episodes", type=int, default=episodes)
    ap.add_argument("--root", default="data/processed")
    return ap


def trace_with_workers(tiers: list, workers: int) -> None:
    """Each ray-traced tier of ``tiers`` traces its candidates in ``workers`` Ray tasks, on a local Ray of that many
    CPUs started here when more than one (the maps are the same whatever the number)."""
    for tier in tiers:
        if hasattr(tier, "workers"):
            tier.workers = workers
    if workers > 1:
        from uavplace.infra.cluster import start_ray

        start_ray(None, 1.0, "--workers", num_cpus=workers)
