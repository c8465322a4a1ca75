"""Where runs execute: the seam between the studies and the processes that compute them.

A study maps a top-level function (importable by name in every process, e.g. `montecarlo.execute`)
over a list of items. An executor hands back `(index, result)` pairs as the items finish, each
index exactly once; `in_order` puts them back in item order. Two executors:

- `LocalPool`: this machine's processes (a spawn pool), or this process when `workers == 1`;
- `DaskCluster`: the workers of a Dask distributed scheduler, on any number of machines that have
  the project installed. A worker that dies loses its runs to the scheduler, which computes them
  again elsewhere (Dask's own mechanism); every run still comes back exactly once.

Results are the same on both for the same items: a run is a pure function of its spec.
"""

from __future__ import annotations

import hashlib
import multiprocessing
import multiprocessing.pool
import os
import signal
import threading
import uuid
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import CancelledError
from contextlib import contextmanager
from functools import cache, partial
from importlib.metadata import version
from itertools import islice
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Protocol, TypeVar

if TYPE_CHECKING:
    from dask.typing import Key
    from distributed import Future

T = TypeVar("T")
R = TypeVar("R")


class ClusterError(RuntimeError):
    """The cluster could not finish a map: its scheduler was lost, or a run kept killing workers."""


class RunExecutor(Protocol):
    """Maps a function over items on some set of processes."""

    workers: int  # runs computed at the same time (processes, or the cluster's worker threads)
    description: str  # for progress bars: "2 local processes", "40 Dask workers"

    def imap_unordered(self, fn: Callable[[T], R], items: Sequence[T]) -> Iterator[tuple[int, R]]:
        """`(i, fn(items[i]))` for every i, in the order they finish. `fn` must be importable by name."""
        ...

    def close(self) -> None:
        """Release the executor's resources (idempotent)."""
        ...


@contextmanager
def open_executor(
    scheduler: str | None = None, workers: int | None = None, keep: bool = False
) -> Iterator[RunExecutor]:
    """The executor that runs the maps: a `DaskCluster` at `scheduler`, or else a `LocalPool`.

    The scheduler is an address such as tcp://10.0.0.1:8786; the pool has `workers` processes and is
    kept across maps with `keep`.
    """
    executor: RunExecutor = LocalPool(workers, keep) if scheduler is None else DaskCluster(scheduler)
    try:
        yield executor
    finally:
        executor.close()


def in_order(
    pairs: Iterable[tuple[int, R]], n: int, on_result: Callable[[], object] | None = None
) -> Iterator[R]:
    """The results of items 0..n-1 in item order, each as soon as every item before it is in.

    `on_result` is called as each one arrives. A missing item, or one that comes twice, raises
    RuntimeError.
    """
    waiting: dict[int, R] = {}
    following = 0
    for i, result in pairs:
        if not following <= i < n or i in waiting:
            raise RuntimeError(f"item {i} of {n} came back twice or does not exist")
        waiting[i] = result
        if on_result is not None:
            on_result()
        while following in waiting:
            yield waiting.pop(following)
            following += 1
    if following < n:
        raise RuntimeError(f"{n - following} of {n} items never came back (the first: {following})")


def _chunk_size(n: int, workers: int) -> int:
    """Runs per task: about four tasks per worker, at most 8 runs each (load balance vs overhead)."""
    return max(1, min(8, n // (4 * workers)))


def _indexed(fn: Callable[[T], R], pair: tuple[int, T]) -> tuple[int, R]:
    return pair[0], fn(pair[1])


def _worker_init() -> None:
    """Pool workers leave SIGINT to the parent, which stops them (a Ctrl-C reaches the whole group)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _interrupt(_signum: int, _frame: FrameType | None) -> None:
    raise KeyboardInterrupt


@contextmanager
def _sigterm_interrupts() -> Iterator[None]:
    """SIGTERM raises KeyboardInterrupt meanwhile (main thread only), so cleanup code runs."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


class LocalPool:
    """A spawn pool of `workers` processes (default: every core); `workers == 1` runs in this process.

    The pool is started for each map and stopped after it, or with `keep` started once and kept
    until `close` (for studies made of many small maps, such as a tune's trials: a fresh pool costs
    seconds). An interrupted map (Ctrl-C, SIGTERM) terminates the pool: no process is left behind.
    """

    def __init__(self, workers: int | None = None, keep: bool = False) -> None:
        self.workers = workers or os.cpu_count() or 1
        if self.workers < 1:
            raise ValueError(f"--workers must be at least 1, not {self.workers}")
        self.description = f"{self.workers} local process{'es' * (self.workers != 1)}"
        self.keep = keep
        self._pool: multiprocessing.pool.Pool | None = None

    def imap_unordered(self, fn: Callable[[T], R], items: Sequence[T]) -> Iterator[tuple[int, R]]:
        if self.workers == 1:
            yield from enumerate(map(fn, items))
            return
        pool = self._pool or multiprocessing.get_context("spawn").Pool(self.workers, initializer=_worker_init)
        self._pool = None
        finished = False
        with _sigterm_interrupts():
            try:
                chunk = _chunk_size(len(items), self.workers)
                yield from pool.imap_unordered(partial(_indexed, fn), enumerate(items), chunksize=chunk)
                finished = True
            finally:
                if finished and self.keep:
                    self._pool = pool
                else:
                    pool.terminate()
                    pool.join()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.terminate()
            self._pool.join()
            self._pool = None


RUN_LIBRARIES = ("numpy", "scipy", "numba", "msgspec")  # what a run computes with, besides `companion`


@cache
def code_fingerprint() -> str:
    """SHA-256 of the `companion` package's sources and the versions of `RUN_LIBRARIES`.

    Two machines have the same fingerprint when they compute the same runs.
    """
    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for name in RUN_LIBRARIES:
        digest.update(f"{name}=={version(name)}\0".encode())
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def _run_chunk(fn: Callable[[T], R], fingerprint: str, chunk: list[tuple[int, T]]) -> list[tuple[int, R]]:
    """A Dask task: a few consecutive items, on a worker that runs the study's code."""
    if code_fingerprint() != fingerprint:  # a worker that joined after `DaskCluster` checked them
        from distributed import get_worker

        raise _other_code([get_worker().address])
    return [(i, fn(item)) for i, item in chunk]


def _other_code(workers: list[str]) -> ValueError:
    return ValueError(
        f"Dask workers {', '.join(workers)} run other uavsearch code or other versions of "
        f"{', '.join(RUN_LIBRARIES)} than this machine (install the same everywhere, or the "
        "results would differ)"
    )


class DaskCluster:
    """The workers of a running Dask scheduler (`dask scheduler`, `dask worker ADDRESS --nthreads 1`).

    Connecting waits up to `worker_timeout` s for a first worker and checks that every worker runs
    this machine's `companion` code (`code_fingerprint`); every task checks it again on its worker
    (workers may join later). A map keeps a bounded window of tasks
    (chunks of consecutive items) on the cluster and submits the next as each one comes back, so a
    study of any size costs the scheduler and this process little memory.
    """

    def __init__(self, address: str, connect_timeout: float = 10.0, worker_timeout: float = 60.0) -> None:
        try:
            from distributed import Client
            from distributed.comm import get_address_host_port
        except ImportError as exc:
            raise ValueError("--scheduler needs Dask distributed: pip install 'uavsearch[cluster]'") from exc
        self.address = address
        try:
            get_address_host_port(address)
        except ValueError as exc:
            raise ValueError(f"--scheduler {address!r}: {exc} (expected tcp://HOST:PORT)") from exc
        try:
            self.client = Client(address, timeout=connect_timeout, set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise ValueError(f"cannot reach the Dask scheduler at {address}: {exc}") from exc
        try:
            self._check_workers(worker_timeout)
        except OSError as exc:
            self.client.close()
            raise ClusterError(f"lost the Dask scheduler at {address}: {exc}") from exc
        except BaseException:
            self.client.close()
            raise
        self.workers = sum(self.client.nthreads().values())
        self.description = f"{self.workers} Dask worker{'s' * (self.workers != 1)}"

    def _check_workers(self, timeout: float) -> None:
        try:
            self.client.wait_for_workers(1, timeout=timeout)
        except TimeoutError as exc:
            raise ValueError(
                f"no Dask worker joined the scheduler at {self.address} within {timeout:.0f} s "
                f"(start some: dask worker {self.address} --nthreads 1)"
            ) from exc
        try:
            found = self.client.run(code_fingerprint)
        except Exception as exc:
            raise ValueError(
                f"a Dask worker of {self.address} cannot run uavsearch ({type(exc).__name__}: {exc}); "
                "install the project on every worker machine"
            ) from exc
        other = sorted(w for w, fingerprint in found.items() if fingerprint != code_fingerprint())
        if other:
            raise _other_code(other)

    def imap_unordered(self, fn: Callable[[T], R], items: Sequence[T]) -> Iterator[tuple[int, R]]:
        from distributed import KilledWorker, as_completed

        size = _chunk_size(len(items), self.workers)
        indexed = list(enumerate(items))
        numbered = enumerate(indexed[s : s + size] for s in range(0, len(indexed), size))
        task = partial(_run_chunk, fn, code_fingerprint())
        batch = f"{fn.__name__}-{uuid.uuid4().hex}"
        in_flight: dict[Key, Future] = {}

        def submit(number: int, chunk: list[tuple[int, T]]) -> Future:
            future = self.client.submit(task, chunk, key=f"{batch}-{number}", pure=False)
            in_flight[future.key] = future
            return future

        window = max(16, 4 * self.workers)
        done = as_completed(
            [submit(*c) for c in islice(numbered, window)], loop=self.client.loop, with_results=True
        )  # holds each future until it comes back, then only `in_flight` until it is popped
        try:
            with _sigterm_interrupts():
                for future, pairs in done:
                    # decided on what came back, not on the future's status now: a worker that dies
                    # after its result was gathered turns a finished future "lost" (Dask recomputes it)
                    if isinstance(pairs, CancelledError):  # the connection to the scheduler is lost
                        raise ClusterError(f"lost the Dask scheduler at {self.address} mid-study")
                    in_flight.pop(future.key).release()  # its result leaves the cluster's memory
                    following = next(numbered, None)
                    if following is not None:
                        done.add(submit(*following))
                    yield from pairs
        except KilledWorker as exc:  # a task outlived `allowed-failures` workers
            raise ClusterError(f"Dask gave up on a task: {exc}") from exc
        finally:
            if in_flight:
                self.client.cancel(list(in_flight.values()))

    def close(self) -> None:
        self.client.close()
