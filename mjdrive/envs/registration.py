"""gymnasium ids: `gymnasium.make("mjdrive/Waypoints-Straight-v0", actions="table2", observation="camera")`."""

from __future__ import annotations

import warnings
from typing import Any

import gymnasium as gym

# id -> (domain, task, default task kwargs)
GYM_IDS: dict[str, tuple[str, str, dict]] = {
    "mjdrive/Waypoints-Straight-v0": ("waypoints", "straight", {}),
    "mjdrive/Waypoints-FourRoutes-v0": ("waypoints", "four_routes", {}),
    "mjdrive/Waypoints-RandomRoutes-v0": ("waypoints", "random_routes", {}),
    "mjdrive/Waypoints-Straight-Camera-v0": ("waypoints", "straight", {"observation": "camera"}),
    "mjdrive/Waypoints-FourRoutes-Camera-v0": ("waypoints", "four_routes", {"observation": "camera"}),
    "mjdrive/Waypoints-RandomRoutes-Camera-v0": ("waypoints", "random_routes", {"observation": "camera"}),
    **{f"mjdrive/Roundabout-D{level}-v0": ("roundabout", f"d{level}", {"observation": "features"})
       for level in (120, 140, 160, 210)},
    **{f"mjdrive/Roundabout-D{level}-Camera-v0": ("roundabout", f"d{level}", {"observation": "camera"})
       for level in (120, 140, 160, 210)},
    **{f"mjdrive/Urban-{name}-v0": ("urban", task, {"observation": "features"})
       for name, task in (("Roundabout", "roundabout"), ("LaneChange", "lane_change"), ("Crossroad", "crossroad"),
                          ("Merge", "merge"), ("Concatenated", "concatenated"), ("OpenDrive", "opendrive"))},
    **{f"mjdrive/Urban-{name}-Camera-v0": ("urban", task, {"observation": "camera"})
       for name, task in (("Roundabout", "roundabout"), ("LaneChange", "lane_change"), ("Crossroad", "crossroad"),
                          ("Merge", "merge"), ("Concatenated", "concatenated"), ("OpenDrive", "opendrive"))},
}


# old id -> its name now (named after the task); still made, with a DeprecationWarning
DEPRECATED_IDS: dict[str, str] = {
    "mjdrive/Waypoints-Random-v0": "mjdrive/Waypoints-RandomRoutes-v0",
    "mjdrive/Waypoints-Random-Camera-v0": "mjdrive/Waypoints-RandomRoutes-Camera-v0",
}


def make_deprecated(old_id: str, new_id: str, **kwargs: Any) -> gym.Env:
    """Entry point of a deprecated id: warns, then makes the env of the id it was renamed to."""
    from mjdrive.envs.gym_env import make_env

    warnings.warn(f"{old_id} is deprecated: it is now {new_id} (named after its task)", DeprecationWarning,
                  stacklevel=2)
    return make_env(**kwargs)


def register_all() -> None:
    for env_id, (domain, task, kwargs) in GYM_IDS.items():
        if env_id not in gym.registry:
            gym.register(env_id, entry_point="mjdrive.envs.gym_env:make_env",
                         kwargs={"domain": domain, "task": task, **kwargs})
    for old_id, new_id in DEPRECATED_IDS.items():
        if old_id not in gym.registry:
            domain, task, kwargs = GYM_IDS[new_id]
            gym.register(old_id, entry_point="mjdrive.envs.registration:make_deprecated",
                         kwargs={"old_id": old_id, "new_id": new_id, "domain": domain, "task": task, **kwargs})
