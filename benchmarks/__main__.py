"""`python -m benchmarks`: run every benchmark module, in order.

Each module in `MODULES` is `benchmarks.<name>` with a `main() -> int`. A
module that does not exist yet is skipped with a note; one that raises is
reported and the others still run. The exit status is non-zero if any
benchmark's `main` returned non-zero or raised.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import traceback

MODULES = [
    "goals",
    "transport",
    "parser",
    "journal",
    "daemon",
    "status_flood",
    "socket_attacks",
    "sonde",
    "winch",
    "storm",
    "flood",
    "sonar_stream",
    "sonar_rss",
    "web",
    "journal_attacks",
    "web_attacks",
    "bathymetry",
    "profiles",
]


def main() -> int:
    failed: list[str] = []
    for name in MODULES:
        module_name = f"{__package__ or 'benchmarks'}.{name}"
        if importlib.util.find_spec(module_name) is None:
            print(f"== {module_name}: not written yet, skipped\n", flush=True)
            continue
        print(f"== {module_name}", flush=True)
        try:
            status = importlib.import_module(module_name).main()
        except Exception:  # one broken benchmark must not hide the others' figures
            traceback.print_exc()
            status = 1
        print(flush=True)
        if status:
            failed.append(f"{name} ({status})")
    if failed:
        print(f"benchmarks that failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
