"""Small C kernels compiled on this machine and loaded with ctypes.

The truth FMU is built from C with the machine's compiler (:func:`find_compiler`); the same
compiler builds numeric kernels whose Python loops cost more than their arithmetic (e.g. the
sensitivity recursion of the filter-error fit, :func:`sysid.models.propagate`). A kernel is
compiled once per source, compiler and CPU into the cache (:func:`~sysid.core.paths.cache_dir`,
``native/``), with ``-march=native`` where the compiler accepts it, and loaded on first use;
where there is no compiler, the build fails or ``SYSID_NATIVE=0`` is set, the caller's numpy
path runs instead (the same results to rounding). :func:`native_status` says which.
:func:`steady_heap` sets the C library's malloc thresholds for the same numerics.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
from pathlib import Path

from sysid.core.errors import FMUError
from sysid.core.paths import cache_dir

__all__ = ["find_compiler", "run_compiler", "native_library", "native_status",
           "NATIVE_CFLAGS", "steady_heap", "HEAP_MMAP_THRESHOLD", "HEAP_TRIM_THRESHOLD"]

#: Flags of a kernel build; ``-march=native`` is dropped where the compiler refuses it (the
#: cache key holds the CPU, so a library built here is not loaded on another processor).
NATIVE_CFLAGS = ("-O3", "-march=native", "-fPIC", "-shared")

_status: dict[str, str] = {}

#: glibc's malloc under :func:`steady_heap`: blocks up to this many bytes come from the heap
#: instead of a fresh mapping, and up to HEAP_TRIM_THRESHOLD bytes stay free at its top
#: instead of going back to the system. They are where glibc's own adaptive thresholds end
#: (its largest mmap threshold, 32 MiB on 64 bits, and twice that for the trim); left
#: adaptive they follow the sizes freed so far, and a fit whose arrays fall just above them
#: page-faults on every temporary: 8000 faults and 10 ms of 30 per filter-error evaluation
#: (docs/notes/2026-11-28-filter-error-steady-heap.md).
HEAP_MMAP_THRESHOLD = 32 << 20
HEAP_TRIM_THRESHOLD = 64 << 20
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # mallopt's parameters (glibc malloc.h)


def find_compiler() -> list[str]:
    """The C compiler command: ``$CC`` if set (no fallback), else cc, gcc or clang."""
    env = os.environ.get("CC", "").strip()
    if env:
        parts = env.split()
        if shutil.which(parts[0]) is None:
            raise FMUError(f"C compiler CC={env!r} not found; install a C compiler or fix $CC")
        return parts
    for name in ("cc", "gcc", "clang"):
        if shutil.which(name):
            return [name]
    raise FMUError("no C compiler found (tried $CC, cc, gcc, clang); install one "
                   "(e.g. gcc or clang) to build the FMU and the kernels from their sources")


def _cpu_identity() -> str:
    """What a ``-march=native`` build depends on: the machine and, on Linux, the CPU's model
    and feature flags."""
    parts = [platform.machine(), platform.processor()]
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.startswith(("model name", "flags", "Features", "CPU part")):
                    parts.append(line.strip())
                if line.strip() == "":  # the first processor is enough
                    break
    except OSError:
        pass
    return "\n".join(parts)


def _compiler_identity(compiler: list[str]) -> str:
    try:
        out = subprocess.run([*compiler, "--version"], capture_output=True, text=True,
                             timeout=30)
        return out.stdout.splitlines()[0] if out.stdout else " ".join(compiler)
    except (OSError, subprocess.TimeoutExpired):
        return " ".join(compiler)


def run_compiler(compiler: list[str], args: list[str], output: Path, *, what: str,
                 log: Path | None = None, timeout: float = 300.0) -> Path:
    """Run ``compiler`` with ``args`` to write ``output``.

    Raises :class:`FMUError` naming ``what`` with the compiler's first error line (and
    writes the full command and output to ``log`` when given); a compiler that cannot be
    run or does not finish within ``timeout`` seconds is one clear line too.
    """
    cmd = [*compiler, *args]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except OSError as exc:
        raise FMUError(f"could not run the C compiler {compiler[0]!r}: {exc}") from None
    except subprocess.TimeoutExpired:
        raise FMUError(f"the C compiler {compiler[0]!r} did not finish within "
                       f"{timeout:g} s") from None
    if proc.returncode != 0 or not Path(output).is_file():
        text = proc.stderr + proc.stdout
        first = next((line for line in text.splitlines() if "error" in line.lower()),
                     text.strip()[:300] or f"exit status {proc.returncode}, no output")
        where = ""
        if log is not None:
            log.write_text(" ".join(cmd) + "\n\n" + text)
            where = f" (full log: {log})"
        raise FMUError(f"compiling {what} failed: {first.strip()} "
                       f"(compiler: {' '.join(compiler)}){where}")
    return Path(output)


def _build(compiler: list[str], source: Path, library: Path) -> str | None:
    """Compile ``source`` into ``library`` (written under a temporary name, then renamed:
    concurrent builds of the same kernel leave one whole file); the error when both flag
    sets fail."""
    fd, tmp = tempfile.mkstemp(dir=library.parent, prefix=library.stem, suffix=library.suffix)
    os.close(fd)
    os.unlink(tmp)  # a failed build must not leave an empty file that looks built
    error = "no output"
    try:
        for flags in (NATIVE_CFLAGS, tuple(f for f in NATIVE_CFLAGS if f != "-march=native")):
            try:
                run_compiler(compiler, [*flags, str(source), "-o", tmp, "-lm"], Path(tmp),
                             what=f"the {source.name} kernel", timeout=120.0)
            except FMUError as exc:
                error = str(exc)
                continue
            os.replace(tmp, library)
            return None
        return error
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


@functools.lru_cache(maxsize=None)
def native_library(name: str, source: str) -> ctypes.CDLL | None:
    """The kernel ``name`` built from the C file ``source`` (a path), loaded; ``None`` where
    it cannot be (no compiler, a failed build, ``SYSID_NATIVE=0``), the reason then in
    :func:`native_status`. A cached library that does not load is rebuilt once."""
    if os.environ.get("SYSID_NATIVE", "1").strip() == "0":
        _status[name] = "off (SYSID_NATIVE=0)"
        return None
    path = Path(source)
    try:
        compiler = find_compiler()
    except FMUError as exc:
        _status[name] = f"numpy: {exc}"
        return None
    key = hashlib.sha256()
    for part in (path.read_bytes(), _compiler_identity(compiler).encode(),
                 " ".join(NATIVE_CFLAGS).encode(), _cpu_identity().encode()):
        key.update(part)
        key.update(b"\0")
    folder = cache_dir() / "native"
    folder.mkdir(parents=True, exist_ok=True)
    library = folder / f"{name}-{key.hexdigest()[:16]}.so"
    for attempt in (0, 1):
        if not library.is_file() or attempt:
            error = _build(compiler, path, library)
            if error is not None:
                _status[name] = f"numpy: building {path.name} failed: {error}"
                return None
        try:
            loaded = ctypes.CDLL(str(library))
        except OSError as exc:  # a truncated or foreign file in the cache: build it again
            if attempt:
                _status[name] = f"numpy: {library} does not load: {exc}"
                return None
            continue
        _status[name] = f"native ({library.name})"
        return loaded
    return None


def native_status() -> dict[str, str]:
    """Per kernel asked for so far: ``native (<file>)``, or why its numpy path runs."""
    return dict(_status)


@functools.lru_cache(maxsize=None)
def steady_heap() -> bool:
    """Fix glibc's malloc thresholds at :data:`HEAP_MMAP_THRESHOLD` and
    :data:`HEAP_TRIM_THRESHOLD`, once per process, so that the numerics' mid-sized
    temporaries (megabytes, allocated and freed at every fit evaluation) reuse the heap
    instead of being mapped, faulted in and unmapped each time. Left alone: another C
    library, an environment that sets either threshold itself (``MALLOC_MMAP_THRESHOLD_``,
    ``MALLOC_TRIM_THRESHOLD_``: its owner's choice), and ``SYSID_STEADY_HEAP=0``. Returns
    whether the thresholds were set."""
    if (os.environ.get("SYSID_STEADY_HEAP", "1") == "0"
            or platform.libc_ver()[0] != "glibc"
            or any(f"MALLOC_{k}_THRESHOLD_" in os.environ for k in ("MMAP", "TRIM"))):
        return False
    try:
        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # pragma: no cover - glibc has it
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, HEAP_MMAP_THRESHOLD)
                and mallopt(_M_TRIM_THRESHOLD, HEAP_TRIM_THRESHOLD))
