"""``inspector plugin new NAME``: write a complete plugin package.

    inspector plugin new acme [--stage] [--driver] [--hook] [--out DIR]

writes ``DIR/acme/`` (default: the current folder), a pip package that installs and passes
its own tests at once::

    pip install -e acme && pytest acme

* ``pyproject.toml``: distribution ``inspector-acme``, the entry point ``acme`` in the
  ``inspector`` group, pytest's ``inspector_plugins = ["acme"]`` (the fixtures of
  :mod:`inspector_tools.testing` then hold the built-ins plus this plugin only);
* ``inspector_acme/__init__.py``: the plugin (``INSPECTOR_API``, the ``@hookimpl`` functions);
* ``--stage``: ``classify.acme``, a stage that measures the reconstruction's bounding box and
  puts its size and class in ``context.extras`` (so they appear in ``result.json`` ``extras``
  and the history), with typed parameters and the plugin's recipe settings
  (``[plugins.acme]``);
* ``--driver``: ``acme``, a driver that yields the capture folders of a folder with the
  public capture reader (where a vendor SDK's frames would be turned into captures);
* ``--hook``: an ``inspector_on_result`` hook that appends each verdict to a JSON-lines file
  beside the result folders (where a PLC or MES would be told);
* ``tests/``: a test of each, with the shipped fixtures; ``README.md``.

With none of ``--stage``, ``--driver``, ``--hook``, all three are written.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from inspector import API_VERSION, __version__
from inspector.errors import RecipeError

__all__ = ["add_arguments", "run", "write_plugin"]

_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("name", metavar="NAME", help="the plugin's name: a lower-case identifier (entry point NAME, "
                                                "package inspector_NAME, distribution inspector-NAME)")
    p.add_argument("--stage", action="store_true", help="an example stage (classify.NAME) writing context.extras")
    p.add_argument("--driver", action="store_true", help="an example acquisition driver (NAME)")
    p.add_argument("--hook", action="store_true", help="an example inspector_on_result hook")
    p.add_argument("--out", default=".", metavar="DIR", help="where the package folder NAME/ is written (default: here)")


def run(args: argparse.Namespace) -> int:
    parts = {k for k in ("stage", "driver", "hook") if getattr(args, k)} or {"stage", "driver", "hook"}
    try:
        folder = write_plugin(args.name, Path(args.out), parts)
    except ValueError as e:
        raise RecipeError(f"plugin new: {e}") from None
    print(f"wrote {folder}/ ({', '.join(sorted(parts))}): now\n"
          f"    pip install -e {folder}\n"
          f"    pytest {folder}\n"
          f"    inspector plugins        # lists {args.name!r}")
    return 0


def write_plugin(name: str, out: Path, parts: set[str] | frozenset[str] = frozenset({"stage", "driver", "hook"})) -> Path:
    """Write the package ``out/name/``; its path. ValueError for a bad name or an existing folder."""
    if not _NAME.match(name):
        raise ValueError(f"{name!r} is not a lower-case identifier (letters, digits, _; e.g. 'acme')")
    unknown = set(parts) - {"stage", "driver", "hook"}
    if unknown or not parts:
        raise ValueError(f"parts must be among stage, driver, hook, got {sorted(parts)}")
    folder = out / name
    if folder.exists():
        raise ValueError(f"{folder} exists; choose another --out or remove it")
    major = API_VERSION.split(".")[0]
    v = {
        "name": name,
        "pkg": f"inspector_{name}",
        "dist": f"inspector-{name.replace('_', '-')}",
        "api": f">={API_VERSION},<{int(major) + 1}",
        "inspector_version": __version__,
        "Title": name.replace("_", " ").title().replace(" ", ""),
    }
    files: dict[str, str] = {
        "pyproject.toml": _PYPROJECT,
        "README.md": _README_HEAD + "".join(_README_PART[p] for p in ("stage", "driver", "hook") if p in parts)
        + _README_TAIL,
        f"{v['pkg']}/__init__.py": _init(parts),
        "tests/test_plugin.py": _TEST_HEAD + "".join(_TEST_PART[p] for p in ("stage", "driver", "hook") if p in parts),
    }
    if "stage" in parts:
        files[f"{v['pkg']}/stage.py"] = _STAGE
    if "driver" in parts:
        files[f"{v['pkg']}/driver.py"] = _DRIVER
    if "hook" in parts:
        files[f"{v['pkg']}/hooks.py"] = _HOOKS
    for rel, text in files.items():
        path = folder / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        for key, value in v.items():
            text = text.replace("{{" + key + "}}", value)
        path.write_text(text, encoding="utf-8")
    return folder


def _init(parts: set[str] | frozenset[str]) -> str:
    imports = ["hookimpl"]
    regs = []
    if parts & {"stage", "hook"}:
        imports.append("SettingsRegistry")
        regs.append('''


@hookimpl
def inspector_register_settings(registry: SettingsRegistry) -> None:
    """The recipe table [plugins.{{name}}], validated when a recipe is loaded."""
    registry.add(Settings, "{{name}}: the production line its outputs name")''')
    if "stage" in parts:
        imports.append("StageRegistry")
        regs.append('''


@hookimpl
def inspector_register_stages(registry: StageRegistry) -> None:
    from {{pkg}}.stage import STAGE

    registry.add(STAGE)''')
    if "driver" in parts:
        imports.append("DriverRegistry")
        regs.append('''


@hookimpl
def inspector_register_drivers(registry: DriverRegistry) -> None:
    from {{pkg}}.driver import DRIVER

    registry.add(DRIVER)''')
    if "hook" in parts:
        imports.append("InspectionResult")
        regs.append('''


@hookimpl
def inspector_on_result(result: InspectionResult, outdir: Path | None) -> None:
    """Called once per inspected capture, after its result folder was written."""
    from {{pkg}}.hooks import publish

    publish(result, outdir)''')
    settings = ""
    if parts & {"stage", "hook"}:
        imports.append("param")
        settings = '''


@dataclass(frozen=True)
class Settings:
    """``[plugins.{{name}}]`` in a recipe (every field optional: these are the defaults)."""

    line: str = param("line-1", "the production line, written with each result")'''
    return f'''"""Inspector plugin ``{{{{name}}}}`` (entry point ``{{{{name}}}}`` in the ``inspector`` group).

Only the ``@hookimpl`` functions live here; each imports its module when it is called, so
loading the plugin (every ``inspector`` command does) stays cheap.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from inspector.api import {", ".join(sorted(imports, key=str.lower))}

#: The plugin API this plugin is written for, checked when it loads (inspector.API_VERSION).
INSPECTOR_API = "{{{{api}}}}"{settings}{"".join(regs)}
'''


_PYPROJECT = '''[build-system]
requires = ["setuptools>=70"]
build-backend = "setuptools.build_meta"

[project]
name = "{{dist}}"
version = "0.1.0"
description = "Inspector plugin {{name}}"
readme = "README.md"
requires-python = ">=3.11"
# The plugin API range is INSPECTOR_API in {{pkg}}/__init__.py; this is the distribution.
dependencies = ["inspector-bcps>={{inspector_version}}"]

[project.optional-dependencies]
test = ["pytest>=8"]

# How Inspector finds the plugin: `inspector plugins` lists it as '{{name}}'
# (block it with INSPECTOR_BLOCK_PLUGINS={{name}} or inspector --block {{name}}).
[project.entry-points.inspector]
{{name}} = "{{pkg}}"

[tool.setuptools]
packages = ["{{pkg}}"]

[tool.pytest.ini_options]
testpaths = ["tests"]
# The fixtures shipped with Inspector (inspector_tools.testing) hold the built-ins plus these.
inspector_plugins = ["{{name}}"]
'''

_STAGE = '''"""Stage ``classify.{{name}}``: the part's bounding-box size (in the reference's frame) and a
size class.

What a stage puts in ``context.extras`` is kept: ``result.json`` ``extras``, the history
(``inspector history OUTDIR --json``) and ``InspectionResult.extras`` in ``on_result`` hooks.
Keys are best prefixed with the plugin's name; values must be JSON (numbers, strings,
lists, dicts; numpy numbers and arrays are converted).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from inspector.api import InspectionContext, StageError, StageSpec, param


@dataclass(frozen=True)
class Params:
    """``params = {...}`` of the stage in a recipe, checked when the recipe is loaded."""

    large_mm: float = param(50.0, "a part whose largest bounding-box side exceeds this is 'large', mm",
                            min=0.0, max=10000.0)


def run(context: InspectionContext, params: Params) -> InspectionContext:
    """Read the reconstruction, return a new context with the stage's extras."""
    points = context.need("bcps", "classify.{{name}}").points  # on the part's surface, world mm
    pose = context.need("alignment", "classify.{{name}}").pose  # reference -> world, 4x4
    if len(points) == 0:
        raise StageError("classify.{{name}}: no BCPS points to measure")
    # In the reference's frame: the part's own axes, whatever its pose in the rig.
    local = (np.asarray(points) - pose[:3, 3]) @ pose[:3, :3]
    size = np.ptp(local, axis=0)
    settings = context.settings.get("{{name}}")
    extras = {
        **context.extras,
        "{{name}}.size_mm": [round(float(x), 3) for x in size],
        "{{name}}.size_class": "large" if float(size.max()) > params.large_mm else "small",
        "{{name}}.line": settings.line if settings is not None else None,
    }
    return context.evolve(extras=extras)


STAGE = StageSpec(
    name="classify.{{name}}",
    run=run,
    params=Params,
    requires=("align", "bcps"),
    doc="bounding-box size and size class of the part (context.extras '{{name}}.*')",
)
'''

_DRIVER = '''"""Driver ``{{name}}``: the capture folders of a folder, oldest name first.

A driver for real hardware does the same with the vendor's SDK: in ``acquire``, wait for a
trigger, read one frame per camera, and yield an ``Acquisition(name, load)`` whose ``load()``
returns a ``Capture(rig, images)`` (see ``inspector.api.Capture``). The capture-folder
reader used here, ``inspector.api.read_capture``, checks everything (rig, image sizes,
limits) and raises a one-line ``CaptureError`` naming the file: that capture is then an
error, and the others go on.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from inspector.api import Acquisition, DriverSpec, RecipeError, is_capture_folder, param, read_capture


@dataclass(frozen=True)
class Params:
    """``[driver] params = {...}`` in a recipe (or ``inspector capture --param``)."""

    folder: str = param("", "the folder whose capture folders are acquired")
    count: int = param(0, "acquire at most this many captures (0: all)", min=0)


class Driver:
    def __init__(self, params: Params) -> None:
        folder = Path(params.folder)
        if not folder.is_dir():
            raise RecipeError(f"driver {{name}}: folder {params.folder!r} is not a folder")
        self.folder = folder
        self.params = params

    def acquire(self) -> Iterator[Acquisition]:
        captures = sorted(p for p in self.folder.iterdir() if is_capture_folder(p))
        if self.params.count:
            captures = captures[: self.params.count]
        for path in captures:
            yield Acquisition(path.name, lambda path=path: read_capture(path))

    def close(self) -> None:
        """Release the hardware (nothing to do for folders)."""


DRIVER = DriverSpec(name="{{name}}", open=Driver, params=Params,
                    doc="the capture folders of a folder (a template for a vendor SDK's driver)")
'''

_HOOKS = '''"""Publish each result: one JSON line per inspection in ``OUTDIR/{{name}}-results.jsonl``.

Where a PLC, MES or database would be told. A lifecycle hook is an observer: it must not
change what it receives; if it raises, that is one warning line naming the plugin and the
inspection goes on; its time is in ``result.json`` ``timings_s["hook:{{name}}:on_result"]``
and a call slower than the recipe's ``[budget] hook_s`` (1 s) is a warning.
"""

from __future__ import annotations

import json
from pathlib import Path

from inspector.api import InspectionResult

RESULTS_FILE = "{{name}}-results.jsonl"


def publish(result: InspectionResult, outdir: Path | None) -> None:
    if outdir is None:  # nothing was written for this capture (e.g. cancelled)
        return
    line = {"capture": result.capture, "verdict": result.verdict, "error": result.error,
            "extras": dict(result.extras)}
    with open(Path(outdir).parent / RESULTS_FILE, "a", encoding="utf-8") as f:
        f.write(json.dumps(line) + "\\n")
'''

_TEST_HEAD = '''"""Tests of plugin {{name}}, with the fixtures Inspector ships (inspector_tools.testing):
inspector_pm (the built-ins plus this plugin only), inspector_capture (a small simulated
capture), inspector_recipe (the built-in pipeline plus stages) and inspector_run.
"""

from __future__ import annotations

import json

import pytest

from inspector.api import RecipeError


def test_the_plugin_loads_without_a_problem(inspector_pm):
    assert "{{name}}" in inspector_pm.plugin_names()
    assert [p.message() for p in inspector_pm.problems if p.plugin.name == "{{name}}"] == []
'''

_TEST_PART = {
    "stage": '''

def test_the_stage_output_is_in_result_json_and_history(inspector_run, inspector_recipe, inspector_capture):
    recipe = inspector_recipe({"use": "classify.{{name}}"}, plugins={"{{name}}": {"line": "L7"}})
    run = inspector_run(recipe, inspector_capture("part"))
    assert run.exit_status == 0, run.result.result.error
    extras = run.result.extras
    assert extras["{{name}}.size_class"] == "small"
    assert extras["{{name}}.line"] == "L7"
    assert 25 < max(extras["{{name}}.size_mm"]) < 35  # the 30 mm cube
    assert run.history()[0]["extras"]["{{name}}.size_class"] == "small"


def test_stage_parameters_are_checked_when_the_recipe_loads(inspector_run, inspector_recipe, inspector_capture):
    recipe = inspector_recipe({"use": "classify.{{name}}", "params": {"large_mm": -1.0}})
    with pytest.raises(RecipeError, match="large_mm"):
        inspector_run(recipe, inspector_capture("part"))


def test_settings_are_checked_when_the_recipe_loads(inspector_run, inspector_recipe, inspector_capture):
    recipe = inspector_recipe(plugins={"{{name}}": {"line": 3}})
    with pytest.raises(RecipeError, match="plugins.{{name}}"):
        inspector_run(recipe, inspector_capture("part"))
''',
    "driver": '''

def test_the_driver_yields_the_captures_of_a_folder(inspector_pm, inspector_capture, tmp_path):
    import shutil

    from inspector.api import build_params

    shutil.copytree(inspector_capture("part"), tmp_path / "part")
    spec = inspector_pm.driver("{{name}}")
    driver = spec.open(build_params(spec.params, {"folder": str(tmp_path)}, "test"))
    try:
        acquisitions = list(driver.acquire())
    finally:
        driver.close()
    assert [a.name for a in acquisitions] == ["part"]
    capture = acquisitions[0].load()
    assert len(capture.rig.cameras) == 8 and set(capture.images) == {c.name for c in capture.rig.cameras}
''',
    "hook": '''

def test_the_hook_publishes_each_result(inspector_run, inspector_recipe, inspector_capture):
    run = inspector_run(inspector_recipe(), inspector_capture("part"))
    lines = (run.outdir / "{{name}}-results.jsonl").read_text().splitlines()
    assert [json.loads(x)["verdict"] for x in lines] == ["pass"]
    assert "hook:{{name}}:on_result" in run.result.json["timings_s"]
''',
}

_README_HEAD = '''# {{dist}}

An [Inspector](https://pypi.org/project/inspector-bcps/) plugin, written by
`inspector plugin new {{name}}`. Plugin API: `INSPECTOR_API = "{{api}}"` in
`{{pkg}}/__init__.py`.

    pip install -e .          # registers the entry point '{{name}}' (group 'inspector')
    pytest                    # its tests, with the fixtures Inspector ships
    inspector plugins         # lists '{{name}}', what it provides, and any problem

Block it without uninstalling: `inspector --block {{name}} ...` or
`INSPECTOR_BLOCK_PLUGINS={{name}}`. Try a change without installing:
`inspector --plugin path/to/module.py ...`.
'''

_README_PART = {
    "stage": '''
## Stage `classify.{{name}}` (`{{pkg}}/stage.py`)

Puts the part's bounding-box size and class in `context.extras`: they appear in each
`result.json` under `extras`, in the history (`inspector history OUT --json`) and in
`on_result` hooks. In a recipe, after the align and bcps stages:

    [[stages]]
    use = "classify.{{name}}"
    params = { large_mm = 50.0 }

    [plugins.{{name}}]        # the plugin's settings (optional; checked like parameters)
    line = "L3"
''',
    "driver": '''
## Driver `{{name}}` (`{{pkg}}/driver.py`)

Yields the capture folders of a folder through the public capture reader
(`inspector.api.read_capture`); replace it with your camera SDK's frames:

    [driver]
    use = "{{name}}"
    params = { folder = "captures/" }
''',
    "hook": '''
## Hook `inspector_on_result` (`{{pkg}}/hooks.py`)

Appends each verdict to `OUTDIR/{{name}}-results.jsonl`: where a PLC or MES would be told.
''',
}

_README_TAIL = '''
The hooks, the public API (`inspector.api`) and the fixtures are documented in Inspector's
`docs/plugins.md` (`inspector plugin reference`).
'''


if __name__ == "__main__":  # pragma: no cover
    sys.exit(run(argparse.Namespace(name=sys.argv[1], stage=False, driver=False, hook=False, out=".")))
