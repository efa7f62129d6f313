"""Where the arithmetic runs: ``auto`` (CUDA where there is a GPU, else the CPU), ``cpu`` or ``cuda``, one rule for
torch (the agents' networks, the belief products) and for Mitsuba (the ray tracer's variant, ``simulate.raytrace``).

What moves to a GPU, and how far its numbers may differ from the CPU's, is in docs/benchmarks.md ("A GPU where
there is one"). A choice of ``cuda`` on a machine without one is an error, never a silent fall back to the CPU.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal, get_args

if TYPE_CHECKING:
    import torch

#: The settings of a ``--device`` option.
Device = Literal["auto", "cpu", "cuda"]
DEVICES: tuple[str, ...] = ("auto", "cpu", "cuda")
#: How an acting network's features are computed (``rl.agent.dqn.DQNPolicy``'s ``precision``, a report's
#: ``network_precision``): float32, or under torch's bfloat16 autocast (2 to 4 x faster on a CPU with bfloat16 units;
#: its moves validated per report, docs/benchmarks.md).
NetworkPrecision = Literal["float32", "bfloat16"]
NETWORK_PRECISIONS: tuple[str, ...] = get_args(NetworkPrecision)
#: The description every ``--device`` option shares.
DEVICE_HELP = "auto: CUDA where there is a GPU, else the CPU; cpu; cuda (an error without a GPU)"


def pick(device: str, cuda_available: bool, what: str) -> str:
    """``cpu`` or ``cuda`` for the setting ``device`` when ``cuda_available`` says whether ``what`` finds a GPU;
    ``ValueError`` for an unknown setting or ``cuda`` without one."""
    if device not in DEVICES:
        raise ValueError(f"unknown device {device!r}: {', '.join(DEVICES)}")
    if device == "cuda" and not cuda_available:
        raise ValueError(f"device cuda: no GPU that {what} can use here (auto or cpu run on the CPU)")
    return "cuda" if device != "cpu" and cuda_available else "cpu"


def torch_device(device: str, cuda_available: bool | None = None) -> torch.device:
    """The torch device of the setting ``device``, or of ``cuda:N`` (one GPU of several); ``cuda_available``
    overrides the look (None: ask torch)."""
    import torch

    if cuda_available is None:
        cuda_available = torch.cuda.is_available()
    one_gpu = device.startswith("cuda:") and device[5:].isdigit()
    return torch.device(device if one_gpu and pick("cuda", cuda_available, "torch") else pick(device, cuda_available, "torch"))


def require_torch_device(device: str) -> None:
    """A command's check of its ``--device`` before any work: ``click.BadParameter`` where torch cannot run there.
    Only ``cuda`` asks torch (imported then); ``auto`` and ``cpu`` always run."""
    import click

    try:
        if device.startswith("cuda"):
            torch_device(device)
        else:
            pick(device, False, "torch")
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint="'--device'") from None
