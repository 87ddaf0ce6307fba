"""Sonar stream benchmark: a Ping1D at 1000 readings a second into a real journal.

The daemon's own sonar (`cc_daemon.daemon.sonar.OnboardSonar`) journals at most
`sonar.journal_rate_hz` readings a second (4 by default) and counts the rest in
`sonar_thinned` events. Fed 1000 readings a second for `BENCH_SONAR_S` seconds of
sonar time (60 by default; one in seven impossible, confidence 255), it reports
the journal's growth per minute against the 1 MB/min bound, the rows kept, and
the CPU the thinning took per reading.

    python -m benchmarks.sonar_stream      (or: make bench)
"""

from __future__ import annotations

import os
import sqlite3
import tempfile
import time
from pathlib import Path

from cc_daemon.config import Settings
from cc_daemon.daemon.sonar import OnboardSonar
from cc_daemon.drivers.sonar.client import SonarReading
from cc_daemon.store import Journal

SECONDS = int(os.environ.get("BENCH_SONAR_S", "60"))
PER_S = 1000
BUDGET_BYTES_PER_MIN = 1_000_000


def _on_disk(db: Path) -> int:
    wal = db.with_name(db.name + "-wal")
    return db.stat().st_size + (wal.stat().st_size if wal.exists() else 0)


def main() -> int:
    with tempfile.TemporaryDirectory(prefix="cc-bench-sonar-") as tmp:
        db = Path(tmp) / "sonar.db"
        journal = Journal(db)
        journal.open()
        empty = _on_disk(db)
        settings = Settings.model_validate({"sonar": {"port": str(Path(tmp) / "ttyPING")}})
        sonar = OnboardSonar(settings.sonar, clock=None, journal=lambda: journal)  # type: ignore[arg-type]
        cpu0 = time.process_time()
        for k in range(PER_S * SECONDS):
            confidence = 255 if k % 7 == 0 else 90
            sonar._record(SonarReading(3000 + k % 500, confidence, 1000.0 + k / PER_S))
        sonar._summarise(1000.0 + SECONDS, everything=True)
        cpu = time.process_time() - cpu0
        journal.close()
        growth = _on_disk(db) - empty
        with sqlite3.connect(db) as conn:
            rows = conn.execute("SELECT count(*) FROM sonar_readings").fetchone()[0]
    per_min = growth * 60 / SECONDS
    verdict = "PASS" if per_min <= BUDGET_BYTES_PER_MIN else "FAIL"
    print(
        f"sonar at {PER_S}/s for {SECONDS} s: {rows} rows journaled, "
        f"{per_min / 1e6:.3f} MB/min (bound 1 MB/min) {verdict}; "
        f"{cpu / (PER_S * SECONDS) * 1e6:.1f} us of CPU a reading"
    )
    return 0 if verdict == "PASS" else 1


if __name__ == "__main__":
    raise SystemExit(main())
