"""What every task's Gymnasium face shares: its settings from a model, a dict or overrides, validated as the command
line's are (``with_overrides``), the bundles it is made from (``task_bundles``), and its observation's bounds
(``observation_bounds``). The faces are each task's ``gym.py``; ``rl/__init__.py`` registers them."""

from __future__ import annotations


def with_overrides(kind: type, config: object, overrides: dict) -> object:
    """The settings ``config`` (a ``kind``, a dict of its fields or None) with ``overrides``, validated as the command
    line's are: an unknown field, or a value out of its range, is a ``ValueError`` of one line naming the field
    (``model_copy(update=...)`` would take anything)."""
    from pydantic import ValidationError

    from uavplace.schemas.base import validation_message

    try:
        base = config if isinstance(config, kind) else kind(**(config or {}))
        return kind.model_validate({**base.model_dump(), **overrides})
    except ValidationError as exc:
        field, message = validation_message(exc)
        raise ValueError(f"{kind.__name__}.{field}: {message}") from None


def task_bundles(dataset: str | list[str], config: object, kind: type, root: str, overrides: dict) -> tuple[list, object]:
    """(the bundles of ``dataset``, a city name or list; the task's ``kind`` config from ``config``, a ``kind``, a
    dict of its fields or None, with ``overrides``): what the tracking and fleet environments are made from."""
    from uavplace.dataset.bundle import load_bundle

    merged = with_overrides(kind, config, overrides)
    names = [dataset] if isinstance(dataset, str) else list(dataset)
    return [load_bundle(n, root=root) for n in names], merged


def observation_bounds(config: object, *more_high: float) -> tuple[float, float]:
    """(low, high) of an observation: P_L and the clipped depth below, P_H, the clipped height, the edge's height
    (and ``more_high``) above."""
    low = min(config.p_l_db, -config.height_clip_m)
    return low, max(config.p_h_db, config.height_clip_m, config.edge_height_m, *more_high)
