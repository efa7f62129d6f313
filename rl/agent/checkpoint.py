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
  rename (``schemas.files.atomic_directory``), so it is whole or absent:
  ``networks.pt`` (networks, optimiser, torch RNG), ``env.npz`` (environment
  and run arrays), ``replay.npz``, ``metrics.parquet`` and ``eval.parquet``
  (the rows up to this step) and, written last, ``checkpoint.json`` (step,
  counters, numpy RNG states).
"""

from __future__ import annotations

import pickle
import re
from pathlib import Path

import torch

from uavplace.schemas import InputError

#: The reason inside ``torch.load(weights_only=True)``'s refusal ("Unsupported global: GLOBAL os.system ...").
_UNPICKLER_ERROR = re.compile(r"WeightsUnpickler error:\s*(\S[^\n]*)")
#: The resumable checkpoint folder's marker, written last.
CHECKPOINT_JSON = "checkpoint.json"


def save_tensors(obj: dict, path: str | Path) -> None:
    """``torch.save`` of tensors and plain containers only (the caller makes it atomic)."""
    torch.save(obj, path)


def load_tensors(path: str | Path, map_location: str | torch.device = "cpu") -> dict:
    """Load a ``.pt`` of tensors and plain data with ``weights_only=True``; refuse anything else.

    Raises ``InputError`` naming the file: for a checkpoint that carries other
    Python objects (nothing of it runs), for a file that is not a PyTorch
    checkpoint, and for one that is not a dict.
    """
    path = Path(path)
    try:
        obj = torch.load(path, weights_only=True, map_location=map_location)
    except pickle.UnpicklingError as exc:
        found = _UNPICKLER_ERROR.search(str(exc))
        reason = found.group(1).strip() if found else (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        if "Unsupported global" not in reason:  # not a pickle of objects at all: the bytes of something else
            raise InputError(path, f"not a readable PyTorch checkpoint ({reason[:160]})") from None
        raise InputError(
            path,
            "refused: the checkpoint holds Python objects other than tensors and plain data, which could run code "
            f"when loaded; uavplace loads weights only ({reason.split('. Please')[0][:160]}); nothing of it was run",
            field="pickle",
        ) from None
    except FileNotFoundError:
        raise InputError(path, "no such checkpoint") from None
    except Exception as exc:  # torch raises many types on bytes that are not a checkpoint
        raise InputError(path, f"not a readable PyTorch checkpoint ({type(exc).__name__}: {str(exc)[:160]})") from None
    if not isinstance(obj, dict):
        raise InputError(path, f"a checkpoint holds a dict, this one a {type(obj).__name__}")
    return obj


def require(ck: dict, path: str | Path, *keys: str) -> None:
    """``InputError`` if the checkpoint dict lacks one of ``keys``."""
    missing = [k for k in keys if k not in ck]
    if missing:
        raise InputError(path, f"checkpoint lacks {', '.join(missing)}", field=missing[0])
