"""The registry: names, tags, clear errors, and dm_env conformance of every task."""

import dm_env
import numpy as np
import pytest
from absl.testing import absltest
from dm_env import test_utils

from mjdrive import suite


def test_all_tasks_listed_by_domain_and_tag():
    assert ("waypoints", "straight") in suite.ALL_TASKS
    assert set(suite.TASKS_BY_DOMAIN["waypoints"]) >= {"straight", "four_routes", "random_routes"}
    assert ("waypoints", "straight") in suite.tasks_with_tag("evaluation")
    assert ("waypoints", "random_routes") not in suite.tasks_with_tag("crafted")


def test_unknown_names_list_the_valid_ones():
    with pytest.raises(ValueError, match="valid tasks: .*waypoints/straight"):
        suite.load("waypoints", "no_such_task")
    with pytest.raises(ValueError, match="valid domains: .*waypoints"):
        suite.load("nowhere", "straight")
    with pytest.raises(ValueError, match="valid tags"):
        suite.tasks_with_tag("nope")
    with pytest.raises(ValueError, match="observation='lidar': must be one of 'features', 'camera'"):
        suite.load("waypoints", "straight", {"observation": "lidar"})


def test_nan_action_raises():
    env = suite.load("waypoints", "straight", {"random": 0})
    env.reset()
    with pytest.raises(ValueError, match="NaN|nan|finite"):
        env.step(np.array([np.nan, 0.0, 0.0]))


def test_physics_blow_up_ends_the_episode_with_a_flag():
    env = suite.load("waypoints", "straight", {"random": 0})
    env.reset()
    env.physics.data.qvel[:] = 1e12  # an unstable state: MuJoCo raises a bad-qacc warning
    timestep = env.step(np.zeros(3))
    assert timestep.last() and timestep.discount == 0.0
    assert env.task.info["physics_error"]
    assert env.step(np.zeros(3)).first()  # the next step starts a fresh episode


def _conformance_case(domain, task, observation):
    class Case(test_utils.EnvironmentTestMixin, absltest.TestCase):
        def make_object_under_test(self):
            return suite.load(domain, task, {"random": 0, "observation": observation})

        def make_action_sequence(self):
            rng = np.random.default_rng(0)
            spec = self.environment.action_spec()
            for _ in range(20):
                yield rng.uniform(spec.minimum, spec.maximum)

    Case.__name__ = f"TestConformance_{domain}_{task}_{observation}"
    return Case


for _domain, _task in suite.ALL_TASKS:
    for _obs in ("features", "camera"):
        _case = _conformance_case(_domain, _task, _obs)
        globals()[_case.__name__] = _case
del _case  # collected by name only


def test_first_step_types():
    env = suite.load("waypoints", "straight", {"random": 0})
    assert env.reset().step_type == dm_env.StepType.FIRST
    assert env.step(np.zeros(3)).step_type == dm_env.StepType.MID
