"""A PLC's trigger on the way to a capture: its ``PartId`` checked (:func:`part_id_problem`), the
:class:`Job` it starts, and the recipe's driver wrapped so that the capture is named after the
PartId (:class:`PartIdDriver`): what joins the OPC UA server
(:class:`~inspector_frontends.opcua.server.InspectorServer`) to its session.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from typing import Any

from inspector.names import name_problem
from inspector.registry import Acquisition

__all__ = ["part_id_problem", "MAX_PART_ID_BYTES", "Job", "PartIdDriver", "now"]

#: Longest PartId: a result folder name, with room for a ``-N`` suffix.
MAX_PART_ID_BYTES = 200


def part_id_problem(part_id: str) -> str | None:
    """Why ``part_id`` cannot name a capture and its result folder, or None ("" is allowed:
    the driver names the capture)."""
    if part_id == "":
        return None
    if len(part_id.encode("utf-8", "surrogatepass")) > MAX_PART_ID_BYTES:
        return f"is longer than {MAX_PART_ID_BYTES} bytes"
    why = name_problem(part_id)
    if why is not None:
        return why
    if part_id.startswith("."):
        return "starts with a dot (a hidden folder)"
    return None


def now() -> str:
    """The time now (UTC, ISO 8601 to the millisecond): a trigger's ``triggered_at``."""
    return datetime.now(UTC).isoformat(timespec="milliseconds")


@dataclasses.dataclass(frozen=True)
class Job:
    """One accepted trigger: the part's id ("" none), when, and the clock at acceptance."""

    part_id: str
    triggered_at: str
    t0: float


class PartIdDriver:
    """The recipe's driver with each capture named after the PartId of the trigger that
    asked for it (``PartId``, then ``PartId-2`` ... when the name is taken in ``--out`` or the
    history), and the PartId and trigger time in its metadata (``capture.json``'s
    ``part_id`` and ``timestamp``: the history's ``part_id`` and ``triggered_at``)."""

    def __init__(self, inner: Any, job: Callable[[], Job | None],
                 named: Callable[[str, str, str], None] = lambda name, part_id, at: None) -> None:
        self._inner = inner
        self._job = job
        self._named = named  # the journal: the capture's name, before it is loaded and inspected
        #: Set by the session (``Session._hand_off``): whether a name is taken downstream.
        self.taken: Callable[[str], bool] = lambda name: False

    @property
    def sleep(self) -> Any:  # a waiting driver's poll (AttributeError when it has none)
        return self._inner.sleep

    @sleep.setter
    def sleep(self, value: Any) -> None:
        self._inner.sleep = value

    def acquire(self) -> Iterator[Acquisition]:
        for acq in self._inner.acquire():
            job = self._job()
            part_id = job.part_id if job is not None else ""
            at = job.triggered_at if job is not None else now()
            name = self._free(part_id) if part_id else acq.name
            self._named(name, part_id, at)
            yield Acquisition(name, functools.partial(self._load, acq, name, part_id, at))

    def _free(self, part_id: str) -> str:
        name, n = part_id, 2
        while self.taken(name) and n < 100_000:
            name, n = f"{part_id}-{n}", n + 1
        return name

    @staticmethod
    def _load(acq: Acquisition, name: str, part_id: str, at: str) -> Any:
        capture = acq.load()
        meta = dict(capture.metadata)
        if part_id:
            meta["part_id"] = part_id
        meta["timestamp"] = at
        return dataclasses.replace(capture, name=name, metadata=meta)

    def close(self) -> None:
        self._inner.close()
