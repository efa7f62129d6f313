"""UAV placement environments and agents; reads map bundles only (``dataset.bundle``).

Importing ``rl`` registers the Gymnasium environments ``uavplace/UavPlacement-v0`` and
``uavplace/BlindUavPlacement-v0``: ``gymnasium.make("uavplace/UavPlacement-v0", dataset="cityA")``, and the
tracking task's ``uavplace/UavTracking-v0`` (a bundle with routes; ``rl.tasks.tracking``) and the fleet task's
``uavplace/UavFleet-v0`` (several UAVs, several users; ``rl.tasks.fleet``).
"""

from gymnasium.envs.registration import register, registry

for _id, _kwargs in (("uavplace/UavPlacement-v0", {}), ("uavplace/BlindUavPlacement-v0", {"blind": True})):
    if _id not in registry:
        register(id=_id, entry_point="uavplace.rl.tasks.placement.gym:UavPlacementEnv", kwargs=_kwargs)
if "uavplace/UavTracking-v0" not in registry:
    register(id="uavplace/UavTracking-v0", entry_point="uavplace.rl.tasks.tracking.gym:UavTrackingEnv")
if "uavplace/UavFleet-v0" not in registry:
    register(id="uavplace/UavFleet-v0", entry_point="uavplace.rl.tasks.fleet.gym:UavFleetEnv")
