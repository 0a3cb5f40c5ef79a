"""The envs a learner's config describes: one batched env in this process, or a vector env over workers."""

from __future__ import annotations

from mjdrive.envs.batched import BatchedEnv
from mjdrive.suite import split_task


def training_tasks(config: dict) -> tuple[str, list[str]]:
    """(domain, task names) the copies of a config's batched env run: `task`, then the optional `mix_tasks`
    (same domain) in turn, copy i running the i-th modulo their count. Evaluation defaults to `task` alone."""
    domain, task = split_task(config["task"])
    names = [task]
    for other in config.get("mix_tasks") or []:
        other_domain, other_task = split_task(other)
        if other_domain != domain:
            raise ValueError(f"mix_tasks must be tasks of {domain} (the domain of task), got {other!r}")
        names.append(other_task)
    return domain, names


def make_batched_env(config: dict, num_envs: int | None = None, **overrides) -> BatchedEnv:
    """The BatchedEnv a config describes (`task`, `mix_tasks`, `task_kwargs`, `actions`, `num_envs`, `nthread`,
    `backend`)."""
    domain, tasks = training_tasks(config)
    task_kwargs = {**config.get("task_kwargs", {}), **overrides}
    return BatchedEnv(domain, tasks, num_envs=num_envs or config.get("num_envs", 1),
                      actions=config.get("actions", "continuous"), nthread=config.get("nthread", 1),
                      backend=config.get("backend", "threads"), record_dir=config.get("record_dir"),
                      **task_kwargs)


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
