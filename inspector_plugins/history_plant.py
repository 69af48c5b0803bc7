"""The plant history: the ``history`` plugin's rows in a PostgreSQL database shared by the cells.

Same columns as ``OUTDIR/history.sqlite`` (:data:`PG_SCHEMA`: ``REAL`` becomes ``DOUBLE
PRECISION``, ``id`` an identity), with ``cell`` (which cell inspected) and ``uid`` (a UUID
given to the row when it was recorded, ``UNIQUE``); a column added since (:data:`PG_ADDED`)
is added to an older plant database when a cell connects. Rows are inserted with ``ON CONFLICT
(uid) DO NOTHING``, so a row sent twice (a spool flushed again after a crash between the
server's commit and the spool's delete) is stored once, and its defects with it. ``chain`` is
the row's link of the cell's hash chain (:mod:`inspector.ledger`): the plant database keeps a
copy of it, out of the cell's reach.

:class:`PlantDatabase` is one connection, kept open, with its outage state: a connection that
fails raises :class:`PlantUnavailable`, and the caller (``inspector_plugins/history.py``'s sender thread)
keeps the rows in its spool. Its ``statement_timeout`` and ``lock_timeout`` are set when it
opens, so a slow server or a locked table fails a call after seconds, as a server that is down. Nothing here prints; nothing here imports ``psycopg`` until a connection is made,
so the plugin (and ``import inspector``) stays light. A URL is shown only through
:func:`mask_url`: a password never reaches a log line or an error message.
"""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any
from urllib.parse import unquote, urlsplit

from inspector.history_store import COLUMNS, DEFECT_COLUMNS

__all__ = ["COLUMNS", "DEFECT_COLUMNS", "PG_ADDED", "PG_SCHEMA", "PlantDatabase", "PlantUnavailable", "check_url", "mask_url", "scrub"]

#: The plant tables: ``history.sqlite``'s, column for column, plus ``cell`` and ``uid``.
PG_SCHEMA = (
    """CREATE TABLE IF NOT EXISTS inspections (
    id BIGINT GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
    inspected_at TEXT NOT NULL,
    capture TEXT NOT NULL,
    part_id TEXT,
    triggered_at TEXT,
    recipe TEXT NOT NULL,
    verdict TEXT NOT NULL CHECK (verdict IN ('pass', 'fail', 'error')),
    error TEXT,
    n_points INTEGER,
    deviation_mean_mm DOUBLE PRECISION,
    deviation_min_mm DOUBLE PRECISION,
    deviation_max_mm DOUBLE PRECISION,
    n_defects INTEGER NOT NULL,
    worst_mm DOUBLE PRECISION,
    tolerance_lower_mm DOUBLE PRECISION,
    tolerance_upper_mm DOUBLE PRECISION,
    total_s DOUBLE PRECISION,
    result_dir TEXT,
    metadata TEXT,
    extras TEXT,
    cell TEXT NOT NULL,
    uid TEXT NOT NULL UNIQUE,
    calibration_json TEXT,
    chain TEXT
)""",
    "CREATE INDEX IF NOT EXISTS inspections_capture ON inspections (capture)",
    "CREATE INDEX IF NOT EXISTS inspections_part ON inspections (part_id)",
    "CREATE INDEX IF NOT EXISTS inspections_cell ON inspections (cell, inspected_at)",
    """CREATE TABLE IF NOT EXISTS defects (
    inspection_id BIGINT NOT NULL REFERENCES inspections (id),
    kind TEXT NOT NULL,
    n_points INTEGER NOT NULL,
    worst_mm DOUBLE PRECISION NOT NULL,
    x DOUBLE PRECISION, y DOUBLE PRECISION, z DOUBLE PRECISION,
    region TEXT
)""",
    "CREATE INDEX IF NOT EXISTS defects_inspection ON defects (inspection_id)",
)

#: Columns added to the plant tables since they were first made, with their type: a database
#: made by an older version gets them when a cell connects (its older rows have NULL there).
PG_ADDED = (("calibration_json", "TEXT"), ("chain", "TEXT"))

_INSERT = (f"INSERT INTO inspections ({', '.join(COLUMNS)}) VALUES ({', '.join(['%s'] * len(COLUMNS))})"
           " ON CONFLICT (uid) DO NOTHING RETURNING id")
_INSERT_DEFECT = (f"INSERT INTO defects (inspection_id, {', '.join(DEFECT_COLUMNS)})"
                  f" VALUES ({', '.join(['%s'] * (len(DEFECT_COLUMNS) + 1))})")
#: Two cells creating the tables at once would race in the catalogue: one advisory lock.
_SCHEMA_LOCK = 0x1A5EC7_0017


class PlantUnavailable(Exception):
    """The plant database cannot take or give rows now; the message names its masked URL."""


# --------------------------------------------------------------------------- URLs


def _split_userinfo(url: str) -> tuple[str, str, str] | None:
    """(before the password, the password, after it) of ``scheme://user:password@host...``; None
    without a password. The last ``@`` before the query ends it (a raw ``@`` or ``/`` in a
    password, not percent-encoded, is still masked whole)."""
    sep = url.find("://")
    if sep < 0:
        return None
    start = sep + 3
    head_end = url.find("?", start)
    head = url[start:] if head_end < 0 else url[start:head_end]
    at = head.rfind("@")
    if at < 0:
        return None
    colon = head.find(":", 0, at)
    if colon < 0:
        return None
    return url[:start + colon + 1], url[start + colon + 1:start + at], url[start + at:]


def mask_url(url: str) -> str:
    """``url`` with its password (``user:PASSWORD@`` and a ``password=`` parameter) as ``***``."""
    parts = _split_userinfo(url)
    if parts is not None:
        url = f"{parts[0]}***{parts[2]}"
    return re.sub(r"([?&]password=)[^&]*", r"\1***", url, flags=re.IGNORECASE)


def _secrets(url: str) -> list[str]:
    parts = _split_userinfo(url)
    found = [] if parts is None else [parts[1]]
    found += re.findall(r"[?&]password=([^&]*)", url, flags=re.IGNORECASE)
    return [s for p in found for s in {p, unquote(p)} if len(s) >= 3]


def scrub(text: str, url: str) -> str:
    """``text`` (a driver's message) with the URL's password replaced by ``***``, if it is there."""
    for secret in _secrets(url):
        text = text.replace(secret, "***")
    return text


def check_url(url: str) -> None:
    """Raise ValueError (``"url: ..."``, the URL masked) unless ``url`` is a PostgreSQL URL."""
    shown = mask_url(url)
    if any(c.isspace() or ord(c) < 32 or ord(c) == 127 for c in url):
        raise ValueError(f"url: a PostgreSQL URL has no spaces or control characters: {shown!r}")
    if not re.match(r"postgres(ql)?://", url, flags=re.IGNORECASE):
        raise ValueError(f"url: expected a PostgreSQL URL, postgresql://USER@HOST[:PORT]/DATABASE, got {shown!r}")
    try:
        parts = urlsplit(url)
        if "," not in parts.netloc:  # one host: its port must be a number (libpq takes lists too)
            parts.port  # noqa: B018 - raises ValueError on a bad port
    except ValueError:
        raise ValueError(f"url: not a valid port in {shown!r}") from None


# --------------------------------------------------------------------------- the database


def _first_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return text[0] if text else type(e).__name__


class PlantDatabase:
    """One cell's connection to the plant database, and whether it is down.

    Parameters
    ----------
    url : str
        ``postgresql://USER[:PASSWORD]@HOST[:PORT]/DATABASE`` (libpq's variables, ``PGPASSWORD``
        and ``~/.pgpass`` included, fill in what it leaves out).
    connect_timeout_s : int
        Seconds to wait for the server to answer a connection (libpq's ``connect_timeout``);
        also bounds how long sent data may stay unacknowledged on a connection that breaks.
    retry_s : float
        After a failure, :meth:`due` is False for this long: rows go to the spool without
        waiting for a server that does not answer.
    application_name : str
        What ``pg_stat_activity`` shows for the connection.
    statement_timeout_s : float
        Seconds any one statement may run on the server (PostgreSQL's ``statement_timeout``,
        set on the connection): a server that is slow, not down, fails the send after this
        long instead of holding it (the rows stay in the spool). 0: no limit.
    lock_timeout_s : float
        Seconds a statement may wait for a lock (``lock_timeout``): a ``LOCK TABLE`` held by
        another session fails the send after this long. 0: no limit.
    """

    def __init__(self, url: str, *, connect_timeout_s: int = 3, retry_s: float = 30.0,
                 application_name: str = "inspector history", statement_timeout_s: float = 10.0,
                 lock_timeout_s: float = 3.0) -> None:
        check_url(url)
        self.url = url
        self.label = mask_url(url)
        self.connect_timeout_s = int(connect_timeout_s)
        self.retry_s = float(retry_s)
        self.statement_timeout_s = float(statement_timeout_s)
        self.lock_timeout_s = float(lock_timeout_s)
        self.application_name = application_name[:63]
        #: Held while the spool is flushed through this connection.
        self.lock = threading.RLock()
        self._conn: Any = None
        self._down_at: float | None = None  # monotonic time of the last failure, None: up

    # -- outage state ----------------------------------------------------------------
    def due(self) -> bool:
        """Whether to try the server now: up, or down for at least ``retry_s``."""
        return self._down_at is None or time.monotonic() - self._down_at >= self.retry_s

    def failed(self) -> bool:
        """Record a failure; True when it starts an outage (the caller warns once)."""
        first = self._down_at is None
        self._down_at = time.monotonic()
        return first

    def succeeded(self) -> bool:
        """Record a success; True when it ends an outage."""
        was_down = self._down_at is not None
        self._down_at = None
        return was_down

    # -- connection ------------------------------------------------------------------
    def _unavailable(self, e: BaseException) -> PlantUnavailable:
        return PlantUnavailable(f"plant database {self.label}: {scrub(_first_line(e), self.url)}")

    def _connect(self) -> Any:
        try:
            import psycopg
        except ImportError:
            raise PlantUnavailable(f"plant database {self.label}: psycopg is not installed "
                                   "(pip install -r requirements.lock, or inspector-bcps[plant])") from None
        timeout_ms = 1000 * self.connect_timeout_s
        try:
            conn = psycopg.connect(self.url, autocommit=True, connect_timeout=self.connect_timeout_s,
                                   application_name=self.application_name, keepalives=1, keepalives_idle=10,
                                   keepalives_interval=3, keepalives_count=3, tcp_user_timeout=timeout_ms)
        except psycopg.Error as e:
            raise self._unavailable(e) from None
        try:
            # Set before anything that may wait: the schema check below and every insert are
            # bounded too (in ms; set_config takes a bound parameter, SET does not).
            for name, seconds in (("statement_timeout", self.statement_timeout_s), ("lock_timeout", self.lock_timeout_s)):
                conn.execute("SELECT set_config(%s, %s, false)", (name, str(max(0, round(1000 * seconds)))))
            exists = conn.execute("SELECT to_regclass('inspections') IS NOT NULL AND to_regclass('defects') IS NOT NULL")
            row = exists.fetchone()
            if not (row and row[0]):
                with conn.transaction():
                    conn.execute("SELECT pg_advisory_xact_lock(%s)", (_SCHEMA_LOCK,))
                    for statement in PG_SCHEMA:
                        conn.execute(statement)
            have = {r[0] for r in conn.execute(
                "SELECT attname FROM pg_attribute WHERE attrelid = to_regclass('inspections') AND attnum > 0"
                " AND NOT attisdropped")}
            if any(column not in have for column, _ in PG_ADDED):  # a database made by an older version
                with conn.transaction():
                    conn.execute("SELECT pg_advisory_xact_lock(%s)", (_SCHEMA_LOCK,))
                    for column, kind in PG_ADDED:
                        conn.execute(f"ALTER TABLE inspections ADD COLUMN IF NOT EXISTS {column} {kind}")
        except psycopg.Error as e:
            conn.close()
            raise self._unavailable(e) from None
        return conn

    def close(self) -> None:
        """Close the connection (the next call opens a new one)."""
        conn, self._conn = self._conn, None
        if conn is not None:
            try:
                conn.close()
            except Exception:  # noqa: BLE001 - a broken connection may fail to close; it is dropped
                pass

    def _run(self, work: Any) -> Any:
        """``work(conn)`` on the open connection, or a new one; a connection that had been open
        and fails is replaced once (a server restarted since the last call), then the failure
        is :class:`PlantUnavailable`."""
        for attempt in (0, 1):
            fresh = self._conn is None
            if fresh:
                self._conn = self._connect()
            import psycopg  # installed: _connect said so otherwise

            try:
                return work(self._conn)
            except psycopg.Error as e:
                self.close()
                if fresh or attempt == 1 or not isinstance(e, psycopg.OperationalError):
                    raise self._unavailable(e) from None
        raise AssertionError("unreachable")

    # -- rows ------------------------------------------------------------------------
    def insert(self, rows: Sequence[tuple[Mapping[str, Any], Sequence[Mapping[str, Any]]]]) -> int:
        """Insert ``(row, defects)`` pairs in one transaction, each row once (by its ``uid``);
        returns how many were new. Raises :class:`PlantUnavailable` (nothing inserted)."""

        def work(conn: Any) -> int:
            new = 0
            with conn.transaction(), conn.cursor() as cur:
                for row, defects in rows:
                    cur.execute(_INSERT, [_text(row.get(c)) for c in COLUMNS])
                    got = cur.fetchone()
                    if got is None:  # already stored: sent before (a spool flushed twice)
                        continue
                    new += 1
                    if defects:
                        cur.executemany(_INSERT_DEFECT, [(got[0], *(_text(d.get(c)) for c in DEFECT_COLUMNS))
                                                         for d in defects])
            return new

        if not rows:
            return 0
        result: int = self._run(work)
        return result

    def read(self, *, last: int | None = None, cell: str | None = None) -> list[dict[str, Any]]:
        """The plant's inspections, oldest first by ``inspected_at`` (the ``last`` ones only;
        one cell's only). Raises :class:`PlantUnavailable`."""

        def work(conn: Any) -> list[dict[str, Any]]:
            from psycopg.rows import dict_row

            where, params = ("WHERE cell = %s", [cell]) if cell is not None else ("", [])
            limit = f" LIMIT {int(last)}" if last is not None else ""
            q = (f"SELECT id, {', '.join(COLUMNS)} FROM inspections {where}"
                 f" ORDER BY inspected_at DESC, id DESC{limit}")
            with conn.cursor(row_factory=dict_row) as cur:
                rows = list(cur.execute(q, params))
            return rows[::-1]

        result: list[dict[str, Any]] = self._run(work)
        return result


def _text(value: Any) -> Any:
    """A value PostgreSQL's TEXT takes: NUL characters (SQLite keeps them) as U+FFFD."""
    return value.replace("\x00", "\ufffd") if isinstance(value, str) else value
