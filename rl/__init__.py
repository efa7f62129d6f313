"""UAV placement environments and agents; reads map bundles only (``dataset.bundle``).

Importing ``rl`` registers every task's Gymnasium environments (its entry's ``gym``, ``rl.tasks.registry``):
placement's ``uavplace/UavPlacement-v0`` and ``uavplace/BlindUavPlacement-v0``
(``gymnasium.make("uavplace/UavPlacement-v0", dataset="cityA")``), and one for each other task.
"""

from gymnasium.envs.registration import register, registry

from uavplace.rl.tasks.registry import TASKS

for _task in TASKS.values():
    for _id, _entry, _kwargs in _task.gym:
        if _id not in registry:
            register(id=_id, entry_point=_entry, kwargs=_kwargs)
