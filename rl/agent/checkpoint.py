"""Checkpoints that are data, never code.

A PyTorch ``.pt`` file is a pickle: loaded with ``weights_only=False`` it can run
any code its author put in it. Agents are what researchers exchange, so every
checkpoint uavplace reads is loaded with ``torch.load(weights_only=True)``,
which unpickles tensors, dicts, lists, strings and numbers only, and refuses
anything else with an ``InputError`` instead of running it. What is not a
tensor (random-generator states, counters) is kept in JSON and ``.npz``
(``allow_pickle=False``) beside the weights.

Formats:

- ``checkpoints/best.pt``: ``{"online": state_dict, "config": DQNConfig as JSON
  values, "eval": the evaluation row}``; the agent a report evaluates.
- ``checkpoints/last/``: the resumable state, one folder published by a
  rename (``infra.files.atomic_directory``), so it is whole or absent:
  ``networks.pt`` (networks, optimiser, torch RNG), ``env.npz`` (environment
  and run arrays), ``replay.npz``, ``metrics.parquet`` and ``eval.parquet``
  (the rows up to this step) and, written last, ``checkpoint.json`` (step,
  counters, numpy RNG states).
"""

from __future__ import annotations

import hashlib
import io
import math
import os
import pickle
import re
from pathlib import Path
from typing import Any

import torch
from pydantic import Field, model_validator

from uavplace.infra.files import atomic_write_bytes, read_small_file
from uavplace.infra.limits import limits
from uavplace.schemas import InputError
from uavplace.schemas.base import Contract

#: The reason inside ``torch.load(weights_only=True)``'s refusal ("Unsupported global: GLOBAL os.system ...").
_UNPICKLER_ERROR = re.compile(r"WeightsUnpickler error:\s*(\S[^\n]*)")
#: The resumable checkpoint folder's marker, written last.
CHECKPOINT_JSON = "checkpoint.json"


class CheckpointState(Contract):
    """``checkpoint.json``: the counters and random-generator states of a resumable checkpoint, checked on resume."""

    step: int = Field(ge=0, description="Environment steps done")
    updates: int = Field(ge=0, description="Gradient updates done")
    best_score: tuple[float, float] | None = Field(description="(success, -median steps) of the best evaluation")
    synced_at: int = Field(ge=0, description="Step of the last target-network sync")
    losses: list[float] = Field(max_length=10_000)
    episodes_started: int = Field(ge=0)
    rng: dict[str, Any] = Field(description="The trainer's numpy bit-generator state")
    env_rng: dict[str, Any] = Field(description="The environment's numpy bit-generator state")
    wall_s: float | None = Field(default=None, ge=0, description="Training seconds so far (None before they were kept)")

    @model_validator(mode="after")
    def _ordered(self) -> CheckpointState:
        if self.synced_at > self.step:
            raise ValueError(f"synced_at {self.synced_at} is after step {self.step}")
        if self.best_score is not None and not (0 <= self.best_score[0] <= 1 and self.best_score[1] <= 0):
            raise ValueError(f"best_score {list(self.best_score)}: expected (success in 0..1, -median steps <= 0)")
        if not all(math.isfinite(v) for v in self.losses):
            raise ValueError("losses holds NaN or inf: a training stops before it saves a non-finite loss")
        return self


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


def best_checkpoint(folder: str | Path) -> Path:
    """A run folder's ``checkpoints/best.pt``; ``InputError`` when there is none (one that is there but no regular
    file is refused by ``load_tensors``, as such)."""
    path = Path(folder) / "checkpoints" / "best.pt"
    if not os.path.lexists(path):
        raise InputError(folder, "no checkpoints/best.pt (not a training run, or it never evaluated)")
    return path


def load_tensors(path: str | Path, map_location: str | torch.device = "cpu", sha256: str | None = None) -> dict:
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
    bound = 16 * limits().network_params
    data = read_small_file(
        path, "a PyTorch checkpoint", missing="no such checkpoint", max_bytes=bound, limit="network_params x 16 bytes"
    )
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


def require(ck: dict, path: str | Path, *keys: str) -> None:
    """``InputError`` if the checkpoint dict lacks one of ``keys``."""
    missing = [k for k in keys if k not in ck]
    if missing:
        raise InputError(path, f"checkpoint lacks {', '.join(missing)}", field=missing[0])
