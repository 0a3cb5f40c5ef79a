"""Action sets as gymnasium wrappers over (throttle, steer, brake): the studies' discrete tables, and "pedal"
(one signed pedal axis + steer) for continuous learners."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from mjdrive.config import action_index

KEEP = np.nan  # in a table's steer column: keep the previous steer command

# Study 004, Table 1: throttle 0.5 with steer -0.1 / 0 / 0.1, or coast (throttle 0) keeping the last steer.
TABLE1 = np.array([[0.5, -0.1, 0.0], [0.5, 0.0, 0.0], [0.5, 0.1, 0.0], [0.0, KEEP, 0.0]])
# Study 004, Table 2: throttle {0, 0.5, 1} x steer {-1, -0.75, ..., 1}.
TABLE2 = np.array([[t, s, 0.0] for t in (0.0, 0.5, 1.0) for s in np.linspace(-1.0, 1.0, 9)])
# Study 000, Table 1: DQN's a0..a6 as (throttle, steer, brake).
ROUNDABOUT7 = np.array([
    [0.6, 0.0, 0.0], [0.5, -0.5, 0.0], [0.5, 0.5, 0.0], [0.3, 0.0, 0.0],
    [0.3, -0.5, 0.5], [0.3, 0.5, 0.0], [0.0, 0.0, 0.5],
])
ACTION_TABLES = {"table1": TABLE1, "table2": TABLE2, "roundabout7": ROUNDABOUT7}


class DiscreteActions(gym.ActionWrapper):
    """Maps a discrete action index to a row (throttle, steer, brake) of `table`."""

    def __init__(self, env: gym.Env, table: np.ndarray, name: str = "discrete"):
        super().__init__(env)
        self.table = np.asarray(table, np.float64)
        self.name = name  # the action set's name, in errors
        self.action_space = gym.spaces.Discrete(len(self.table))
        self._last_steer = 0.0

    def reset(self, **kwargs):
        self._last_steer = 0.0
        return self.env.reset(**kwargs)

    def action(self, action) -> np.ndarray:
        command = self.table[action_index(action, len(self.table), self.name)].copy()
        if np.isnan(command[1]):
            command[1] = self._last_steer
        self._last_steer = command[1]
        return command.astype(np.float32)


class PedalActions(gym.ActionWrapper):
    """(pedal, steer) in [-1, 1]^2 -> (throttle, steer, brake) = (max(pedal, 0), steer, max(-pedal, 0)).

    The same three channels, never throttle and brake at once. With (throttle, steer, brake) a policy that
    starts at the middle of its box (tanh-Gaussian SAC: throttle 0.5, brake 0.5) holds the car still, and
    uniform random exploration brakes as often as it drives; here zero is coasting and the sign picks
    the pedal (as CARLA RL agents such as Roach, Zhang et al. 2021, do).
    """

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)

    def action(self, action) -> np.ndarray:
        pedal, steer = np.asarray(action, np.float64).reshape(2)
        if not (np.isfinite(pedal) and np.isfinite(steer)):
            raise ValueError(f"pedal action must be finite, got {action!r}")
        return np.array([max(pedal, 0.0), steer, max(-pedal, 0.0)], np.float32)


ACTION_SETS = ("continuous", "pedal", *ACTION_TABLES)


def wrap_actions(env: gym.Env, actions: str) -> gym.Env:
    """"continuous" leaves the env as is; "pedal" and the table names of ACTION_TABLES wrap it."""
    if actions == "continuous":
        return env
    if actions == "pedal":
        return PedalActions(env)
    if actions not in ACTION_TABLES:
        raise ValueError(f"unknown action set {actions!r}; valid: {', '.join(ACTION_SETS)}")
    return DiscreteActions(env, ACTION_TABLES[actions], actions)
