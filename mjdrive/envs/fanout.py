"""Independent jobs (evaluation episodes) fanned out over worker processes or a Ray cluster, gathered by index.

    from mjdrive.envs.fanout import fan_out
    results = fan_out(run_episode, spec, range(200), workers=4)            # {index: result}, 4 processes
    results = fan_out(run_episode, spec, range(200), workers=8, ray="auto")  # Ray tasks on a cluster

`function(spec, index)` must be a module-level (picklable) function whose result depends only on `spec` and
`index` (an episode seeds itself from its index, never from the worker or the order of completion): then the
results are the same for any number of workers and either backend. Worker processes may keep state between
jobs in module globals (a loaded policy, a built env).

Backends: `workers=0` runs the jobs here in order; `workers=N` in a `concurrent.futures.ProcessPoolExecutor`
of N processes (forkserver on Linux, else spawn), each with one compute thread (`vector.pin_threads`) and
Ctrl-C left to the parent; `ray` (an address, "local" for a private Ray of `workers` CPUs) as Ray tasks of one
CPU, at most `workers` in flight (all of the cluster's CPUs when `workers=0`).
Faults: a worker process that dies (kill -9, out of memory) breaks the pool; its unfinished jobs run again in
a new pool (`max_restarts` times at most); Ray reruns a task whose worker died by itself (`max_retries`).
Ctrl-C (KeyboardInterrupt), and SIGTERM where nobody else handles it, terminate the workers (or cancel the Ray
tasks) before propagating; a parent killed outright (SIGKILL) takes its workers with it (`exit_with_parent`).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

from mjdrive.envs.vector import exit_with_parent, pin_threads, ray_connect, ray_module, worker_context

T = TypeVar("T")
MAX_RESTARTS = 3  # new pools (local) or retries per task (Ray) after workers died


def _init_worker(parent_pid: int) -> None:
    pin_threads()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's: it terminates the workers
    exit_with_parent(parent_pid)  # a parent killed outright (SIGKILL) leaves no worker behind


@contextlib.contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM (kill, a scheduler's time limit) stops a fan-out like Ctrl-C, workers terminated, where nobody
    else handles it (the main thread, default handler)."""
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        yield
        return

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def fan_out(function: Callable[[Any, int], T], spec: Any, indices: Iterable[int], workers: int = 0,
            ray: str | None = None, on_result: Callable[[int, T], None] | None = None,
            max_restarts: int = MAX_RESTARTS, context: str | None = None,
            log: Callable[[str], None] | None = None) -> dict[int, T]:
    """{index: function(spec, index)} for every index; `on_result(index, result)` as each one arrives (in
    completion order). `log` receives a line per restart (default: stderr)."""
    indices = list(indices)
    if len(set(indices)) != len(indices):
        raise ValueError("indices must be distinct")
    if workers < 0:
        raise ValueError(f"workers must be >= 0, got {workers}")
    log = log or (lambda line: print(line, file=sys.stderr, flush=True))
    if ray is not None:
        with _sigterm_as_interrupt():
            return _fan_out_ray(function, spec, indices, workers, ray, on_result, max_restarts)
    if workers == 0:
        results = {}
        for index in indices:
            results[index] = function(spec, index)
            if on_result is not None:
                on_result(index, results[index])
        return results
    with _sigterm_as_interrupt():
        return _fan_out_local(function, spec, indices, workers, on_result, max_restarts, context, log)


def _fan_out_local(function, spec, indices, workers, on_result, max_restarts, context, log) -> dict:
    results: dict[int, Any] = {}
    ctx = worker_context(context)
    for attempt in range(max_restarts + 1):
        pending = [i for i in indices if i not in results]
        if not pending:
            break
        pool = ProcessPoolExecutor(min(workers, len(pending)), mp_context=ctx, initializer=_init_worker,
                                   initargs=(os.getpid(),))
        broken = False
        try:
            futures = {pool.submit(function, spec, i): i for i in pending}
            waiting = set(futures)
            while waiting:
                done, waiting = wait(waiting, return_when=FIRST_COMPLETED)
                for future in done:
                    try:
                        result = future.result()
                    except BrokenProcessPool:
                        broken = True  # a worker died: every unfinished job of this pool fails so
                        continue
                    results[futures[future]] = result
                    if on_result is not None:
                        on_result(futures[future], result)
        except BaseException:
            _terminate(pool)  # Ctrl-C or an error in a job: no worker outlives the call
            raise
        pool.shutdown(wait=True)
        if broken:
            missing = [i for i in indices if i not in results]
            if attempt == max_restarts:
                raise RuntimeError(f"worker processes died {max_restarts + 1} times; {len(missing)} jobs "
                                   f"never finished: {missing[:10]}")
            log(f"a worker process died; running its {len(missing)} unfinished jobs again in new workers")
    return results


def _terminate(pool: ProcessPoolExecutor) -> None:
    """Stop a pool's workers now (Python < 3.14 has no public `terminate_workers`)."""
    if hasattr(pool, "terminate_workers"):
        pool.terminate_workers()
        return
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for process in processes:
        if process.is_alive():
            process.terminate()
    pool.shutdown(wait=True, cancel_futures=True)
    for process in processes:
        process.join(timeout=5)


def _pinned_call(function: Callable[[Any, int], T], spec: Any, index: int) -> T:
    """A Ray task: one compute thread in its worker process (before the job builds an env or runs torch)."""
    pin_threads()
    return function(spec, index)


def _fan_out_ray(function, spec, indices, workers, address, on_result, max_restarts) -> dict:
    ray = ray_module()
    owns = ray_connect(address, num_cpus=workers or None)
    try:
        remote = ray.remote(num_cpus=1, max_retries=max_restarts)(_pinned_call)
        in_flight = workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
        spec_ref = ray.put(spec)
        queue, refs, results = list(indices), {}, {}
        try:
            while queue or refs:
                while queue and len(refs) < in_flight:
                    index = queue.pop(0)
                    refs[remote.remote(function, spec_ref, index)] = index
                done, _ = ray.wait(list(refs), num_returns=1)
                for ref in done:
                    index = refs.pop(ref)
                    results[index] = ray.get(ref)
                    if on_result is not None:
                        on_result(index, results[index])
        except BaseException:
            for ref in refs:
                ray.cancel(ref, force=True)
            raise
        return results
    finally:
        if owns:
            ray.shutdown()
