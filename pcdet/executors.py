"""Where independent pieces of work run: this process, a local process pool, or a Ray cluster.

``map_unordered(setup, task, shared, items, ...)`` gives each worker ``state = setup(shared)`` once and then
yields ``task(state, item)`` for every item as soon as it is done (in order of completion), so a caller can
write each result at once. ``map_chunks(fn, shared, chunks, ...)`` yields ``fn(shared, chunk)`` in chunk order.
``setup``, ``task`` and ``fn`` must be module-level functions.

Without an address, Ray is started as a local instance that listens on the loopback interface only, with no
dashboard (an exposed Ray cluster runs whatever code reaches it); see ``start_local_ray``.
"""
from __future__ import annotations

import ipaddress
import os
import sys
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Any, Callable, Iterable, Iterator, Sequence

from .errors import ConfigError, DependencyError

EXECUTORS = ("local", "ray")

_STATE: Any = None  # a pool worker's state (set by _pool_init)


def _check(executor: str) -> None:
    if executor not in EXECUTORS:
        raise ConfigError(f"executor must be one of {EXECUTORS}, got {executor!r}")


def _pool_init(setup, shared) -> None:
    global _STATE
    _STATE = setup(shared)


def _pool_task(task, item):
    return task(_STATE, item)


def map_unordered(setup: Callable[[Any], Any], task: Callable[[Any, Any], Any], shared: Any, items: Iterable[Any],
                  *, workers: int = 1, executor: str = "local", ray_address: str | None = None) -> Iterator[Any]:
    """``task(setup(shared), item)`` for every item, each result as soon as it is ready. executor "local":
    ``workers`` processes (1: this process, in item order); "ray": one worker per CPU of a local instance
    (``workers`` CPUs) or per ``workers`` on the cluster at ``ray_address``."""
    _check(executor)
    items = list(items)
    if executor == "ray":
        yield from _ray_unordered(setup, task, shared, items, workers, ray_address)
        return
    if workers <= 1 or len(items) < 2:
        state = setup(shared)
        for item in items:
            yield task(state, item)
        return
    with ProcessPoolExecutor(workers, initializer=_pool_init, initargs=(setup, shared)) as pool:
        queue = iter(items)
        pending = set()
        for item in queue:  # keep a few tasks per worker in flight, submit more as they finish
            pending.add(pool.submit(_pool_task, task, item))
            if len(pending) >= 2 * workers:
                break
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                yield f.result()
                nxt = next(queue, None)
                if nxt is not None:
                    pending.add(pool.submit(_pool_task, task, nxt))


def map_chunks(fn: Callable[[Any, Any], Any], shared: Any, chunks: Sequence[Any], *, workers: int = 1,
               executor: str = "local", ray_address: str | None = None) -> Iterator[Any]:
    """``fn(shared, chunk)`` for each chunk, results in chunk order. executor "local": ``workers`` processes
    (1: this process); "ray": tasks on the Ray cluster at ``ray_address`` (None: a local instance with
    ``workers`` CPUs, shut down afterwards)."""
    _check(executor)
    if executor == "ray":
        with _Ray(workers, ray_address) as ray:
            remote = ray.remote(fn)
            ref = ray.put(shared)
            futures = [remote.remote(ref, c) for c in chunks]
            for f in futures:
                yield ray.get(f)
    elif workers <= 1 or len(chunks) < 2:
        for c in chunks:
            yield fn(shared, c)
    else:
        with ProcessPoolExecutor(workers) as pool:
            yield from pool.map(fn, [shared] * len(chunks), chunks)


def start_local_ray(cpus: int):
    """Start a Ray instance on this machine that accepts connections from this machine only: every Ray server
    listens on the loopback interface (Ray's single-node mode, chosen before Ray is imported) and there is no
    dashboard (Ray 2.59 and later also require a token on local instances). Returns the ``ray`` module.
    Refuses (and shuts the instance down) when Ray still picked a network address, which happens when Ray was
    imported before pcdet could choose the mode: set ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0`` before importing
    Ray, or start Ray yourself and pcdet will use it."""
    key = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
    saved = os.environ.get(key)
    if "ray" not in sys.modules:
        os.environ[key] = "0"  # read once, when Ray is imported
    try:
        ray = _import_ray()
    finally:
        if saved is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = saved
    ray.init(num_cpus=max(1, cpus), include_dashboard=False, log_to_driver=False, configure_logging=False)
    ip = ray.util.get_node_ip_address()
    if not ipaddress.ip_address(ip).is_loopback:
        ray.shutdown()
        raise DependencyError(f"the local Ray instance would listen on {ip}, not only on this machine (Ray was "
                              "imported before pcdet could choose its single-node mode): set "
                              "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0 before importing Ray, or start Ray yourself")
    return ray


def _import_ray():
    try:
        import ray
    except ImportError:
        raise DependencyError("--executor ray needs Ray: pip install 'pcdet[ray]'") from None
    return ray


class _Ray:
    """``with _Ray(workers, address) as ray``: the cluster at ``address``, an instance already running in this
    process, or a loopback-only local one started (and shut down at the end) here."""

    def __init__(self, workers: int, address: str | None):
        self.workers, self.address, self.started = workers, address, False

    def __enter__(self):
        if "ray" in sys.modules and sys.modules["ray"].is_initialized():
            return sys.modules["ray"]
        self.started = True
        if self.address:
            ray = _import_ray()
            ray.init(address=self.address, log_to_driver=False, configure_logging=False)
            return ray
        return start_local_ray(self.workers)  # imports Ray itself, after choosing loopback

    def __exit__(self, *exc):
        if self.started:
            _import_ray().shutdown()


class _RayWorker:
    """One Ray actor: the state ``setup(shared)`` built once, then tasks on it."""

    def __init__(self, setup, shared):
        self.state = setup(shared)

    def run(self, task, item):
        return task(self.state, item)


def _ray_unordered(setup, task, shared, items, workers: int, address: str | None) -> Iterator[Any]:
    with _Ray(workers, address) as ray:
        from ray.util import ActorPool

        n = max(1, workers if workers > 1 or not address else int(ray.cluster_resources().get("CPU", 1)))
        ref = ray.put(shared)
        actors = [ray.remote(_RayWorker).remote(setup, ref) for _ in range(min(n, max(len(items), 1)))]
        yield from ActorPool(actors).map_unordered(lambda a, item: a.run.remote(task, item), items)
