"""World assembly with MjSpec: scene (sky, light, ground) + road meshes + vehicles + traffic + cameras."""

from __future__ import annotations

import mujoco

from mjdrive import XML_DIR

PHYSICS_TIMESTEP = 0.002  # [s]


def scene_spec(timestep: float = PHYSICS_TIMESTEP) -> mujoco.MjSpec:
    """An empty flat world: ground plane (the drivable surface), sky, light, solver options."""
    spec = mujoco.MjSpec.from_file(str(XML_DIR / "scenes" / "ground.xml"))
    spec.option.timestep = timestep
    return spec
