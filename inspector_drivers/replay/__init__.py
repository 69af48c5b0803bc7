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

from collections.abc import Iterator
from dataclasses import dataclass

from inspector import hookimpl
from inspector.params import param
from inspector.registry import Acquisition, DriverRegistry, DriverSpec
from inspector_drivers.replay import hotfolder


@dataclass(frozen=True)
class ReplayParams:
    captures: tuple[str, ...] = param((), "capture folders, or folders of capture folders (the CLI's --capture)")


@dataclass
class ReplayDriver:
    params: ReplayParams

    def acquire(self) -> Iterator[Acquisition]:
        from inspector.capture_folder import expand, named_acquisition, read_capture

        for folder in expand(self.params.captures):
            yield named_acquisition(folder, read_capture)

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
    registry.add(
        DriverSpec(
            name="hotfolder",
            open=hotfolder.HotFolderDriver,  # looked up when registered (a test may replace it)
            params=hotfolder.HotFolderParams,
            doc="Hot folder: capture folders another program drops in an inbox, inspected once complete, then moved to done/",
        )
    )
