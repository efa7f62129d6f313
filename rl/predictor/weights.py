"""The learned tier's weights read as data: a bounded regular file of tensors only (``torch.load(weights_only=True)``,
``infra.tensors.load_tensors``), whose sha256 is the one its ``model.json`` names, loaded into the network it was
made for. The bound is the network's own size: a U-Net of ``n`` float32 parameters is ``4 n`` bytes and a little
of torch's zip framing, so a larger file is refused unread."""

from __future__ import annotations

from pathlib import Path

from torch import nn

from uavplace.infra.tensors import load_tensors
from uavplace.schemas import InputError

#: Bytes a weights file may hold beyond its parameters' float32 values: torch's zip headers, names and pickle.
FRAMING_BYTES = 1 << 20


def load_weights(net: nn.Module, path: Path, sha256: str, shape: str) -> None:
    """Load the weights at ``path`` into ``net`` (in place): ``InputError`` naming the file when it is larger than
    ``net``'s parameters allow, not the bytes ``sha256`` names, not tensors only, or of other shapes than ``net``'s
    (``shape`` says what ``net`` was made as, e.g. ``widths [16, 32]``)."""
    params = sum(p.numel() for p in net.state_dict().values())
    bound = 4 * params + FRAMING_BYTES
    state = load_tensors(path, sha256=sha256, max_bytes=bound, limit=f"{params} parameters of float32")
    try:
        net.load_state_dict(state)
    except RuntimeError as exc:
        raise InputError(path, f"weights do not fit {shape}: {str(exc)[:200]}") from None
