"""Where the simulation-heavy steps run: this process, a local Dask cluster, or a scheduler.

A :class:`Cluster` says where; :meth:`Cluster.open` gives a :class:`Pool` for the length of a
job, which the steps use in two ways:

- :attr:`Pool.address`: the scheduler's address, for a step that talks to Dask itself
  (the training-data generation submits its chunks there), ``None`` in this process;
- :meth:`Pool.map`: a function over a list of independent tasks, in order, on the pool's
  workers (threads of this process when no cluster is given: XLA releases the interpreter
  while it solves).

Every task is seeded on its own, so the results do not depend on where it ran: the same
seeds give the same numbers in this process and on any cluster (the tests compare them to
the last digit). A task sent to a worker process runs under this process's JAX settings
(float64, the compilation cache folder), so a worker reads the programs this process
compiled instead of compiling them again.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

import jax

T = TypeVar("T")


@dataclasses.dataclass(frozen=True)
class Cluster:
    """Where the simulation-heavy steps run.

    Attributes
    ----------
    address
        A running Dask scheduler's address (``"tcp://host:port"``); ``None``: none.
    workers
        Without an address: ``0`` runs every task in this process (``threads`` at a time);
        ``N >= 1`` starts a ``distributed.LocalCluster`` of ``N`` worker processes of one
        thread each for the length of the job.
    threads
        Tasks run at once in this process when no cluster is used.
    """

    address: str | None = None
    workers: int = 0
    threads: int = 2

    def __post_init__(self) -> None:
        for name, low in (("workers", 0), ("threads", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"Cluster.{name}={value!r} must be an integer >= {low}")
        if self.address is not None:
            if not isinstance(self.address, str) or "://" not in self.address:
                raise ValueError(
                    f"Cluster.address={self.address!r} must be a Dask scheduler's address "
                    "such as 'tcp://10.0.0.5:8786'"
                )
            if self.workers:
                raise ValueError(
                    f"Cluster: give a scheduler's address or a number of local workers, not "
                    f"both (address={self.address!r}, workers={self.workers})"
                )

    @property
    def distributed(self) -> bool:
        """The tasks leave this process."""
        return self.address is not None or self.workers > 0

    def describe(self) -> str:
        if self.address is not None:
            return f"the Dask scheduler at {self.address}"
        if self.workers:
            return f"a local Dask cluster of {self.workers} worker processes"
        return f"this process ({self.threads} threads)"

    @contextlib.contextmanager
    def open(self) -> Iterator[Pool]:
        """The pool of this cluster, started (and, for a local cluster, stopped) here."""
        if not self.distributed:
            yield Pool(None, None, self.threads)
            return
        from distributed import Client, LocalCluster

        with contextlib.ExitStack() as stack:
            if self.address is None:
                local = stack.enter_context(
                    LocalCluster(
                        n_workers=self.workers,
                        threads_per_worker=1,
                        processes=True,
                        dashboard_address=None,
                    )
                )
                client = stack.enter_context(Client(local))
            else:
                client = stack.enter_context(Client(self.address))
            yield Pool(client, client.scheduler.address, self.threads)


@dataclasses.dataclass(frozen=True)
class _Settings:
    """The JAX settings a worker process runs a task under."""

    x64: bool
    cache_dir: str | None

    @classmethod
    def here(cls) -> _Settings:
        cache = getattr(jax.config, "jax_compilation_cache_dir", None)
        return cls(bool(jax.config.read("jax_enable_x64")), cache or None)

    def apply(self) -> None:
        jax.config.update("jax_enable_x64", self.x64)
        if self.cache_dir is not None:
            jax.config.update("jax_compilation_cache_dir", self.cache_dir)
            jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


def _call(settings: _Settings, function: Callable[..., T], *args: Any) -> T:
    settings.apply()
    return function(*args)


@dataclasses.dataclass(frozen=True)
class Pool:
    """An open :class:`Cluster`: its Dask client (``None`` in this process) and address."""

    client: Any
    address: str | None
    threads: int = 2

    def map(self, function: Callable[..., T], tasks: Sequence[tuple[Any, ...]]) -> list[T]:
        """``[function(*task) for task in tasks]``, run on the pool, in the tasks' order.

        In this process, ``threads`` tasks run at once (one when there is one task). On a
        cluster every task is a Dask future of its own; an exception in a task is raised
        here.
        """
        if self.client is None:
            if self.threads == 1 or len(tasks) <= 1:
                return [function(*task) for task in tasks]
            with ThreadPoolExecutor(min(self.threads, len(tasks))) as pool:
                return list(pool.map(lambda task: function(*task), tasks))
        settings = _Settings.here()
        shared = self._scatter_shared(tasks)
        futures = [
            self.client.submit(
                _call,
                settings,
                function,
                *(shared.get(id(arg), arg) for arg in task),
                pure=False,
            )
            for task in tasks
        ]
        return list(self.client.gather(futures))

    def _scatter_shared(self, tasks: Sequence[tuple[Any, ...]]) -> dict[int, Any]:
        """The arguments that several tasks share (the same object: a refit's setup, a
        catalogue), sent to the workers once each instead of once per task."""
        seen: dict[int, int] = {}
        objects: dict[int, Any] = {}
        for task in tasks:
            for arg in task:
                if arg is None or isinstance(arg, bool | int | float | str):
                    continue
                seen[id(arg)] = seen.get(id(arg), 0) + 1
                objects[id(arg)] = arg
        return {
            # in a list: scatter would send a dict item by item
            key: self.client.scatter([objects[key]], broadcast=True, hash=False)[0]
            for key, count in seen.items()
            if count > 1
        }


def in_process(threads: int | None = None) -> Pool:
    """The pool of this process, ``threads`` at a time (``None``: 2, or 1 on one core)."""
    if threads is None:
        threads = min(2, os.cpu_count() or 1)
    return Pool(None, None, threads)
