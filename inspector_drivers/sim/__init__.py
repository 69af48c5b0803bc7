"""Driver ``sim``: a simulated 16-camera spherical rig rendering a (defective) part.

Registered through the ``inspector`` entry-point group like any third-party driver, with
its sub-commands ``inspector simulate`` and ``inspector demo`` (:mod:`.commands`).
Heavy imports happen only when a capture is rendered.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from inspector import hookimpl
from inspector.model import Capture
from inspector.registry import Acquisition, CommandRegistry, DriverRegistry, DriverSpec
from inspector_drivers.sim.commands import COMMANDS
from inspector_drivers.sim.simulate import SimParams, sim_rig, simulate


@dataclass
class SimDriver:
    """Yields ``params.count`` simulated captures (capture i uses seed + i)."""

    params: SimParams

    def acquire(self) -> Iterator[Acquisition]:
        rig = sim_rig(self.params)
        for i in range(self.params.count):
            name = f"{self.params.part}-s{self.params.seed + i:04d}"

            def load(i: int = i, name: str = name) -> Capture:
                return simulate(self.params, i, rig, name=name)

            yield Acquisition(name, load)

    def close(self) -> None:
        pass


@hookimpl
def inspector_register_drivers(registry: DriverRegistry) -> None:
    registry.add(
        DriverSpec(
            name="sim",
            open=SimDriver,
            params=SimParams,
            doc="Simulated spherical rig: a built-in or given part, random pose, defects, anti-aliased noisy images",
        )
    )


@hookimpl
def inspector_register_commands(registry: CommandRegistry) -> None:
    for spec in COMMANDS:
        registry.add(spec)
