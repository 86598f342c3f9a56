"""Run independent tasks on Ray, yielded as they finish: the executor the benchmark grid and
``railwatch scan`` share. Tasks send results back; only the caller (the driver) writes files."""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator, Sequence
from typing import Any, TypeVar

from railwatch.errors import RailwatchError

T = TypeVar("T")


def ray_imap(fn: Callable[..., Any], items: Sequence[T], args: tuple[Any, ...] = (),
             address: str | None = None, memory_bytes: int | None = None,
             ) -> Iterator[tuple[T, Any]]:
    """``(item, fn(item, *args))`` for every item, each call a Ray task of one CPU (and
    ``memory_bytes`` of Ray's memory resource, which bounds how many run at once on a node), in
    the order they finish.

    ``address`` joins an existing cluster; without it a local Ray starts on this machine and
    stops at the end. Each task runs torch on one thread.
    """
    try:
        import ray
    except ImportError:
        raise RailwatchError("--executor ray needs Ray: pip install 'railwatch[ray]'") from None
    started_here = not ray.is_initialized()
    if started_here:
        ray.init(address=address, include_dashboard=False, log_to_driver=False,
                 logging_level=logging.WARNING)
    try:
        options: dict[str, Any] = {"num_cpus": 1}
        if memory_bytes:
            options["memory"] = int(memory_bytes)
        remote = ray.remote(**options)(_one_thread)
        pending = {remote.remote(fn, item, *args): item for item in items}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            item = pending.pop(ready[0])
            yield item, ray.get(ready[0])
    finally:
        if started_here:
            ray.shutdown()


def _one_thread(fn: Callable[..., Any], *args: Any) -> Any:
    import torch

    torch.set_num_threads(1)  # one CPU per task
    return fn(*args)
