"""Driver ``replay``: capture folders on disk (CONTRACT format).

Each path given is either a capture folder (it holds ``rig.json``) or a folder of capture
folders (batch); a path that is neither still yields one acquisition, whose loading fails
with a one-line reason, so the rest of the batch is inspected.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from inspector import hookimpl
from inspector.params import param
from inspector.registry import Acquisition, DriverRegistry, DriverSpec


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
            yield Acquisition(folder.name or str(folder), lambda folder=folder: read_capture(folder))

    def close(self) -> None:
        pass


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
