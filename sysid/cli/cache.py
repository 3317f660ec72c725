"""``sysid cache``: where the cache of built and extracted FMUs is, how big, and emptying it."""

from __future__ import annotations

from sysid.core.paths import cache_dir, cache_max_bytes, cache_usage, clear_cache


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "cache", help="show or clear the cache of built and extracted FMUs",
        description="Print the cache folder (SYSID_CACHE_DIR, default ~/.cache/sysid) and "
                    "the bytes in it; extracted FMUs are capped at SYSID_CACHE_MAX_BYTES "
                    "(least recently used removed first). --clear empties it; everything "
                    "in it is rebuilt when next needed.")
    p.add_argument("--clear", action="store_true", help="remove everything in the cache")
    p.set_defaults(func=_cache)


def _cache(args) -> int:
    if args.clear:
        freed = clear_cache()
        print(f"{cache_dir()}: cleared ({freed / 2**20:.1f} MiB freed)")
        return 0
    usage = cache_usage()
    print(f"{cache_dir()}: {sum(usage.values()) / 2**20:.1f} MiB "
          f"(extracted FMUs capped at {cache_max_bytes() / 2**20:.0f} MiB)")
    for name, size in usage.items():
        print(f"  {name:<10} {size / 2**20:10.1f} MiB")
    return 0
