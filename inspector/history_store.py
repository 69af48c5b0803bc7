"""The history store (core): every inspection one row of ``OUTDIR/history.sqlite``.

The traceability record of a production line: one row per inspection (a capture inspected
twice has two rows: nothing is overwritten), with the part's id and trigger time from
``capture.json``, the verdict, the deviation summary, the defects, the timings, the cell
that inspected it and a unique ``uid``. The built-in ``history`` plugin
(``inspector_plugins.history``) writes it from its ``inspector_on_result`` hook and sends
it on to the plant's database; the hot folder, the OPC UA server, the shift counters and the
audit trail read it here.

SQLite with a WAL journal, so a reader never blocks the runner; the schema is :data:`SCHEMA`.
Every ``inspections`` row is hash-chained (:mod:`inspector.ledger`). The ``spool`` table
lists the rows not yet sent to the plant database (the plugin's sender empties it).
"""

from __future__ import annotations

import json
import math
import os
import socket
import sqlite3
import uuid
from collections.abc import Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from inspector import ledger
from inspector.errors import InputError
from inspector.model import InspectionResult

__all__ = ["HISTORY_FILE", "CELL_ENV", "SCHEMA", "COLUMNS", "DEFECT_COLUMNS", "connect", "migrate", "record",
           "calibration_of", "default_cell", "spooled", "spooled_batch", "recorded", "read_history", "read_table"]

#: The history database, in the run's OUTDIR (beside the result folders).
HISTORY_FILE = "history.sqlite"

#: The cell's name when the recipe gives none (``[plugins.history] cell``); else the host name.
CELL_ENV = "INSPECTOR_HISTORY_CELL"

#: The row columns (``id`` aside), in the order of ``history.sqlite`` and of the plant database (``inspector_plugins.history_plant``).
COLUMNS = ("inspected_at", "capture", "part_id", "triggered_at", "recipe", "verdict", "error", "n_points",
           "deviation_mean_mm", "deviation_min_mm", "deviation_max_mm", "n_defects", "worst_mm", "tolerance_lower_mm",
           "tolerance_upper_mm", "total_s", "result_dir", "metadata", "extras", "cell", "uid", "calibration_json", "chain")
#: The defect columns (``inspection_id`` aside).
DEFECT_COLUMNS = ("kind", "n_points", "worst_mm", "x", "y", "z", "region")

#: Version 1. ``inspected_at`` is UTC ISO-8601; deviations in mm; ``metadata`` is capture.json
#: (minus polarity) as JSON; ``extras`` what the stages put in ``context.extras`` (JSON, the
#: result's ``extras``); ``cell`` the cell that inspected (recipe, ``$INSPECTOR_HISTORY_CELL``
#: or the host name); ``uid`` a UUID given when the row is recorded (what makes a row sent to
#: the plant database twice one row there); ``calibration_json`` the evaluate stage's calibration
#: health (:func:`calibration_of`: how far each camera is off and its median residual, px, the flagged cameras
#: and the threshold; NULL when it was not checked); ``chain`` the row's link of the hash chain
#: (:mod:`inspector.ledger`). ``extras``, ``cell``, ``uid``, ``calibration_json`` and ``chain``
#: were added compatibly: :func:`record` adds them to an older file (its older rows have NULL
#: there: the chain starts at the first row written after).
#: The deviation and tolerance columns come from the evaluate stage's typed summary
#: (:class:`inspector.model.EvaluationSummary`), whichever evaluate variant ran. ``spool``
#: lists the rows not yet in the plant database (empty without one), oldest first.
SCHEMA = """
CREATE TABLE IF NOT EXISTS inspections (
    id INTEGER PRIMARY KEY,
    inspected_at TEXT NOT NULL,
    capture TEXT NOT NULL,
    part_id TEXT,
    triggered_at TEXT,
    recipe TEXT NOT NULL,
    verdict TEXT NOT NULL CHECK (verdict IN ('pass', 'fail', 'error')),
    error TEXT,
    n_points INTEGER,
    deviation_mean_mm REAL,
    deviation_min_mm REAL,
    deviation_max_mm REAL,
    n_defects INTEGER NOT NULL,
    worst_mm REAL,
    tolerance_lower_mm REAL,
    tolerance_upper_mm REAL,
    total_s REAL,
    result_dir TEXT,
    metadata TEXT,
    extras TEXT,
    cell TEXT,
    uid TEXT,
    calibration_json TEXT,
    chain TEXT
);
CREATE INDEX IF NOT EXISTS inspections_capture ON inspections (capture);
CREATE INDEX IF NOT EXISTS inspections_part ON inspections (part_id);
CREATE TABLE IF NOT EXISTS defects (
    inspection_id INTEGER NOT NULL REFERENCES inspections (id),
    kind TEXT NOT NULL,
    n_points INTEGER NOT NULL,
    worst_mm REAL NOT NULL,
    x REAL, y REAL, z REAL,
    region TEXT
);
CREATE INDEX IF NOT EXISTS defects_inspection ON defects (inspection_id);
CREATE TABLE IF NOT EXISTS spool (
    inspection_id INTEGER PRIMARY KEY REFERENCES inspections (id)
);
PRAGMA user_version = 1;
"""

#: Columns added since the first files, with their type: added to an older file when written.
_ADDED = (("extras", "TEXT"), ("cell", "TEXT"), ("uid", "TEXT"), ("calibration_json", "TEXT"), ("chain", "TEXT"))


def connect(path: Path) -> sqlite3.Connection:
    con = sqlite3.connect(str(path), timeout=10.0)
    con.execute("PRAGMA journal_mode=WAL")
    return con


def _finite(value: Any) -> Any:
    """``value`` with every non-finite float (NaN, +-inf, numpy's too) as None.

    capture.json may hold ``NaN`` (Python's json writes and reads it), which is not JSON:
    the ``metadata`` column must stay readable by any SQL client's JSON functions. Only
    floats change; what ``default=str`` writes for other types is unchanged.
    """
    if isinstance(value, float | np.floating):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def default_cell() -> str:
    """This cell's name when the recipe gives none: ``$INSPECTOR_HISTORY_CELL``, else the host name."""
    return os.environ.get(CELL_ENV, "").strip() or socket.gethostname() or "cell"


def migrate(con: sqlite3.Connection) -> None:
    """Create the tables, and add the columns an older file lacks (nothing written when the
    file is current: the unique index on ``uid`` is made last)."""
    if ({"inspections", "defects", "spool", "inspections_uid", "defects_inspection"}
            <= {r[0] for r in con.execute("SELECT name FROM sqlite_master")}
            and {c for c, _ in _ADDED} <= {r[1] for r in con.execute("PRAGMA table_info(inspections)")}):
        return
    con.executescript(SCHEMA)
    con.execute("BEGIN IMMEDIATE")  # two writers migrating one file: the second finds the columns there
    have = {r[1] for r in con.execute("PRAGMA table_info(inspections)")}
    for column, kind in _ADDED:
        if column not in have:  # a file from before
            con.execute(f"ALTER TABLE inspections ADD COLUMN {column} {kind}")
    con.execute("CREATE UNIQUE INDEX IF NOT EXISTS inspections_uid ON inspections (uid)")
    con.commit()


def record(result: InspectionResult, outdir: Path, *, now: datetime | None = None, cell: str | None = None,
           spool: bool = False, con: sqlite3.Connection | None = None) -> int:
    """Append one inspection to ``outdir/history.sqlite``; returns its row id.

    ``outdir`` is the run's result folder (the parent of the capture's own folder). ``cell``
    names the cell (default :func:`default_cell`). ``spool``: also list the row in the
    ``spool`` table, in the same transaction, for the plant database (the history plugin's ``flush_spool`` sends it).
    ``con``: an open connection to that file to use (committed, left open).
    """
    if con is not None:
        return _record(con, result, now=now, cell=cell, spool=spool)
    own = connect(Path(outdir) / HISTORY_FILE)
    try:
        return _record(own, result, now=now, cell=cell, spool=spool)
    finally:
        own.close()


def calibration_of(stats: Mapping[str, Any]) -> str | None:
    """The ``calibration_json`` of a result's ``stats``: ``{"off_px": {camera: px}, "median_px":
    {camera: px}, "flagged": [cameras], "threshold_px": px}`` (JSON; ``off_px`` is what the
    threshold judges, see ``stats.calibration``), None when the evaluate stage did not check
    the calibration."""
    cal = stats.get("calibration") if isinstance(stats, Mapping) else None
    if not isinstance(cal, Mapping) or not isinstance(cal.get("cameras"), Mapping):
        return None
    cams = cal["cameras"]
    doc: dict[str, Any] = {key: {name: (c or {}).get(key) for name, c in cams.items()} for key in ("off_px", "median_px")}
    doc.update(flagged=list(cal.get("flagged") or []), threshold_px=cal.get("threshold_px"))
    return json.dumps(_finite(doc), sort_keys=True, allow_nan=False)


def _record(con: sqlite3.Connection, result: InspectionResult, *, now: datetime | None, cell: str | None,
            spool: bool) -> int:
    """:func:`record` on an open connection (committed)."""
    meta = dict(result.metadata or {})
    summary = result.summary  # the evaluate stage's contract; None: no evaluate stage, or an error
    dev = summary.deviation_mm if summary is not None else None
    worst = max((d.worst_mm for d in result.defects), key=abs, default=None)
    tol = summary.tolerance_mm if summary is not None else (None, None)
    row = (
        (now or datetime.now(UTC)).isoformat(timespec="milliseconds"),
        result.capture,
        None if meta.get("part_id") is None else str(meta["part_id"]),
        None if meta.get("timestamp") is None else str(meta["timestamp"]),
        result.recipe,
        result.verdict,
        result.error,
        summary.n_points if summary is not None else None,
        dev.mean if dev is not None else None,
        dev.min if dev is not None else None,
        dev.max if dev is not None else None,
        len(result.defects),
        worst,
        tol[0],
        tol[1],
        result.timings_s.get("total"),
        result.capture,
        json.dumps(_finite(meta), default=str, sort_keys=True, allow_nan=False),
        json.dumps(_finite(dict(result.extras)), default=str, sort_keys=True, allow_nan=False) if result.extras else None,
        cell if cell is not None else default_cell(),
        str(uuid.uuid4()),
        calibration_of(result.stats),
        None,  # chain: sealed below, from the row as stored, in the same transaction
    )
    migrate(con)
    cur = con.execute(f"INSERT INTO inspections ({', '.join(COLUMNS)}) VALUES ({', '.join('?' * len(COLUMNS))})", row)
    rid = int(cur.lastrowid or 0)
    con.executemany(
        "INSERT INTO defects (inspection_id, kind, n_points, worst_mm, x, y, z, region) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
        [(rid, d.kind, d.n_points, d.worst_mm, *d.position, d.region) for d in result.defects],
    )
    ledger.seal(con, "inspections", rid, child=("defects", "inspection_id"))
    if spool:
        con.execute("INSERT INTO spool (inspection_id) VALUES (?)", (rid,))
    con.commit()
    return rid


def spooled(outdir: Path) -> int:
    """How many of ``outdir``'s inspections wait in its spool for the plant database (0 when
    there is no history, or no spool)."""
    path = Path(outdir) / HISTORY_FILE
    if not path.is_file():
        return 0
    try:
        con = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=10.0)
        try:
            if con.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'spool'").fetchone() is None:
                return 0
            return int(con.execute("SELECT COUNT(*) FROM spool").fetchone()[0])
        finally:
            con.close()
    except sqlite3.Error:
        return 0


def spooled_batch(con: sqlite3.Connection, limit: int) -> list[tuple[int, dict[str, Any], list[dict[str, Any]]]]:
    """The oldest ``limit`` spooled rows: (local id, row, defects)."""
    cur = con.cursor()
    cur.row_factory = sqlite3.Row
    rows = [dict(r) for r in cur.execute(
        f"SELECT i.id, {', '.join('i.' + c for c in COLUMNS)} FROM spool s JOIN inspections i ON i.id = s.inspection_id"
        " ORDER BY s.inspection_id LIMIT ?", (limit,))]
    missing = [r for r in rows if not r["uid"]]  # cannot happen with record(); a uid is what makes a send idempotent
    for r in missing:
        r["uid"] = str(uuid.uuid4())
        con.execute("UPDATE inspections SET uid = ? WHERE id = ?", (r["uid"], r["id"]))
    if missing:
        con.commit()
    defects: dict[int, list[dict[str, Any]]] = {}
    if rows:
        ids = [r["id"] for r in rows]
        q = (f"SELECT inspection_id, {', '.join(DEFECT_COLUMNS)} FROM defects"
             f" WHERE inspection_id IN ({', '.join('?' * len(ids))}) ORDER BY rowid")
        for d in cur.execute(q, ids):
            defects.setdefault(d["inspection_id"], []).append(dict(d))
    out = []
    for r in rows:
        rid = r.pop("id")
        out.append((rid, r, defects.get(rid, [])))
    return out


def recorded(outdir: Path, capture: str) -> bool | None:
    """Whether ``outdir``'s history has a row for ``capture``; None when it cannot be read
    (a corrupt file: then no row could be written either). What a hot folder asks after a
    crash, to tell a result that was recorded from one that was not."""
    path = Path(outdir) / HISTORY_FILE
    if not path.is_file():
        return False
    try:
        con = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=10.0)
        try:
            if con.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'inspections'").fetchone() is None:
                return False
            return con.execute("SELECT 1 FROM inspections WHERE capture = ? LIMIT 1", (capture,)).fetchone() is not None
        finally:
            con.close()
    except sqlite3.Error:
        return None


def read_history(outdir: Path, *, last: int | None = None, cell: str | None = None) -> list[dict[str, Any]]:
    """The recorded inspections of ``outdir``, oldest first (the ``last`` ones only; those of
    ``cell`` only).

    Raises InputError naming the file when there is no history or it cannot be read.
    """
    path = Path(outdir) / HISTORY_FILE
    if not path.is_file():
        raise InputError(f"{path}: no history (inspector run writes it beside the result folders)")
    return read_table(path, "inspections", last=last, where=None if cell is None else {"cell": cell}) or []


def read_table(path: Path, table: str, columns: tuple[str, ...] | None = None, *,
               last: int | None = None, where: Mapping[str, Any] | None = None) -> list[dict[str, Any]] | None:
    """Rows of ``table`` in the SQLite file ``path`` (read-only), oldest first, the ``last``
    ones only, those whose columns equal ``where``'s values only (a column the file lacks:
    no row); None when the file has no such table. InputError naming the file when it
    cannot be read. Shared by the history and the audit trail (``inspector.roles``)."""
    cols = ", ".join(columns) if columns else "*"
    try:
        con = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=10.0)
        try:
            con.row_factory = sqlite3.Row
            if con.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = ?", (table,)).fetchone() is None:
                return None
            cond, params = "", []
            if where:
                have = {r[1] for r in con.execute(f"PRAGMA table_info({table})")}
                if not set(where) <= have:
                    return []
                cond = " WHERE " + " AND ".join(f"{k} = ?" for k in where)
                params = list(where.values())
            q = f"SELECT {cols} FROM {table}{cond} ORDER BY id"
            if last is not None:
                q = f"SELECT * FROM (SELECT {cols} FROM {table}{cond} ORDER BY id DESC LIMIT {int(last)}) ORDER BY id"
            return [dict(r) for r in con.execute(q, params)]
        finally:
            con.close()
    except sqlite3.Error as e:
        raise InputError(f"{path}: cannot be read ({e})") from None
