"""The rows the journal writes: their kinds, the SQL that stores each, and the
columns a row has in a spill file. What builds them is `journal`; what commits
them is `writer`. Pure data: no I/O.
"""

from __future__ import annotations

from cc_daemon.store import sonde
from cc_daemon.store.buffer import FIX

# Row kinds besides `FIX` (0, a telemetry fix; see `buffer`): a row is the kind,
# then its values in the order of the matching INSERT.
# An event row ends with the `cast_id` of its details (or None), after the
# INSERT's values, so a cast stored under a new id can be followed.
CAST = 1
SAMPLE = 2
END = 3
EVENT = 4
SONAR = 6  # written in bulk with the fixes (`bulk_kinds`); 5 is the sonde's (`store.sonde`)

INSERT_FIX = (
    "INSERT INTO fixes (session_id, mono_s, wall_s, clock_synced, frame, ap_timestamp_s,"
    " lon_e7, lat_e7, alt_mm, sonar_distance_mm, sonar_confidence_pct, measuring_mode,"
    " ap_time_s, ap_time_order) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)"
)
INSERT_CAST = (
    "INSERT INTO casts (id, session_id, start_mono_s, start_wall_s, start_clock_synced,"
    " ap_timestamp_s, lon_e7, lat_e7, alt_mm, sonar_distance_mm, sonar_confidence_pct,"
    " planned_depth_m, mode, plan_json, winch_backend, simulated)"
    " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)"
)
INSERT_SAMPLE = (
    "INSERT INTO samples (cast_id, mono_s, wall_s, clock_synced, depth_m, phase)"
    " VALUES (?, ?, ?, ?, ?, ?)"
)
UPDATE_END = (
    "UPDATE casts SET end_mono_s = ?, end_wall_s = ?, end_clock_synced = ?, outcome = ?,"
    " reached_depth_m = ?, reason = ? WHERE id = ?"
)
INSERT_SONAR = (
    "INSERT INTO sonar_readings (session_id, mono_s, wall_s, clock_synced, port, distance_mm,"
    " confidence_pct) VALUES (?, ?, ?, ?, ?, ?, ?)"
)
INSERT_EVENT = (
    "INSERT INTO events (session_id, mono_s, wall_s, clock_synced, kind, detail_json)"
    " VALUES (?, ?, ?, ?, ?, ?)"
)
RECOVER_UNFINISHED = """
UPDATE casts SET
    outcome = 'unfinished',
    reason = ?,
    reached_depth_m = (SELECT max(depth_m) FROM samples WHERE cast_id = casts.id),
    end_mono_s = (SELECT max(mono_s) FROM samples WHERE cast_id = casts.id),
    end_wall_s = (SELECT wall_s FROM samples WHERE cast_id = casts.id
                  ORDER BY mono_s DESC LIMIT 1),
    end_clock_synced = (SELECT clock_synced FROM samples WHERE cast_id = casts.id
                        ORDER BY mono_s DESC LIMIT 1)
WHERE outcome IS NULL
"""

# The spill file's columns per row kind: a row's values after its kind, in order.
SPILL_LAYOUT: dict[int, tuple[str, tuple[str, ...]]] = {
    FIX: (
        "fixes",
        (
            "mono_s",
            "wall_s",
            "clock_synced",
            "frame",
            "ap_timestamp_s",
            "lon_e7",
            "lat_e7",
            "alt_mm",
            "sonar_distance_mm",
            "sonar_confidence_pct",
            "measuring_mode",
            "ap_time_s",
            "ap_time_order",
        ),
    ),
    CAST: (
        "casts",
        (
            "id",
            "start_mono_s",
            "start_wall_s",
            "start_clock_synced",
            "ap_timestamp_s",
            "lon_e7",
            "lat_e7",
            "alt_mm",
            "sonar_distance_mm",
            "sonar_confidence_pct",
            "planned_depth_m",
            "mode",
            "plan_json",
            "winch_backend",
            "simulated",
        ),
    ),
    SAMPLE: ("samples", ("cast_id", "mono_s", "wall_s", "clock_synced", "depth_m", "phase")),
    END: (
        "cast_ends",
        (
            "cast_id",
            "end_mono_s",
            "end_wall_s",
            "end_clock_synced",
            "outcome",
            "reached_depth_m",
            "reason",
        ),
    ),
    EVENT: ("events", ("mono_s", "wall_s", "clock_synced", "kind", "detail_json")),
    sonde.SONDE: ("sonde_samples", sonde.COLUMNS),
    SONAR: (
        "sonar_readings",
        ("mono_s", "wall_s", "clock_synced", "port", "distance_mm", "confidence_pct"),
    ),
}
