"""Pytest fixtures for plugin authors, shipped with the product (a pytest plugin).

``pyproject.toml`` declares it in the ``pytest11`` entry-point group, so wherever
``inspector-bcps`` is installed, a plugin's own tests get these fixtures without a
``conftest.py`` (as pytest's ``pytester``, napari's ``make_napari_viewer`` or datasette's test
client):

``inspector_pm``
    A fresh, *isolated* :class:`~inspector.manager.PluginManager`: the built-in plugins plus
    only the plugins under test, so a broken plugin elsewhere on the machine cannot fail
    these tests, and ``INSPECTOR_BLOCK_PLUGINS`` does not apply. A plugin under test that
    does not load, or reports a problem, fails the test with its one-line message.

    Name the plugins under test (entry-point names) with a marker, an ini option, or by
    overriding the fixture ``inspector_plugins_under_test`` in a ``conftest.py``::

        @pytest.mark.inspector_plugins("acme")          # one test or module (pytestmark)
        [tool.pytest.ini_options] inspector_plugins = ["acme"]   # the whole suite

    A module that is not installed can be registered from code instead:
    ``@pytest.mark.inspector_plugins(modules=[my_module])``.

``inspector_capture``
    A factory: ``inspector_capture(name="part", part="cube30", seed=0, bumps=(), **sim)``
    writes a capture folder (CONTRACT layout) rendered by the built-in simulated rig and
    returns its path. Small and fast by default: 8 cameras of 256 x 256 px at 0.4 mm/px
    (about a second); captures of the same parameters are made once per test session and
    shared, so treat them as read-only.

``inspector_recipe``
    A factory: ``inspector_recipe(*stages, plugins=None, base=SMALL_RECIPE, **tables)``
    writes a recipe file: the built-in pipeline sized for those captures
    (:data:`SMALL_RECIPE`, tolerance +-0.5 mm) with ``stages`` (``[[stages]]`` tables such
    as ``{"use": "classify.size"}``) appended and ``plugins`` as its ``[plugins.NAME]``
    tables; returns its path.

``inspector_run``
    A helper: ``inspector_run(recipe, *captures, csv=False, reference=None)`` runs the
    recipe (a path, a TOML string or a dict) on the captures through the same session as
    ``inspector run``, with ``inspector_pm``, into a fresh folder, and returns a
    :class:`RunResult`: the :class:`~inspector.model.InspectionResult` of each capture,
    its ``result.json``, its folder, the run's exit status, and the history rows.

This module imports only pytest and the light core at import time; numpy, the pipeline and
the simulator are imported when a fixture is used.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from inspector.errors import PluginError
from inspector.params import build_params

if TYPE_CHECKING:
    from inspector.manager import PluginManager
    from inspector.model import InspectionResult

__all__ = [
    "SMALL_CAPTURE",
    "SMALL_RECIPE",
    "RunResult",
    "CaptureResult",
    "make_plugin_manager",
    "simulate_capture",
    "write_recipe",
    "run_recipe",
]

#: Simulator parameters of :func:`simulate_capture`'s default capture: small and fast.
SMALL_CAPTURE: dict[str, Any] = {"part": "cube30", "cameras": 8, "width": 256, "height": 256, "mm_per_px": 0.4}

#: The built-in pipeline sized for :data:`SMALL_CAPTURE` (what ``inspector_recipe`` extends).
SMALL_RECIPE: dict[str, Any] = {
    "recipe": {"name": "plugin-test", "reference": "builtin:cube30"},
    "driver": {"use": "replay"},
    "stages": [
        {"use": "segment.threshold"},
        {"use": "carve.hull", "params": {"voxel_mm": 1.0}},
        {"use": "align.global_icp"},
        {"use": "bcps.ray"},
        {"use": "evaluate.tolerance"},
    ],
    "tolerance": {"default": {"lower": -0.5, "upper": 0.5}},
}


# ----------------------------------------------------------------------------- functions
def make_plugin_manager(names: Sequence[str] = (), modules: Sequence[object] = (), *,
                        strict: bool = True) -> PluginManager:
    """An isolated plugin manager: the built-ins, the entry points ``names`` and the
    ``modules`` registered from code; the environment's block list does not apply.

    ``strict``: a named plugin that is not installed, does not load or reports a problem
    raises :class:`~inspector.errors.PluginError` with its one-line message.
    """
    # lazy: inspector.manager loads numpy and inspector.model, which a pytest session
    # that never uses these fixtures should not pay for (tests/tools/test_plugin_kit.py).
    from inspector.manager import create_plugin_manager

    lines: list[str] = []
    pm = create_plugin_manager(only=names, block=(), plugins=modules, warn=lines.append)
    if strict:
        for name in names:
            problems = [p.message() for p in pm.problems if p.plugin.name == name]
            if problems:
                raise PluginError(problems[0])
            if name not in pm.plugin_names():
                raise PluginError(f"plugin {name!r} is not installed (no entry point {name!r} in the 'inspector' "
                                  f"group): pip install -e . in its project folder")
    return pm


def simulate_capture(folder: str | Path, pm: PluginManager | None = None, **params: Any) -> Path:
    """Render one capture with the built-in ``sim`` driver (``params``: its parameters, over
    :data:`SMALL_CAPTURE`) and write it as a capture folder ``folder``; its path."""
    from inspector.api import save_capture
    if pm is None:
        pm = make_plugin_manager()
    spec = pm.driver("sim")
    table = {**SMALL_CAPTURE, **params, "count": 1}
    driver = spec.open(build_params(spec.params, table, "inspector_capture"))
    try:
        acquisition = next(iter(driver.acquire()))
        capture = acquisition.load()
    finally:
        driver.close()
    return Path(save_capture(capture, Path(folder), overwrite=True))


def write_recipe(path: str | Path, recipe: Mapping[str, Any] | str) -> Path:
    """Write ``recipe`` (a TOML document as a dict, or its text) to ``path``; its path."""
    path = Path(path)
    if isinstance(recipe, str):
        path.write_text(recipe, encoding="utf-8")
    else:
        import tomli_w

        path.write_text(tomli_w.dumps(_plain(recipe)), encoding="utf-8")
    return path


def _plain(value: Any) -> Any:
    """Tuples as lists, Paths as strings: what TOML can write."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return value


@dataclass
class CaptureResult:
    """One capture's outcome in a :class:`RunResult`.

    Attributes
    ----------
    result : InspectionResult
        What the runner produced (what ``inspector_on_result`` received).
    json : dict
        The capture's ``result.json`` (empty when no result folder was written).
    folder : Path
        Its result folder, ``OUTDIR/<capture>/``.
    """

    result: InspectionResult
    json: dict[str, Any]
    folder: Path

    @property
    def verdict(self) -> str:
        return self.result.verdict

    @property
    def extras(self) -> Mapping[str, Any]:
        """``result.json`` ``extras``: what the stages put in ``context.extras``."""
        value = self.json.get("extras", {})
        return value if isinstance(value, Mapping) else {}


@dataclass
class RunResult:
    """What :func:`run_recipe` returns.

    Attributes
    ----------
    outdir : Path
        The run's result folder.
    exit_status : int
        What ``inspector run`` would have exited with (CONTRACT: 0, 1, 3).
    captures : list of CaptureResult
        In the order inspected.
    """

    outdir: Path
    exit_status: int
    captures: list[CaptureResult] = field(default_factory=list)

    def __getitem__(self, name: str | int) -> CaptureResult:
        if isinstance(name, int):
            return self.captures[name]
        for c in self.captures:
            if c.result.capture == name:
                return c
        raise KeyError(name)

    @property
    def result(self) -> CaptureResult:
        """The only capture's outcome (a run of one capture)."""
        if len(self.captures) != 1:
            raise ValueError(f"{len(self.captures)} captures were inspected; index by name")
        return self.captures[0]

    def history(self) -> list[dict[str, Any]]:
        """The run's ``history.sqlite`` rows, oldest first (the built-in ``history`` plugin),
        their ``extras`` and ``metadata`` JSON columns decoded."""
        # lazy: the history store loads numpy (inspector.model), which pytest loading this plugin must not
        from inspector.history_store import read_history

        rows = read_history(self.outdir)
        for row in rows:
            for key in ("extras", "metadata"):
                if isinstance(row.get(key), str):
                    row[key] = json.loads(row[key])
        return rows


def run_recipe(recipe: str | Path | Mapping[str, Any], captures: Sequence[str | Path], outdir: str | Path, *,
               pm: PluginManager | None = None, reference: str | None = None, csv: bool = False) -> RunResult:
    """Run ``recipe`` (a file, a TOML string or a dict) on capture folders into ``outdir``
    through :class:`inspector.session.Session`, exactly as ``inspector run`` does."""
    from inspector.session import Inspected, Session, Source

    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    if isinstance(recipe, Mapping) or (isinstance(recipe, str) and "\n" in recipe):
        recipe = write_recipe(outdir.parent / f"{outdir.name}.recipe.toml", recipe)
    session = Session.open(str(recipe), outdir, reference=reference, pm=pm or make_plugin_manager(), csv=csv)
    results: list[InspectionResult] = []

    def keep(event: object) -> None:
        if isinstance(event, Inspected):
            results.append(event.outcome.result)

    session.subscribe(keep)
    try:
        summary = session.run(Source(captures=tuple(str(c) for c in captures)))
    finally:
        session.close()
    run = RunResult(outdir, summary.exit_status)
    for res in results:
        folder = outdir / res.capture
        doc = json.loads((folder / "result.json").read_text()) if (folder / "result.json").is_file() else {}
        run.captures.append(CaptureResult(res, doc, folder))
    return run


# ----------------------------------------------------------------------------- pytest
def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addini("inspector_plugins", type="args", default=[],
                  help="entry-point names of the plugins under test (inspector_pm loads only these and the built-ins)")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        "inspector_plugins(*names, modules=()): the plugins under test that inspector_pm holds besides the built-ins "
        "(entry-point names; modules: objects registered from code)")


@pytest.fixture
def inspector_plugins_under_test(request: pytest.FixtureRequest) -> tuple[tuple[str, ...], tuple[object, ...]]:
    """``(entry-point names, modules)`` of the plugins under test: from the nearest
    ``inspector_plugins`` marker, else the ``inspector_plugins`` ini option. Override it in
    a ``conftest.py`` to name them in code."""
    marker = request.node.get_closest_marker("inspector_plugins")
    if marker is not None:
        return tuple(marker.args), tuple(marker.kwargs.get("modules", ()))
    return tuple(request.config.getini("inspector_plugins")), ()


@pytest.fixture
def inspector_pm(inspector_plugins_under_test: tuple[tuple[str, ...], tuple[object, ...]]) -> PluginManager:
    """A fresh isolated plugin manager: the built-ins plus the plugins under test."""
    names, modules = inspector_plugins_under_test
    try:
        return make_plugin_manager(names, modules)
    except PluginError as e:
        pytest.fail(str(e), pytrace=False)


@pytest.fixture(scope="session")
def _inspector_capture_cache(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return {}


@pytest.fixture
def inspector_capture(_inspector_capture_cache: dict[str, Path],
                      tmp_path_factory: pytest.TempPathFactory) -> Callable[..., Path]:
    """Factory: ``inspector_capture(name="part", **sim_params) -> Path`` of a simulated
    capture folder (8 cameras, 256 px, 0.4 mm/px unless told otherwise), made once per
    session for the same arguments."""

    def make(name: str = "part", **params: Any) -> Path:
        key = json.dumps([name, _plain(params)], sort_keys=True, default=str)
        if key not in _inspector_capture_cache:
            root = tmp_path_factory.mktemp("inspector-captures")
            _inspector_capture_cache[key] = simulate_capture(root / name, **params)
        return _inspector_capture_cache[key]

    return make


@pytest.fixture
def inspector_recipe(tmp_path: Path) -> Callable[..., Path]:
    """Factory: ``inspector_recipe(*stages, plugins=None, base=SMALL_RECIPE, **tables) ->
    Path`` of a recipe file: ``base`` with ``stages`` appended, ``plugins`` as its
    ``[plugins.NAME]`` tables, and any other top-level table replaced."""
    count = iter(range(1_000_000))

    def make(*stages: Mapping[str, Any], plugins: Mapping[str, Mapping[str, Any]] | None = None,
             base: Mapping[str, Any] = SMALL_RECIPE, **tables: Any) -> Path:
        doc = json.loads(json.dumps(_plain(base)))
        doc["stages"] = [*doc.get("stages", []), *(dict(s) for s in stages)]
        if plugins:
            doc["plugins"] = _plain(plugins)
        doc.update(_plain(tables))
        return write_recipe(tmp_path / f"recipe-{next(count)}.toml", doc)

    return make


@pytest.fixture
def inspector_run(inspector_pm: PluginManager, tmp_path: Path) -> Iterator[Callable[..., RunResult]]:
    """Helper: ``inspector_run(recipe, *captures, csv=False, reference=None) -> RunResult``,
    each call into a fresh result folder, with ``inspector_pm``."""
    count = iter(range(1_000_000))

    def run(recipe: str | Path | Mapping[str, Any], *captures: str | Path, csv: bool = False,
            reference: str | None = None) -> RunResult:
        return run_recipe(recipe, captures, tmp_path / f"out-{next(count)}", pm=inspector_pm, reference=reference,
                          csv=csv)

    yield run
