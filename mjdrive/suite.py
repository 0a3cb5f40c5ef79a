"""The task registry, dm_control-style: `load(domain, task)`, `ALL_TASKS`, `TASKS_BY_DOMAIN`, tags.

    from mjdrive import suite
    env = suite.load("waypoints", "straight", task_kwargs={"random": 0, "observation": "camera"})
"""

from __future__ import annotations

import collections
from typing import Any

from mjdrive.tasks import roundabout, waypoints
from mjdrive.tasks.base import DrivingEnvironment

_DOMAINS = {"roundabout": roundabout, "waypoints": waypoints}


def _get_tasks(tag: str | None) -> tuple[tuple[str, str], ...]:
    result = []
    for domain_name in sorted(_DOMAINS):
        tasks = _DOMAINS[domain_name].SUITE
        tasks = tasks if tag is None else tasks.tagged(tag)
        result.extend((domain_name, task_name) for task_name in tasks)
    return tuple(result)


def _get_tasks_by_domain(tasks) -> dict[str, tuple[str, ...]]:
    result = collections.defaultdict(list)
    for domain_name, task_name in tasks:
        result[domain_name].append(task_name)
    return {k: tuple(v) for k, v in result.items()}


ALL_TASKS = _get_tasks(tag=None)
TASKS_BY_DOMAIN = _get_tasks_by_domain(ALL_TASKS)
TAGS = tuple(sorted({tag for module in _DOMAINS.values() for tag in module.SUITE.tags()}))


def tasks_with_tag(tag: str) -> tuple[tuple[str, str], ...]:
    """(domain, task) pairs carrying `tag`; unknown tags raise ValueError listing the valid ones."""
    if tag not in TAGS:
        raise ValueError(f"unknown tag {tag!r}; valid tags: {', '.join(TAGS)}")
    return _get_tasks(tag)


def load(
    domain_name: str,
    task_name: str,
    task_kwargs: dict[str, Any] | None = None,
    environment_kwargs: dict[str, Any] | None = None,
) -> DrivingEnvironment:
    """Build a task's environment. Unknown names raise ValueError listing the valid ones.

    task_kwargs go to the task constructor (e.g. `random` seed, `observation`, `buildings`, `vehicle`,
    `time_limit`); environment_kwargs to the dm_control Environment (e.g. `control_timestep`).
    """
    if domain_name not in _DOMAINS:
        raise ValueError(f"unknown domain {domain_name!r}; valid domains: {', '.join(sorted(_DOMAINS))}")
    domain = _DOMAINS[domain_name]
    if task_name not in domain.SUITE:
        valid = ", ".join(f"{domain_name}/{t}" for t in domain.SUITE)
        raise ValueError(f"unknown task {domain_name}/{task_name}; valid tasks: {valid}")
    task_kwargs = dict(task_kwargs or {})
    if environment_kwargs is not None:
        task_kwargs["environment_kwargs"] = environment_kwargs
    return domain.SUITE[task_name](**task_kwargs)
