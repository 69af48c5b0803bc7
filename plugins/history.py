"""Built-in plugin ``history``: every inspection recorded in ``OUTDIR/history.sqlite``.

The traceability record of a production line: one row per inspection (a capture inspected
twice has two rows: nothing is overwritten), with the part's id and trigger time from
``capture.json``, the verdict, the deviation summary, the defects and the timings. It is an
``inspector_on_result`` hook like an integrator's PLC or MES publisher, registered through
the same entry-point group; ``inspector history OUTDIR`` reads it.

The database is SQLite (WAL journal, so a reader never blocks the runner); the schema is
:data:`SCHEMA`. A history that cannot be written (read-only folder, a corrupt file) costs
only the history row: the result folder is already written, and the runner says so in one
line.
"""

from __future__ import annotations

import json
import math
import sqlite3
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from inspector import hookimpl
from inspector.errors import InputError
from inspector.model import InspectionResult
from inspector.registry import CommandRegistry

__all__ = ["HISTORY_FILE", "SCHEMA", "record", "recorded", "read_history", "read_table", "tally", "draw_history", "plot_history"]

#: The history database, in the run's OUTDIR (beside the result folders).
HISTORY_FILE = "history.sqlite"

#: Version 1. ``inspected_at`` is UTC ISO-8601; deviations in mm; ``metadata`` is capture.json
#: (minus polarity) as JSON; ``extras`` what the stages put in ``context.extras`` (JSON, the
#: result's ``extras``; added compatibly: :func:`record` adds the column to an older file).
#: The deviation and tolerance columns come from the evaluate stage's typed summary
#: (:class:`inspector.model.EvaluationSummary`), whichever evaluate variant ran.
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
    extras TEXT
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
PRAGMA user_version = 1;
"""


def _connect(path: Path) -> sqlite3.Connection:
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


def record(result: InspectionResult, outdir: Path, *, now: datetime | None = None) -> int:
    """Append one inspection to ``outdir/history.sqlite``; returns its row id.

    ``outdir`` is the run's result folder (the parent of the capture's own folder).
    """
    meta = dict(result.metadata or {})
    summary = result.summary  # the evaluate stage's contract; None: no evaluate stage, or an error
    dev = summary.deviation_mm if summary is not None else None
    worst = max((d.worst_mm for d in result.defects), key=abs, default=None)
    tol = summary.tolerance_mm if summary is not None else (None, None)
    row = (
        (now or datetime.now(timezone.utc)).isoformat(timespec="milliseconds"),
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
    )
    con = _connect(outdir / HISTORY_FILE)
    try:
        con.executescript(SCHEMA)
        if "extras" not in {r[1] for r in con.execute("PRAGMA table_info(inspections)")}:  # a file from before
            con.execute("ALTER TABLE inspections ADD COLUMN extras TEXT")
        cur = con.execute(
            "INSERT INTO inspections (inspected_at, capture, part_id, triggered_at, recipe, verdict, error, n_points,"
            " deviation_mean_mm, deviation_min_mm, deviation_max_mm, n_defects, worst_mm, tolerance_lower_mm,"
            " tolerance_upper_mm, total_s, result_dir, metadata, extras)"
            " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            row,
        )
        rid = int(cur.lastrowid)
        con.executemany(
            "INSERT INTO defects (inspection_id, kind, n_points, worst_mm, x, y, z, region) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
            [(rid, d.kind, d.n_points, d.worst_mm, *d.position, d.region) for d in result.defects],
        )
        con.commit()
    finally:
        con.close()
    return rid


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


def read_history(outdir: Path, *, last: int | None = None) -> list[dict[str, Any]]:
    """The recorded inspections of ``outdir``, oldest first (the ``last`` ones only).

    Raises InputError naming the file when there is no history or it cannot be read.
    """
    path = Path(outdir) / HISTORY_FILE
    if not path.is_file():
        raise InputError(f"{path}: no history (inspector run writes it beside the result folders)")
    return read_table(path, "inspections", last=last) or []


def read_table(path: Path, table: str, columns: tuple[str, ...] | None = None, *,
               last: int | None = None) -> list[dict[str, Any]] | None:
    """Rows of ``table`` in the SQLite file ``path`` (read-only), oldest first, the ``last``
    ones only; None when the file has no such table. InputError naming the file when it
    cannot be read. Shared by the history and the audit trail (``inspector.roles``)."""
    cols = ", ".join(columns) if columns else "*"
    try:
        con = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=10.0)
        try:
            con.row_factory = sqlite3.Row
            if con.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = ?", (table,)).fetchone() is None:
                return None
            q = f"SELECT {cols} FROM {table} ORDER BY id"
            if last is not None:
                q = f"SELECT * FROM (SELECT {cols} FROM {table} ORDER BY id DESC LIMIT {int(last)}) ORDER BY id"
            return [dict(r) for r in con.execute(q)]
        finally:
            con.close()
    except sqlite3.Error as e:
        raise InputError(f"{path}: cannot be read ({e})") from None


@hookimpl
def inspector_on_result(result: InspectionResult, outdir: Path | None) -> None:
    if outdir is not None:
        record(result, Path(outdir).parent)


# --------------------------------------------------------------------------- inspector history


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("history", help="list the inspections recorded in OUTDIR/history.sqlite, and the yield")
    p.add_argument("outdir", metavar="OUTDIR", help="an inspector run --out folder")
    p.add_argument("--last", type=int, metavar="N", help="only the last N inspections")
    p.add_argument("--json", action="store_true", help="the rows as JSON")
    p.add_argument("--plot", metavar="PNG", help="also draw the trend: each part's deviation range against its tolerance")


def plot_history(rows: list[dict[str, Any]], out: Path) -> Path:
    """A trend picture of ``rows`` (:func:`read_history`), drawn by :func:`draw_history`,
    written to ``out`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(12, 4.5), dpi=110)
    draw_history(ax, rows)
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)
    return out


#: Verdict colours of the trend (the GUI's history strip uses the same).
VERDICT_COLOURS = {"pass": "#2e8b2e", "fail": "#c01010", "error": "#888888"}


def tally(rows: list[dict[str, Any]]) -> tuple[dict[str, int], float | None]:
    """Inspections per verdict (pass, fail, error) and the yield: the passed share of the
    parts judged (pass or fail); None when none was judged."""
    n = {v: sum(r["verdict"] == v for r in rows) for v in ("pass", "fail", "error")}
    judged = n["pass"] + n["fail"]
    return n, (n["pass"] / judged if judged else None)


def draw_history(ax: Any, rows: list[dict[str, Any]], *, labels: bool = True) -> str:
    """Draw the trend of ``rows`` on the matplotlib axes ``ax``: per inspection, in order, the
    range of its BCPS deviations (mm) as a bar, green for a pass and red for a fail, its
    worst defect as a dot, errors as grey marks on the zero line, and the tolerance band.
    Returns the title (counts and yield). ``inspector history --plot`` and the GUI's history
    strip both draw with this function, so they show the same data and limits."""
    colour = VERDICT_COLOURS
    for k, r in enumerate(rows):
        c = colour.get(r["verdict"], "#888888")
        if r["verdict"] == "error" or r["deviation_min_mm"] is None:
            ax.plot([k], [0.0], marker="x", color=c, ms=7, mew=2)
            continue
        ax.vlines(k, r["deviation_min_mm"], r["deviation_max_mm"], color=c, lw=3)
        if r["worst_mm"] is not None:
            ax.plot([k], [r["worst_mm"]], "o", color=c, ms=5)
    nan = float("nan")  # an error row has no tolerance: a gap in the band
    lo = [nan if r["tolerance_lower_mm"] is None else r["tolerance_lower_mm"] for r in rows]
    hi = [nan if r["tolerance_upper_mm"] is None else r["tolerance_upper_mm"] for r in rows]
    if any(v == v for v in lo + hi):
        x = list(range(len(rows)))
        ax.step(x, lo, where="mid", color="k", ls="--", lw=1, label="tolerance")
        ax.step(x, hi, where="mid", color="k", ls="--", lw=1)
        ax.legend(loc="upper right", fontsize=8)
    ax.axhline(0.0, color="#cccccc", lw=0.8, zorder=0)
    from matplotlib.ticker import MaxNLocator

    ax.set_xlim(-0.5, max(len(rows), 1) - 0.5)
    ax.xaxis.set_major_locator(MaxNLocator(integer=True, min_n_ticks=1))  # inspections are counted, not measured
    if labels:
        ax.set_xlabel("inspection (oldest first)")
        ax.set_ylabel("BCPS deviation, mm (negative: missing)")
    n, share = tally(rows)
    yld = f"yield {share:.1%}" if share is not None else "no part judged"
    title = f"{len(rows)} inspections: {n['pass']} pass, {n['fail']} fail, {n['error']} error; {yld}"
    ax.set_title(title, fontsize=11 if labels else 9)
    if labels and len(rows) <= 30:
        ax.set_xticks(range(len(rows)), [r["capture"][:14] for r in rows], rotation=60, ha="right", fontsize=7)
    return title


def _fmt(x: Any, spec: str) -> str:
    return "-" if x is None else format(x, spec)


def run(args) -> int:
    import sys

    if args.last is not None and args.last < 1:
        print(f"inspector: error: --last: expected a number >= 1, got {args.last}", file=sys.stderr)
        return 2
    try:
        rows = read_history(Path(args.outdir), last=args.last)
    except InputError as e:
        print(f"inspector: error: {e}", file=sys.stderr)
        return 3
    if args.plot:
        try:
            plot_history(rows, Path(args.plot))
        except OSError as e:
            print(f"inspector: error: {args.plot}: cannot write ({e.strerror or e})", file=sys.stderr)
            return 3
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"{'inspected at (UTC)':24s} {'capture':24s} {'part id':14s} {'verdict':7s} {'defects':>7s} {'worst mm':>9s} {'s':>6s}")
    for r in rows:
        print(f"{r['inspected_at'][:23]:24s} {r['capture'][:24]:24s} {(r['part_id'] or '-')[:14]:14s} "
              f"{r['verdict'].upper():7s} {r['n_defects']:7d} {_fmt(r['worst_mm'], '+9.3f'):>9s} {_fmt(r['total_s'], '6.2f'):>6s}")
    n, share = tally(rows)
    yld = f"yield {share:.1%} of the parts judged" if share is not None else "no part judged"
    span = f", {rows[0]['inspected_at'][:19]} to {rows[-1]['inspected_at'][:19]}" if rows else ""
    print(f"{len(rows)} inspections: {n['pass']} pass, {n['fail']} fail, {n['error']} error; {yld}{span}")
    if args.plot:
        print(f"wrote {args.plot}")
    return 0


@hookimpl
def inspector_register_commands(registry: CommandRegistry) -> None:
    """``inspector history OUTDIR``."""
    from inspector.registry import CommandSpec

    registry.add(CommandSpec("history", add_parser, run, "the inspections recorded in OUTDIR/history.sqlite, the yield"))
