"""Hash chains over SQLite tables: a record that says when a row was changed or removed.

The ``inspections`` rows of ``history.sqlite`` (with their ``defects``) and the ``audit`` rows
of the station (:mod:`inspector.roles`) each carry a ``chain`` column: the SHA-256 (hex) of the
previous row's ``chain`` and this row's own content::

    chain[i] = sha256(chain[i-1] + "\\n" + canonical(row[i]))        (chain[-1] = "")

``canonical`` is the row as JSON: its columns but ``chain``, ``id`` included, NULL columns left
out (a column added to the table later, NULL in older rows, does not change their hash), keys
sorted, no spaces, UTF-8; a table with child rows (an inspection's defects) adds them, in the
order they were written, under ``"_children"``. The value is computed from the row as SQLite
stores it (read back inside the writing transaction), so what is verified is what was hashed.

:func:`seal` sets a new row's ``chain`` inside the transaction that inserted it (the writer
holds SQLite's write lock, so the previous row is the one with the next lower ``id``);
:func:`verify` walks a table in ``id`` order and names the first row whose content no longer
matches its hash (changed), or the ``id`` values missing before the first row that no longer
follows its predecessor (removed). A file written before the chain existed gets the column when
it is next written: its older rows have no hash, the chain starts at the first new row, and
:func:`verify` says how many rows came before it.

What a chain cannot show, without a copy of its last hash kept elsewhere: the newest rows
removed (nothing follows them), or a forger who recomputes every hash after the row they changed
(the algorithm is public, nothing is secret). The plant database receives each inspection's
``chain`` value: it is such a copy. This module is plain Python (``sqlite3``, ``hashlib``).
"""

from __future__ import annotations

import hashlib
import json
import sqlite3
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

__all__ = ["CHAIN_COLUMN", "ChainReport", "add_chain_column", "canonical", "link", "seal", "verify"]

#: The column that holds each row's link of the chain.
CHAIN_COLUMN = "chain"
_GENESIS = ""


def canonical(row: Mapping[str, Any], children: Sequence[Mapping[str, Any]] | None = None,
              child_key: str | None = None) -> bytes:
    """A row's content as hashed: JSON of its non-NULL columns but ``chain`` (keys sorted, no
    spaces, UTF-8), with ``children`` (their non-NULL columns but ``child_key``, the foreign
    key) under ``"_children"`` when given."""
    doc: dict[str, Any] = {k: v for k, v in row.items() if k != CHAIN_COLUMN and v is not None}
    if children is not None:
        doc["_children"] = [{k: v for k, v in c.items() if k != child_key and v is not None} for c in children]
    return json.dumps(doc, sort_keys=True, separators=(",", ":"), ensure_ascii=False, default=_bytes).encode("utf-8")


def _bytes(value: Any) -> Any:
    if isinstance(value, bytes | bytearray | memoryview):
        return bytes(value).hex()
    raise TypeError(f"not hashable in a row: {type(value).__name__}")


def link(previous: str | None, content: bytes) -> str:
    """The ``chain`` value of a row of ``content`` after a row whose value is ``previous``
    (None or "": the first row of a chain)."""
    h = hashlib.sha256((previous or _GENESIS).encode("ascii"))
    h.update(b"\n")
    h.update(content)
    return h.hexdigest()


def add_chain_column(con: sqlite3.Connection, table: str) -> bool:
    """Add the ``chain`` column to ``table`` when it lacks it (a file from before); True when
    added. Its older rows keep NULL there: the chain starts at the next row written."""
    have = {r[1] for r in con.execute(f"PRAGMA table_info({table})")}
    if CHAIN_COLUMN in have:
        return False
    con.execute(f"ALTER TABLE {table} ADD COLUMN {CHAIN_COLUMN} TEXT")
    return True


def _row(con: sqlite3.Connection, table: str, rowid: int) -> dict[str, Any]:
    cur = con.execute(f"SELECT * FROM {table} WHERE id = ?", (rowid,))
    names = [d[0] for d in cur.description]
    found = cur.fetchone()
    if found is None:
        raise LookupError(f"{table}: no row id {rowid}")
    return dict(zip(names, found))


def _children(con: sqlite3.Connection, child: tuple[str, str] | None, rowid: int) -> list[dict[str, Any]] | None:
    if child is None:
        return None
    table, key = child
    cur = con.execute(f"SELECT * FROM {table} WHERE {key} = ? ORDER BY rowid", (rowid,))
    names = [d[0] for d in cur.description]
    return [dict(zip(names, r)) for r in cur]


def seal(con: sqlite3.Connection, table: str, rowid: int, *, child: tuple[str, str] | None = None) -> str:
    """Set the ``chain`` of ``table``'s row ``rowid`` (just inserted, with its children, in
    the caller's open transaction, not committed here); returns the value.

    ``child``: ``(table, foreign key)`` of the rows that belong to it (an inspection's defects).
    The previous row is the one with the next lower ``id``; one without a ``chain`` (written
    before the chain) starts a new chain.
    """
    prev = con.execute(f"SELECT {CHAIN_COLUMN} FROM {table} WHERE id < ? ORDER BY id DESC LIMIT 1", (rowid,)).fetchone()
    row = _row(con, table, rowid)
    value = link(prev[0] if prev else None, canonical(row, _children(con, child, rowid), child[1] if child else None))
    con.execute(f"UPDATE {table} SET {CHAIN_COLUMN} = ? WHERE id = ?", (value, rowid))
    return value


@dataclass(frozen=True)
class ChainReport:
    """What :func:`verify` found.

    Attributes
    ----------
    table : str
    rows : int
        Rows in the table.
    unchained : int
        Rows before the first hashed row (written before the chain existed).
    first_id, last_id : int or None
        ``id`` of the first hashed row and of the last row (None: none).
    last_chain : str or None
        The last row's ``chain`` value (keep it elsewhere to detect the newest rows removed).
    bad_id : int or None
        The first row that no longer matches (None: intact).
    removed : tuple of int
        The ``id`` values missing just before ``bad_id`` when rows were removed there (empty:
        ``bad_id`` itself was changed).
    problem : str or None
        One line saying what is wrong (None: intact), without the file's name.
    """

    table: str
    rows: int
    unchained: int
    first_id: int | None
    last_id: int | None
    last_chain: str | None
    bad_id: int | None = None
    removed: tuple[int, ...] = ()
    problem: str | None = None

    @property
    def ok(self) -> bool:
        """Whether the chain is intact."""
        return self.problem is None

    def summary(self) -> str:
        """One line: the verdict, what is chained, what came before the chain."""
        if not self.ok:
            return f"{self.table}: chain broken: {self.problem}"
        if self.rows == 0:
            return f"{self.table}: no rows"
        chained = self.rows - self.unchained
        before = (f"; the {self.unchained} row{'s' if self.unchained != 1 else ''} before id {self.first_id} were "
                  "written before the chain (no hash, not verifiable)" if self.unchained and self.first_id is not None
                  else "")
        if self.first_id is None:
            return (f"{self.table}: no row has a hash: all {self.rows} were written before the chain "
                    "(it starts at the next row written)")
        last = f"; last row id {self.last_id}, chain {(self.last_chain or '')[:16]}"
        return f"{self.table}: chain intact: {chained} row{'s' if chained != 1 else ''} from id {self.first_id}{before}{last}"


def _walk(con: sqlite3.Connection, table: str, child: tuple[str, str] | None) -> Iterator[tuple[dict[str, Any], list[dict[str, Any]] | None]]:
    """(row, its children) of ``table`` in ``id`` order, children read alongside."""
    cur = con.execute(f"SELECT * FROM {table} ORDER BY id")
    names = [d[0] for d in cur.description]
    kids: Iterator[tuple[Any, ...]] | None = None
    kid_names: list[str] = []
    pending: tuple[Any, ...] | None = None
    key_at = 0
    if child is not None:
        kcur = con.execute(f"SELECT * FROM {child[0]} ORDER BY {child[1]}, rowid")
        kid_names = [d[0] for d in kcur.description]
        kids = iter(kcur.fetchall())
        pending = next(kids, None)
        key_at = kid_names.index(child[1])
    for values in cur.fetchall():
        row = dict(zip(names, values))
        if child is None or kids is None:
            yield row, None
            continue
        mine: list[dict[str, Any]] = []
        while pending is not None and pending[key_at] is not None and pending[key_at] < row["id"]:
            pending = next(kids, None)  # a child of no row (its row removed): the row that follows shows it
        while pending is not None and pending[key_at] == row["id"]:
            mine.append(dict(zip(kid_names, pending)))
            pending = next(kids, None)
        yield row, mine


def verify(con: sqlite3.Connection, table: str, *, child: tuple[str, str] | None = None,
           describe: Callable[[Mapping[str, Any]], str] | None = None) -> ChainReport:
    """Walk ``table``'s chain; the first row changed or removed, or that it is intact.

    Parameters
    ----------
    con : sqlite3.Connection
        The database (read only).
    table : str
        A table with ``id`` and ``chain`` columns.
    child : (str, str), optional
        The child table and its foreign key, hashed with each row (as :func:`seal`).
    describe : callable, optional
        A row -> a few words naming it for the report (e.g. its capture).

    Returns
    -------
    ChainReport
        ``problem`` names the first broken row; a table without the ``chain`` column reports
        every row as written before the chain.
    """
    have = {r[1] for r in con.execute(f"PRAGMA table_info({table})")}
    if not have:
        return ChainReport(table, 0, 0, None, None, None)
    n = int(con.execute(f"SELECT COUNT(*) FROM {table}").fetchone()[0])
    if CHAIN_COLUMN not in have:
        last = con.execute(f"SELECT MAX(id) FROM {table}").fetchone()[0]
        return ChainReport(table, n, n, None, last, None)
    name = describe or (lambda r: "")
    prev_chain: str | None = None
    prev_id: int | None = None
    first: int | None = None
    unchained = 0
    for row, kids in _walk(con, table, child):
        rid = int(row["id"])
        label = name(row)
        label = f" ({label})" if label else ""
        if row[CHAIN_COLUMN] is None:
            if first is None:
                unchained += 1
                prev_id = rid
                continue
            return ChainReport(table, n, unchained, first, None, None, rid, (),
                               f"row id {rid}{label} was changed: its hash was removed")
        expected_prev = (prev_id + 1) if prev_id is not None else (1 if first is None and unchained == 0 else rid)
        value = link(prev_chain, canonical(row, kids, child[1] if child else None))
        if first is None:
            first = rid
        if value != row[CHAIN_COLUMN]:
            if rid > expected_prev:
                gone = tuple(range(expected_prev, rid))
                ids = f"id {gone[0]}" if len(gone) == 1 else f"ids {gone[0]} to {gone[-1]}"
                return ChainReport(table, n, unchained, first, None, None, rid, gone,
                                   f"{len(gone)} row{'s' if len(gone) != 1 else ''} removed before row id {rid}{label}: "
                                   f"{ids} missing")
            return ChainReport(table, n, unchained, first, None, None, rid, (),
                               f"row id {rid}{label} was changed after it was written: its content does not match its hash")
        prev_chain, prev_id = row[CHAIN_COLUMN], rid
    return ChainReport(table, n, unchained, first, prev_id, prev_chain)
