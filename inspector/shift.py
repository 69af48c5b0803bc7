"""The shift at a glance: counters of the cell's history by shift (Qt-free).

A shift leader asks for the shift's parts, not the last fifty: how many were inspected, how
many passed, failed and could not be judged, the yield, where the parts fail most (the
defects' regions), which measured characteristics are worst (NOK, not measurable, most of
the tolerance used) and why inspections ended in an error (their reasons, grouped). This
module reads them from ``OUTDIR/history.sqlite`` (the history store's file, opened
read-only: ``sqlite3`` with a ``mode=ro`` URI, so a reader never locks out the runner) for
the shift times of the cell's settings (:mod:`inspector.cell`)::

    [shifts]                                   # in the cell's settings file (cell.toml)
    starts = ["06:00", "14:00", "22:00"]       # local times, ascending; each shift ends where the next begins
    names = ["early", "late", "night"]         # one per start
    timezone = ""                              # IANA name (Europe/Berlin); empty: the computer's own

A shift is named by its start (``night 2026-12-02 22:00``): the night shift that starts at
22:00 ends at 06:00 the next day. ``inspected_at`` is UTC in the history; a row belongs to
the shift whose local interval ``[start, end)`` holds it.

The yield is the history's own (:func:`inspector_plugins.history.tally`'s rule): the passed
share of the parts judged (pass or fail); an error is counted, never judged. An aborted
inspection writes no history row, so it is not counted here either.

``inspector history OUTDIR --shift`` prints :func:`format_shifts` of :func:`shift_counters`;
the GUI shows the current shift's counters.
"""

from __future__ import annotations

import json
import math
import re
import sqlite3
import sys
from collections import Counter, defaultdict
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, time, timedelta, tzinfo
from pathlib import Path
from typing import Any

from inspector.cell import cell_file, load_cell
from inspector.errors import InputError, RecipeError
from inspector.locale import gettext, number
from inspector.params import build_params, param

__all__ = ["ShiftSettings", "Shift", "RegionCount", "ErrorGroup", "CharacteristicCount", "ShiftCounters", "HISTORY_FILE",
           "shift_settings", "shift_at", "shifts_until", "read_shift_rows", "count", "shift_counters", "error_key",
           "count_characteristics", "format_shift", "format_shifts", "print_shifts", "translate", "set_translator"]

#: The history database in a run's OUTDIR (the ``history`` plugin's :data:`HISTORY_FILE`; the
#: name is repeated here so that the core does not import a plugin).
HISTORY_FILE = "history.sqlite"

_HHMM = re.compile(r"^([01]\d|2[0-3]):([0-5]\d)$")

# -- translation hook ---------------------------------------------------------------------------
# The texts below are marked with translate("Shift", ...), which Qt's lupdate collects into the
# GUI's translation files and Babel into the headless catalogues (inspector/locale); the GUI
# installs Qt's translator, a command line the language of --lang.
def _headless(context: str, text: str) -> str:
    """The headless language's text (:mod:`inspector.locale`: ``--lang``, ``$INSPECTOR_LANG``)."""
    return gettext(text)


_translator: Callable[[str, str], str] = _headless


def set_translator(func: Callable[[str, str], str] | None) -> None:
    """Translate this module's texts with ``func(context, text)`` (None: the headless
    catalogues again, :mod:`inspector.locale`)."""
    global _translator
    _translator = func if func is not None else _headless


def translate(context: str, text: str) -> str:
    """``text`` in the language of the installed translator (see :func:`set_translator`)."""
    return _translator(context, text)


_installed = translate


@dataclass(frozen=True)
class ShiftSettings:
    """``[shifts]`` of the cell's settings: when each shift starts, its name and the clock's zone."""

    starts: tuple[str, ...] = param(("06:00", "14:00", "22:00"),
                                    "local start times HH:MM, ascending; a shift ends where the next starts")
    names: tuple[str, ...] = param(("early", "late", "night"), "one name per start")
    timezone: str = param("", "IANA time zone of the shift times (Europe/Berlin); empty: the computer's own")

    def __post_init__(self) -> None:
        if not self.starts:
            raise ValueError("starts: give at least one start time")
        for s in self.starts:
            if not _HHMM.match(s):
                raise ValueError(f"starts: {s!r} is not a time HH:MM (00:00 to 23:59)")
        if list(self.starts) != sorted(set(self.starts)):
            raise ValueError(f"starts: expected ascending, distinct times, got {list(self.starts)}")
        if len(self.names) != len(self.starts):
            raise ValueError(f"names: expected {len(self.starts)} names (one per start), got {len(self.names)}")
        self.zone()  # an unknown zone is refused here, not at the first count

    def zone(self) -> tzinfo:
        """The shift times' time zone."""
        if not self.timezone:
            local = datetime.now().astimezone().tzinfo
            assert local is not None  # astimezone() always sets one
            return local
        from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

        try:
            return ZoneInfo(self.timezone)
        except (ZoneInfoNotFoundError, ValueError):
            raise ValueError(f"timezone: unknown time zone {self.timezone!r} (an IANA name: Europe/Berlin)") from None

    def times(self) -> list[time]:
        return [time(int(s[:2]), int(s[3:])) for s in self.starts]


@dataclass(frozen=True)
class Shift:
    """One shift: its name and local interval ``[start, end)`` (aware datetimes)."""

    name: str
    start: datetime
    end: datetime

    def label(self) -> str:
        return f"{self.name} {self.start:%Y-%m-%d %H:%M}"


@dataclass(frozen=True)
class RegionCount:
    """Defects of one region over a shift.

    Attributes
    ----------
    region : str
    parts : int
        Inspections with at least one defect there.
    defects : int
        Defect clusters there.
    worst_mm : float
        The signed deviation of largest magnitude among them, mm (negative: missing material).
    """

    region: str
    parts: int
    defects: int
    worst_mm: float


@dataclass(frozen=True)
class CharacteristicCount:
    """One measured characteristic over a shift (the ``[[characteristics]]`` rows of the
    inspections' ``extras``, issue 28).

    Attributes
    ----------
    id : str
    parts : int
        Inspections that report it.
    nok : int
        Of those, measured out of its limits.
    not_measurable : int
        Of those, not measurable (too few points on its features).
    worst_use : float or None
        The largest share of the tolerance used, over the parts measured: ``|deviation -
        middle| / half width`` of the limits (1.0 at a limit, above 1 outside); None when none
        was measured.
    """

    id: str
    parts: int
    nok: int
    not_measurable: int
    worst_use: float | None


@dataclass(frozen=True)
class ErrorGroup:
    """Errors of one kind: their reason with the numbers and quoted names left out
    (:func:`error_key`), how many, and the latest full text."""

    reason: str
    count: int
    example: str


@dataclass(frozen=True)
class ShiftCounters:
    """What a shift did.

    Attributes
    ----------
    shift : Shift
    ids : tuple of int
        The history rows counted (``inspections.id``), oldest first.
    passed, failed, errors : int
    regions : tuple of RegionCount
        Worst first: most parts, then largest deviation.
    error_groups : tuple of ErrorGroup
        Most frequent first.
    characteristics : tuple of CharacteristicCount
        Worst first: most NOK, then most not measurable, then most of the tolerance used.
    """

    shift: Shift
    ids: tuple[int, ...] = ()
    passed: int = 0
    failed: int = 0
    errors: int = 0
    regions: tuple[RegionCount, ...] = ()
    error_groups: tuple[ErrorGroup, ...] = field(default_factory=tuple)
    characteristics: tuple[CharacteristicCount, ...] = ()

    @property
    def inspected(self) -> int:
        return len(self.ids)

    @property
    def judged(self) -> int:
        return self.passed + self.failed

    @property
    def yield_(self) -> float | None:
        """The passed share of the parts judged (None: none judged)."""
        return self.passed / self.judged if self.judged else None


# -- settings -----------------------------------------------------------------------------------
def shift_settings(path: str | Path | None) -> ShiftSettings:
    """The ``[shifts]`` of the cell's settings file (defaults without a file or table)."""
    table = load_cell(path).get("shifts")
    settings: ShiftSettings = build_params(ShiftSettings, table, f"{Path(path).name if path else 'cell'}: shifts")
    return settings


# -- shifts -------------------------------------------------------------------------------------
def shift_at(t: datetime, settings: ShiftSettings) -> Shift:
    """The shift that holds the instant ``t`` (aware; a naive one is taken as UTC)."""
    if t.tzinfo is None:
        t = t.replace(tzinfo=UTC)
    zone = settings.zone()
    local = t.astimezone(zone)
    times = settings.times()
    # Candidate starts from the day before to the day after, in local wall-clock time (a
    # shift starts at 06:00 whatever the daylight-saving offset of that day).
    starts = [(datetime.combine(local.date() + timedelta(days=d), s, tzinfo=zone), settings.names[k])
              for d in (-1, 0, 1) for k, s in enumerate(times)]
    starts.sort(key=lambda x: x[0])
    for (s, name), (e, _) in zip(starts, starts[1:]):
        if s <= local < e:
            return Shift(name, s, e)
    raise AssertionError("unreachable: a day's shifts cover it")  # pragma: no cover


def shifts_until(now: datetime, settings: ShiftSettings, n: int) -> list[Shift]:
    """The shift that holds ``now`` and the ``n - 1`` before it, oldest first."""
    out = [shift_at(now, settings)]
    while len(out) < n:
        out.insert(0, shift_at(out[0].start - timedelta(seconds=1), settings))
    return out


# -- reading ------------------------------------------------------------------------------------
def _parse_utc(text: str) -> datetime | None:
    try:
        t = datetime.fromisoformat(text)
    except (TypeError, ValueError):
        return None
    return t.replace(tzinfo=UTC) if t.tzinfo is None else t


def read_shift_rows(path: Path, start: datetime, end: datetime
                    ) -> tuple[list[dict[str, Any]], dict[int, list[dict[str, Any]]]]:
    """The inspections of the history file ``path`` inspected in ``[start, end)`` (oldest
    first: ``id``, ``inspected_at``, ``verdict``, ``error``, ``extras``) and their defects by inspection
    id (``kind``, ``worst_mm``, ``region``). Read-only. InputError naming the file when there is
    none or it cannot be read."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no history (inspector run writes it beside the result folders)")
    # The stored text is UTC ISO-8601 (lexically ordered); a day's margin for any other
    # offset a foreign writer used, the exact interval is then checked on the parsed time.
    lo = (start.astimezone(UTC) - timedelta(days=1)).isoformat()
    hi = (end.astimezone(UTC) + timedelta(days=1)).isoformat()
    try:
        con = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True, timeout=10.0)
        try:
            con.row_factory = sqlite3.Row
            tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
            if "inspections" not in tables:
                return [], {}
            rows = []
            have = {r[1] for r in con.execute("PRAGMA table_info(inspections)")}
            extras = "extras" if "extras" in have else "NULL AS extras"  # a file from before the column
            for r in con.execute(f"SELECT id, inspected_at, verdict, error, {extras} FROM inspections "
                                 "WHERE inspected_at >= ? AND inspected_at < ? ORDER BY id", (lo, hi)):
                t = _parse_utc(r["inspected_at"])
                if t is not None and start <= t < end:
                    rows.append(dict(r))
            defects: dict[int, list[dict[str, Any]]] = defaultdict(list)
            if rows and "defects" in tables:
                cols = {r[1] for r in con.execute("PRAGMA table_info(defects)")}
                region = "region" if "region" in cols else "NULL"
                for d in con.execute(f"SELECT inspection_id, kind, worst_mm, {region} AS region FROM defects "
                                     "WHERE inspection_id BETWEEN ? AND ?", (rows[0]["id"], rows[-1]["id"])):
                    defects[int(d["inspection_id"])].append(dict(d))
            return rows, dict(defects)
        finally:
            con.close()
    except sqlite3.Error as e:
        raise InputError(f"{path}: cannot be read ({e})") from None


_NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")
_QUOTED = re.compile(r"'[^']*'|\"[^\"]*\"")


def error_key(text: str | None) -> str:
    """An error's reason without what differs between parts (numbers, quoted names): errors
    with the same key are the same reason. Its first line only."""
    first = (text or "").strip().splitlines()[0] if (text or "").strip() else ""
    if not first:
        return translate("Shift", "no reason recorded")
    return _NUMBER.sub("#", _QUOTED.sub("'…'", first))


def count(shift: Shift, rows: Sequence[Mapping[str, Any]], defects: Mapping[int, Iterable[Mapping[str, Any]]]
          ) -> ShiftCounters:
    """The counters of ``rows`` (those of ``shift``) and their ``defects`` by inspection id."""
    verdicts = Counter(str(r["verdict"]) for r in rows)
    regions: dict[str, list[Any]] = {}
    for r in rows:
        seen = set()
        for d in defects.get(int(r["id"]), ()):
            name = str(d.get("region") or "default")
            worst = float(d["worst_mm"])
            entry = regions.setdefault(name, [0, 0, 0.0])
            entry[1] += 1
            if abs(worst) > abs(entry[2]):
                entry[2] = worst
            if name not in seen:
                seen.add(name)
                entry[0] += 1
    region_rows = sorted((RegionCount(k, v[0], v[1], v[2]) for k, v in regions.items()),
                         key=lambda g: (-g.parts, -abs(g.worst_mm), g.region))
    groups: dict[str, list[Any]] = {}
    for r in rows:
        if r["verdict"] == "error":
            key = error_key(r.get("error"))
            g = groups.setdefault(key, [0, ""])
            g[0] += 1
            g[1] = str(r.get("error") or "")  # the latest (rows are oldest first)
    error_rows = sorted((ErrorGroup(k, v[0], v[1]) for k, v in groups.items()), key=lambda g: (-g.count, g.reason))
    return ShiftCounters(shift, tuple(int(r["id"]) for r in rows), verdicts["pass"], verdicts["fail"],
                         verdicts["error"], tuple(region_rows), tuple(error_rows), count_characteristics(rows))


def _tolerance_use(row: Mapping[str, Any]) -> float | None:
    """``|deviation - middle| / half width`` of a characteristics row's limits (None: not
    measured, or limits without a width); the deviation is ``measured - nominal`` in a row
    that does not carry it."""
    try:
        dev = row.get("deviation")
        dev = float(dev) if dev is not None else float(row["measured"]) - float(row.get("nominal") or 0.0)
        lo, hi = float(row["lower"]), float(row["upper"])
    except (KeyError, TypeError, ValueError):
        return None
    half = (hi - lo) / 2.0
    if not (math.isfinite(dev) and math.isfinite(half)) or half <= 0:
        return None
    return abs(dev - (hi + lo) / 2.0) / half


def count_characteristics(rows: Sequence[Mapping[str, Any]]) -> tuple[CharacteristicCount, ...]:
    """The characteristics counters of history rows (their ``extras`` column, JSON), worst
    first (:class:`ShiftCounters`)."""
    from inspector.characteristics.definitions import rows_of

    found: dict[str, list[Any]] = {}
    for r in rows:
        raw = r.get("extras")
        try:
            extras = json.loads(raw) if isinstance(raw, str) else raw
        except ValueError:
            continue  # a row a foreign writer garbled: its characteristics are not counted
        for c in rows_of({"extras": extras if isinstance(extras, Mapping) else {}}):
            entry = found.setdefault(str(c.get("id")), [0, 0, 0, None])
            entry[0] += 1
            entry[1] += c.get("verdict") == "nok"
            entry[2] += c.get("verdict") == "not_measurable"
            use = _tolerance_use(c)
            if use is not None and (entry[3] is None or use > entry[3]):
                entry[3] = use
    out = (CharacteristicCount(k, *v) for k, v in found.items())
    return tuple(sorted(out, key=lambda c: (-c.nok, -c.not_measurable, -(c.worst_use or 0.0), c.id)))


def shift_counters(history: str | Path, settings: ShiftSettings | None = None, *, now: datetime | None = None,
                   shifts: int = 1) -> list[ShiftCounters]:
    """The counters of the shift that holds ``now`` (default: now) and of the ``shifts - 1``
    before it, oldest first.

    Parameters
    ----------
    history : path
        ``OUTDIR/history.sqlite`` (or ``OUTDIR``: its history file), opened read-only.
    settings : ShiftSettings, optional
        Shift times (default: 06:00, 14:00, 22:00 in the computer's time zone).

    Raises
    ------
    InputError
        No history file, or one that cannot be read (one line naming it).
    """
    settings = settings or ShiftSettings()
    path = Path(history)
    if path.is_dir() or path.suffix != ".sqlite":  # an OUTDIR (one that does not exist too)
        path = path / HISTORY_FILE
    now = now or datetime.now(UTC)
    spans = shifts_until(now, settings, max(1, shifts))
    rows, defects = read_shift_rows(path, spans[0].start, spans[-1].end)
    out = []
    for s in spans:
        mine = [r for r in rows if s.start <= (_parse_utc(r["inspected_at"]) or s.end) < s.end]
        out.append(count(s, mine, {int(r["id"]): defects.get(int(r["id"]), []) for r in mine}))
    return out


# -- text ---------------------------------------------------------------------------------------
def _pct(x: float | None) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{number(100 * x, '.1f')} %"


def format_shift(c: ShiftCounters, *, top: int = 5, translate: Callable[[str, str], str] | None = None) -> str:
    """One shift's counters as lines of text (``inspector history --shift``), translated by
    ``translate(context, text)`` (default: the installed translator, :func:`translate`; the
    name kept so that lupdate and Babel find the texts)."""
    translate = translate or _installed
    s = c.shift
    lines = [translate("Shift", "shift {name} {start} to {end}").format(
        name=s.name, start=f"{s.start:%Y-%m-%d %H:%M}", end=f"{s.end:%H:%M}")]
    lines.append("  " + translate("Shift", "{n} inspected: {p} pass, {f} fail, {e} error; yield {y}").format(
        n=c.inspected, p=c.passed, f=c.failed, e=c.errors, y=_pct(c.yield_)))
    if c.regions:
        lines.append("  " + translate("Shift", "worst regions (parts with a defect there, defects, worst mm):"))
        for g in c.regions[:top]:
            lines.append(f"    {g.region:24s} {g.parts:5d} {g.defects:5d} {number(g.worst_mm, '+.3f'):>9s}")
    if c.characteristics:
        lines.append("  " + translate("Shift", "worst characteristics (parts, NOK, not measurable, most of the tolerance used):"))
        for k in c.characteristics[:top]:
            lines.append(f"    {k.id:24s} {k.parts:5d} {k.nok:5d} {k.not_measurable:5d} {_pct(k.worst_use):>9s}")
    if c.error_groups:
        lines.append("  " + translate("Shift", "errors by reason:"))
        for e in c.error_groups[:top]:
            lines.append(f"    {e.count:5d}  {e.reason}")
    return "\n".join(lines)


def format_shifts(counters: Sequence[ShiftCounters], *, top: int = 5,
                  translate: Callable[[str, str], str] | None = None) -> str:
    """Several shifts' counters, oldest first, a blank line between them (``translate``: see
    :func:`format_shift`)."""
    return "\n\n".join(format_shift(c, top=top, translate=translate) for c in counters)


def print_shifts(outdir: str | Path, *, shifts: int = 1, config: str | Path | None = None,
                 pdf: str | Path | None = None) -> int:
    """``inspector history OUTDIR --shift [N] [--config cell.toml]``: print the counters of the
    current shift and the ``N - 1`` before it, with the shift times of ``config`` (else the
    configuration folder's ``cell.toml``, see :func:`inspector.cell.cell_file`; else the defaults); the exit
    status (2: bad settings, 3: no readable history or the PDF not written), the reason in one
    line on stderr. ``pdf``: also the shift report there (:mod:`inspector.shift_report`)."""
    if shifts < 1:
        print(f"inspector: error: --shift: expected a number >= 1, got {shifts}", file=sys.stderr)
        return 2
    try:
        settings = shift_settings(cell_file(config))
    except RecipeError as e:
        print(f"inspector: error: {e}", file=sys.stderr)
        return 2
    try:
        counters = shift_counters(outdir, settings, shifts=shifts)
    except InputError as e:
        print(f"inspector: error: {e}", file=sys.stderr)
        return 3
    print(format_shifts(counters, translate=_headless))  # the command's language (--lang), not a window's Qt translator
    if pdf is not None:
        from inspector.shift_report import render_shift_pdf

        try:
            written = render_shift_pdf(counters, Path(pdf), source=str(Path(outdir).resolve()))
        except OSError as e:
            print(f"inspector: error: --pdf {pdf}: cannot be written ({e.strerror or e})", file=sys.stderr)
            return 3
        print(f"shift report written to {written}")
    return 0
