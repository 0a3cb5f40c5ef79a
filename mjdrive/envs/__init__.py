"""gymnasium adapters: DrivingGymEnv, action tables, registered ids.

Kept light on import (the ids are registered when `mjdrive` is imported); the env classes load lazily.
"""

from mjdrive.envs.actions import ACTION_TABLES, DiscreteActions, wrap_actions
from mjdrive.envs.registration import GYM_IDS, register_all

register_all()


def __getattr__(name: str):
    if name in ("DrivingGymEnv", "make_env"):
        from mjdrive.envs import gym_env

        return getattr(gym_env, name)
    raise AttributeError(name)


__all__ = ["ACTION_TABLES", "DiscreteActions", "DrivingGymEnv", "GYM_IDS", "make_env", "register_all", "wrap_actions"]
