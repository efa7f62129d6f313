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
