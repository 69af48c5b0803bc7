"""The stage watchdog: a stage call that may not return, given a time limit and an abort flag.

A Python thread cannot be killed, so a stage runs in a thread of its own (a daemon) while the
inspection's thread waits for it in short slices: when the stage returns, its result (or its
exception) is the call's; when the time limit passes, or ``should_abort`` says so, or Ctrl-C
arrives, the waiting thread gives up on it and the cell goes on with the next part. The
stage's thread is left behind: it ends whenever the stage does (a stage that never returns
keeps its thread, and its core if it spins, until the process ends; :func:`abandoned`
counts them so the run can say so). Cost: one thread start per stage call, about 0.1 ms;
measured over the default recipe's five stages, well under 1 ms per part.

Running plugin stages in a worker process instead would let a stuck stage be ended, at the
price of sending the capture (16 × 1 MP images: 16 MB) and the context between processes on
every stage of every part; the thread design costs nothing per part and ends the *part*
within its limit, which is what the line needs.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["StageTimeout", "StageAborted", "call_with_limit", "abandoned", "POLL_S"]

T = TypeVar("T")

#: How often the waiting thread looks at the abort flag, s: ``Abort`` and Ctrl-C act within it.
POLL_S = 0.1

_abandoned: list[threading.Thread] = []
_lock = threading.Lock()


class StageTimeout(Exception):
    """The call did not return within its limit (its thread is left behind)."""

    def __init__(self, limit_s: float) -> None:
        super().__init__(f"exceeded {limit_s:g} s")
        self.limit_s = limit_s


class StageAborted(Exception):
    """``should_abort`` became true while the call ran (its thread is left behind)."""


def abandoned() -> int:
    """Stage threads given up on that are still running."""
    with _lock:
        _abandoned[:] = [t for t in _abandoned if t.is_alive()]
        return len(_abandoned)


def call_with_limit(fn: Callable[..., T], *args: Any, limit_s: float | None,
                    should_abort: Callable[[], bool] | None = None, name: str = "stage") -> T:
    """``fn(*args)``, given up after ``limit_s`` seconds or as soon as ``should_abort()``.

    Parameters
    ----------
    fn : callable
    *args
        Its arguments.
    limit_s : float or None
        Seconds the call may take; None: no limit (the call still runs in its own thread
        only when ``should_abort`` is given, so that an abort does not wait for it).
    should_abort : callable, optional
        Asked every :data:`POLL_S` seconds while the call runs.
    name : str
        The thread's name (seen in a debugger or ``py-spy``).

    Returns
    -------
    What ``fn`` returns; what it raises is raised here.

    Raises
    ------
    StageTimeout
        After ``limit_s`` seconds.
    StageAborted
        When ``should_abort()`` became true first.
    KeyboardInterrupt
        Ctrl-C while waiting (the call is left behind, as on a time-out).
    """
    if limit_s is None and should_abort is None:
        return fn(*args)
    done = threading.Event()
    box: dict[str, Any] = {}

    def target() -> None:
        try:
            box["value"] = fn(*args)
        except BaseException as exc:  # noqa: BLE001 - handed to the waiting thread, which raises it
            box["error"] = exc
        finally:
            done.set()

    thread = threading.Thread(target=target, name=f"inspector-{name}", daemon=True)
    thread.start()
    deadline = None if limit_s is None else time.monotonic() + limit_s
    try:
        while True:
            left = POLL_S if deadline is None else min(POLL_S, deadline - time.monotonic())
            if done.wait(max(left, 0.0)):
                break
            if should_abort is not None and should_abort():
                raise StageAborted()
            if deadline is not None and time.monotonic() >= deadline:
                raise StageTimeout(float(limit_s or 0.0))
    except BaseException:
        if not done.is_set():
            with _lock:
                _abandoned.append(thread)
        raise
    if "error" in box:
        raise box["error"]
    return box["value"]
