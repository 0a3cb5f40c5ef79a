"""The envs a learner's config describes."""

from __future__ import annotations

from mjdrive.agents.common import make_batched_env, training_tasks


def make_training_env(config: dict, num_envs: int | None = None, **overrides):
    """The vector env a config describes (`make_batched_env`'s keys), in this process, or with `workers: N`
    over N worker processes, or with `ray: ADDRESS` ("local", "auto", HOST:PORT) over N Ray actors
    (`mjdrive.envs.vector`); every backend gives the same episodes."""
    workers, address = int(config.get("workers") or 0), config.get("ray")
    if not workers and address is None:
        return make_batched_env(config, num_envs, **overrides)
    from mjdrive.envs.vector import make_vec_env

    domain, tasks = training_tasks(config)
    return make_vec_env(domain, tasks, num_envs=num_envs or config.get("num_envs", 1),
                        actions=config.get("actions", "continuous"), workers=workers, ray=address,
                        backend=config.get("backend", "threads"), record_dir=config.get("record_dir"),
                        **{**config.get("task_kwargs", {}), **overrides})
