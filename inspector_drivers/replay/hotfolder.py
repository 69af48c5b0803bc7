"""Driver ``hotfolder``: inspect capture folders as another program drops them in an inbox.

The production-line mode of the headless runner::

    inspector run recipes/default.toml --watch INBOX --out OUT --reference part.stl

Outside programs write capture folders (CONTRACT) into ``INBOX``. A folder is handed to the
runner once it is complete and quiet:

* ``rig.json`` exists and parses, ``images/`` holds a PNG for every camera it names, and every
  PNG of the folder is whole (a valid header, and the final ``IEND`` chunk at its end:
  :func:`~inspector.capture_folder.is_complete_png`), and ``capture.json``, if there is
  one, parses (:func:`~inspector.capture_folder.write_capture` writes ``rig.json``
  last, so its folders are complete as soon as ``rig.json`` appears; other writers need not
  be);
* nothing in the folder changed (names, sizes, modification times) for ``settle_s``.

A writer that stalls in the middle of an image (its file has no end yet), or a file that
cannot be read yet, leaves the folder incomplete: it is looked at again after each change and
``settle_s``, and read once whole. A folder that stays incomplete is handed over anyway once
it has not changed for ``give_up_s``: the runner then reports what is missing (``camera cam03
has no image``, ``images/cam03.png: truncated PNG``), so a broken writer shows up as an error
result instead of a silent backlog.

Hand-off (``after = "move"``), crash-safe and exclusive:

* One watcher per inbox: the inbox folder is locked (``flock``) while a driver is open; a
  second watcher is refused in one line (the command exits 2). The lock dies with its process.
* A ready folder is *claimed* by renaming it into ``INBOX/processing/`` (atomic on one file
  system), under a name no result has: if ``done/``, ``processing/`` or downstream (the CLI:
  ``OUTDIR/<name>/`` exists or the history has a row of that name: a reused part number)
  already has it, or it is reserved in the result folder (``history.sqlite``, ``recipes``:
  :data:`inspector.names.RESERVED`), it becomes ``NAME-2``, ``NAME-3``... so its result
  never overwrites an earlier one and the result folder keeps the capture folder's name.
* The runner writes the result folder whole or not at all (:func:`inspector.outputs.write_result`),
  then its history row. When it asks for the next capture, the driver checks the capture is
  *settled* downstream (result and history row: :attr:`HotFolderDriver.settled`) and moves it
  to ``INBOX/done/``. One whose result could not be written (a full disk) stays in
  ``processing/``.
* At start, what a crash (kill -9, power loss) left in ``processing/`` is reconciled before
  anything else: a capture settled downstream only lacked its move to ``done/``; any other is
  inspected again under the same name, after what its unfinished inspection left downstream
  is removed (:attr:`HotFolderDriver.discard`: a partial result, or a result without its
  history row). So a capture is either waiting (in the inbox or ``processing/``) or done with
  exactly one result and one history row; nothing is inspected twice, nothing is deleted.

A name no result folder can take (a control character, bytes that are not UTF-8) is reported
as an error in one line and the folder is moved to ``done/``
(:func:`~inspector_drivers.replay.named_acquisition`). With ``after = "keep"`` folders stay
where they are and each is inspected once per run (no claim, no ``processing/``). Folders
already in the inbox at start (a backlog) come first, oldest first. Names starting with
``.`` or ending in ``.tmp``/``.partial`` are ignored (writers' temporary folders), and so are
``done/`` and ``processing/``.

The watch ends after ``count`` captures, after ``idle_exit_s`` without a new one (0:
never), or on Ctrl-C (results written so far are kept; a capture in progress stays in
``processing/`` and is inspected first at the next start).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from inspector.errors import InputError, InspectorError, RecipeError
from inspector.limits import limit, load_json
from inspector.names import RESERVED, name_problem
from inspector.params import check_params, param
from inspector.registry import Acquisition

__all__ = ["HotFolderParams", "HotFolderDriver", "DONE_DIR", "PROCESSING_DIR", "folder_state"]

#: Sub-folder of the inbox that receives inspected capture folders.
DONE_DIR = "done"
#: Sub-folder of the inbox that holds the capture being inspected (claimed, not yet done).
PROCESSING_DIR = "processing"
_TEMP_SUFFIXES = (".tmp", ".partial")


@dataclass(frozen=True)
class HotFolderParams:
    folder: str = param("", "the inbox: capture folders appear in it (the CLI's --watch)")
    settle_s: float = param(0.5, "a complete folder must be unchanged this long before it is read, s", min=0.0, max=3600.0)
    give_up_s: float = param(30.0, "an incomplete folder (a file missing, or one not whole: a stalled writer) unchanged this long is handed over anyway (the result names what is missing), s", min=0.0, max=86400.0)
    poll_s: float = param(0.2, "how often the inbox is scanned, s", min=0.01, max=60.0)
    idle_exit_s: float = param(0.0, "stop after this long without a new capture, s (0: never)", min=0.0, max=604800.0)
    count: int = param(0, "stop after this many captures (0: no limit)", min=0)
    after: Literal["move", "keep"] = param("move", "what becomes of an inspected folder: moved to INBOX/done/ (through INBOX/processing/ while it is inspected), or kept in place")

    def __post_init__(self) -> None:
        # The CLI builds these from --watch/--count/--idle-exit, not from a recipe table:
        # the same checks (a NaN poll_s once killed the watcher; an infinite settle_s
        # never read a complete capture).
        check_params(self, "hotfolder")


def folder_state(folder: Path) -> tuple[tuple[str, int, int], ...]:
    """What a writer changes: (relative path, size, mtime ns) of every entry, sorted.

    Never raises: an entry that vanishes while it is listed is simply not there.
    """
    out: list[tuple[str, int, int]] = []
    for root, dirs, files in os.walk(folder):
        dirs.sort()
        for name in dirs + sorted(files):
            p = Path(root) / name
            try:
                st = p.stat()
            except OSError:
                continue
            out.append((str(p.relative_to(folder)), st.st_size if name in files else -1, st.st_mtime_ns))
    return tuple(out)


def _complete(folder: Path) -> bool:
    """Every file the capture needs is there and whole (cheap; never raises).

    ``rig.json`` parses within the input bounds (:mod:`inspector.limits`: a huge or deeply
    nested one is never complete, so it is handed over after ``give_up_s`` and its result says
    why), every camera it names has an image, every PNG in ``images/`` and ``background/`` is
    a whole PNG (a writer stalled inside one leaves it without its end), and ``capture.json``,
    if there is one, parses.
    """
    from inspector.capture_folder import is_complete_png

    try:
        data = load_json(folder / "rig.json", "rig.json")
        cameras = data["cameras"]
        if len(cameras) > limit("MAX_CAMERAS"):
            return False
        names = [c["name"] for c in cameras]
        if not names or not all((folder / "images" / f"{n}.png").is_file() for n in names):
            return False
        if (folder / "capture.json").exists():
            load_json(folder / "capture.json", "capture.json")
        for sub in ("images", "background"):
            d = folder / sub
            if d.is_dir():
                for p in d.iterdir():
                    if p.suffix == ".png" and not p.name.startswith(".") and not is_complete_png(p):
                        return False
        return True
    except (InspectorError, OSError, ValueError, KeyError, TypeError):
        return False


def _lock(inbox: Path) -> int:
    """An exclusive lock on the inbox folder, held by the returned descriptor until it is
    closed (or the process dies). RecipeError when another process holds it."""
    import fcntl

    try:
        fd = os.open(inbox, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as e:
        raise RecipeError(f"hotfolder: inbox {inbox}: cannot be opened ({e.strerror or e})") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as e:
        os.close(fd)
        if isinstance(e, BlockingIOError):
            holder = _lock_holder(inbox)
            who = f"another watcher (pid {holder})" if holder else "another watcher"
            raise RecipeError(f"hotfolder: inbox {inbox}: {who} is already inspecting it; "
                              "stop it first (two would inspect every capture twice)") from None
        raise RecipeError(f"hotfolder: inbox {inbox}: cannot be locked ({e.strerror or e})") from None
    return fd


def _lock_holder(inbox: Path) -> int | None:
    """The process holding the flock of ``inbox``, from /proc/locks (Linux), or None."""
    try:
        st = os.stat(inbox)
        key = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
        with open("/proc/locks", encoding="ascii", errors="replace") as f:
            for line in f:
                parts = line.split()
                if "FLOCK" in parts and key in parts:
                    return int(parts[parts.index(key) - 1])
    except (OSError, ValueError, IndexError):
        pass
    return None


def _age(p: Path) -> tuple[float, str]:
    try:
        return (p.stat().st_mtime, p.name)
    except OSError:
        return (float("inf"), p.name)


def _suffixed(name: str, k: int) -> str:
    """``NAME-k``, ``NAME`` shortened so that the whole fits a file name (255 bytes)."""
    suffix = f"-{k}"
    base = name
    while base and len((base + suffix).encode("utf-8", "surrogateescape")) > 255:
        base = base[:-1]
    return base + suffix


@dataclass
class _Seen:
    state: tuple[tuple[str, int, int], ...]
    since: float  # monotonic time the state was first seen unchanged


@dataclass
class HotFolderDriver:
    """Yields one :class:`Acquisition` per capture folder that lands in ``params.folder``.

    The consumer's side of the hand-off is three callables (the session sets them for the
    run's result folder; the defaults suit a consumer with nothing downstream):
    :attr:`taken`, :attr:`settled` and :attr:`discard`.
    """

    params: HotFolderParams
    clock: Callable[[], float] = time.monotonic
    sleep: Callable[[float], None] = time.sleep
    #: Whether a capture name is already used downstream (the CLI: a result folder of that
    #: name exists, or a history row names it). Such a folder is renamed ``NAME-2``, ``-3``...
    #: as it is claimed, so a reused part number never overwrites an earlier result.
    taken: Callable[[str], bool] = lambda name: False
    #: Whether the inspection of capture ``name`` is complete downstream (the CLI: its result
    #: folder and its history row are written). Asked when the consumer asks for the next
    #: capture (then the folder moves to ``done/``; if not, it stays in ``processing/``) and,
    #: at start, for each capture a crash left in ``processing/``.
    settled: Callable[[str], bool] = lambda name: True
    #: Remove what an unfinished inspection of ``name`` left downstream (a partial result, a
    #: result without its history row) before it is inspected again after a crash.
    discard: Callable[[str], None] = lambda name: None
    _seen: dict[str, _Seen] = field(default_factory=dict)
    _done: set[str] = field(default_factory=set)
    _lock_fd: int | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        inbox = Path(self.params.folder)
        if not self.params.folder:
            raise RecipeError("hotfolder: no inbox folder given (--watch DIR, or the driver's folder parameter)")
        if not inbox.is_dir():
            raise RecipeError(f"hotfolder: inbox {inbox}: not a folder")
        self._lock_fd = _lock(inbox)

    @property
    def inbox(self) -> Path:
        return Path(self.params.folder)

    def _candidates(self) -> list[Path]:
        try:
            entries = list(self.inbox.iterdir())
        except OSError as e:
            raise InputError(f"hotfolder: inbox {self.inbox}: cannot be read ({e.strerror or e})") from None
        out = []
        for p in entries:
            n = p.name
            if n in (DONE_DIR, PROCESSING_DIR) or n.startswith(".") or n.endswith(_TEMP_SUFFIXES) or n in self._done:
                continue
            if p.is_dir():
                out.append(p)
        return sorted(out, key=_age)

    def _ready(self, folder: Path, now: float) -> bool:
        """Complete and unchanged for settle_s, or unchanged for give_up_s."""
        state = folder_state(folder)
        seen = self._seen.get(folder.name)
        if seen is None or seen.state != state:
            self._seen[folder.name] = _Seen(state, now)
            # A complete folder with settle_s = 0 is ready at once.
            return self.params.settle_s == 0 and _complete(folder)
        quiet = now - seen.since
        return (quiet >= self.params.settle_s and _complete(folder)) or quiet >= self.params.give_up_s

    def _free(self, name: str) -> bool:
        if name in RESERVED or self.taken(name):
            return False
        if self.params.after != "move":
            return True
        return not any(os.path.lexists(self.inbox / sub / name) for sub in (DONE_DIR, PROCESSING_DIR))

    def _free_name(self, name: str) -> str:
        """``name``, or ``NAME-2``, ``NAME-3``... the first that is free (:meth:`_free`)."""
        free, k = name, 1
        while not self._free(free):
            k += 1
            free = _suffixed(name, k)
        return free

    def _claim(self, folder: Path) -> Path | None:
        """Take a ready folder: move it into ``processing/`` under a free name (``keep``:
        rename it in place only if its name is taken). None if it vanished meanwhile."""
        name = self._free_name(folder.name)
        if self.params.after == "move":
            target = self.inbox / PROCESSING_DIR / name
            target.parent.mkdir(exist_ok=True)
        else:
            target = folder.with_name(name)
        if target != folder:
            try:
                os.rename(folder, target)  # atomic: the folder is in the inbox or claimed
            except FileNotFoundError:
                self._seen.pop(folder.name, None)
                return None
            except OSError as e:
                raise InputError(f"hotfolder: cannot move {folder} to {target} ({e.strerror or e})") from None
        self._seen.pop(folder.name, None)
        return target

    def _file_away(self, folder: Path) -> None:
        """Move a settled capture folder into ``done/`` (under a free name there)."""
        done = self.inbox / DONE_DIR
        done.mkdir(exist_ok=True)
        name, k = folder.name, 1
        while os.path.lexists(done / name):  # only if done/ was changed by hand meanwhile
            k += 1
            name = _suffixed(folder.name, k)
        try:
            os.rename(folder, done / name)
        except OSError as e:
            raise InputError(f"hotfolder: cannot move {folder} to {done / name} ({e.strerror or e})") from None

    def _recover(self) -> list[Path]:
        """Reconcile what a crash left in ``processing/``: a capture settled downstream is
        filed in ``done/``; any other is returned (oldest first), to be inspected again
        under its name once what its unfinished inspection left downstream is discarded."""
        processing = self.inbox / PROCESSING_DIR
        if self.params.after != "move" or not processing.is_dir():
            return []
        again = []
        try:
            entries = sorted((p for p in processing.iterdir() if p.is_dir() and not p.name.startswith(".")), key=_age)
        except OSError as e:
            raise InputError(f"hotfolder: {processing}: cannot be read ({e.strerror or e})") from None
        for p in entries:
            if name_problem(p.name) is None and self.settled(p.name):
                self._file_away(p)  # inspected and recorded: only the move was missing
            else:
                self.discard(p.name)
                again.append(p)
        return again

    def _finish(self, folder: Path) -> None:
        """The consumer asks for the next capture: file this one away if it is settled."""
        self._seen.pop(folder.name, None)
        if self.params.after != "move":
            self._done.add(folder.name)  # kept in place: inspected once per run
            return
        if not folder.exists():
            return
        if name_problem(folder.name) is None and not self.settled(folder.name):
            return  # no result (a full disk) or no history row: inspected again at the next start
        self._file_away(folder)

    def acquire(self) -> Iterator[Acquisition]:
        from inspector.capture_folder import named_acquisition, read_capture

        n = 0
        last_new = self.clock()
        pending = self._recover()  # claimed before a crash: first, no settling (they were ready)
        while True:
            now = self.clock()
            handed = False
            batch, pending = (pending or self._candidates()), []
            for folder in batch:
                if folder.parent == self.inbox:  # not claimed yet
                    if not self._ready(folder, now):
                        continue
                    claimed = self._claim(folder)
                    if claimed is None:
                        continue
                    folder = claimed
                handed = True
                yield named_acquisition(folder, read_capture)
                # Resumed: the consumer has inspected it and written its result.
                self._finish(folder)
                n += 1
                last_new = now = self.clock()
                if self.params.count and n >= self.params.count:
                    return
            if not handed:
                if self.params.idle_exit_s and now - last_new >= self.params.idle_exit_s:
                    return
                self.sleep(self.params.poll_s)

    def close(self) -> None:
        """Release the inbox (its lock). A capture claimed but not finished stays in
        ``processing/``, first in line at the next start."""
        fd, self._lock_fd = self._lock_fd, None
        if fd is not None:
            os.close(fd)

    def __del__(self) -> None:
        self.close()
