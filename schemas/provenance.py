"""Where each cell's value came from: the code table every stage shares (docs/simulate.md, "Provenance").

A map's value at a cell is measured (a ray tracer's paths reached it) or estimated (a fill made it up from its
neighbours), and a user must be able to tell which. ``uavdata simulate`` records the code of every receiver and
transmitter in a side file beside its InSite-shaped export (``<city>.provenance.csv.gz``, ``PROVENANCE_COLUMNS``:
one row the codes of up to ``CODES_PER_ROW`` consecutive receivers, a digit each; ``RUN_COLUMNS``, runs of receivers
that share a code, is the form earlier versions wrote, still read; InSite-compatible readers read neither), ingest keeps it
as the ``provenance`` column of the receivers table, and a bundle carries it per user and cell (``maps.npz``,
``provenance``), checked against the bundle's ``dead`` and ``num_rx`` when it is loaded.

An export without the side file: a real Wireless InSite export says "ray-traced" for every receiver it reaches; an
export of ``uavdata simulate --solver paths`` (its simulation.json says so) "exact paths"; an export of an older
``uavdata simulate`` that filled gaps without recording them "not recorded".
"""

from __future__ import annotations

UNREACHED = 0
RAY_TRACED = 1
EXACT_PATHS = 2
STRAIGHT_PATH = 3
WALKED = 4
COARSE_MAP = 5
NOT_RECORDED = 6
NO_RECEIVER = 7
NEAREST_RECEIVER = 8

#: Code -> (short name, what it means). Codes 0-6 describe a receiver of an export; 7 and 8 only a bundle's cell.
CODES: dict[int, tuple[str, str]] = {
    UNREACHED: ("unreached", "a receiver that no path reached (the export's no-path value; the cell is dead)"),
    RAY_TRACED: ("ray-traced", "the ray tracer's paths reached it (every receiver a Wireless InSite export reaches)"),
    EXACT_PATHS: (
        "exact paths",
        "every path to the point, found by Sionna's PathSolver (--solver paths, --complete-missed)",
    ),
    STRAIGHT_PATH: (
        "straight path",
        "the ray tracer missed it; the exact straight path through the walls alone (a lower bound: no reflection or diffraction)",
    ),
    WALKED: ("walked", "estimated: the ray tracer missed it; walked from the cells it hit, less a decay a metre"),
    COARSE_MAP: ("coarse map", "estimated: the ray tracer missed it; taken from a coarser radio map's cell"),
    NOT_RECORDED: (
        "not recorded",
        "reached, by a simulation that did not record how (a uavplace export made before provenance)",
    ),
    NO_RECEIVER: ("no receiver", "no receiver of the export lies in the cell (the cell is dead)"),
    NEAREST_RECEIVER: (
        "nearest receiver",
        "estimated: no receiver lies in the cell; copied from the nearest one (an export coarser than the grid)",
    ),
}
#: The codes a receiver of an export may carry (the side file, the receivers table).
RECEIVER_CODES = (UNREACHED, RAY_TRACED, EXACT_PATHS, STRAIGHT_PATH, WALKED, COARSE_MAP, NOT_RECORDED)
#: Codes of values a tracer computed for the cell itself; the rest of the live codes are estimates.
TRACED = (RAY_TRACED, EXACT_PATHS)
ESTIMATED = (STRAIGHT_PATH, WALKED, COARSE_MAP, NOT_RECORDED, NEAREST_RECEIVER)
#: The codes of dead cells: every other code is live.
DEAD = (UNREACHED, NO_RECEIVER)
#: Live receiver codes from the most to the least trusted: a cell whose receivers disagree takes the least trusted.
TRUST = (EXACT_PATHS, RAY_TRACED, STRAIGHT_PATH, NOT_RECORDED, COARSE_MAP, WALKED)

#: The side file beside a simulated export: ``<city>`` + this suffix (gzip-compressed CSV).
SIDE_FILE_SUFFIX = ".provenance.csv.gz"
#: Its header, in order: the codes of receivers ``first_rx``, ``first_rx + 1``, ... of receiver set ``rx_set``
#: (numbered as in the .p2m files) of transmitter ``tx_point`` of set ``tx_set``, one digit a receiver (``codes``).
PROVENANCE_COLUMNS = ("tx_set", "tx_point", "rx_set", "first_rx", "codes")
#: How many receivers' codes a row holds at most (a line stays short; gzip packs the digits about ten to a byte).
CODES_PER_ROW = 2000
#: The header of the side files of earlier versions, still read: a run of ``count`` receivers from ``first_rx`` on,
#: all of them with ``code`` (about four times the bytes of ``PROVENANCE_COLUMNS``'s rows for the same codes).
RUN_COLUMNS = ("tx_set", "tx_point", "rx_set", "first_rx", "count", "code")


def code_name(code: int) -> str:
    """The short name of ``code`` (``CODES``), or ``code <n>`` when it is not one."""
    return CODES[code][0] if code in CODES else f"code {code}"


def code_table() -> str:
    """The code table as text, one ``code name: meaning`` a line (the side file's comment and the docs)."""
    return "\n".join(f"{c} {name}: {text}" for c, (name, text) in CODES.items())
