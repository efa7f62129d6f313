"""File-level contracts shared by every stage: safe names, content hashes, and atomic publication of outputs.

Every folder uavplace writes is built in a temporary folder beside its final
place and renamed into place (``atomic_directory``). The swap holds a per-folder
lock, so two processes writing the same output (two ingests of one city) take
turns instead of deleting each other's temporary folders, and it replaces an
existing folder only if that folder carries uavplace's own marker file (an
ingest manifest, a bundle manifest, a report's ``report.json``): a folder a
user made is never deleted.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import os
import re
import shutil
import stat
import tempfile
import zipfile
from collections.abc import Collection, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

from pydantic import BaseModel, ValidationError

from uavplace.schemas.base import NAME_PATTERN, InputError, validation_message

if TYPE_CHECKING:
    import numpy as np

M = TypeVar("M", bound=BaseModel)

#: Default root of ingested cities and bundles (relative to the working folder).
DEFAULT_ROOT = Path("data/processed")
#: The project's folder, where the shipped agents and predictor (``data/agents/``) are found whatever the working
#: folder: the folder above the installed ``uavplace.infra`` package (the repository, for the README's editable
#: install).
PROJECT_ROOT = Path(__file__).resolve().parent.parent


def shipped(relative: str) -> Path:
    """``relative`` (e.g. ``data/agents``) in the project's folder (``PROJECT_ROOT``), not the working folder."""
    return PROJECT_ROOT / relative


_CHUNK = 1 << 20
_NAME_RE = re.compile(NAME_PATTERN)


def check_name(name: str, what: str = "name") -> str:
    """``name`` if it is one safe path component (``NAME_PATTERN``), else ``InputError`` saying why.

    Called before anything is created, so a name such as ``../../x`` or ``/abs/path`` never reaches the file system.
    """
    if _NAME_RE.fullmatch(name) and name not in (".", ".."):
        return name
    suggestion = re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("._-")[:64]
    hint = f" (e.g. '{suggestion}')" if suggestion and _NAME_RE.fullmatch(suggestion) else ""
    raise InputError(
        None,
        f"{name!r} is not a safe name: use 1-64 ASCII letters, digits, '_', '.' or '-', starting with a letter "
        f"or digit, and no path separators{hint}",
        field=what,
    )


def in_corpus(city: str, name: str) -> bool:
    """True when ``city`` is ``name`` or a member ``NAME-NNN`` of the corpus ``name`` (as ``uavdata simulate --count``
    names them)."""
    return city == name or (city.startswith(f"{name}-") and city[len(name) + 1 :].isdigit())


def array_digest(*arrays: np.ndarray, extra: str = "") -> str:
    """The sha256 of ``arrays`` (each with its dtype and shape) and the text ``extra``: what names data by content."""
    import numpy  # here: the command line imports this module before any array is at hand

    digest = hashlib.sha256(extra.encode())
    for a in arrays:
        a = numpy.ascontiguousarray(a)
        digest.update(f"{a.dtype.str}{a.shape}".encode() + a.tobytes())
    return digest.hexdigest()


def sha256_file(path: str | Path) -> str:
    """Hex sha256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)
    return h.hexdigest()


def write_model_json(model: BaseModel, path: str | Path) -> None:
    """Write a pydantic model as indented JSON (the caller makes it atomic)."""
    Path(path).write_text(model.model_dump_json(indent=2) + "\n", encoding="utf-8")


def check_inside(folder: str | Path, path: str | Path, what: str) -> Path:
    """``path`` if it lies inside ``folder`` and is no symbolic link (nor under a linked folder), else ``InputError``:
    a file that an input names (a raster, a table, a pack) is read only from the input itself."""
    path = Path(path)
    try:
        inside = path.resolve().is_relative_to(Path(folder).resolve())
    except (OSError, RuntimeError):  # a link loop
        inside = False
    if path.is_symlink() or not inside:
        raise InputError(path, f"a link or a path that leads out of {folder}: not read ({what} is read from the input only)")
    return path


def read_small_file(
    path: str | Path, what: str, missing: str | None = None, max_bytes: int | None = None, limit: str = "record_bytes"
) -> bytes:
    """The bytes of a record or settings file; ``InputError`` naming it when it is missing (``missing``, or "no such
    file"), is not a regular file (a FIFO, a device, a folder: refused without waiting on it) or is over ``max_bytes``
    (default: the limits' ``record_bytes``; ``limit`` names the limit a caller's ``max_bytes`` comes from). ``what``
    says what the file should be."""
    from uavplace.infra.limits import limits

    path = Path(path)
    bound = limits().record_bytes if max_bytes is None else max_bytes
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)  # a FIFO opens at once, and is then refused
    except FileNotFoundError:
        raise InputError(path, missing or f"no such file: {what}") from None
    except OSError as err:
        raise InputError(path, f"unreadable ({describe_os_error(err)}): {what}") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise InputError(path, f"not a regular file: {what}")
        if info.st_size > bound:
            raise InputError(path, f"over {bound:,} bytes (limit {limit}): not {what}")
        with os.fdopen(os.dup(fd), "rb") as f:
            data = f.read(bound + 1)
    finally:
        os.close(fd)
    if len(data) > bound:
        raise InputError(path, f"over {bound:,} bytes (limit {limit}): not {what}")
    return data


def read_model_json(path: str | Path, model: type[M], what: str, max_bytes: int | None = None) -> M:
    """A small JSON file as the pydantic ``model``; ``InputError`` naming the file (and the field) when it is not a
    regular file, is over ``max_bytes`` (``read_small_file``) or does not validate. ``what`` says what the file should
    be ("a predictor's constants (`uavrl fit-predictor` writes them)")."""
    path = Path(path)
    data = read_small_file(path, what, max_bytes=max_bytes)
    try:
        return model.model_validate_json(data)
    except ValidationError as exc:
        where, message = validation_message(exc)
        raise InputError(path, message, field=where) from None


def read_model_toml(path: str | Path, model: type[M], what: str, missing: str | None = None) -> M:
    """A small TOML file (a sweep spec, a roles file) as the pydantic ``model``; ``InputError`` naming the file (and
    the field) when it is missing (``missing``), not a regular file or over the limit (``read_small_file``), not TOML,
    or does not validate."""
    import tomllib

    path = Path(path)
    data = read_small_file(path, what, missing=missing)
    try:
        doc = tomllib.loads(data.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise InputError(path, f"not a TOML file ({exc})", field="toml") from None
    try:
        return model.model_validate(doc)
    except ValidationError as exc:
        where, message = validation_message(exc)
        raise InputError(path, message, field=where) from None


def write_json(obj: object, path: str | Path) -> None:
    Path(path).write_text(json.dumps(obj, indent=2, sort_keys=True) + "\n", encoding="utf-8")


def umask_mode(full: int = 0o666) -> int:
    """``full`` less the process's umask: the mode ``open`` would give a new file (0o777 for a folder)."""
    mask = os.umask(0)
    os.umask(mask)
    return full & ~mask


def atomic_write_text(path: str | Path, text: str) -> None:
    """``atomic_write_bytes`` of ``text`` in UTF-8."""
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to a temporary file beside ``path``, then rename it into place (never half-written). The file
    gets the mode a plain write would (the umask's, not ``mkstemp``'s private 0600). On any failure (a full disk)
    the temporary file is removed, and an ``OSError`` names ``path``. Only a regular file or nothing is replaced:
    ``InputError`` (``check_replaceable_file``) for a folder, a device, a FIFO, a socket or a link at ``path``."""
    path = Path(path)
    check_replaceable_file(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        os.fchmod(fd, umask_mode())
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError) and exc.filename is None:
            raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from None
        raise


@contextlib.contextmanager
def folder_lock(final: str | Path) -> Iterator[None]:
    """Hold an exclusive lock on ``final`` (a sibling ``.<name>.lock`` file) while the block runs.

    A second process writing the same folder waits for the first to finish. The
    lock is released by the kernel if its holder dies, so a killed writer never
    leaves a folder locked.
    """
    fd = _open_lock(final)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing the descriptor releases the lock


def _open_lock(final: str | Path, kind: str = "") -> int:
    """A descriptor of ``final``'s lock file, ``.<name>.lock`` beside it (``.<name>.<kind>.lock``: a second lock of
    the same folder), created with its parent if missing."""
    final = Path(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    name = f".{final.name}.{kind}.lock" if kind else f".{final.name}.lock"
    return os.open(final.parent / name, os.O_RDWR | os.O_CREAT, 0o644)


@contextlib.contextmanager
def exclusive_folder(final: str | Path, what: str, kind: str = "") -> Iterator[None]:
    """Hold ``final``'s lock (``folder_lock``'s file; with ``kind``, a lock of its own, so that the block may publish
    ``final`` itself with ``atomic_directory``) for the whole block, or refuse at once (``InputError``) when another
    process holds it: for long work on one folder (a training run, a report) that a second command must not join."""
    fd = _open_lock(final, kind)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError(final, f"another process is working on this {what} now: wait for it to finish") from None
        yield
    finally:
        os.close(fd)


def check_replaceable_file(final: str | Path) -> None:
    """Refuse (``InputError``) an output file path that exists and is not a regular file (a folder, a device, a FIFO, a
    socket, a link): only a regular file or nothing is ever replaced."""
    final = Path(final)
    if final.is_symlink() or (final.exists() and not final.is_file()):
        raise InputError(final, "exists and is not a regular file: refusing to replace it")


#: What reading a damaged or foreign archive (an ``.npz``, a zip) raises: a cut or altered file (``BadZipFile``,
#: ``OSError``, ``ValueError``, ``EOFError``), a compression method zipfile lacks (``NotImplementedError``), an
#: encrypted member (``RuntimeError``), an array header that claims more memory than there is (``MemoryError``).
ARCHIVE_ERRORS = (zipfile.BadZipFile, OSError, ValueError, EOFError, NotImplementedError, RuntimeError, MemoryError)


def npz_format(path: Path, limit: int = 1 << 16) -> str | None:
    """The ``format`` that the JSON ``meta`` member of the ``.npz`` at ``path`` names (uavplace's array files record one),
    read without unpacking anything else (a member over ``limit`` bytes is not read); None for anything else."""
    import numpy as np

    try:
        with zipfile.ZipFile(path) as z:
            info = z.getinfo("meta.npy")
            if info.file_size > limit or info.flag_bits & 0x1:  # too large, or encrypted
                return None
            with z.open(info) as f:
                meta = json.loads(np.lib.format.read_array(f, allow_pickle=False).tobytes().decode("utf-8"))
    except (*ARCHIVE_ERRORS, KeyError):  # UnicodeDecodeError is a ValueError
        return None
    fmt = meta.get("format") if isinstance(meta, dict) else None
    return fmt if isinstance(fmt, str) else None


def check_own_npz(final: str | Path, fmt: str, what: str) -> None:
    """Refuse (``InputError``) to replace ``final`` unless it is absent or an ``.npz`` uavplace wrote in format ``fmt``
    (its ``meta``'s ``format`` begins with it): a user's own file of that name is never replaced."""
    final = Path(final)
    check_replaceable_file(final)
    if final.exists() and not (npz_format(final) or "").startswith(fmt):
        raise InputError(
            final, f"exists and is not a {what} uavplace wrote: refusing to replace it; move it or choose another --out"
        )


def _folder(what: str) -> str:
    """``what`` as a folder's name: "report folder", but "RadioMapSeer-style folder" as it is."""
    return what if what.endswith("folder") else f"{what} folder"


def check_replaceable(final: str | Path, marker: str, what: str) -> None:
    """Refuse (``InputError``) if ``final`` exists and is not an empty folder or a ``what`` uavplace made.

    uavplace's outputs carry ``marker`` (e.g. ``manifest.json``); anything else at
    that path (a file, someone's folder) is left alone.
    """
    final = Path(final)
    if final.is_symlink() or (final.exists() and not final.is_dir()):
        raise InputError(final, f"exists and is not a {_folder(what)}: refusing to replace it")
    if final.is_dir() and not (final / marker).is_file() and any(final.iterdir()):
        raise InputError(
            final,
            f"exists and is not a {what} made by uavplace (it has no {marker}): refusing to replace it; "
            "choose another output folder or name",
        )


#: The list of what uavplace wrote into an output folder, written beside what it lists: a later output replaces the
#: folder only if it holds nothing else (a user's file put there is never lost).
CONTENTS = ".uavplace-contents.json"
#: The largest contents list read (a larger one is not uavplace's).
_CONTENTS_BYTES = 1 << 20


def _entries(folder: Path) -> set[str]:
    return {p.name for p in folder.iterdir()} - {CONTENTS}


def foreign_entries(folder: Path) -> set[str] | None:
    """The entries of output ``folder`` that uavplace did not write there (not in its ``CONTENTS`` list); None when the
    folder has no readable list (made before the lists, or not by uavplace)."""
    listed = folder / CONTENTS
    try:
        if listed.is_symlink() or not listed.is_file() or listed.stat().st_size > _CONTENTS_BYTES:
            return None
        names = json.loads(listed.read_text(encoding="utf-8")).get("entries")
    except (OSError, ValueError, AttributeError):
        return None
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        return None
    return _entries(folder) - set(names)


def _refuse_foreign(final: Path, foreign: set[str], what: str, why: str) -> None:
    if foreign:
        shown = ", ".join(sorted(foreign)[:5]) + (f" and {len(foreign) - 5} more" if len(foreign) > 5 else "")
        raise InputError(
            final,
            f"holds {len(foreign)} entr{'y' if len(foreign) == 1 else 'ies'} {why} ({shown}): refusing to replace the "
            f"{_folder(what)}, which would lose them; move them away or choose another output",
        )


def check_output_folder(final: str | Path, marker: str, what: str, writes: Collection[str] = ()) -> set[str] | None:
    """Refuse (``InputError``) an output folder ``atomic_directory`` would not replace, before any work: not a
    ``what`` (``check_replaceable``), or holding entries that its contents list does not name, or, without a list,
    entries outside ``writes`` (the names such an output always has, where the caller knows them). Returns the
    folder's foreign entries by its list (empty), or None when it has no list (then checked again once the output is
    made)."""
    final = Path(final)
    check_replaceable(final, marker, what)
    if not final.is_dir():
        return set()
    listed = foreign_entries(final)
    _refuse_foreign(final, listed or set(), what, "that uavplace did not write there")
    if listed is None and writes:
        _refuse_foreign(final, _entries(final) - set(writes), what, f"that a {what} does not hold")
    return listed


@contextlib.contextmanager
def atomic_directory(
    final: str | Path, *, marker: str | None = None, what: str = "output", new: bool = False, lock: str | Path | None = None
) -> Iterator[Path]:
    """Yield a fresh temporary folder beside ``final``; on success it replaces ``final``.

    ``marker``: the file every folder of this kind holds; an existing ``final``
    without it (and not empty) is refused before anything is written
    (``check_replaceable``), and so is one holding entries its ``CONTENTS`` list
    (written into every output) does not name; one without a list (made before
    the lists) is replaced only if the new output has every entry it has. ``new``: a folder written once: an existing
    ``final`` is refused (``InputError``), also one another process wrote
    while this one worked. The whole block runs under ``folder_lock(final)``, or
    ``folder_lock(lock)``: one lock for many folders of one kind (every bundle
    version of a city), so that lock files do not pile up one per folder.

    On any exception the temporary folder is removed and ``final`` is left as
    it was. The swap is two renames on the same file system: the old folder is
    renamed aside, the new one into place, then the old one is deleted. If the
    process dies between the two renames, the next call restores the old
    folder first (``recover_directory``).
    """
    final = Path(final)
    with folder_lock(final if lock is None else lock):
        recover_directory(final)
        if new and (final.exists() or final.is_symlink()):
            raise InputError(final, f"exists: choose another output (the {_folder(what)} is written once)")
        listed = check_output_folder(final, marker, what) if marker is not None else None
        tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.tmp-", dir=final.parent))
        tmp.chmod(umask_mode(0o777))  # mkdtemp makes it private; outputs are not
        try:
            yield tmp
            if marker is not None and not (tmp / marker).is_file():
                raise RuntimeError(f"{final}: the output has no {marker}: not published")
            (tmp / CONTENTS).write_text(json.dumps({"what": what, "entries": sorted(_entries(tmp))}) + "\n", encoding="utf-8")
            if marker is not None and listed is None and final.is_dir():  # no list: whatever the new output lacks
                _refuse_foreign(final, _entries(final) - _entries(tmp), what, "that this output does not write")
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        old = final.parent / f".{final.name}.old"
        if final.exists():
            os.replace(final, old)
        os.replace(tmp, final)
        shutil.rmtree(old, ignore_errors=True)


def recover_directory(final: str | Path) -> None:
    """Undo a swap interrupted between its two renames, and remove stale temporary folders.

    Call it only while holding ``folder_lock(final)``: then every temporary
    folder of ``final`` belongs to a writer that is gone.
    """
    final = Path(final)
    old = final.parent / f".{final.name}.old"
    if old.exists():
        if final.exists():
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(old, final)
    for stale in final.parent.glob(f".{final.name}.tmp-*"):
        shutil.rmtree(stale, ignore_errors=True)


def describe_os_error(err: OSError) -> str:
    """One line for an operating-system error: the path and what went wrong (``ENOSPC`` spelled out)."""
    where = err.filename if err.filename is not None else "<file system>"
    if err.errno == errno.ENOSPC:
        return f"{where}: no space left on device (nothing was published; free space and run again)"
    return f"{where}: {err.strerror or err}"


def regular_file_bytes(path: Path, name: str, limit: str) -> bytes:
    """The bytes of ``path`` if it is a regular file within the limit ``limit`` (``mesh_bytes``: a mesh, or a file a
    mesh refers to, an OBJ's material library, a glTF's buffer; ``text_bytes``: a text export), else ``InputError``.
    Checked with ``stat`` before opening: a FIFO or a device would block or never end, and a sparse file of
    gigabytes is refused by its size before a byte of it is read."""
    from uavplace.infra.limits import check_limit

    try:
        st = os.stat(path)
    except OSError as exc:
        raise InputError(name, f"cannot read ({exc.strerror})") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError(name, "not a regular file (a FIFO, device or folder): refused")
    check_limit(limit, st.st_size, name, "file size [bytes]")
    return path.read_bytes()
