"""Built-in plugin ``history``: every inspection recorded in ``OUTDIR/history.sqlite``, and
in the plant's PostgreSQL database when one is configured.

The traceability record of a production line: one row per inspection (a capture inspected
twice has two rows: nothing is overwritten), with the part's id and trigger time from
``capture.json``, the verdict, the deviation summary, the defects, the timings, the cell
that inspected it and a unique ``uid``. It is an ``inspector_on_result`` hook like an
integrator's PLC or MES publisher, registered through the same entry-point group;
``inspector history OUTDIR`` reads the cell's file, ``inspector history --url URL`` the plant's.

The cell's database and its schema are the core's history store
(:mod:`inspector.history_store`); this plugin writes it and sends it on. A history that cannot
be written (read-only folder, a corrupt file) costs only the history row: the result folder is
already written, and the runner says so in one line.

The plant database (``[plugins.history] url``, else ``$INSPECTOR_HISTORY_URL``; the
connection is ``inspector_plugins/history_plant.py``) is off the inspection's path: every row is first
committed to the cell's file together with an entry of its ``spool`` table, and the inspection
goes on; a sender thread of its own (one per run folder and database, fed by a bounded queue
of nudges: a full queue loses nothing, the row is in the spool) sends the spool, oldest first,
each batch in one PostgreSQL transaction, its entries deleted only after that commit. The
connection has a ``statement_timeout`` and a ``lock_timeout`` (``[plugins.history]``), so a
server that is slow or a table that is locked fails a send after seconds, like a server that is
down: one warning line per episode (its URL without the password), the rows wait in the spool
and are sent when it answers again (the sender retries every ``retry_s``, at least 1 s), at a
run's start or end, or by ``inspector history OUTDIR --send``. A run's end waits at most
``flush_wait_s`` for the spool to be sent; what is not sent stays in the spool. A row is
inserted with ``ON CONFLICT (uid) DO NOTHING``: sent twice (a crash between the server's commit
and the spool's delete), it is stored once.

Every ``inspections`` row is hash-chained (:mod:`inspector.ledger`: its ``chain`` column is the
SHA-256 of the previous row's ``chain`` and its own content, its defects included);
``inspector history OUTDIR --verify`` names the first row changed or removed (exit 1).
"""

from __future__ import annotations

import json
import os
import queue
import sqlite3
import sys
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from inspector import hookimpl
from inspector import ledger
from inspector.errors import InputError
from inspector.model import InspectionResult
from inspector.params import param
from inspector.registry import CommandRegistry, SettingsRegistry
from inspector.history_store import HISTORY_FILE, connect, default_cell, read_history, record, spooled, spooled_batch
from inspector_plugins.history_plant import PlantDatabase, PlantUnavailable, check_url, mask_url

if TYPE_CHECKING:
    from inspector.recipe import Recipe
    from inspector.session import RunSummary

__all__ = ["URL_ENV", "HistorySettings", "read_plant", "flush_spool", "tally", "draw_history", "plot_history",
           "draw_cameras", "plot_cameras", "settle", "verify_history"]

#: The plant database's URL when the recipe gives none (``[plugins.history] url``).
URL_ENV = "INSPECTOR_HISTORY_URL"


#: Spooled rows sent per PostgreSQL transaction.
SEND_BATCH = 200


def flush_spool(outdir: Path, plant: PlantDatabase, *, con: sqlite3.Connection | None = None) -> int:
    """Send ``outdir``'s spooled rows to ``plant``, oldest first, :data:`SEND_BATCH` per
    transaction; each batch leaves the spool only after the server committed it. Returns
    how many rows were sent. Raises :class:`PlantUnavailable` (what was not sent stays).
    ``con``: an open connection to the history to use (no transaction is held while the
    server is waited for)."""
    path = Path(outdir) / HISTORY_FILE
    own = con is None
    if con is None:
        if not path.is_file():
            return 0
        con = connect(path)
    try:
        if con.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'spool'").fetchone() is None:
            return 0
        sent = 0
        while True:
            batch = spooled_batch(con, SEND_BATCH)
            if not batch:
                return sent
            plant.insert([(row, defects) for _, row, defects in batch])
            ids = [rid for rid, _, _ in batch]
            con.execute(f"DELETE FROM spool WHERE inspection_id IN ({', '.join('?' * len(ids))})", ids)
            con.commit()
            sent += len(batch)
    finally:
        if own:
            con.close()


def read_plant(url: str, *, last: int | None = None, cell: str | None = None,
               connect_timeout_s: int = 10) -> list[dict[str, Any]]:
    """The plant database's inspections (every cell's, or ``cell``'s), oldest first by
    ``inspected_at``, the ``last`` ones only: the same keys as :func:`read_history`'s rows.

    Raises InputError naming the URL (without its password) when it is not a PostgreSQL URL or
    the database cannot be read.
    """
    try:
        plant = PlantDatabase(url, connect_timeout_s=connect_timeout_s, application_name="inspector history (reader)")
    except ValueError as e:
        raise InputError(str(e)) from None
    try:
        return plant.read(last=last, cell=cell)
    except PlantUnavailable as e:
        raise InputError(str(e)) from None
    finally:
        plant.close()


# --------------------------------------------------------------------------- the plugin


@dataclass(frozen=True)
class HistorySettings:
    """``[plugins.history]``: the plant database besides ``OUTDIR/history.sqlite``, and the cell."""

    url: str = param("", "the plant database, postgresql://USER@HOST[:PORT]/DATABASE; '' takes "
                         "$INSPECTOR_HISTORY_URL, else only OUTDIR/history.sqlite is written")
    cell: str = param("", "this cell's name in the history; '' takes $INSPECTOR_HISTORY_CELL, else the host name")
    connect_timeout_s: int = param(3, "seconds to wait for the plant database to answer", min=1, max=60)
    retry_s: float = param(30.0, "after a failed send, seconds during which rows go straight to the spool "
                                 "(the sender tries again after this long, at least 1 s)", min=0.0, max=3600.0)
    statement_timeout_s: float = param(10.0, "seconds one statement may run on the plant database before the send "
                                             "fails and the rows wait in the spool (PostgreSQL statement_timeout)",
                                       min=0.1, max=3600.0)
    lock_timeout_s: float = param(3.0, "seconds a statement may wait for a lock on the plant database "
                                       "(a LOCK TABLE held elsewhere; PostgreSQL lock_timeout)", min=0.1, max=3600.0)
    flush_wait_s: float = param(10.0, "at a run's end, seconds to wait for the spool to be sent; what is not sent "
                                      "stays in the spool", min=0.0, max=3600.0)
    queue_size: int = param(1000, "nudges the sender may hold; more cost nothing (the rows are in the spool)",
                            min=1, max=1_000_000)

    def __post_init__(self) -> None:
        if self.url:
            check_url(self.url)
        if len(self.cell) > 64 or any(ord(c) < 32 or ord(c) == 127 for c in self.cell):
            raise ValueError(f"cell: at most 64 characters, none a control character: {self.cell[:70]!r}")

    def __repr__(self) -> str:  # a recipe's repr, in a log or a traceback, never shows the password
        return (f"HistorySettings(url={mask_url(self.url)!r}, cell={self.cell!r}, "
                f"connect_timeout_s={self.connect_timeout_s!r}, retry_s={self.retry_s!r}, "
                f"statement_timeout_s={self.statement_timeout_s!r}, lock_timeout_s={self.lock_timeout_s!r}, "
                f"flush_wait_s={self.flush_wait_s!r}, queue_size={self.queue_size!r})")


@dataclass(frozen=True)
class _Target:
    """Where one run's rows go: the cell's name and the plant database (None: the file only)."""

    cell: str
    url: str | None
    settings: HistorySettings


_lock = threading.Lock()
#: The recipe's settings of each run folder (resolved path), from inspector_on_run_start.
_settings: dict[str, HistorySettings] = {}
#: One connection (and outage state) per run folder and URL, kept between runs.
_plants: dict[tuple[str, str], PlantDatabase] = {}
#: The sender thread of each run folder and URL, while it runs.
_senders: dict[tuple[str, str], _Sender] = {}
#: URLs already warned about as invalid (from the environment: the recipe's are checked on load).
_invalid_warned: set[str] = set()


def _key(outdir: Path) -> str:
    return str(Path(outdir).resolve())


def _target(outdir: Path) -> _Target:
    with _lock:
        settings = _settings.get(_key(outdir)) or HistorySettings()
    url = settings.url or os.environ.get(URL_ENV, "").strip() or None
    return _Target(settings.cell or default_cell(), url, settings)


def _warn(text: str) -> None:
    print(f"inspector: warning: {text}", file=sys.stderr, flush=True)


def _plant(outdir: Path, target: _Target) -> PlantDatabase | None:
    """The run folder's connection to ``target.url`` (None, warned once, for an invalid URL)."""
    assert target.url is not None
    key = (_key(outdir), target.url)
    with _lock:
        plant = _plants.get(key)
        if plant is None:
            try:
                plant = PlantDatabase(target.url, connect_timeout_s=target.settings.connect_timeout_s,
                                      retry_s=target.settings.retry_s,
                                      application_name=f"inspector history ({target.cell})",
                                      statement_timeout_s=target.settings.statement_timeout_s,
                                      lock_timeout_s=target.settings.lock_timeout_s)
            except ValueError as e:
                if target.url not in _invalid_warned:
                    _invalid_warned.add(target.url)
                    _warn(f"history: {URL_ENV}: {str(e).removeprefix('url: ')}; rows wait in the spool of "
                          f"{Path(outdir) / HISTORY_FILE}")
                return None
            _plants[key] = plant
    return plant


def _send(outdir: Path, plant: PlantDatabase, *, force: bool = False, con: sqlite3.Connection | None = None) -> int | None:
    """Flush the run folder's spool to the plant database; the rows sent, None when it could
    not be reached (one warning line per episode, naming the database without its password).
    Called by the sender thread only (and by nothing on an inspection's path). ``force``: try
    even within ``retry_s`` of a failure (the last send of a run). ``con``: the sender's open
    connection to the history."""
    with plant.lock:
        if not (force or plant.due()):
            return None  # failed a moment ago: the rows wait in the spool for the next try
        try:
            sent = flush_spool(outdir, plant, con=con)
        except PlantUnavailable as e:
            if plant.failed():
                left = spooled(outdir)
                _warn(f"history: {e}; {left} inspection{'s wait' if left != 1 else ' waits'} in the spool of "
                      f"{Path(outdir) / HISTORY_FILE}, sent when it answers again")
            return None
        except (sqlite3.Error, OSError) as e:  # the cell's own file: the next record says so too
            if plant.failed():
                _warn(f"history: {Path(outdir) / HISTORY_FILE}: the spool cannot be read ({e})")
            return None
        if plant.succeeded():
            print(f"inspector: history: plant database {plant.label} answers again; {sent} spooled "
                  f"inspection{'s' if sent != 1 else ''} sent", file=sys.stderr, flush=True)
        return sent


class _Sender:
    """The thread that sends one run folder's spool to one plant database.

    Fed by :meth:`nudge` (a bounded queue: when it is full the nudge is dropped, and nothing is
    lost, since the row waits in the spool and the next send takes every spooled row). The
    thread owns the connection: nothing on an inspection's path waits for the server. After a
    failed send it tries again every ``retry_s`` (at least 1 s) while rows wait; idle (nothing
    spooled) for :attr:`IDLE_EXIT_S`, or asked by :meth:`stop`, it closes the connection and
    ends (the next nudge starts a new one).
    """

    #: Seconds without work after which the thread ends.
    IDLE_EXIT_S = 60.0
    _STOP = -1

    def __init__(self, key: tuple[str, str], outdir: Path, plant: PlantDatabase, settings: HistorySettings) -> None:
        self.key, self.outdir, self.plant, self.settings = key, Path(outdir), plant, settings
        self.queue: queue.Queue[int] = queue.Queue(maxsize=settings.queue_size)
        self.cond = threading.Condition()
        self.posted = 0  # nudges given (dropped ones too) ...
        self.handled = 0  # ... and how many of them a send attempt has covered since
        self.stopping = False
        self.thread = threading.Thread(target=self._main, name=f"history sender {plant.label}", daemon=True)

    def nudge(self, rid: int = 0) -> None:
        """A row was spooled (or may be waiting): send soon. Never blocks."""
        with self.cond:
            self.posted += 1
        try:
            self.queue.put_nowait(rid)
        except queue.Full:
            pass  # a send is due anyway, and it takes every spooled row

    def stop(self) -> None:
        """Send what waits once more, then end (:meth:`wait` for it)."""
        with self.cond:
            self.stopping = True
            self.posted += 1
        try:
            self.queue.put_nowait(self._STOP)
        except queue.Full:
            pass  # the thread finds `stopping` set after the queued nudges

    def wait(self, timeout_s: float, target: int | None = None) -> bool:
        """Wait until every nudge posted so far (``target``: that many) was covered by a send
        attempt, at most ``timeout_s``; whether it was."""
        deadline = time.monotonic() + timeout_s
        with self.cond:
            goal = self.posted if target is None else target
            while self.handled < goal and self.thread.is_alive():
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self.cond.wait(min(left, 0.5))
            return self.handled >= goal

    def _main(self) -> None:
        waiting = False  # rows left in the spool by a failed send
        # Kept open while the thread runs: besides saving a connection per send, a history file
        # that stays open is not checkpointed (WAL copied back, fsynced, deleted) each time the
        # recording side closes its own connection, which halves what a row costs the line.
        con: sqlite3.Connection | None = None
        try:
            while True:
                period = max(self.settings.retry_s, 1.0) if waiting else self.IDLE_EXIT_S
                try:
                    self.queue.get(timeout=period)
                except queue.Empty:
                    if not waiting:
                        with _lock, self.cond:  # idle: end, unless a nudge just came
                            if self.queue.empty() and self.handled >= self.posted:
                                _senders.pop(self.key, None)
                                return
                        continue
                    # rows wait and no part came for `retry_s`: try again (below)
                while True:  # every queued nudge is covered by the one send below
                    try:
                        self.queue.get_nowait()
                    except queue.Empty:
                        break
                with self.cond:
                    goal = self.posted
                    stopping = self.stopping
                if stopping or self.plant.due():
                    if con is None and (self.outdir / HISTORY_FILE).is_file():
                        try:
                            con = connect(self.outdir / HISTORY_FILE)
                        except sqlite3.Error:
                            con = None  # flush_spool opens its own, and says what is wrong
                    sent = _send(self.outdir, self.plant, force=stopping, con=con)
                    waiting = sent is None and spooled(self.outdir) > 0
                # else: failed a moment ago; the rows wait in the spool for the next try (nothing
                # is read here: a nudge per part must cost the line nothing while the server is out)
                with self.cond:
                    self.handled = max(self.handled, goal)
                    self.cond.notify_all()
                if stopping:
                    with self.cond:
                        if self.handled >= self.posted:
                            return  # (the finally below leaves the registry)
        finally:
            if con is not None:
                con.close()
            with self.plant.lock:
                self.plant.close()
            with _lock:
                if _senders.get(self.key) is self:
                    _senders.pop(self.key, None)
            with self.cond:
                self.cond.notify_all()


def _nudge(outdir: Path, target: _Target, rid: int = 0) -> _Sender | None:
    """Nudge the running sender of the run folder and ``target.url``, started if there is none
    (None for an invalid URL). Under the registry's lock, so that a sender ending for idleness
    never takes a nudge with it."""
    plant = _plant(outdir, target)
    if plant is None:
        return None
    assert target.url is not None
    key = (_key(outdir), target.url)
    with _lock:
        sender = _senders.get(key)
        if sender is None or sender.stopping or not sender.thread.is_alive():
            sender = _Sender(key, Path(outdir), plant, target.settings)
            _senders[key] = sender
            sender.thread.start()
        sender.nudge(rid)
        return sender


def settle(outdir: Path, timeout_s: float = 30.0) -> int:
    """Wait until the run folder's sender has tried to send every row spooled so far (sent, or
    found the server unavailable), at most ``timeout_s``; the rows still in the spool. What a
    test or a tool calls instead of sleeping; an inspection never does."""
    key = _key(outdir)
    with _lock:
        senders = [s for (k, _), s in _senders.items() if k == key]
    for sender in senders:
        sender.wait(timeout_s)
    return spooled(outdir)


@hookimpl
def inspector_register_settings(registry: SettingsRegistry) -> None:
    """``[plugins.history]``: the plant database (PostgreSQL) and the cell's name."""
    registry.add(HistorySettings, "the plant database (a PostgreSQL URL), its timeouts, and this cell's name")


@hookimpl
def inspector_on_run_start(recipe: Recipe, outdir: Path, source: str) -> None:
    settings = recipe.plugins.get("history")
    with _lock:
        _settings[_key(outdir)] = settings if isinstance(settings, HistorySettings) else HistorySettings()
    target = _target(outdir)
    if target.url is not None and spooled(outdir):
        _nudge(outdir, target)  # what an earlier run left in the spool, sent in the background


@hookimpl
def inspector_on_result(result: InspectionResult, outdir: Path | None) -> None:
    if outdir is None:
        return
    run_dir = Path(outdir).parent
    target = _target(run_dir)
    rid = record(result, run_dir, cell=target.cell, spool=target.url is not None)
    if target.url is not None:
        _nudge(run_dir, target, rid)  # the row is in the spool: the line goes on, the sender sends it


@hookimpl
def inspector_on_run_end(recipe: Recipe, outdir: Path, summary: RunSummary) -> None:
    target = _target(outdir)
    if target.url is None:
        return
    with _lock:
        sender = _senders.get((_key(outdir), target.url))
    if sender is None:
        if not spooled(outdir):
            return
        sender = _nudge(outdir, target)
        if sender is None:
            return
    sender.stop()  # one last send, then the connection closes (its outage state stays for the next run)
    if not sender.wait(target.settings.flush_wait_s):
        left = spooled(outdir)
        if left:
            _warn(f"history: plant database {mask_url(target.url)}: not answered within {target.settings.flush_wait_s:g} s "
                  f"at the run's end; {left} inspection{'s wait' if left != 1 else ' waits'} in the spool of "
                  f"{Path(outdir) / HISTORY_FILE} (sent by the next run, or by inspector history OUTDIR --send)")


# --------------------------------------------------------------------------- inspector history


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("history", help="list the inspections recorded in OUTDIR/history.sqlite or in the plant "
                                              "database, and the yield")
    p.add_argument("outdir", metavar="OUTDIR", nargs="?",
                   help="an inspector run --out folder (none: the plant database, --url or $" + URL_ENV + ")")
    p.add_argument("--url", metavar="URL", help="the plant database, postgresql://USER@HOST[:PORT]/DATABASE (default: "
                                                "--recipe's [plugins.history] url, else $" + URL_ENV
                                                + "; a password is better in $PGPASSWORD or ~/.pgpass)")
    p.add_argument("--recipe", metavar="RECIPE", help="take the plant database from this recipe's [plugins.history] url "
                                                      "(as the run did) when --url is not given")
    p.add_argument("--cell", metavar="NAME", help="only the inspections of this cell")
    p.add_argument("--send", action="store_true", help="send OUTDIR's spooled inspections to the plant database now")
    p.add_argument("--verify", action="store_true", help="check OUTDIR's hash chain: name the first inspection changed "
                                                         "or removed since it was recorded (exit 1), else exit 0")
    p.add_argument("--last", type=int, metavar="N", help="only the last N inspections")
    p.add_argument("--json", action="store_true", help="the rows as JSON")
    p.add_argument("--plot", metavar="PNG", help="also draw the trend: each part's deviation range against its tolerance")
    p.add_argument("--cameras", metavar="PNG", help="also draw the calibration health: how far each camera was off (px) "
                                                    "in each inspection, against the flagging threshold")
    p.add_argument("--characteristics", nargs="?", const="", metavar="PNG",
                   help="each characteristic over the parts: n, mean, s, Cp, Cpk, out of tolerance, Cg, Cgk; with PNG "
                        "also its individuals control chart with the tolerance band")
    p.add_argument("--shift", nargs="?", type=int, const=1, metavar="N",
                   help="the current shift's counters (and the N-1 before it): yield, worst regions, errors by reason")
    p.add_argument("--config", metavar="TOML", help="the cell's settings for --shift ([shifts]; default cell.toml in "
                                                    "$INSPECTOR_CONFIG_DIR or ~/.config/inspector when present)")
    p.add_argument("--pdf", metavar="FILE", help="with --shift: also the shift report as a PDF, one A4 page per shift")
    p.add_argument("--lang", metavar="LANG", help="with --shift: the language of its lines and PDF: en, de or es "
                                                  "(default: $INSPECTOR_LANG, else en; never the system locale)")


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


def plot_cameras(rows: list[dict[str, Any]], out: Path) -> Path:
    """The calibration health of ``rows`` (:func:`read_history`), drawn by
    :func:`draw_cameras`, written to ``out`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(12, 4.5), dpi=110)
    draw_cameras(ax, rows)
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)
    return out


def _calibration(row: Mapping[str, Any]) -> dict[str, Any] | None:
    """A row's ``calibration_json`` read (None: not checked, or not readable)."""
    raw = row.get("calibration_json")
    if not raw:
        return None
    try:
        doc = json.loads(raw) if isinstance(raw, str) else raw
    except ValueError:
        return None
    return doc if isinstance(doc, dict) and isinstance(doc.get("off_px"), dict) else None


def draw_cameras(ax: Any, rows: list[dict[str, Any]]) -> str:
    """Draw each camera's calibration health over ``rows`` on the matplotlib axes ``ax``: per
    camera a line of how far it was off (px, ``stats.calibration`` ``off_px``) in each
    inspection, in order, a flagged inspection as a ring, and the threshold as a dashed
    line. Inspections without the figures (errors, older rows) are gaps. Returns the title."""
    docs = [_calibration(r) for r in rows]
    names = sorted({n for d in docs if d is not None for n in d["off_px"]})
    nan = float("nan")
    x = list(range(len(rows)))
    worst: dict[str, float] = {}
    cmap = _camera_colours(len(names))
    for k, name in enumerate(names):
        y = [nan if d is None or d["off_px"].get(name) is None else float(d["off_px"][name]) for d in docs]
        worst[name] = max((v for v in y if v == v), default=nan)
        ax.plot(x, y, "-", color=cmap[k], lw=1.2, marker=".", ms=4, label=name)
        flagged = [(i, v) for i, (d, v) in enumerate(zip(docs, y)) if d is not None and name in (d.get("flagged") or [])]
        if flagged:
            ax.plot([i for i, _ in flagged], [v for _, v in flagged], "o", mfc="none", mec="#c01010", ms=10, mew=2)
    limit = [nan if d is None or d.get("threshold_px") is None else float(d["threshold_px"]) for d in docs]
    if any(v == v for v in limit):
        ax.step(x, limit, where="mid", color="#c01010", ls="--", lw=1.2, label="threshold")
    from matplotlib.ticker import MaxNLocator

    ax.set_xlim(-0.5, max(len(rows), 1) - 0.5)
    ax.set_ylim(bottom=0.0)
    ax.xaxis.set_major_locator(MaxNLocator(integer=True, min_n_ticks=1))
    ax.set_xlabel("inspection (oldest first)")
    ax.set_ylabel("camera off by, px")
    if names:
        ax.legend(loc="upper left", fontsize=7, ncol=min(len(names) + 1, 9))
    flagged_rows = sum(1 for d in docs if d is not None and d.get("flagged"))
    checked = sum(1 for d in docs if d is not None)
    top = max(worst, key=lambda n: worst[n] if worst[n] == worst[n] else -1.0) if worst else None
    most = f"; most off: {top} {worst[top]:.2f} px" if top is not None and worst[top] == worst[top] else ""
    title = f"calibration health: {checked} of {len(rows)} inspections checked, {flagged_rows} with a camera flagged{most}"
    ax.set_title(title, fontsize=11)
    if len(rows) <= 30:
        ax.set_xticks(range(len(rows)), [r["capture"][:14] for r in rows], rotation=60, ha="right", fontsize=7)
    return title


def _camera_colours(n: int) -> list[Any]:
    """``n`` distinguishable line colours (matplotlib's tab20, then repeated)."""
    import matplotlib

    cmap = matplotlib.colormaps["tab20"]
    return [cmap(k % 20) for k in range(n)]


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


def _url_of(args) -> tuple[str | None, str]:
    """(the plant database's URL, where it came from) of ``inspector history``'s arguments, in
    this order: ``--url``; the ``--recipe``'s ``[plugins.history] url`` (what the run used);
    ``$INSPECTOR_HISTORY_URL``. Raises RecipeError (one line naming the recipe) for a recipe
    that cannot be read."""
    if args.url:
        return args.url, "--url"
    if getattr(args, "recipe", None):
        from inspector.recipe import load_recipe

        recipe = load_recipe(args.recipe, args.plugin_manager)
        settings = recipe.plugins.get("history")
        if isinstance(settings, HistorySettings) and settings.url:
            return settings.url, f"{args.recipe}: plugins.history.url"
    return os.environ.get(URL_ENV, "").strip() or None, URL_ENV


def _verify_cmd(outdir: Path) -> int:
    """``inspector history OUTDIR --verify``: 0 intact, 1 broken, 3 unreadable."""
    path = outdir / HISTORY_FILE
    if not path.is_file():
        print(f"inspector: error: {path}: no history", file=sys.stderr)
        return 3
    try:
        report = verify_history(outdir)
    except InputError as e:
        print(f"inspector: error: {e}", file=sys.stderr)
        return 3
    if not report.ok:
        print(f"inspector: error: {path}: {report.summary()}", file=sys.stderr)
        return 1
    print(f"{path}: {report.summary()}")
    return 0


def verify_history(outdir: Path) -> ledger.ChainReport:
    """The hash chain of ``outdir``'s inspections checked (:func:`inspector.ledger.verify`,
    each row with its defects). InputError naming the file when it cannot be read."""
    path = Path(outdir) / HISTORY_FILE
    try:
        con = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=10.0)
        try:
            return ledger.verify(con, "inspections", child=("defects", "inspection_id"),
                                 describe=lambda r: f"capture {r.get('capture')}, {r.get('verdict')}")
        finally:
            con.close()
    except sqlite3.Error as e:
        raise InputError(f"{path}: cannot be read ({e})") from None


def _send_now(outdir: Path, url: str) -> int:
    """``inspector history OUTDIR --send``."""
    plant = PlantDatabase(url, connect_timeout_s=10, application_name="inspector history --send")
    try:
        sent = flush_spool(outdir, plant)
    except PlantUnavailable as e:
        print(f"inspector: error: {e}; {spooled(outdir)} inspections stay in the spool", file=sys.stderr)
        return 3
    finally:
        plant.close()
    print(f"sent {sent} spooled inspection{'s' if sent != 1 else ''} to {plant.label}")
    return 0


def run(args) -> int:
    if args.last is not None and args.last < 1:
        print(f"inspector: error: --last: expected a number >= 1, got {args.last}", file=sys.stderr)
        return 2
    if args.shift is not None:
        if args.outdir is None:
            print("inspector: error: --shift: give OUTDIR (its history.sqlite)", file=sys.stderr)
            return 2
        from inspector.locale import choose, using
        from inspector.shift import print_shifts

        try:
            lang = choose(args.lang)
        except ValueError as e:
            print(f"inspector: error: --lang: {e}", file=sys.stderr)
            return 2
        with using(lang):
            return print_shifts(args.outdir, shifts=args.shift, config=args.config, pdf=args.pdf)
    if args.pdf is not None:
        print("inspector: error: --pdf: the shift report; give --shift too", file=sys.stderr)
        return 2
    if args.verify:
        if args.outdir is None or args.send or args.url:
            print("inspector: error: --verify: give OUTDIR only (its history.sqlite is checked)", file=sys.stderr)
            return 2
        return _verify_cmd(Path(args.outdir))
    url, source = _url_of(args)
    if url is not None and (args.send or args.outdir is None):
        try:
            check_url(url)
        except ValueError as e:
            print(f"inspector: error: {source}: {str(e).removeprefix('url: ')}", file=sys.stderr)
            return 2
    if args.send:
        if args.outdir is None or url is None:
            print(f"inspector: error: --send: give OUTDIR and the plant database (--url URL, --recipe RECIPE with "
                  f"[plugins.history] url, or ${URL_ENV})", file=sys.stderr)
            return 2
        if not (Path(args.outdir) / HISTORY_FILE).is_file():
            print(f"inspector: error: {Path(args.outdir) / HISTORY_FILE}: no history", file=sys.stderr)
            return 3
        return _send_now(Path(args.outdir), url)
    if args.outdir is not None and args.url:
        print("inspector: error: give OUTDIR (its history.sqlite) or --url (the plant database), not both", file=sys.stderr)
        return 2
    plant = args.outdir is None
    if plant and url is None:
        print(f"inspector: error: history: give OUTDIR, or the plant database with --url URL or ${URL_ENV}", file=sys.stderr)
        return 2
    try:
        if plant:
            assert url is not None
            rows = read_plant(url, last=args.last, cell=args.cell)
        else:
            rows = read_history(Path(args.outdir), last=args.last, cell=args.cell)
    except InputError as e:
        print(f"inspector: error: {e}", file=sys.stderr)
        return 3
    if args.characteristics is not None:
        return _characteristics_cmd(rows, args.characteristics)
    for picture, draw in ((args.plot, plot_history), (args.cameras, plot_cameras)):
        if picture:
            try:
                draw(rows, Path(picture))
            except OSError as e:
                print(f"inspector: error: {picture}: cannot write ({e.strerror or e})", file=sys.stderr)
                return 3
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    cell_head = f"{'cell':14s} " if plant else ""
    print(f"{'inspected at (UTC)':24s} {cell_head}{'capture':24s} {'part id':14s} {'verdict':7s} {'defects':>7s} "
          f"{'worst mm':>9s} {'s':>6s}")
    for r in rows:
        cell = f"{(r['cell'] or '-')[:14]:14s} " if plant else ""
        print(f"{r['inspected_at'][:23]:24s} {cell}{r['capture'][:24]:24s} {(r['part_id'] or '-')[:14]:14s} "
              f"{r['verdict'].upper():7s} {r['n_defects']:7d} {_fmt(r['worst_mm'], '+9.3f'):>9s} {_fmt(r['total_s'], '6.2f'):>6s}")
    n, share = tally(rows)
    yld = f"yield {share:.1%} of the parts judged" if share is not None else "no part judged"
    span = f", {rows[0]['inspected_at'][:19]} to {rows[-1]['inspected_at'][:19]}" if rows else ""
    print(f"{len(rows)} inspections: {n['pass']} pass, {n['fail']} fail, {n['error']} error; {yld}{span}")
    waiting = 0 if plant else spooled(Path(args.outdir))
    if waiting:
        print(f"{waiting} of them wait in the spool for the plant database (sent at the next record, or with --send)")
    for picture in (args.plot, args.cameras):
        if picture:
            print(f"wrote {picture}")
    return 0


def _characteristics_cmd(rows: list[dict[str, Any]], picture: str) -> int:
    """``--characteristics [PNG]``: the capability table, and the control charts."""
    from inspector.characteristics.charts import capability_text, parts_rows, plot_charts

    parts = parts_rows(rows)
    if not parts:
        print(f"inspector: error: none of the {len(rows)} inspections measured characteristics (a recipe's "
              "[[characteristics]] and its evaluate.characteristics stage)", file=sys.stderr)
        return 3
    for line in capability_text(parts):
        print(line)
    print(f"{len(parts)} parts with characteristics of {len(rows)} inspections")
    if picture:
        try:
            plot_charts(parts, Path(picture))
        except OSError as e:
            print(f"inspector: error: {picture}: cannot write ({e.strerror or e})", file=sys.stderr)
            return 3
        print(f"wrote {picture}")
    return 0


@hookimpl
def inspector_register_commands(registry: CommandRegistry) -> None:
    """``inspector history [OUTDIR]``."""
    from inspector.registry import CommandSpec

    registry.add(CommandSpec("history", add_parser, run,
                             "the inspections recorded in OUTDIR/history.sqlite or the plant database, the yield"))
