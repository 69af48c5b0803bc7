from __future__ import annotations

import inspect
import subprocess
import sys
from pathlib import Path

import pluggy
import pytest

from inspector import hookimpl, hookspecs
from inspector.manager import create_plugin_manager
from inspector.registry import StageSpec

HOOKS = sorted(n for n, f in vars(hookspecs).items() if n.startswith("inspector_") and callable(f))
BUILTIN_STAGES = {"segment.threshold", "carve.hull", "align.global_icp", "bcps.ray", "bcps.surface", "evaluate.tolerance"}


def test_builtins_come_through_the_entry_point_group(pm):
    assert {"segment", "carve", "align", "bcps", "evaluate", "sim", "replay"} <= set(pm.plugin_names())
    assert BUILTIN_STAGES <= set(pm.stages.names())
    assert {"sim", "replay"} <= set(pm.drivers.names())


def test_no_entrypoints_means_no_stages():
    pm = create_plugin_manager(load_entrypoints=False)
    assert pm.stages.names() == [] and pm.drivers.names() == []


def test_block_list(monkeypatch):
    monkeypatch.setenv("INSPECTOR_BLOCK_PLUGINS", "bcps, sim")
    pm = create_plugin_manager()
    assert "bcps.ray" not in pm.stages and "sim" not in pm.drivers
    assert "carve.hull" in pm.stages


def test_every_hook_is_documented_and_prefixed():
    assert HOOKS, "no hooks found"
    for name in HOOKS:
        doc = inspect.getdoc(getattr(hookspecs, name))
        assert doc and len(doc) > 20, f"{name} has no docstring"


def test_every_hook_is_exercised_by_a_test():
    """Meta-test (as datasette does): each hook name appears in some test module."""
    text = "".join(p.read_text() for p in Path(__file__).parents[1].rglob("test_*.py"))
    for name in HOOKS:
        assert name in text, f"no test exercises {name}"


def test_hookimpl_signature_is_checked():
    class Bad:
        @hookimpl
        def inspector_register_stages(self, registry, unknown_arg):
            pass

    with pytest.raises(pluggy.PluginValidationError):
        create_plugin_manager(load_entrypoints=False, plugins=[Bad()])


def test_third_party_stage_registers_like_a_builtin():
    class Plugin:
        @hookimpl
        def inspector_register_stages(self, registry):
            registry.add(StageSpec(name="classify.size", run=lambda ctx, p: ctx, doc="by size"))

    pm = create_plugin_manager(plugins=[Plugin()])
    assert "classify.size" in pm.stages


def test_duplicate_and_bad_kind_rejected():
    class Dup:
        @hookimpl
        def inspector_register_stages(self, registry):
            registry.add(StageSpec(name="carve.hull", run=lambda c, p: c))

    with pytest.raises(ValueError, match="registered twice"):
        _ = create_plugin_manager(plugins=[Dup()]).stages
    class Kind:
        @hookimpl
        def inspector_register_stages(self, registry):
            registry.add(StageSpec(name="paint.red", run=lambda c, p: c))

    with pytest.raises(ValueError, match="kind must be one of"):
        _ = create_plugin_manager(load_entrypoints=False, plugins=[Kind()]).stages


def test_import_inspector_is_light():
    code = (
        "import sys, inspector, inspector.manager, inspector.recipe, inspector.runner, inspector_frontends.cli\n"
        "import inspector.session, inspector.roles, inspector.recipe_form, inspector_frontends.gui, inspector.report, inspector_tools.bench.command\n"
        "heavy = [m for m in ('PySide6', 'PyQt5', 'PyQt6', 'vtk', 'pyvista', 'pyvistaqt', 'harvesters', 'gi', 'open3d', 'cv2', 'trimesh') if m in sys.modules]\n"
        "print(','.join(heavy))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"import inspector pulled in: {out.stdout.strip()}"


def test_only_the_gui_package_imports_qt_or_vtk():
    """The core, the CLI, the plugins and the drivers never import Qt, pyvista or VTK: an
    ``inspector run`` and every plugin load without them (read from the sources)."""
    import ast

    root = Path(__file__).parents[2]
    banned = {"PySide6", "PyQt5", "PyQt6", "pyvista", "pyvistaqt", "vtk", "vtkmodules", "qtpy"}
    offenders = []
    for folder in ("inspector", "plugins", "drivers"):
        for path in (root / folder).rglob("*.py"):
            if "gui" in path.relative_to(root).parts:
                continue
            for node in ast.walk(ast.parse(path.read_text())):
                names = [a.name for a in node.names] if isinstance(node, ast.Import) else (
                    [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
                offenders += [f"{path.relative_to(root)}: {n}" for n in names if n.split(".")[0] in banned]
    assert not offenders, offenders


def test_third_party_driver_registers_like_a_builtin():
    from inspector.registry import DriverSpec

    class Plugin:
        @hookimpl
        def inspector_register_drivers(self, registry):
            registry.add(DriverSpec(name="usb", open=lambda p: None, doc="a camera"))

    pm = create_plugin_manager(plugins=[Plugin()])
    assert "usb" in pm.drivers and "replay" in pm.drivers
