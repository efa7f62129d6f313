"""The predicted maps of every canvas on disk (``PredictionCache``): keyed by everything that made them, checked
whenever read, made again when anything is off (docs/security.md)."""

from __future__ import annotations

import hashlib
import io
from pathlib import Path

import numpy as np

from uavplace.infra.files import ARCHIVE_ERRORS, atomic_write_bytes, read_small_file
from uavplace.infra.limits import limits
from uavplace.schemas import InputError

#: The folder of cached predicted maps beside the bundles (safe to delete: they are made again on demand).
PREDICTIONS = ".predictions"
#: Bytes a predicted-maps cache entry may hold beside its two float16 arrays: the archive's headers and its meta.
ENTRY_BYTES = 1 << 16


class PredictionCache:
    """Predicted maps on disk, one ``.npz`` per canvas, named by the hash of everything they depend on (the bundle, the
    symmetry, the lattice, the blanked map, the predictor's weights, constants and code: ``Predictor.version``).

    An entry is data, never trusted as it is (docs/security.md): it is read only when it is a regular file inside the
    cache folder (no link, no FIFO) of at most its two float16 arrays and ``ENTRY_BYTES`` (a larger one is not read),
    and used only when it names its own key, its arrays hash to the sha256 it records, they have the expected shape,
    and every value is finite with the dead probability in [0, 1] and the SINR within +-``MAX_ABS_DB``. Anything else is predicted again and replaced."""

    #: The largest |SINR| [dB] a cached prediction may hold.
    MAX_ABS_DB = 400.0

    def __init__(self, folder: str | Path | None) -> None:
        # absolute: a copy in a Ray task (another working folder) reads the same cache
        self.folder = None if folder is None else Path(folder).absolute()

    def path(self, key: str) -> Path | None:
        return None if self.folder is None else self.folder / f"{key}.npz"

    def load(self, key: str, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray] | None:
        """(mu, p_dead) as float32 if the entry passes every check of the class's docstring; else None (made again)."""
        path = self.path(key)
        if path is None or path.is_symlink():
            return None
        try:
            # at most what two float16 arrays of this shape and the entry's meta take: a larger file is not ours, and
            # is never read (a sparse file of gigabytes within prediction_bytes had been read whole)
            bound = min(ENTRY_BYTES + 4 * shape[0] * shape[1], limits().prediction_bytes)
            data = read_small_file(path, "a predicted-maps cache entry", max_bytes=bound)
        except InputError:  # missing, a link, a FIFO, a folder, too large
            return None
        try:
            with np.load(io.BytesIO(data), allow_pickle=False) as z:
                if int(sum(z.zip.getinfo(n).file_size for n in z.zip.namelist())) > 2 * 4 * (shape[0] * shape[1] + 64):
                    return None  # inflates beyond two float16 arrays of this shape: not ours
                mu, p_dead, meta = z["mu"], z["p_dead"], bytes(z["meta"])
        except (*ARCHIVE_ERRORS, KeyError):
            return None  # a damaged or older cache file is made again
        if mu.shape != shape or p_dead.shape != shape or mu.dtype != np.float16 or p_dead.dtype != np.float16:
            return None
        if meta != _entry_meta(key, mu, p_dead):
            return None
        mu, p_dead = mu.astype(np.float32), p_dead.astype(np.float32)
        if not (np.isfinite(mu).all() and np.isfinite(p_dead).all()):
            return None
        if (np.abs(mu) > self.MAX_ABS_DB).any() or (p_dead < 0).any() or (p_dead > 1).any():
            return None
        return mu, p_dead

    def save(self, key: str, mu: np.ndarray, p_dead: np.ndarray) -> None:
        """Keep ``mu`` and ``p_dead`` [C, M] as float16 with their key and sha256 (atomically; a cache that can't be
        written, or whose entry's path is not a regular file, is skipped)."""
        path = self.path(key)
        if path is None:
            return
        mu16, p16 = mu.astype(np.float16), p_dead.astype(np.float16)
        buf = io.BytesIO()
        np.savez(buf, mu=mu16, p_dead=p16, meta=np.frombuffer(_entry_meta(key, mu16, p16), np.uint8))
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_bytes(path, buf.getvalue())
        except (InputError, OSError):
            pass


def _entry_meta(key: str, mu: np.ndarray, p_dead: np.ndarray) -> bytes:
    """What a cache entry records of itself: its key and the sha256 of its two float16 arrays."""
    digest = hashlib.sha256(np.ascontiguousarray(mu).tobytes() + np.ascontiguousarray(p_dead).tobytes()).hexdigest()
    return f"{key}:{digest}".encode()
