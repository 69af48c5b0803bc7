"""Recipes: TOML files that name the driver, the ordered stages and the tolerances.

A recipe is validated completely when it is loaded (every table, key, type, range, stage
name, stage order and file), and refused with one :class:`~inspector.errors.RecipeError`
naming the file and the key. A loaded :class:`Recipe` cannot fail half-way for
configuration reasons.

Layout::

    [recipe]
    name = "cube-30"
    reference = "parts/cube_30.stl"     # or "builtin:cube30"; relative to the recipe
    [driver]
    use = "replay"
    params = {}
    [[stages]]
    name = "segment"                    # optional; defaults to the stage's kind
    use = "segment.threshold"
    params = { polarity = "auto" }
    ...
    [tolerance]
    default = { lower = -0.1, upper = 0.1 }
    [[tolerance.regions]]
    name = "flange"
    box_min = [-15, -15, 10]
    box_max = [15, 15, 15]
    lower = -0.05
    upper = 0.05
    [outputs]                           # optional
    csv = true                          # also bcps_points.csv and regions.csv (inspector run --csv)
    [budget]                            # optional; else INSPECTOR_STAGE_BUDGET_S / _HOOK_BUDGET_S
    stage_s = 60.0                      # a stage slower than this is a warning naming it
    hook_s = 1.0                        # a plugin's lifecycle hook slower than this, too
    [plugins.acme]                      # optional: plugin acme's settings (inspector_register_settings),
    line = "L3"                         # validated like stage parameters; never code to load
    [[characteristics]]                 # optional: measured characteristics (docs/characteristics.md),
    id = "1"                            # checked against the reference's features at load
    kind = "diameter"
    feature = "F14"
    lower = -0.05
    upper = 0.05
"""

from __future__ import annotations

import math
import os
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from inspector.characteristics.definitions import SETTINGS_KEY, measured_in, parse_characteristics
from inspector.errors import RecipeError
from inspector.params import build_params, param
from inspector.pipeline import Band, Region, Tolerance
from inspector.registry import DriverSpec, StageSpec

if TYPE_CHECKING:
    from inspector.manager import PluginManager

__all__ = ["Step", "DriverStep", "Outputs", "Budget", "BUDGET_ENV", "Recipe", "load_recipe", "parse_recipe",
           "read_recipe_toml", "rig_problems"]


@dataclass(frozen=True)
class Outputs:
    """``[outputs]``: optional result files, beside the CONTRACT ones."""

    csv: bool = param(False, "also write bcps_points.csv (per-point deviations) and regions.csv (per-region "
                             "summary) in each result folder (inspector run --csv)")


@dataclass(frozen=True)
class Budget:
    """``[budget]``: how long a stage, or a plugin's lifecycle hook, may take before it is a
    warning naming it (in ``result.json`` ``stats.warnings`` and on stderr, once per run),
    and the watchdog's limits (:mod:`inspector.watchdog`): past ``stage_limit_s`` or
    ``inspection_limit_s`` the part is given up as ``error`` and the cell goes on."""

    stage_s: float = param(60.0, "seconds a stage may take on one capture", min=0.001, max=86400.0)
    hook_s: float = param(1.0, "seconds one call of a plugin's lifecycle hook (on_result...) may take",
                          min=0.001, max=86400.0)
    stage_limit_s: float = param(120.0, "seconds after which a stage is given up: the part is 'error' naming the "
                                 "stage and its plugin, and the cell goes on with the next part", min=0.01, max=86400.0)
    inspection_limit_s: float = param(300.0, "seconds one inspection (all its stages) may take before it is given "
                                      "up as 'error'", min=0.01, max=86400.0)


#: Environment variables for the budget when the recipe does not set it.
BUDGET_ENV = {"stage_s": "INSPECTOR_STAGE_BUDGET_S", "hook_s": "INSPECTOR_HOOK_BUDGET_S",
              "stage_limit_s": "INSPECTOR_STAGE_LIMIT_S", "inspection_limit_s": "INSPECTOR_INSPECTION_LIMIT_S"}


@dataclass(frozen=True)
class Step:
    """One stage of a recipe: its name in the recipe, its spec and validated params."""

    name: str
    spec: StageSpec
    params: Any


@dataclass(frozen=True)
class DriverStep:
    spec: DriverSpec
    params: Any


@dataclass(frozen=True)
class Recipe:
    """A validated recipe.

    Attributes
    ----------
    name : str
    path : Path or None
    reference : str or None
        ``builtin:NAME`` or an absolute path to the reference mesh.
    driver : DriverStep
    steps : tuple of Step
    tolerance : Tolerance
    sha256 : str or None
        Hex SHA-256 of the recipe file's bytes (None for a recipe built from a table):
        what an inspection's result and report name as "the recipe", exactly.
    outputs : Outputs
        ``[outputs]``: optional result files (CSV).
    budget : Budget
        ``[budget]``, else the environment (:data:`BUDGET_ENV`), else the defaults.
    plugins : mapping
        Plugin name -> its validated settings (``[plugins.NAME]``, the defaults when the
        recipe has no table), for every loaded plugin that declares settings; and
        ``"characteristics"`` -> :attr:`characteristics` when the recipe has some.
    characteristics : tuple of Characteristic
        ``[[characteristics]]`` (:mod:`inspector.characteristics.definitions`), checked
        against the reference's features at load; () when none.
    """

    name: str
    path: Path | None
    reference: str | None
    driver: DriverStep
    steps: tuple[Step, ...]
    tolerance: Tolerance
    sha256: str | None = None
    outputs: Outputs = field(default_factory=Outputs)
    budget: Budget = field(default_factory=Budget)
    plugins: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))
    characteristics: tuple[Any, ...] = ()


def _table(value: Any, where: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise RecipeError(f"{where}: expected a table, got {value!r}")
    return value


def _only(table: Mapping[str, Any], allowed: set[str], where: str) -> None:
    extra = sorted(set(table) - allowed)
    if extra:
        raise RecipeError(f"{where}: unknown key {extra[0]!r} (expected {', '.join(sorted(allowed))})")


def _number(table: Mapping[str, Any], key: str, where: str) -> float:
    if key not in table:
        raise RecipeError(f"{where}: missing key {key!r}")
    v = table[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise RecipeError(f"{where}.{key}: expected a number, got {v!r}")
    return _finite(v, f"{where}.{key}")


def _finite(v: int | float, where: str) -> float:
    """``v`` as a float, refused unless finite: an infinite limit passes every part, and a
    NaN passes every comparison."""
    try:
        f = float(v)
    except OverflowError:  # an integer beyond any float
        f = math.inf
    if not math.isfinite(f):
        raise RecipeError(f"{where}: expected a finite number, got {v!r}")
    return f


def _band(table: Mapping[str, Any], where: str) -> Band:
    lower, upper = _number(table, "lower", where), _number(table, "upper", where)
    if not lower <= 0 <= upper:
        raise RecipeError(f"{where}: expected lower <= 0 <= upper, got lower={lower}, upper={upper}")
    return Band(lower, upper)


def _vec3(table: Mapping[str, Any], key: str, where: str) -> tuple[float, float, float]:
    v = table.get(key)
    if not isinstance(v, list) or len(v) != 3 or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
        raise RecipeError(f"{where}.{key}: expected 3 numbers, got {v!r}")
    x, y, z = (_finite(c, f"{where}.{key}[{i}]") for i, c in enumerate(v))
    return (x, y, z)


def _tolerance(raw: Any, where: str) -> Tolerance:
    if raw is None:
        return Tolerance()
    t = _table(raw, where)
    _only(t, {"default", "regions"}, where)
    default = _band(_table(t["default"], f"{where}.default"), f"{where}.default") if "default" in t else Tolerance().default
    regions = []
    raw_regions = t.get("regions", [])
    if not isinstance(raw_regions, list):
        raise RecipeError(f"{where}.regions: expected an array of tables")
    for i, r in enumerate(raw_regions):
        w = f"{where}.regions[{i}]"
        r = _table(r, w)
        _only(r, {"name", "box_min", "box_max", "lower", "upper"}, w)
        name = r.get("name")
        if not isinstance(name, str) or not name:
            raise RecipeError(f"{w}.name: expected a non-empty string")
        lo, hi = _vec3(r, "box_min", w), _vec3(r, "box_max", w)
        if any(a > b for a, b in zip(lo, hi)):
            raise RecipeError(f"{w}: box_min must be <= box_max")
        regions.append(Region(name, lo, hi, _band(r, w)))
    return Tolerance(default, tuple(regions))


def parse_recipe(data: Mapping[str, Any], pm: PluginManager, *, path: Path | None = None,
                 reference: str | None = None) -> Recipe:
    """Validate a parsed TOML document against the registered stages and drivers.

    Parameters
    ----------
    data : mapping
        The TOML document.
    pm : inspector.manager.PluginManager
        Its stages and drivers; a name it lacks is refused with
        :meth:`~inspector.manager.PluginManager.missing` (naming a disabled plugin).
    path : Path, optional
        The recipe file (for messages and relative paths).
    reference : str, optional
        Overrides ``recipe.reference`` (the ``--reference`` option).
    """
    label = path.name if path is not None else "<recipe>"
    base = path.parent if path is not None else Path.cwd()
    _only(data, {"recipe", "driver", "stages", "tolerance", "outputs", "budget", "plugins", "characteristics"}, label)

    head = _table(data.get("recipe", {}), f"{label}: recipe")
    _only(head, {"name", "reference", "description"}, f"{label}: recipe")
    name = head.get("name", path.stem if path else "recipe")
    if not isinstance(name, str):
        raise RecipeError(f"{label}: recipe.name: expected a string")

    ref = reference if reference is not None else head.get("reference")
    if ref is not None:
        if not isinstance(ref, str) or not ref:
            raise RecipeError(f"{label}: recipe.reference: expected a file path or builtin:NAME")
        if not ref.startswith("builtin:"):
            p = Path(ref).expanduser()
            if reference is None and not p.is_absolute():
                p = base / p
            if not p.is_file():
                where = "--reference" if reference is not None else f"{label}: recipe.reference"
                raise RecipeError(f"{where}: file not found: {p}")
            ref = str(p.resolve())

    drv = _table(data.get("driver", {"use": "replay"}), f"{label}: driver")
    _only(drv, {"use", "params"}, f"{label}: driver")
    use = drv.get("use", "replay")
    if not isinstance(use, str) or use not in pm.drivers:
        raise RecipeError(f"{label}: driver.use: {pm.missing('driver', str(use))}")
    dspec: DriverSpec = pm.driver(use)
    driver = DriverStep(dspec, build_params(dspec.params, drv.get("params"), f"{label}: driver.params", base))

    raw_stages = data.get("stages")
    if not isinstance(raw_stages, list) or not raw_stages:
        raise RecipeError(f"{label}: stages: expected at least one [[stages]] table")
    steps: list[Step] = []
    seen_kinds: set[str] = set()
    seen_names: set[str] = set()
    for i, raw in enumerate(raw_stages):
        w = f"{label}: stages[{i}]"
        st = _table(raw, w)
        _only(st, {"name", "use", "params"}, w)
        use = st.get("use")
        if not isinstance(use, str):
            raise RecipeError(f"{w}.use: expected a stage name like 'carve.hull'")
        if use not in pm.stages:
            raise RecipeError(f"{w}.use: {pm.missing('stage', use)}")
        spec: StageSpec = pm.stage(use)
        sname = st.get("name", spec.kind)
        if not isinstance(sname, str) or not sname:
            raise RecipeError(f"{w}.name: expected a non-empty string")
        if sname in seen_names:
            raise RecipeError(f"{w}.name: stage name {sname!r} is used twice")
        w = f"{label}: stages.{sname}"
        missing = [k for k in spec.requires if k not in seen_kinds]
        if missing:
            raise RecipeError(f"{w}: {use} needs a {missing[0]!r} stage before it")
        params = build_params(spec.params, st.get("params"), f"{w}.params", base)
        steps.append(Step(sname, spec, params))
        seen_names.add(sname)
        seen_kinds.add(spec.kind)
    tol = _tolerance(data.get("tolerance"), f"{label}: tolerance")
    if any(s.spec.kind in ("align", "bcps", "evaluate") for s in steps) and ref is None:
        raise RecipeError(f"{label}: recipe.reference: no reference mesh (set it in the recipe or pass --reference)")
    outputs = build_params(Outputs, _table(data.get("outputs", {}), f"{label}: outputs"), f"{label}: outputs")
    budget = _budget(data.get("budget"), f"{label}: budget")
    plugins = _plugin_settings(data.get("plugins"), pm, f"{label}: plugins", base)
    chars = _characteristics(data.get("characteristics"), f"{label}: characteristics", ref, steps)
    if chars:  # the measuring stage reads them from context.settings, like a plugin's settings

        plugins = MappingProxyType({**plugins, SETTINGS_KEY: chars})
    return Recipe(name, path, ref, driver, tuple(steps), tol, outputs=outputs,
                  budget=budget, plugins=plugins, characteristics=chars)


def _characteristics(raw: Any, where: str, ref: str | None, steps: list[Step]) -> tuple[Any, ...]:
    """``[[characteristics]]`` checked against the reference's features (issue 28); refused
    when no stage of the recipe measures them."""
    if raw is None:
        return ()
    chars = parse_characteristics(raw, where, ref)
    if chars and not measured_in(steps):
        raise RecipeError(f"{where}: no stage measures them (add [[stages]] name = \"characteristics\", "
                          "use = \"evaluate.characteristics\" after the evaluate stage)")
    return chars


def _plugin_settings(raw: Any, pm: PluginManager, where: str, base: Path) -> Mapping[str, Any]:
    """``[plugins.NAME]`` tables validated against each plugin's declared settings; the
    defaults for a plugin with settings that the recipe does not mention. A table for a
    plugin without settings (or not loaded: disabled, blocked, not installed) is refused
    naming it."""
    tables = _table(raw if raw is not None else {}, where)
    out: dict[str, Any] = {}
    for name, table in tables.items():
        if name not in pm.settings:
            raise RecipeError(f"{where}.{name}: {pm.missing('settings', name)}")
        spec = pm.settings_spec(name)
        out[name] = build_params(spec.params, _table(table, f"{where}.{name}"), f"{where}.{name}", base)
    for name in pm.settings.names():
        if name not in out:
            out[name] = build_params(pm.settings_spec(name).params, {}, f"{where}.{name}", base)
    return MappingProxyType(out)


def _budget(raw: Any, where: str) -> Budget:
    """``[budget]``; a key not set there comes from its environment variable
    (:data:`BUDGET_ENV`), else the default. RecipeError naming the key or the variable."""
    table = dict(_table(raw if raw is not None else {}, where))
    for key, var in BUDGET_ENV.items():
        text = os.environ.get(var, "").strip()
        if key in table or not text:
            continue
        try:
            build_params(Budget, {key: float(text)}, var)
        except (ValueError, RecipeError) as e:
            why = str(e).split(": ", 1)[-1] if isinstance(e, RecipeError) else f"expected seconds, got {text!r}"
            raise RecipeError(f"{var}: {why}") from None
        table[key] = float(text)
    budget: Budget = build_params(Budget, table, where)
    return budget


def read_recipe_toml(path: str | Path) -> dict[str, Any]:
    """The TOML document of a recipe file, unvalidated; RecipeError naming the file."""
    p = Path(path)
    if not p.is_file():
        raise RecipeError(f"{p}: recipe file not found")
    try:
        return tomllib.loads(p.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise RecipeError(f"{p.name}: not a UTF-8 text file") from None
    except tomllib.TOMLDecodeError as e:
        raise RecipeError(f"{p.name}: not valid TOML ({e})") from None
    except RecursionError:  # tomllib recurses once per level of nested arrays and tables
        raise RecipeError(f"{p.name}: not a recipe (arrays or tables nested too deeply)") from None


def load_recipe(path: str | Path, pm: PluginManager, *, reference: str | None = None) -> Recipe:
    """Read and validate a recipe file; raises RecipeError naming the file and key."""
    import dataclasses
    import hashlib

    recipe = parse_recipe(read_recipe_toml(path), pm, path=Path(path), reference=reference)
    try:
        digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:  # read a moment ago: gone since, the recipe itself is valid
        digest = None
    return dataclasses.replace(recipe, path=Path(path).resolve(), sha256=digest)


def rig_problems(recipe: Recipe, rig: Any) -> list[str]:
    """Why ``recipe`` could never reject a part measured with ``rig`` (a
    :class:`~inspector.model.Rig`): one line per stage whose parameters say so, naming the
    step and the key; [] when it can. A stage's parameter class may define
    ``rig_problem(rig) -> str | None`` (the built-in evaluate stage's checks ``min_cameras``
    and ``min_points``); ``inspector recipe check --rig`` and the stage itself ask it.
    """
    problems = []
    for step in recipe.steps:
        check = getattr(step.params, "rig_problem", None)
        why = check(rig) if callable(check) else None
        if why:
            problems.append(f"stage {step.name!r} ({step.spec.name}): {why}")
    return problems
