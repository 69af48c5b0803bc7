"""Driver ``hotfolder``: inspect capture folders as another program drops them in an inbox.

The production-line mode of the headless runner::

    inspector run recipes/default.toml --watch INBOX --out OUT --reference part.stl

Outside programs write capture folders (CONTRACT) into ``INBOX``. A folder is handed to the
runner once it is complete and quiet:

* ``rig.json`` exists and parses, and ``images/`` holds a PNG for every camera it names
  (:func:`~inspector_drivers.replay.folder.write_capture` writes ``rig.json`` last, so its
  folders are complete as soon as ``rig.json`` appears; other writers need not be);
* nothing in the folder changed (names, sizes, modification times) for ``settle_s``.

A folder that stays incomplete is handed over anyway once it has not changed for
``give_up_s``: the runner then reports what is missing (``camera cam03 has no image``),
so a broken writer shows up as an error result instead of a silent backlog.

After the runner has written a capture's result, its folder is moved to ``INBOX/done/``
(``after = "move"``, atomic on one file system), so nothing is inspected twice, even across
restarts, and nothing is deleted. A folder whose name is already used, in ``done/`` or
downstream (the CLI: ``OUTDIR/<name>/`` exists: a reused part number), is renamed
``NAME-2``, ``NAME-3``... in the inbox before it is read, so its result never overwrites an
earlier one and the result folder keeps the capture folder's name. A name reserved in the
result folder (``history.sqlite``, ``recipes``: :data:`inspector.names.RESERVED`) is renamed
the same way; a name no result folder can take (a control character, bytes that are not
UTF-8) is reported as an error in one line and the folder is moved to ``done/``
(:func:`~inspector_drivers.replay.named_acquisition`). With ``after = "keep"`` folders stay
where they are and each is inspected once per run. Folders already in the inbox at start
(a backlog) come first, oldest first. Names starting with ``.`` or ending in
``.tmp``/``.partial`` are ignored (writers' temporary folders), and so is ``done/``.

The watch ends after ``count`` captures, after ``idle_exit_s`` without a new one (0:
never), or on Ctrl-C (results written so far are kept).
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
from inspector.names import RESERVED
from inspector.params import check_params, param
from inspector.registry import Acquisition

__all__ = ["HotFolderParams", "HotFolderDriver", "DONE_DIR", "folder_state"]

#: Sub-folder of the inbox that receives inspected capture folders.
DONE_DIR = "done"
_TEMP_SUFFIXES = (".tmp", ".partial")


@dataclass(frozen=True)
class HotFolderParams:
    folder: str = param("", "the inbox: capture folders appear in it (the CLI's --watch)")
    settle_s: float = param(0.5, "a complete folder must be unchanged this long before it is read, s", min=0.0, max=3600.0)
    give_up_s: float = param(30.0, "an incomplete folder unchanged this long is handed over anyway (the result names what is missing), s", min=0.0, max=86400.0)
    poll_s: float = param(0.2, "how often the inbox is scanned, s", min=0.01, max=60.0)
    idle_exit_s: float = param(0.0, "stop after this long without a new capture, s (0: never)", min=0.0, max=604800.0)
    count: int = param(0, "stop after this many captures (0: no limit)", min=0)
    after: Literal["move", "keep"] = param("move", "what becomes of an inspected folder: moved to INBOX/done/, or kept in place")

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
    """rig.json parses and every camera it names has an image (cheap; never raises).

    Within the input bounds (:mod:`inspector.limits`): a huge or deeply nested rig.json is
    never complete, so it is handed over after ``give_up_s`` and its result says why.
    """
    try:
        data = load_json(folder / "rig.json", "rig.json")
        cameras = data["cameras"]
        if len(cameras) > limit("MAX_CAMERAS"):
            return False
        names = [c["name"] for c in cameras]
        return bool(names) and all((folder / "images" / f"{n}.png").is_file() for n in names)
    except (InspectorError, OSError, ValueError, KeyError, TypeError):
        return False


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
    """Yields one :class:`Acquisition` per capture folder that lands in ``params.folder``."""

    params: HotFolderParams
    clock: Callable[[], float] = time.monotonic
    sleep: Callable[[float], None] = time.sleep
    #: Whether a capture name is already used downstream (the CLI: a result folder of that
    #: name exists). Such a folder is renamed ``NAME-2``, ``-3``... before it is read, so a
    #: reused part number never overwrites an earlier result.
    taken: Callable[[str], bool] = lambda name: False
    _seen: dict[str, _Seen] = field(default_factory=dict)
    _done: set[str] = field(default_factory=set)

    def __post_init__(self) -> None:
        inbox = Path(self.params.folder)
        if not self.params.folder:
            raise RecipeError("hotfolder: no inbox folder given (--watch DIR, or the driver's folder parameter)")
        if not inbox.is_dir():
            raise RecipeError(f"hotfolder: inbox {inbox}: not a folder")

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
            if n == DONE_DIR or n.startswith(".") or n.endswith(_TEMP_SUFFIXES) or n in self._done:
                continue
            if p.is_dir():
                out.append(p)

        def age(p: Path) -> tuple[float, str]:
            try:
                return (p.stat().st_mtime, p.name)
            except OSError:
                return (float("inf"), p.name)

        return sorted(out, key=age)

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

    def _unique(self, folder: Path) -> Path:
        """``folder``, renamed in the inbox if its name is taken downstream or in done/."""
        done = self.inbox / DONE_DIR
        name, k = folder.name, 1
        while name in RESERVED or self.taken(name) or (self.params.after == "move" and (done / name).exists()):
            k += 1
            name = _suffixed(folder.name, k)
        if name == folder.name:
            return folder
        target = folder.with_name(name)
        try:
            folder.rename(target)
        except OSError as e:
            raise InputError(f"hotfolder: cannot rename {folder} to {target} ({e.strerror or e})") from None
        self._seen.pop(folder.name, None)
        return target

    def _finish(self, folder: Path) -> None:
        """The runner has written this capture's result: file the folder away."""
        self._seen.pop(folder.name, None)
        if self.params.after != "move":
            self._done.add(folder.name)  # kept in place: inspected once per run
            return
        if not folder.exists():
            return
        done = self.inbox / DONE_DIR
        done.mkdir(exist_ok=True)
        target = done / folder.name  # free: _unique chose the name
        try:
            folder.rename(target)
        except OSError as e:
            raise InputError(f"hotfolder: cannot move {folder} to {target} ({e.strerror or e})") from None

    def acquire(self) -> Iterator[Acquisition]:
        from inspector_drivers.replay import named_acquisition
        from inspector_drivers.replay.folder import read_capture

        n = 0
        last_new = self.clock()
        while True:
            now = self.clock()
            handed = False
            for folder in self._candidates():
                if not self._ready(folder, now):
                    continue
                handed = True
                folder = self._unique(folder)
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
        pass
