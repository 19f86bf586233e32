"""Where independent pieces of work run: this process, a local process pool, or a Ray cluster.

``map_chunks(fn, shared, chunks, ...)`` calls ``fn(shared, chunk)`` for every chunk and yields the results in
chunk order, whatever finishes first. ``shared`` (the model library and the pipeline, say) is sent to each
process once per chunk (pool) or put in Ray's object store once. ``fn`` must be a module-level function.
"""
from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from typing import Any, Callable, Iterator, Sequence

from .errors import ConfigError, DependencyError

EXECUTORS = ("local", "ray")


def map_chunks(fn: Callable[[Any, Any], Any], shared: Any, chunks: Sequence[Any], *, workers: int = 1,
               executor: str = "local", ray_address: str | None = None) -> Iterator[Any]:
    """``fn(shared, chunk)`` for each chunk, results in order. executor "local": ``workers`` processes (1: this
    process); "ray": tasks on the Ray cluster at ``ray_address`` (None: start a local Ray instance with
    ``workers`` CPUs, shut down afterwards)."""
    if executor not in EXECUTORS:
        raise ConfigError(f"executor must be one of {EXECUTORS}, got {executor!r}")
    if executor == "ray":
        yield from _ray_map(fn, shared, chunks, workers, ray_address)
    elif workers <= 1 or len(chunks) < 2:
        for c in chunks:
            yield fn(shared, c)
    else:
        with ProcessPoolExecutor(workers) as pool:
            yield from pool.map(fn, [shared] * len(chunks), chunks)


def _ray_map(fn, shared, chunks, workers: int, address: str | None) -> Iterator[Any]:
    try:
        import ray
    except ImportError:
        raise DependencyError("--executor ray needs Ray: pip install 'pcdet[ray]'") from None
    started = not ray.is_initialized()
    if started:
        kw = {"address": address} if address else {"num_cpus": max(1, workers)}
        ray.init(include_dashboard=False, log_to_driver=False, configure_logging=False, **kw)
    try:
        remote = ray.remote(fn)
        ref = ray.put(shared)
        futures = [remote.remote(ref, c) for c in chunks]
        for f in futures:
            yield ray.get(f)
    finally:
        if started:
            ray.shutdown()


def split(items: Sequence[Any], parts: int) -> list[list[Any]]:
    """``items`` in at most ``parts`` contiguous, nearly equal, non-empty runs."""
    parts = max(1, min(parts, len(items)))
    n, extra = divmod(len(items), parts)
    out, i = [], 0
    for k in range(parts):
        j = i + n + (k < extra)
        out.append(list(items[i:j]))
        i = j
    return [c for c in out if c]
