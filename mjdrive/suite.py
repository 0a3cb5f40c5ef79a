"""The task registry, dm_control-style: `load(domain, task)`, `ALL_TASKS`, `TASKS_BY_DOMAIN`, tags.

    from mjdrive import suite
    env = suite.load("waypoints", "straight", task_kwargs={"random": 0, "observation": "camera"})
"""

from __future__ import annotations

import collections
import difflib
from collections.abc import Mapping
from typing import Any

from mjdrive.config import ConfigError
from mjdrive.tasks import roundabout, urban, waypoints
from mjdrive.tasks.base import DrivingConfig, DrivingEnvironment

_DOMAINS = {"roundabout": roundabout, "urban": urban, "waypoints": waypoints}


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


def split_task(name: str) -> tuple[str, str]:
    """(domain, task) of a "DOMAIN/TASK" name; ValueError when it is not of that form (not a registry check:
    `task_config` does that)."""
    domain, sep, task = name.partition("/")
    if not sep or not domain or not task or "/" in task:
        raise ValueError(f"expected DOMAIN/TASK (e.g. waypoints/straight), got {name!r}")
    return domain, task


def tasks_with_tag(tag: str) -> tuple[tuple[str, str], ...]:
    """(domain, task) pairs carrying `tag`; unknown tags raise ValueError listing the valid ones."""
    if tag not in TAGS:
        raise ValueError(f"unknown tag {tag!r}; valid tags: {', '.join(TAGS)}")
    return _get_tasks(tag)


def _task_fn(domain_name: str, task_name: str):
    if domain_name not in _DOMAINS:
        raise ConfigError(f"unknown domain {domain_name!r}; valid domains: {', '.join(sorted(_DOMAINS))}")
    domain = _DOMAINS[domain_name]
    if task_name not in domain.SUITE:
        valid = ", ".join(f"{domain_name}/{t}" for t in domain.SUITE)
        close = difflib.get_close_matches(task_name, list(domain.SUITE), n=1)
        hint = f" (did you mean {domain_name}/{close[0]}?)" if close else ""
        raise ConfigError(f"unknown task {domain_name}/{task_name}{hint}; valid tasks: {valid}")
    return domain.SUITE[task_name]


def task_config(domain_name: str, task_name: str) -> tuple[type[DrivingConfig], dict[str, Any]]:
    """The task's config class and its per-task defaults: `cls.from_dict(kwargs, defaults)` validates
    keywords, `cls.markdown(defaults)` is its table."""
    task_fn = _task_fn(domain_name, task_name)
    return task_fn.config_class, dict(task_fn.config_defaults)


def task_description(domain_name: str, task_name: str) -> str:
    """The task's docstring (its first line is a one-line description)."""
    return (_task_fn(domain_name, task_name).__doc__ or "").strip()


def kwargs_reference() -> str:
    """Markdown of every task's keywords (tasks with the same table share one section); docs/task_kwargs.md
    is this text (`mjdrive list --kwargs all > docs/task_kwargs.md`; a test keeps them equal)."""
    sections: dict[str, list[str]] = {}
    for domain_name, task_name in ALL_TASKS:
        config_class, defaults = task_config(domain_name, task_name)
        sections.setdefault(config_class.markdown(defaults), []).append(f"`{domain_name}/{task_name}`")
    parts = ["# Task keywords", "",
             "Generated from the tasks' configuration classes by `mjdrive list --kwargs all`; the same checks run "
             "when a task is made (`suite.load`, `gymnasium.make`, `--task-kwarg`), and a bad value raises "
             "`mjdrive.ConfigError` naming the keyword, the value and what is allowed. Lists are given as JSON "
             "on the command line (`--task-kwarg start_noise=[0,0]`), `null` for None."]
    for table, names in sections.items():
        parts += ["", "## " + ", ".join(names), "", table]
    return "\n".join(parts) + "\n"


def load(
    domain_name: str,
    task_name: str,
    task_kwargs: Mapping[str, Any] | None = None,
    environment_kwargs: Mapping[str, Any] | None = None,
) -> DrivingEnvironment:
    """Build a task's environment. Unknown names and bad keywords raise `ConfigError` (a ValueError) that
    names what is wrong and lists what is allowed.

    task_kwargs are validated into the task's config (`mjdrive list --kwargs DOMAIN/TASK` lists them: e.g.
    `random` seed, `observation`, `vehicle`, `time_limit` [s], `physics_dt` [s]); environment_kwargs go to the
    dm_control Environment (`control_timestep` [s], `flat_observation`).
    """
    task_fn = _task_fn(domain_name, task_name)
    for name, kwargs in (("task_kwargs", task_kwargs), ("environment_kwargs", environment_kwargs)):
        if kwargs is not None and not isinstance(kwargs, Mapping):
            raise ConfigError(f"{name} must be a mapping of keyword -> value, got {type(kwargs).__name__}")
    task_kwargs = dict(task_kwargs or {})
    if "environment_kwargs" in task_kwargs:
        raise ConfigError("pass environment_kwargs as load()'s own argument, not inside task_kwargs")
    return task_fn(environment_kwargs=environment_kwargs, **task_kwargs)
