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

The ``inspector history`` command is :mod:`inspector_plugins.history_command` (registered
here), its charts :mod:`inspector_plugins.history_charts` (their functions imported here too).
"""

from __future__ import annotations

import os
import queue
import sqlite3
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from inspector import hookimpl, ledger
from inspector.errors import InputError
from inspector.history_store import HISTORY_FILE, connect, default_cell, record, spooled, spooled_batch
from inspector.model import InspectionResult
from inspector.params import param
from inspector.registry import CommandRegistry, CommandSpec, SettingsRegistry
from inspector_plugins.history_charts import draw_cameras, draw_history, plot_cameras, plot_history, tally
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


@hookimpl
def inspector_register_commands(registry: CommandRegistry) -> None:
    """``inspector history [OUTDIR]`` (:mod:`inspector_plugins.history_command`)."""
    # cycle: inspector_plugins.history_command imports inspector_plugins.history (its settings, the plant database)
    from inspector_plugins.history_command import add_parser, run

    registry.add(CommandSpec("history", add_parser, run,
                             "the inspections recorded in OUTDIR/history.sqlite or the plant database, the yield"))
