"""Plugin ``opcua``: ``inspector serve``, an OPC UA server a PLC triggers.

Registered through the ``inspector`` entry-point group like any plugin; it adds the
sub-command ``serve`` (:mod:`.cli`). The information model is :mod:`.model`, the server
:mod:`.server` (asyncua, imported only when the command runs: building a plugin manager or
``import inspector`` never loads it) with its address space :mod:`.address_space`, a
trigger's job :mod:`.triggers` and the published record :mod:`.records`, the settings
:mod:`.config`, certificates and users :mod:`.security`, the benchmark :mod:`.bench` (``inspector bench --opcua``). A PLC-side
example client is ``examples/plc_client.py``.
"""

from __future__ import annotations

from inspector import hookimpl
from inspector.registry import CommandRegistry, CommandSpec
from inspector_frontends.opcua.cli import add_parser, run


@hookimpl
def inspector_register_commands(registry: CommandRegistry) -> None:
    """``inspector serve``."""
    registry.add(CommandSpec("serve", add_parser, run, "OPC UA server for a PLC: PartId, Trigger -> Verdict, ResultCounter"))
