"""``bgc cache``: what bgc's cache folder holds (compiled models, compiled packages), and clearing it."""

from __future__ import annotations

import argparse
import time

from ..errors import BgcError, printable


def add_parser(sub) -> None:
    p = sub.add_parser("cache", help="list what bgc's cache holds (models compiled once and reused, numba's "
                                     "compiled packages), or clear it")
    p.add_argument("action", nargs="?", choices=["list", "clear"], default="list",
                   help="list (default) or clear: remove what bgc wrote there, nothing else")
    p.add_argument("--unused-days", type=_days, default=None, metavar="DAYS",
                   help="with clear: remove only what was not used for DAYS days (e.g. 30)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..api import cache
    from ..api.folders import cache_root

    root = cache_root()
    where = printable(str(root))
    if args.unused_days is not None and args.action != "clear":
        raise BgcError("--unused-days is for clear", None, "write bgc cache clear --unused-days 30")
    if args.action == "clear":
        removed = cache.clear(root, None if args.unused_days is None else args.unused_days * 86400.0)
        counts = {kind: sum(1 for i in removed if i.kind == kind) for kind in ("model", "package", "unfinished")}
        total = sum(i.bytes for i in removed)
        print(f"removed from {where}: {_count(counts['model'], 'compiled model')}, "
              f"{_count(counts['package'], 'compiled (numba) package')}"
              + (f", {_count(counts['unfinished'], 'unfinished entry', 'unfinished entries')}"
                 if counts["unfinished"] else "")
              + f" ({_size(total)})")
        return 0
    found = cache.items(root)
    print(f"bgc's cache: {where} (BGC_CACHE_DIR, else $XDG_CACHE_HOME/bgc, else ~/.cache/bgc)")
    titles = {"model": "compiled models (reused while the model's text, its options and bgc are unchanged):",
              "package": "compiled (numba) packages, numba's disk cache beside them:",
              "unfinished": "unfinished entries (a write was interrupted; removed by clear after an hour):"}
    for kind, title in titles.items():
        mine = [i for i in found if i.kind == kind]
        if not mine:
            continue
        print(title)
        for i in mine:
            used = time.strftime("%Y-%m-%d %H:%M", time.localtime(i.used)) if i.used else "-"
            name = i.model or i.path.name
            details = f"  {printable(i.details)}" if i.details else ""
            print(f"  {printable(name):<20} {_size(i.bytes):>9}  used {used}{details}")
    if not found:
        print("  (empty)")
    print(f"{_size(sum(i.bytes for i in found))} in all; remove it with: bgc cache clear")
    return 0


def _days(text: str) -> float:
    """A number of days, zero or more (argparse's type)."""
    try:
        days = float(text)
    except ValueError:
        days = float("nan")
    if not days >= 0 or days == float("inf"):
        raise argparse.ArgumentTypeError(f"{printable(text)} is not a number of days (give e.g. 30)")
    return days


def _count(n: int, one: str, many: str | None = None) -> str:
    return f"{n} {one if n == 1 else (many or one + 's')}"


def _size(n: int) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} B"
