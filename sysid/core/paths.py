"""Where the FMU sources live and where built artefacts are cached.

The cache (:func:`cache_dir`, ``~/.cache/sysid`` or ``SYSID_CACHE_DIR``) holds the built
truth FMUs (``fmus/``, keyed by a hash of their sources) and the FMUs extracted for running
(``unzipped/``, keyed by a hash of the archive). The extracted copies are capped at
``SYSID_CACHE_MAX_BYTES`` (default :data:`CACHE_MAX_BYTES`): after each extraction the least
recently used ones are removed (:func:`prune_cache`). :func:`clear_cache` (``sysid cache
--clear``) empties the whole cache; everything in it is rebuilt on demand.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from sysid.core.errors import FMUError, InputDataError

#: Default cap (bytes) of the extracted-FMU cache; FMU archives may declare up to 1 GiB.
CACHE_MAX_BYTES = 2 << 30

#: The repository root when sysid runs from a source checkout (``pip install -e .``).
SOURCE_ROOT = Path(__file__).resolve().parents[2]


def fmu_sources_dir() -> Path:
    """The ``fmus/`` folder holding the C sources of the truth FMU and the export template.

    ``SYSID_FMU_SOURCES`` overrides the location.
    """
    candidate = Path(os.environ.get("SYSID_FMU_SOURCES", SOURCE_ROOT / "fmus"))
    if not (candidate / "helicopter").is_dir():
        raise FMUError(
            f"FMU sources not found at {candidate}: install sysid from a source checkout "
            "(pip install -e .) or set SYSID_FMU_SOURCES to the repository's fmus/ folder"
        )
    return candidate


def cache_dir() -> Path:
    """Git-ignored cache for built FMUs and intermediate results.

    ``SYSID_CACHE_DIR`` overrides the default ``~/.cache/sysid``.
    """
    path = Path(os.environ.get("SYSID_CACHE_DIR", Path.home() / ".cache" / "sysid"))
    path.mkdir(parents=True, exist_ok=True)
    return path


def cache_max_bytes() -> int:
    """The cap of the extracted-FMU cache: ``SYSID_CACHE_MAX_BYTES`` or
    :data:`CACHE_MAX_BYTES`."""
    text = os.environ.get("SYSID_CACHE_MAX_BYTES")
    if text is None:
        return CACHE_MAX_BYTES
    try:
        value = int(float(text))
    except ValueError:
        raise InputDataError(f"SYSID_CACHE_MAX_BYTES={text!r}: expected a number of bytes"
                             ) from None
    if value < 0:
        raise InputDataError(f"SYSID_CACHE_MAX_BYTES={text!r}: expected a number >= 0")
    return value


def _size(path: Path) -> int:
    total = 0
    for root, _, files in os.walk(path):
        for name in files:
            try:
                total += os.lstat(os.path.join(root, name)).st_size
            except OSError:
                pass
    return total


def touch(folder: Path) -> None:
    """Mark a cache entry as used now (its age decides what :func:`prune_cache` removes)."""
    try:
        os.utime(folder)
    except OSError:
        pass


def prune_cache(folder: Path, *, max_bytes: int | None = None, keep: Path | None = None
                ) -> list[Path]:
    """Remove the least recently used entries (sub-folders) of ``folder`` until the rest
    take at most ``max_bytes`` (default :func:`cache_max_bytes`); ``keep`` (the entry just
    made) always stays, as do hidden temporaries of extractions under way. Returns the
    entries removed."""
    limit = cache_max_bytes() if max_bytes is None else max_bytes
    try:
        entries = [p for p in Path(folder).iterdir()
                   if p.is_dir() and not p.name.startswith(".")]
    except OSError:
        return []
    sizes = {p: _size(p) for p in entries}
    total = sum(sizes.values())
    removed = []
    for entry in sorted(entries, key=lambda p: p.stat().st_mtime if p.exists() else 0.0):
        if total <= limit:
            break
        if keep is not None and entry.resolve() == Path(keep).resolve():
            continue
        shutil.rmtree(entry, ignore_errors=True)
        total -= sizes[entry]
        removed.append(entry)
    return removed


def cache_usage() -> dict[str, int]:
    """Bytes in each top-level folder of the cache (``{"fmus": ..., "unzipped": ...}``)."""
    root = cache_dir()
    return {p.name: _size(p) for p in sorted(root.iterdir()) if p.is_dir()}


def clear_cache() -> int:
    """Empty the cache (:func:`cache_dir`); returns the bytes freed. Built truth FMUs and
    extracted FMUs are made again when next needed."""
    root = cache_dir()
    freed = 0
    for entry in list(root.iterdir()):
        if entry.is_dir() and not entry.is_symlink():
            freed += _size(entry)
            shutil.rmtree(entry, ignore_errors=True)
        else:
            freed += entry.lstat().st_size
            entry.unlink(missing_ok=True)
    return freed
