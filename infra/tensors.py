"""Tensors that are data, never code: ``torch.load(weights_only=True)`` of a bounded regular file, a refusal naming the
file for anything else (rl/agent/checkpoint.py for the agents' checkpoints, rl/predictor/weights.py for the learned
predictor's weights)."""

from __future__ import annotations

import hashlib
import io
import pickle
import re
from pathlib import Path

import torch

from uavplace.infra.files import atomic_write_bytes, read_small_file
from uavplace.infra.limits import limits
from uavplace.schemas import InputError

#: The reason inside ``torch.load(weights_only=True)``'s refusal ("Unsupported global: GLOBAL os.system ...").
_UNPICKLER_ERROR = re.compile(r"WeightsUnpickler error:\s*(\S[^\n]*)")
#: Globals a weights-only checkpoint may name: torch's tensor rebuilders and storages, and OrderedDict.
_PLAIN_GLOBALS = ("torch.", "collections.OrderedDict")
#: Bytes of a pickle scanned for the globals it names (the scan runs nothing).
_SCAN_BYTES = 256 << 20


def non_finite(obj: object, prefix: str = "") -> str | None:
    """The key path of the first floating tensor in ``obj`` (dicts and lists of tensors) holding NaN or inf, or None."""
    if isinstance(obj, torch.Tensor):
        return prefix or "tensor" if obj.is_floating_point() and not bool(torch.isfinite(obj).all()) else None
    items = obj.items() if isinstance(obj, dict) else enumerate(obj) if isinstance(obj, (list, tuple)) else ()
    for key, value in items:
        found = non_finite(value, f"{prefix}.{key}" if prefix else str(key))
        if found is not None:
            return found
    return None


def save_tensors(obj: dict, path: str | Path) -> None:
    """``torch.save`` of tensors and plain containers only, written atomically (``atomic_write_bytes``: a full disk is
    an ``OSError`` naming the file, and nothing half-written is left). Weights with NaN or inf are refused (an
    ``InputError`` naming them) so that a diverged training never replaces a good checkpoint."""
    bad = non_finite(obj)
    if bad is not None:
        raise InputError(
            path, f"{bad} holds NaN or inf: the training diverged; the last good checkpoint is kept", field="weights"
        )
    buffer = io.BytesIO()  # serialised in memory: torch's writer words a full disk as an internal assertion
    torch.save(obj, buffer)
    atomic_write_bytes(path, buffer.getvalue())


def pickle_globals(path: str | Path) -> list[str]:
    """The ``module.name`` globals a checkpoint's pickle names (a zip's ``data.pkl``, or a bare pickle), read with
    ``pickletools`` (nothing is run or imported); an empty list when the bytes are no pickle."""
    import pickletools
    import zipfile

    path = Path(path)
    try:
        if zipfile.is_zipfile(path):
            with zipfile.ZipFile(path) as z:
                member = next((n for n in z.namelist() if n.endswith("data.pkl")), None)
                if member is None:
                    return []
                with z.open(member) as f:
                    data = f.read(_SCAN_BYTES)
        else:
            with open(path, "rb") as f:
                data = f.read(_SCAN_BYTES)
    except (OSError, zipfile.BadZipFile):
        return []
    names: list[str] = []
    strings: list[str] = []
    try:
        for op, arg, _ in pickletools.genops(data):
            if op.name in ("GLOBAL", "INST"):
                names.append(str(arg).replace(" ", "."))
            elif op.name == "STACK_GLOBAL":
                names.append(".".join(strings[-2:]))
            elif isinstance(arg, str):
                strings.append(arg)
    except Exception:  # noqa: BLE001 - a truncated or foreign stream: what was read so far is the answer
        pass
    return names


def load_tensors(
    path: str | Path,
    map_location: str | torch.device = "cpu",
    sha256: str | None = None,
    max_bytes: int | None = None,
    limit: str = "network_params x 16 bytes",
) -> dict:
    """Load a ``.pt`` of tensors and plain data with ``weights_only=True``; refuse anything else.

    Raises ``InputError`` naming the file: for a checkpoint that carries other
    Python objects (nothing of it runs), for a file that is not a PyTorch
    checkpoint, for one that is not a dict, and, given ``sha256`` (what a
    description of the weights names), for bytes that do not hash to it (hashed
    after the size check: a file of gigabytes is refused unread).
    """
    path = Path(path)
    # Read as every record is: a regular file (a FIFO is refused at once, never waited on) of a bounded size: a
    # network of the limit's parameters with its optimiser's two moments, in float32, and room to spare.
    bound = 16 * limits().network_params if max_bytes is None else max_bytes
    data = read_small_file(path, "a PyTorch checkpoint", missing="no such checkpoint", max_bytes=bound, limit=limit)
    if sha256 is not None and (digest := hashlib.sha256(data).hexdigest()) != sha256:
        mismatch = f"sha256 {digest[:12]}... is not the {sha256[:12]}... that its description names"
        raise InputError(path, mismatch + ": the weights and their description do not belong together")
    try:
        obj = torch.load(io.BytesIO(data), weights_only=True, map_location=map_location)
    except pickle.UnpicklingError as exc:
        found = _UNPICKLER_ERROR.search(str(exc))
        reason = found.group(1).strip() if found else (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        # Torch words its refusal differently by version and pickle protocol ("Unsupported global", "Unsupported
        # operand"): what the pickle names decides, not the wording.
        foreign = [n for n in pickle_globals(path) if not n.startswith(_PLAIN_GLOBALS)]
        if not foreign and "Unsupported global" not in reason:  # not a pickle of objects: the bytes of something else
            raise InputError(path, f"not a readable PyTorch checkpoint ({reason[:160]})") from None
        named = f"it names {', '.join(dict.fromkeys(foreign))[:120]}" if foreign else reason.split(". Please")[0][:160]
        raise InputError(
            path,
            "refused: the checkpoint holds Python objects other than tensors and plain data, which could run code "
            f"when loaded; uavplace loads weights only ({named}); nothing of it was run",
            field="pickle",
        ) from None
    except FileNotFoundError:
        raise InputError(path, "no such checkpoint") from None
    except Exception as exc:  # torch raises many types on bytes that are not a checkpoint
        raise InputError(path, f"not a readable PyTorch checkpoint ({type(exc).__name__}: {str(exc)[:160]})") from None
    if not isinstance(obj, dict):
        raise InputError(path, f"a checkpoint holds a dict, this one a {type(obj).__name__}")
    bad = non_finite(obj)
    if bad is not None:
        raise InputError(path, f"{bad} holds NaN or inf: not usable weights", field="weights")
    return obj
