"""The journal of ``inspector serve``: what a kill left is reconciled at the next start.

``inspector run --watch`` knows what was in progress from its inbox (``INBOX/processing/``);
``serve`` acquires from a camera or a simulated rig, so it keeps the same knowledge in a
file of its own, ``OUTDIR/.serve-journal.json`` (hidden: no PartId can name it). The file is
rewritten whole (a temporary file renamed over it, so a reader or a restart sees the old
state or the new one, never half of one) at three moments of every cycle:

1. a trigger is accepted (before the PLC's call or write returns): ``pending`` holds its
   PartId and trigger time;
2. the driver's capture is named (in the worker thread, before it is loaded): ``pending``
   gets the capture's name, i.e. its result folder and history row;
3. a result is about to be published: ``counter`` (the ``ResultCounter`` it is published
   under) and ``last`` (its ``LastResult`` record) are written first and ``pending``
   cleared, so a kill during the publication republishes the same result under the same
   counter.

At the next start (:meth:`Journal.load` and the server's recovery) the state is one of:

* nothing pending: the last result is published again under its counter (a PLC reading
  after the restart sees what it saw before);
* a capture pending whose result folder is in place: its history row is added if the kill
  came before it, and the result is published under the next counter;
* a trigger pending without a written result (killed during the inspection, or during the
  result's write: its hidden ``.NAME.partial`` folder is removed): an ``aborted`` result is
  published under the next counter, nothing written (as ``Abort`` does), so the PLC triggers
  the part again and it is inspected under its own name.

The file is not flushed to the disk at every write (neither are the result folders): a kill
leaves it as written, a power loss as the operating system last wrote it.
"""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path
from typing import Any

import numpy as np

from inspector.errors import RecipeError
from inspector.model import Defect, DeviationStats, EvaluationSummary, InspectionResult

__all__ = ["JOURNAL_FILE", "LOCK_FILE", "Journal", "result_from_json", "lock_outdir"]

#: The journal, in the server's result folder (``--out``).
JOURNAL_FILE = ".serve-journal.json"
#: Held (``flock``) by the server using the result folder: one server per folder.
LOCK_FILE = ".serve.lock"
_VERSION = 1
_MAX_BYTES = 1 << 20


class Journal:
    """The journal file of one result folder, and its state in memory.

    Attributes
    ----------
    counter : int
        The ``ResultCounter`` of the last result published (0: none yet).
    last : dict or None
        That result's ``LastResult`` record.
    pending : dict or None
        The cycle in progress: ``part_id``, ``triggered_at``, ``capture`` (None until named).
    """

    def __init__(self, outdir: Path) -> None:
        self.path = Path(outdir) / JOURNAL_FILE
        self.counter = 0
        self.last: dict[str, Any] | None = None
        self.pending: dict[str, Any] | None = None
        self._lock = threading.Lock()  # written from the event loop's helper threads and the worker

    def load(self) -> str | None:
        """Read the file (none: a first start); a warning line when it cannot be used (then
        the state starts empty: nothing is reconciled, the counter starts at 0)."""
        try:
            if self.path.stat().st_size > _MAX_BYTES:
                raise ValueError(f"larger than {_MAX_BYTES} bytes")
            doc = json.loads(self.path.read_text(encoding="utf-8"))
            if not isinstance(doc, dict) or doc.get("version") != _VERSION:
                raise ValueError("not a journal of this version")
            counter = doc.get("counter")
            last, pending = doc.get("last"), doc.get("pending")
            if not isinstance(counter, int) or not 0 <= counter < 2**32:
                raise ValueError("no counter")
            if last is not None and not isinstance(last, dict):
                raise ValueError("bad last result")
            if pending is not None and not (isinstance(pending, dict) and isinstance(pending.get("part_id"), str)
                                            and isinstance(pending.get("capture"), (str, type(None)))):
                raise ValueError("bad pending cycle")
        except FileNotFoundError:
            return None
        except (OSError, ValueError, UnicodeDecodeError) as e:  # JSONDecodeError is a ValueError
            return f"{self.path}: cannot be read ({e}); what a crash left, if anything, is not reconciled"
        self.counter, self.last, self.pending = counter, last, pending
        return None

    def _write(self) -> None:
        doc = {"version": _VERSION, "counter": self.counter, "last": self.last, "pending": self.pending}
        data = json.dumps(doc, separators=(",", ":"), default=str, allow_nan=False).encode("utf-8")
        tmp = self.path.with_name(self.path.name + ".part")
        with open(tmp, "wb") as f:
            f.write(data)
        os.replace(tmp, self.path)

    def accepted(self, part_id: str, triggered_at: str) -> None:
        """A trigger was accepted (moment 1)."""
        with self._lock:
            self.pending = {"part_id": part_id, "triggered_at": triggered_at, "capture": None}
            self._write()

    def named(self, capture: str, part_id: str, triggered_at: str) -> None:
        """The driver's capture is named ``capture`` (moment 2; continuous execution has no
        trigger: the capture starts its own pending cycle)."""
        with self._lock:
            self.pending = {"part_id": part_id, "triggered_at": triggered_at, "capture": capture}
            self._write()

    def published(self, counter: int, record: dict[str, Any]) -> None:
        """Result ``record`` is about to be published under ``counter`` (moment 3)."""
        with self._lock:
            self.counter, self.last, self.pending = counter, record, None
            self._write()


def lock_outdir(outdir: Path) -> Any:
    """An open file holding an exclusive lock on ``outdir`` for this process (closed: released,
    also by a kill); None where file locks do not exist. RecipeError when another server holds it."""
    try:
        import fcntl
    except ImportError:  # not POSIX
        return None
    f = open(Path(outdir) / LOCK_FILE, "a+")
    try:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        f.close()
        raise RecipeError(f"--out {outdir}: another inspector serve uses this result folder (one server per folder: "
                          "its journal would be mixed)") from None
    return f


def _float(x: Any) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return float("nan")


def result_from_json(doc: dict[str, Any]) -> InspectionResult:
    """The :class:`InspectionResult` of a ``result.json`` document, as far as the history
    and ``LastResult`` read it (verdict, error, summary, defects, timings, metadata, stats,
    extras; no points: they stay in the folder's PLY files).

    Raises KeyError or TypeError on a document that is not a result (the caller says so).
    """
    stats = dict(doc.get("stats") or {})
    summary = None
    if isinstance(stats.get("n_points"), int) and isinstance(stats.get("tolerance_mm"), dict):
        dev = stats.get("deviation_mm") or {}
        keys = ("mean", "std", "min", "max", "p01", "p99", "mean_abs")
        dstats = DeviationStats(**{k: _float(dev.get(k)) for k in keys}) if dev else None
        tol = stats["tolerance_mm"]
        summary = EvaluationSummary(n_points=int(stats["n_points"]), deviation_mm=dstats,
                                    tolerance_mm=(_float(tol.get("lower")), _float(tol.get("upper"))),
                                    within_tolerance=_float(stats.get("within_tolerance")),
                                    out_of_tolerance_points=int(stats.get("out_of_tolerance_points") or 0))
    defects = tuple(Defect(kind=str(d["kind"]), position=tuple(_float(x) for x in d["position"]),  # type: ignore[arg-type]
                           extent=tuple(_float(x) for x in d.get("extent") or (0, 0, 0)),  # type: ignore[arg-type]
                           n_points=int(d["n_points"]), worst_mm=_float(d["worst_mm"]), region=str(d.get("region") or ""))
                    for d in doc.get("defects") or ())
    pose = doc.get("pose")
    return InspectionResult(
        capture=str(doc["capture"]), recipe=str(doc["recipe"]), verdict=str(doc["verdict"]), error=doc.get("error"),
        timings_s={str(k): _float(v) for k, v in (doc.get("timings_s") or {}).items()},
        pose=np.asarray(pose, float) if pose is not None else None, stats=stats, defects=defects,
        metadata=dict(doc.get("metadata") or {}), recipe_path=doc.get("recipe_path"),
        recipe_sha256=doc.get("recipe_sha256"), summary=summary, extras=dict(doc.get("extras") or {}))
