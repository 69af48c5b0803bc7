"""Driver ``replay``: capture folders on disk (CONTRACT format).

Each path given is either a capture folder (it holds ``rig.json``) or a folder of capture
folders (batch); a path that is neither still yields one acquisition, whose loading fails
with a one-line reason, so the rest of the batch is inspected.

A capture is named after its folder's absolute path, as :func:`read_capture` names it
(``caps/a/..`` is ``caps``, ``.`` the current folder's name): a name that cannot name a
result folder (:func:`inspector.names.name_problem`: a reserved name such as ``recipes``,
a control character, the root folder's empty name) yields an acquisition whose loading
fails with that reason, under a name that no result folder can take.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from inspector import hookimpl
from inspector.params import param
from inspector.registry import Acquisition, DriverRegistry, DriverSpec

if TYPE_CHECKING:  # pragma: no cover
    from inspector.model import Capture


@dataclass(frozen=True)
class ReplayParams:
    captures: tuple[str, ...] = param((), "capture folders, or folders of capture folders (the CLI's --capture)")


def expand(paths: tuple[str, ...] | list[str]) -> list[Path]:
    """Capture folders named by ``paths`` (folders of captures are expanded, sorted)."""
    from inspector_drivers.replay.folder import is_capture_folder

    out: list[Path] = []
    for raw in paths:
        p = Path(raw)
        if p.is_dir() and not is_capture_folder(p):
            subs = sorted(q for q in p.iterdir() if q.is_dir() and is_capture_folder(q))
            if subs:
                out.extend(subs)
                continue
        out.append(p)
    return out


@dataclass
class ReplayDriver:
    params: ReplayParams

    def acquire(self) -> Iterator[Acquisition]:
        from inspector_drivers.replay.folder import read_capture

        for folder in expand(self.params.captures):
            yield named_acquisition(folder, read_capture)

    def close(self) -> None:
        pass


def named_acquisition(folder: Path, read: Callable[[Path], Capture]) -> Acquisition:
    """The acquisition of capture folder ``folder``, named once for every driver that reads
    folders (replay, hotfolder): after the folder, or refused when that name cannot name a
    result folder. A refused one keeps a printable name (control characters escaped, so
    never a valid one: no result folder is written for it) and fails to load with the reason.
    """
    from inspector.names import check_name, folder_name, name_problem, printable

    name = folder_name(folder)
    if name_problem(name) is None:
        return Acquisition(name, lambda: read(folder))
    shown = printable(name or str(folder))

    def refuse() -> Capture:
        check_name(name)
        raise AssertionError("unreachable")  # pragma: no cover

    return Acquisition(shown, refuse)


@hookimpl
def inspector_register_drivers(registry: DriverRegistry) -> None:
    registry.add(
        DriverSpec(
            name="replay",
            open=ReplayDriver,
            params=ReplayParams,
            doc="Capture folders on disk (rig.json, images/, background/, capture.json, truth/)",
        )
    )
    from inspector_drivers.replay.hotfolder import HotFolderDriver, HotFolderParams

    registry.add(
        DriverSpec(
            name="hotfolder",
            open=HotFolderDriver,
            params=HotFolderParams,
            doc="Hot folder: capture folders another program drops in an inbox, inspected once complete, then moved to done/",
        )
    )
