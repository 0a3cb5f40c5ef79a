"""gymnasium ids: `gymnasium.make("mjdrive/Waypoints-Straight-v0", actions="table2", observation="camera")`."""

from __future__ import annotations

import gymnasium as gym

# id -> (domain, task, default task kwargs)
GYM_IDS: dict[str, tuple[str, str, dict]] = {
    "mjdrive/Waypoints-Straight-v0": ("waypoints", "straight", {}),
    "mjdrive/Waypoints-FourRoutes-v0": ("waypoints", "four_routes", {}),
    "mjdrive/Waypoints-Random-v0": ("waypoints", "random_routes", {}),
    "mjdrive/Waypoints-Straight-Camera-v0": ("waypoints", "straight", {"observation": "camera"}),
    "mjdrive/Waypoints-FourRoutes-Camera-v0": ("waypoints", "four_routes", {"observation": "camera"}),
    "mjdrive/Waypoints-Random-Camera-v0": ("waypoints", "random_routes", {"observation": "camera"}),
    **{f"mjdrive/Roundabout-D{level}-v0": ("roundabout", f"d{level}", {"observation": "features"})
       for level in (120, 140, 160, 210)},
    **{f"mjdrive/Roundabout-D{level}-Camera-v0": ("roundabout", f"d{level}", {"observation": "camera"})
       for level in (120, 140, 160, 210)},
}


def register_all() -> None:
    for env_id, (domain, task, kwargs) in GYM_IDS.items():
        if env_id not in gym.registry:
            gym.register(env_id, entry_point="mjdrive.envs.gym_env:make_env",
                         kwargs={"domain": domain, "task": task, **kwargs})
