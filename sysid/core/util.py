"""Small shared helpers: atomic file output, progress reporting, seeded random generators."""

from __future__ import annotations

import contextlib
import functools
import math
import os
import signal
import sys
import tempfile
import threading
import time
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import numpy as np

from sysid.core.errors import IdentificationError, InputDataError
from sysid.core.native import steady_heap


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None, *,
                hold_interrupts: bool = False):
    """Yield a temporary path next to ``path``; rename it onto ``path`` only on success.

    Whatever is written to the yielded path appears at ``path`` all at once or not at all:
    if the block raises, the temporary file is removed and ``path`` is left untouched. The
    file gets the permissions a plain ``open(path, "w")`` would give it: those of the file it
    replaces, else ``0o666`` less the umask (``mkstemp`` alone makes it owner-only, so a
    shared results folder would hold campaign files nobody else could read).

    With ``hold_interrupts`` SIGINT is held while the block runs (:func:`interrupts_held`):
    one that arrived is raised as :class:`KeyboardInterrupt` before the rename (temporary
    removed, ``path`` unchanged), or after it if it arrived during the rename (the write is
    complete).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    held = interrupts_held() if hold_interrupts else contextlib.nullcontext([])
    with held as received:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}-",
                                   suffix=suffix or path.suffix, dir=path.parent)
        os.close(fd)
        tmp = Path(tmp)
        try:
            yield tmp
            if received:
                raise KeyboardInterrupt
            os.chmod(tmp, _new_file_mode(path))
            os.replace(tmp, path)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
    if received:  # arrived during the rename: the write is complete, stop now
        raise KeyboardInterrupt


@contextlib.contextmanager
def interrupts_held():
    """Hold SIGINT while a file library writes; yields the list of signals received.

    An interrupt raised inside netCDF4/HDF5 or xarray's file-manager lock can deadlock the
    process or be swallowed by a destructor; held, it is raised by the caller at a safe
    point. Only the main thread receives signals, so elsewhere this does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield []
        return
    received: list[int] = []
    try:
        previous = signal.signal(signal.SIGINT, lambda signum, frame: received.append(signum))
    except ValueError:  # pragma: no cover - not the main interpreter
        yield received
        return
    try:
        yield received
    finally:
        signal.signal(signal.SIGINT, previous)


def _new_file_mode(path: Path) -> int:
    """Permission bits ``open(path, "w")`` would leave on ``path``."""
    try:
        return path.stat().st_mode & 0o7777
    except FileNotFoundError:
        return 0o666 & ~_umask()


@functools.cache
def _umask() -> int:
    # Reading the umask means setting it; done once per process, before any worker threads
    # of ours write files, so no other file is created under the temporary value.
    mask = os.umask(0o077)
    os.umask(mask)
    return mask


class Deadline:
    """Wall-clock bound of an iterative computation (e.g. a least-squares fit).

    ``wrap(fun)`` returns ``fun`` checking the bound before each call; past it,
    :class:`~sysid.core.errors.IdentificationError` says what did not finish, after how long,
    and how to allow more. ``seconds=None`` never expires.

    >>> Deadline(None, "fit").wrap(abs)(-2)
    2
    """

    def __init__(self, seconds: float | None, what: str, *, option: str = "time_limit"):
        self.seconds, self.what, self.option = seconds, what, option
        self.end = math.inf if seconds is None else time.monotonic() + float(seconds)

    def check(self) -> None:
        if time.monotonic() > self.end:
            raise IdentificationError(
                f"{self.what} did not finish within {self.seconds:g} s; the data may be "
                f"ill-conditioned or hold non-physical values (pass {self.option}=... to "
                "allow more time)")

    def wrap(self, fun):
        def bounded(*args, **kwargs):
            self.check()
            return fun(*args, **kwargs)
        return bounded


def rng(seed: int | None) -> np.random.Generator:
    """The project's random generator: every random process takes an explicit seed."""
    if seed is None:
        raise ValueError("a seed is required: every random process in sysid is seeded")
    return np.random.default_rng(seed)


class Progress:
    """Per-stage progress lines on stderr, silenced with ``quiet=True``.

    >>> with Progress(quiet=True).stage("spectra"):
    ...     pass
    """

    def __init__(self, quiet: bool = False, stream=None):
        self.quiet = quiet
        self.stream = stream if stream is not None else sys.stderr

    def message(self, text: str) -> None:
        if not self.quiet:
            print(text, file=self.stream, flush=True)

    @contextlib.contextmanager
    def stage(self, name: str):
        start = time.perf_counter()
        self.message(f"[sysid] {name} ...")
        try:
            yield self
        finally:
            self.message(f"[sysid] {name} done in {time.perf_counter() - start:.2f} s")

    def bar(self, iterable, total: int | None = None, label: str = ""):
        """Iterate with a one-line text bar (``label [#####.....] k/n``)."""
        items = list(iterable) if total is None else iterable
        n = len(items) if total is None else total
        start = time.perf_counter()
        for k, item in enumerate(items, 1):
            yield item
            if not self.quiet:
                filled = int(30 * k / max(n, 1))
                self.stream.write(f"\r{label} [{'#' * filled}{'.' * (30 - filled)}] {k}/{n}"
                                  f" {time.perf_counter() - start:.1f} s")
                self.stream.flush()
        if not self.quiet:
            self.stream.write("\n")
            self.stream.flush()


#: What a process pool raises when it cannot start its processes or one of them dies: its
#: callers then do the work in the calling process (the same results, later).
POOL_FAILURES = (OSError, BrokenProcessPool)

#: Modules the forkserver imports once, before it forks any child: the callables that
#: :func:`forkserver_context`'s pools run (the report's figures, filter error's screening),
#: so that a child starts in milliseconds instead of importing them again.
FORKSERVER_PRELOAD = ("sysid.report.plots", "sysid.identify.filter_error")


def forkserver_context():
    """The ``forkserver`` multiprocessing context (a clean child, not a fork of a process
    that may hold threads), its server preloading :data:`FORKSERVER_PRELOAD` when this is
    its first use."""
    import multiprocessing

    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(list(FORKSERVER_PRELOAD))
    return context


def start_forkserver() -> None:
    """Start :func:`forkserver_context`'s server now, so that its imports run beside the
    caller's work (on another core) instead of when the first pool needs a child; nothing
    inside a daemonic process (a Dask worker), which starts no children, nor where it cannot
    start (an optimisation only)."""
    import multiprocessing
    import multiprocessing.forkserver

    if multiprocessing.current_process().daemon:
        return
    try:
        forkserver_context()
        multiprocessing.forkserver.ensure_running()
    except (OSError, ValueError):  # no forkserver here: the pools start it (or fall back)
        pass


def worker_processes(variable: str, maximum: int) -> int:
    """How many worker processes a parallel step may start: the environment ``variable``
    when set, else the usable cores up to ``maximum``; 1 inside a daemonic process (a Dask
    worker), which may not start children. Raises InputDataError for a non-integer
    setting."""
    import multiprocessing

    value = os.environ.get(variable)
    if value:
        try:
            return max(1, int(value))
        except ValueError:
            raise InputDataError(f"{variable} must be an integer, got {value!r}") from None
    if multiprocessing.current_process().daemon:
        return 1
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, maximum))


def blas_threads(default: int = 1):
    """Limit BLAS threads (``SYSID_BLAS_THREADS`` overrides ``default``).

    sysid's numerics are many small-to-mid-sized matrix products (9-state expm, 30-parameter
    Jacobians) for which multi-threaded OpenBLAS is slower, and on a busy 2-core machine up
    to 10x slower (measured: a 19 s time-domain fit took 198 s). One thread per process is
    also what Dask workers want.
    """
    import scipy.linalg  # noqa: F401  (scipy ships its own BLAS: load it so the limit reaches it)
    from threadpoolctl import threadpool_limits

    try:
        limit = int(os.environ.get("SYSID_BLAS_THREADS", default))
    except ValueError:
        limit = default
    return threadpool_limits(limits=max(limit, 1), user_api="blas")


@contextlib.contextmanager
def numeric_settings():
    """The process settings sysid's numerics run under: glibc's heap steadied
    (:func:`~sysid.core.native.steady_heap`, once per process) and BLAS limited
    (:func:`blas_threads`, given back on leaving)."""
    steady_heap()
    with blas_threads():
        yield


def fit_settings(function):
    """``function`` run under :func:`numeric_settings`: the identification entry points set
    them themselves, so that a call from a user's own script is as fast as the study's
    (output error on the hover study: 10.1 s of wall and 20 s of CPU with OpenBLAS's two
    threads against 4.8 s with one)."""

    @functools.wraps(function)
    def limited(*args, **kwargs):
        with numeric_settings():
            return function(*args, **kwargs)

    return limited
