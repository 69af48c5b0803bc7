"""``inspector experiment``: the paper's experiments (cases 1-3) as one command, with plots.

Each run simulates one capture of the rig (:mod:`inspector_drivers.sim.simulate`), inspects
it, and measures the distance of the raw reconstruction's points and of the BCPS points to
the *true* surface (:mod:`inspector.truth`). Runs are spread over a Dask distributed cluster:
a :class:`~distributed.LocalCluster` by default, or an existing one (``--scheduler``).

Cases (Pérez Soler et al., Mathematics 2023, 11(21), 4419, section 4):

1. ``scale``: ``cube30`` and ``sphere30`` scaled around the fixed reference (Figures 7, 8);
2. ``defects``: random bumps of radius up to 3 mm added (``+``) or removed (``-``), with
   Gaussian and impulse image noise (Figures 9, 10);
3. ``objects``: ``gauge``, ``turbine_blade``, ``cube_sphere`` (nominal, excess and missing
   material by scale 1.03 / 0.97 and by added / removed bumps) and the ``spring``
   (Figures 3, 5, 11-17; simulated here, real objects in the paper).

Outputs in ``--out``: one CSV per case (one row per run and BCPS method), one PNG per case
and part (Figures 7-10 style), ``summary.md`` (Table 1 style, improvement ratios beside the
paper's) and ``experiment.json`` (the configuration).

One task per (case, part, value, orientation). A task builds its own plugin manager, recipe
and reference, runs the pipeline up to the alignment once, then each BCPS method on that
same context, and returns small dicts (never images). A failing task becomes rows with
``status = error``: nothing else is lost. Rows are appended to the CSVs as they arrive.

Importing this module is cheap: Dask, tqdm and matplotlib are imported when used.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
import traceback
from collections import defaultdict
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from inspector import hookimpl

if TYPE_CHECKING:
    from inspector.registry import CommandRegistry

__all__ = [
    "CASES",
    "PRESETS",
    "PAPER_TABLE1",
    "CSV_COLUMNS",
    "add_parser",
    "run",
    "make_specs",
    "run_task",
    "execute",
    "start_client",
    "write_plots",
    "write_summary",
    "ratio_ranges",
]

# --------------------------------------------------------------------------- configuration

#: Rig presets. ``full`` is the paper's rig (16 cameras, 1024 px, 0.1 mm/px at the centre);
#: ``quick`` keeps the 16 cameras with a quarter of the pixels (about 3x faster per run).
PRESETS: dict[str, dict[str, Any]] = {
    "full": {"rig": {"cameras": 16, "width": 1024, "height": 1024, "mm_per_px": 0.1}},
    "quick": {"rig": {"cameras": 16, "width": 512, "height": 512, "mm_per_px": 0.2}},
}

#: The experiment's pipeline: ``recipes/default.toml`` with a tolerant alignment gate
#: (parts scaled by up to 10 % are still aligned: the truth, not the gate, judges accuracy),
#: carving at one pixel footprint (:func:`_pipeline` sets the preset's). The ``bcps`` stage
#: is replaced by each method in turn.
DEFAULT_STAGES: tuple[dict[str, Any], ...] = (
    {"use": "segment.threshold", "params": {"polarity": "auto", "threshold": "otsu", "median": "impulse"}},
    {"use": "carve.hull", "params": {"voxel_mm": 0.1}},
    {"use": "align.global_icp", "params": {"inlier_mm": 2.0, "min_fitness": 0.1}},
    {"use": "bcps.ray", "params": {"step_mm": 0.25, "refine_pose": True}},
    {"use": "evaluate.tolerance", "params": {"cluster_radius_mm": 1.0, "min_points": 3}},
)
DEFAULT_TOLERANCE: dict[str, Any] = {"default": {"lower": -0.1, "upper": 0.1}}

#: BCPS methods: ``ray`` (ours, exact rays through sub-pixel contours), ``surface`` (the paper's).
METHODS: dict[str, str] = {"ray": "bcps.ray", "surface": "bcps.surface"}

OBJECT_VARIANTS: dict[str, str] = {
    "nominal": "as the reference",
    "excess": "scale 1.03 (excess material)",
    "missing": "scale 0.97 (missing material)",
    "added": "3 bumps of radius 2 mm added (excess material)",
    "removed": "3 bumps of radius 2 mm removed (missing material)",
}


@dataclass(frozen=True)
class Case:
    """One of the paper's experiments."""

    number: int
    name: str
    title: str
    variable: str
    xlabel: str
    parts: tuple[str, ...]
    values: dict[str, tuple[Any, ...]]  # preset -> swept values
    orientations: dict[str, int]  # preset -> orientations per value
    sim: dict[str, Any] = field(default_factory=dict)  # extra SimParams for every run
    bumps: int = 3  # bumps per run (defects / object variants)
    part_values: dict[str, tuple[Any, ...]] = field(default_factory=dict)  # part -> allowed values (objects)

    @property
    def numeric(self) -> bool:
        return self.variable != "variant"

    @property
    def stem(self) -> str:
        return f"case{self.number}_{self.name}"


def _frange(a: float, b: float, step: float) -> tuple[float, ...]:
    n = int(round((b - a) / step))
    return tuple(round(a + i * step, 6) for i in range(n + 1))


CASES: dict[str, Case] = {
    "scale": Case(
        1, "scale", "Case 1: part scaled around the fixed reference", "scale", "scale of the part (reference = 1.00)",
        ("cube30", "sphere30"),
        {"full": _frange(0.90, 1.10, 0.02), "quick": (0.90, 0.95, 1.00, 1.05, 1.10)},
        {"full": 5, "quick": 2},
    ),
    "defects": Case(
        2, "defects", "Case 2: random impulse defects, Gaussian and impulse image noise", "defect_mm",
        "defect size, mm (bump radius; − removed, + added)",
        ("cube30", "sphere30"),
        {"full": _frange(-3.0, 3.0, 0.5), "quick": (-3.0, -1.5, 0.0, 1.5, 3.0)},
        {"full": 5, "quick": 2},
        sim={"noise_sigma": 4.0, "impulse_fraction": 0.002},
    ),
    "objects": Case(
        3, "objects", "Case 3: objects with excess and missing material", "variant", "variant",
        ("gauge", "turbine_blade", "cube_sphere", "spring"),
        {"full": tuple(OBJECT_VARIANTS), "quick": tuple(OBJECT_VARIANTS)},
        {"full": 5, "quick": 1},
        bumps=3,
        part_values={"spring": ("nominal", "excess", "missing")},  # a 2 mm bump would cut its 1.5 mm wire
    ),
}
_CASE_ALIASES = {"1": "scale", "2": "defects", "noise": "defects", "3": "objects", "all": "all"}

#: The paper's Table 1 (improvement = reconstruction error / BCPS error, min-max over a sweep),
#: keyed by (case, part). Gauge, blade and cube-sphere are *real* objects in the paper.
PAPER_TABLE1: dict[tuple[str, str], dict[str, Any]] = {
    ("scale", "sphere30"): {"label": "Sphere Scale", "figure": "8", "mean": (3.5, 3.5), "max": (4.74, 4.77)},
    ("scale", "cube30"): {"label": "Cube Scale", "figure": "7", "mean": (5.0, 45.0), "max": (6.5, 21.0)},
    ("defects", "sphere30"): {"label": "Sphere Noise", "figure": "10", "mean": (1.5, 2.0), "max": (1.1, 5.0)},
    ("defects", "cube30"): {"label": "Cube Noise", "figure": "9", "mean": (4.8, 8.0), "max": (1.55, 23.0)},
    ("objects", "gauge"): {"label": "Real Gauge", "figure": "11", "mean": (2.3, 5.0), "max": (2.0, 3.9)},
    ("objects", "turbine_blade"): {"label": "Real Blade", "figure": "12-14", "mean": (2.1, 3.3), "max": (1.5, 4.2)},
    ("objects", "cube_sphere"): {"label": "Real Cube-Sphere", "figure": "15-17", "mean": (2.1, 4.28), "max": (1.21, 8.0)},
}

CSV_COLUMNS: tuple[str, ...] = (
    "case", "part", "variable", "value", "orientation", "seed", "method", "status", "verdict", "error",
    "footprint_mm", "recon_points", "recon_mean_mm", "recon_p99_mm", "recon_max_mm", "recon_mean_px", "recon_max_px",
    "bcps_points", "bcps_mean_mm", "bcps_p99_mm", "bcps_max_mm", "bcps_mean_px", "bcps_max_px",
    "ratio_mean", "ratio_max",
    "t_simulate_s", "t_segment_s", "t_carve_s", "t_align_s", "t_bcps_s", "t_evaluate_s", "t_run_s", "worker",
)


def _err_line(exc: BaseException) -> str:
    from inspector.errors import InspectorError

    text = " ".join(str(exc).split())
    return text if isinstance(exc, InspectorError) else f"internal error {type(exc).__name__}: {text}"


# --------------------------------------------------------------------------- task specs


def _resolve_cases(names: Sequence[str]) -> list[Case]:
    from inspector.errors import RecipeError

    out: list[Case] = []
    for n in names or ["all"]:
        key = _CASE_ALIASES.get(n.lower(), n.lower())
        if key == "all":
            chosen = list(CASES.values())
        elif key in CASES:
            chosen = [CASES[key]]
        else:
            raise RecipeError(f"experiment: unknown case {n!r} (known: 1|scale, 2|defects, 3|objects, all)")
        out += [c for c in chosen if c not in out]
    return sorted(out, key=lambda c: c.number)


def _case_values(case: Case, override: Sequence[str] | None, preset: str) -> tuple[Any, ...]:
    from inspector.errors import RecipeError

    if not override:
        return case.values[preset]
    vals: list[Any] = []
    for v in override:
        if case.numeric:
            try:
                x = float(v)
            except ValueError:
                raise RecipeError(f"experiment --values: case {case.name} expects numbers, got {v!r}") from None
            if case.variable == "scale" and not 0.5 <= x <= 2.0:
                raise RecipeError(f"experiment --values: scale must be in [0.5, 2.0], got {v}")
            if case.variable == "defect_mm" and abs(x) > 10.0:
                raise RecipeError(f"experiment --values: defect size must be in [-10, 10] mm, got {v}")
            vals.append(x)
        else:
            if v not in OBJECT_VARIANTS:
                raise RecipeError(f"experiment --values: case {case.name} expects variants ({', '.join(OBJECT_VARIANTS)}), got {v!r}")
            vals.append(v)
    return tuple(dict.fromkeys(vals))


def _pipeline(recipe_path: str | None, preset: str = "full") -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Stages and tolerance of the experiment (from ``--recipe`` or the built-in pipeline).

    The built-in pipeline carves at the preset's pixel footprint: the paper's method selects
    among the reconstruction's points, so its error is the voxel's (cube, 0.5 mm voxels: mean
    0.149 mm, max 2.2 mm; 0.1 mm: 0.016 / 0.90), while ours, on exact rays, does not depend
    on it. The product's default recipe carves at 0.5 mm for speed.
    """
    import tomllib

    from inspector.errors import RecipeError

    if recipe_path is None:
        voxel = float(PRESETS[preset]["rig"]["mm_per_px"])
        stages = [dict(s) for s in DEFAULT_STAGES]
        stages = [{**s, "params": {**s["params"], "voxel_mm": voxel}} if s["use"] == "carve.hull" else s for s in stages]
        return stages, dict(DEFAULT_TOLERANCE)
    p = Path(recipe_path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise RecipeError(f"{p}: recipe file not found") from None
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise RecipeError(f"{p.name}: not a valid TOML recipe ({e})") from None
    raw_stages = data.get("stages")
    if not isinstance(raw_stages, list) or not raw_stages:
        raise RecipeError(f"{p.name}: stages: expected at least one [[stages]] table")
    return [dict(s) for s in raw_stages], dict(data.get("tolerance", DEFAULT_TOLERANCE))


def _method_stages(stages: list[dict[str, Any]], method: str) -> list[dict[str, Any]]:
    """The pipeline with its BCPS stage run by ``method`` (params kept when it is the same stage)."""
    use = METHODS[method]
    out, found = [], False
    for s in stages:
        if str(s.get("use", "")).startswith("bcps."):
            found = True
            new = {"use": use}
            if "name" in s:
                new["name"] = s["name"]
            if s.get("use") == use and "params" in s:
                new["params"] = s["params"]
            s = new
        out.append(dict(s))
    if not found:
        from inspector.errors import RecipeError

        raise RecipeError("experiment: the recipe has no bcps stage")
    return out


def _prefix_len(stages: list[dict[str, Any]]) -> int:
    return next(i for i, s in enumerate(stages) if str(s.get("use", "")).startswith("bcps."))


def make_specs(
    cases: Sequence[Case],
    *,
    preset: str = "full",
    orientations: int | None = None,
    values: Sequence[str] | None = None,
    parts: Sequence[str] | None = None,
    methods: Sequence[str] = ("ray", "surface"),
    seed: int = 0,
    stages: list[dict[str, Any]] | None = None,
    tolerance: Mapping[str, Any] | None = None,
    rig: Mapping[str, Any] | None = None,
) -> list[dict[str, Any]]:
    """One task spec (a small, picklable dict) per (case, part, value, orientation).

    Orientation ``i`` uses simulator seed ``seed + i`` for every value of a sweep, so the
    values of a sweep are compared on the same poses (and, for bumps, the same positions).
    """
    from inspector.errors import RecipeError
    from inspector.parts import part_names

    stages = [dict(s) for s in (stages or DEFAULT_STAGES)]
    tolerance = dict(tolerance or DEFAULT_TOLERANCE)
    for m in methods:
        if m not in METHODS:
            raise RecipeError(f"experiment --methods: unknown method {m!r} (known: {', '.join(METHODS)})")
    known = set(part_names())
    for p in parts or ():
        if p not in known:
            raise RecipeError(f"experiment --parts: unknown part {p!r} (known: {', '.join(sorted(known))})")
    rig = dict(rig or PRESETS[preset]["rig"])
    specs = []
    for case in cases:
        n_or = orientations if orientations is not None else case.orientations[preset]
        vals = _case_values(case, values, preset)
        for part in case.parts:
            if parts and part not in parts:
                continue
            allowed = case.part_values.get(part)
            for v in vals:
                if allowed is not None and v not in allowed:
                    continue
                for i in range(n_or):
                    specs.append({
                        "case": case.name, "case_number": case.number, "part": part, "variable": case.variable,
                        "value": v, "orientation": i, "seed": seed + i, "sim": {**rig, **case.sim},
                        "bumps": case.bumps, "methods": list(methods), "stages": stages, "tolerance": tolerance,
                    })
    if not specs:
        raise RecipeError("experiment: nothing to run (check --parts and --values against the cases)")
    return specs


def _check_pipeline(stages: list[dict[str, Any]], tolerance: Mapping[str, Any], methods: Sequence[str]) -> None:
    """Validate the pipeline for every method here, before anything is submitted."""
    from inspector.manager import create_plugin_manager
    from inspector.recipe import parse_recipe

    pm = create_plugin_manager()
    for m in methods:
        parse_recipe({"recipe": {"name": f"experiment-{m}", "reference": "builtin:cube30"},
                      "stages": _method_stages(stages, m), "tolerance": dict(tolerance)}, pm)


# --------------------------------------------------------------------------- one task


def _sim_table(spec: Mapping[str, Any]) -> dict[str, Any]:
    """SimParams table of a spec: part, pose seed, scale, explicit bumps."""
    import numpy as np

    table: dict[str, Any] = {"part": spec["part"], "seed": int(spec["seed"]), **spec["sim"]}
    var, v = spec["variable"], spec["value"]
    kind, radius = None, 0.0
    if var == "scale":
        table["scale"] = float(v)
    elif var == "defect_mm":
        if float(v) != 0.0:
            kind, radius = ("add" if float(v) > 0 else "remove"), abs(float(v))
    elif var == "variant":
        if v == "excess":
            table["scale"] = 1.03
        elif v == "missing":
            table["scale"] = 0.97
        elif v in ("added", "removed"):
            kind, radius = ("add" if v == "added" else "remove"), 2.0
    if kind is not None and spec.get("bumps", 0) > 0:
        from inspector.parts import load_reference, random_bumps

        mesh = load_reference(f"builtin:{spec['part']}")
        # Seeded by the orientation only: same positions for every size of a sweep.
        rng = np.random.default_rng(10_000 + int(spec["seed"]))
        bumps = random_bumps(mesh, int(spec["bumps"]), max_radius_mm=radius, min_radius_mm=radius, kind=kind, rng=rng)
        table["bumps"] = [{"at": [float(x) for x in b.centre], "radius_mm": float(b.radius_mm), "kind": b.kind} for b in bumps]
    return table


def _base_row(spec: Mapping[str, Any], method: str) -> dict[str, Any]:
    return {
        "case": spec["case"], "part": spec["part"], "variable": spec["variable"], "value": spec["value"],
        "orientation": spec["orientation"], "seed": spec["seed"], "method": method, "status": "error", "verdict": "error",
        "error": "",
    }


def _truth_cols(prefix: str, t: Mapping[str, Any] | None, fp: float | None) -> dict[str, Any]:
    if not t:
        return {}
    out = {f"{prefix}_mean_mm": t["mean_mm"], f"{prefix}_p99_mm": t["p99_mm"], f"{prefix}_max_mm": t["max_mm"],
           f"{prefix}_mean_px": t["mean_px"]}
    if fp:
        out[f"{prefix}_max_px"] = t["max_mm"] / fp
    return out


def error_rows(spec: Mapping[str, Any], message: str) -> list[dict[str, Any]]:
    """The rows of a task that produced nothing (one per method), with ``message``."""
    return [_base_row(spec, m) | {"error": message} for m in spec["methods"]]


def run_task(spec: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Simulate and inspect one capture; one row per BCPS method. Never raises.

    The pipeline runs once up to the alignment (``inspect_capture``); each BCPS method then
    runs (with the stages after it) on that same context.
    """
    t_task = time.perf_counter()
    common: dict[str, Any] = {}
    try:
        from inspector.manager import create_plugin_manager
        from inspector.params import build_params
        from inspector.recipe import parse_recipe
        from inspector.reference import Reference
        from inspector.runner import inspect_capture
        from inspector.truth import truth_stats
        from inspector_drivers.sim.simulate import SimParams, simulate

        try:
            from distributed import get_worker

            common["worker"] = str(get_worker().name)
        except Exception:  # noqa: BLE001 - not in a worker (direct call)
            common["worker"] = ""
        pm = create_plugin_manager()
        ref_spec = f"builtin:{spec['part']}"
        stages = spec["stages"]
        k = _prefix_len(stages)
        recipes = {
            m: parse_recipe({"recipe": {"name": f"experiment-{m}", "reference": ref_spec},
                             "stages": _method_stages(stages, m), "tolerance": spec["tolerance"]}, pm)
            for m in spec["methods"]
        }
        prefix = parse_recipe({"recipe": {"name": "experiment-prefix", "reference": ref_spec},
                               "stages": stages[:k], "tolerance": spec["tolerance"]}, pm)
        reference = Reference.load(ref_spec)
        t0 = time.perf_counter()
        p = build_params(SimParams, _sim_table(spec), "experiment")
        name = f"{spec['case']}-{spec['part']}-{spec['value']}-o{spec['orientation']}"
        capture = simulate(p, 0, name=name)
        common["t_simulate_s"] = time.perf_counter() - t0
        outcome = inspect_capture(capture, prefix, reference, pm)
        res = outcome.result
        for step in prefix.steps:
            if step.name in res.timings_s:
                common[f"t_{step.spec.kind}_s"] = res.timings_s[step.name]
        ctx = outcome.context
        truth = res.stats.get("truth") if res.verdict != "error" else None
        if truth is None and ctx is not None and ctx.reconstruction is not None:
            truth = truth_stats(capture, None, ctx.reconstruction.points)
        fp = float((truth or {}).get("footprint_mm") or capture.rig.footprint_mm())
        common["footprint_mm"] = fp
        if ctx is not None and ctx.reconstruction is not None:
            common["recon_points"] = int(len(ctx.reconstruction.points))
        common |= _truth_cols("recon", (truth or {}).get("reconstruction"), fp)
        if res.verdict == "error":
            msg = res.error or "error"
            return [_base_row(spec, m) | common | {"error": msg, "t_run_s": time.perf_counter() - t_task} for m in spec["methods"]]
    except Exception as exc:  # noqa: BLE001 - a task never raises: its failure is a row
        msg = _err_line(exc)
        if "internal error" in msg:
            msg += " | " + traceback.format_exc().strip().splitlines()[-3].strip()
        return [_base_row(spec, m) | common | {"error": msg, "t_run_s": time.perf_counter() - t_task} for m in spec["methods"]]

    rows = []
    shared_s = time.perf_counter() - t_task
    for m in spec["methods"]:
        row = _base_row(spec, m) | common
        t_m = time.perf_counter()
        c = ctx
        assert c is not None  # the prefix ran without an error
        try:
            for step in recipes[m].steps[k:]:
                t0 = time.perf_counter()
                c = step.spec.run(c, step.params)
                row[f"t_{step.spec.kind}_s"] = time.perf_counter() - t0
            if c.bcps is None or len(c.bcps.points) == 0:
                raise RuntimeError("bcps: no point selected")
            t = truth_stats(capture, c.bcps.points, None) or {}
            row |= _truth_cols("bcps", t.get("bcps"), fp)
            row["bcps_points"] = int(len(c.bcps.points))
            row["verdict"] = c.evaluation.verdict if c.evaluation is not None else "pass"
            row["status"] = "ok"
            for stat in ("mean", "max"):
                r, b = row.get(f"recon_{stat}_mm"), row.get(f"bcps_{stat}_mm")
                if r is not None and b:
                    row[f"ratio_{stat}"] = r / b
        except Exception as exc:  # noqa: BLE001
            row["error"] = _err_line(exc)
        row["t_run_s"] = shared_s + (time.perf_counter() - t_m)  # this method's result from scratch
        rows.append(row)
    return rows


# --------------------------------------------------------------------------- scheduling


class _CsvSink:
    """Per-case CSV files, appended row by row (nothing lost on an interrupt)."""

    def __init__(self, out: Path, cases: Iterable[Case]) -> None:
        self.paths = {c.name: out / f"{c.stem}.csv" for c in cases}
        self.files = {}
        self.writers = {}
        for name, path in self.paths.items():
            f = path.open("w", newline="", encoding="utf-8")
            w = csv.DictWriter(f, fieldnames=list(CSV_COLUMNS), extrasaction="ignore")
            w.writeheader()
            self.files[name], self.writers[name] = f, w

    def add(self, rows: Iterable[Mapping[str, Any]]) -> None:
        for r in rows:
            self.writers[r["case"]].writerow(_csv_row(r))
            self.files[r["case"]].flush()

    def close(self) -> None:
        for f in self.files.values():
            f.close()


def _csv_row(r: Mapping[str, Any]) -> dict[str, Any]:
    out = {}
    for k in CSV_COLUMNS:
        v = r.get(k, "")
        if isinstance(v, float):
            v = f"{v:.6g}"
        out[k] = v
    return out


def _sort_key(r: Mapping[str, Any]) -> tuple:
    case = CASES.get(r["case"])
    order = {m: i for i, m in enumerate(METHODS)}
    v = r["value"]
    vk = (0, float(v), "") if isinstance(v, (int, float)) else (1, list(OBJECT_VARIANTS).index(v) if v in OBJECT_VARIANTS else 99, str(v))
    parts = case.parts if case else ()
    return (case.number if case else 99, parts.index(r["part"]) if r["part"] in parts else 99, vk, int(r["orientation"]),
            order.get(r["method"], 9))


def write_csvs(rows: Sequence[Mapping[str, Any]], out: Path, cases: Iterable[Case]) -> dict[str, Path]:
    """Rewrite the per-case CSVs, sorted by part, value, orientation and method."""
    paths = {}
    for c in cases:
        path = out / f"{c.stem}.csv"
        with path.open("w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, fieldnames=list(CSV_COLUMNS), extrasaction="ignore")
            w.writeheader()
            for r in sorted((r for r in rows if r["case"] == c.name), key=_sort_key):
                w.writerow(_csv_row(r))
        paths[c.name] = path
    return paths


def execute(
    specs: Sequence[Mapping[str, Any]],
    client: Any,
    *,
    fn: Callable[[Mapping[str, Any]], list[dict[str, Any]]] = run_task,
    on_rows: Callable[[list[dict[str, Any]]], None] | None = None,
    progress: bool = True,
    label: Callable[[Mapping[str, Any]], str] | None = None,
    errors: Callable[[Mapping[str, Any], str], list[dict[str, Any]]] | None = None,
    desc: str = "experiment",
) -> list[dict[str, Any]]:
    """Submit one task per spec to ``client``; gather rows as they complete.

    A task whose future fails (worker killed, unpicklable result...) gives error rows
    (``errors(spec, message)``, default :func:`error_rows`); the others are unaffected.
    ``label(spec)`` names a finished task beside the progress bar ``desc``
    (``inspector feasibility`` runs its simulations through here too).
    """
    from distributed import as_completed

    futures = {client.submit(fn, dict(s), pure=False): s for s in specs}
    bar = _progress_bar(len(futures), progress, desc)
    rows: list[dict[str, Any]] = []
    try:
        for fut in as_completed(futures):
            spec = futures[fut]
            try:
                got = fut.result()
            except Exception as exc:  # noqa: BLE001 - one task never loses the others
                got = (errors or error_rows)(spec, f"task failed: {type(exc).__name__}: {' '.join(str(exc).split())}")
            finally:
                fut.release()
            rows += got
            if on_rows is not None:
                on_rows(got)
            bad = sum(r["status"] != "ok" for r in got)
            what = label(spec) if label is not None else f"{spec['case']} {spec['part']} {spec['variable']}={spec['value']} o{spec['orientation']}"
            bar.update(what + (" ERROR" if bad else ""))
    finally:
        bar.close()
        for f in futures:
            if not f.done():
                f.cancel()
    return rows


class _progress_bar:
    """tqdm on stderr, or one plain line per task when tqdm is missing."""

    def __init__(self, total: int, enabled: bool, desc: str = "experiment") -> None:
        self.total, self.n, self.enabled, self.bar = total, 0, enabled, None
        if enabled:
            try:
                from tqdm import tqdm

                self.bar = tqdm(total=total, file=sys.stderr, unit="run", desc=desc, dynamic_ncols=True)
            except ImportError:
                self.bar = None

    def update(self, what: str) -> None:
        self.n += 1
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.set_postfix_str(what, refresh=False)
            self.bar.update(1)
        else:
            print(f"[{self.n}/{self.total}] {what}", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def start_client(scheduler: str | None, workers: int, command: str = "experiment") -> tuple[Any, Any]:
    """(client, cluster-or-None): connect to ``scheduler`` or start a LocalCluster of
    ``workers`` processes; an address that does not answer is an error naming ``command``."""
    from distributed import Client, LocalCluster

    if scheduler:
        from inspector.errors import InspectorError

        try:
            return Client(scheduler, timeout="30s"), None
        except (OSError, TimeoutError) as e:
            raise InspectorError(f"{command} --scheduler {scheduler}: cannot connect ({' '.join(str(e).split())})") from None
    import logging

    # ":0": any free port for the scheduler's HTTP server (8787 may be taken on a shared machine).
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                           silence_logs=logging.ERROR)
    return Client(cluster), cluster


# --------------------------------------------------------------------------- aggregation


def _num(r: Mapping[str, Any], k: str) -> float | None:
    v = r.get(k)
    if v is None or v == "":
        return None
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _groups(rows: Iterable[Mapping[str, Any]]) -> dict[tuple[str, str], list[Mapping[str, Any]]]:
    g: dict[tuple[str, str], list[Mapping[str, Any]]] = defaultdict(list)
    for r in rows:
        g[(r["case"], r["part"])].append(r)
    return g


def _values_in_order(case: Case, rows: Sequence[Mapping[str, Any]]) -> list[Any]:
    vals = list(dict.fromkeys(r["value"] for r in rows))
    if case.numeric:
        return sorted(vals, key=float)
    order = list(OBJECT_VARIANTS)
    return sorted(vals, key=lambda v: order.index(v) if v in order else 99)


def _series(rows: Sequence[Mapping[str, Any]], values: Sequence[Any], method: str | None, key: str) -> dict[str, list[float]]:
    """Mean, min, max, std over orientations of column ``key`` at each value (NaN if none).

    ``method=None``: the reconstruction columns, one sample per (value, orientation).
    """
    import numpy as np

    out: dict[str, list[float]] = {"mean": [], "min": [], "max": [], "std": [], "n": []}
    for v in values:
        if method is None:
            seen: dict[Any, float] = {}
            for r in rows:
                x = _num(r, key)
                if r["value"] == v and x is not None:
                    seen.setdefault(r["orientation"], x)
            xs = list(seen.values())
        else:
            xs = [x for r in rows if r["value"] == v and r["method"] == method and r["status"] == "ok" and (x := _num(r, key)) is not None]
        a = np.asarray(xs, float)
        for s, f in (("mean", np.mean), ("min", np.min), ("max", np.max), ("std", np.std)):
            out[s].append(float(f(a)) if len(a) else float("nan"))
        out["n"].append(len(a))
    return out


def ratio_ranges(rows: Sequence[Mapping[str, Any]], method: str, stat: str) -> tuple[float, float] | None:
    """Min and max over a sweep's values of (reconstruction error / BCPS error).

    At each value, the errors are first averaged over the orientations whose BCPS run
    succeeded (the same runs for numerator and denominator).
    """
    import numpy as np

    per_value: dict[Any, list[tuple[float, float]]] = defaultdict(list)
    for r in rows:
        if r["method"] != method or r["status"] != "ok":
            continue
        a, b = _num(r, f"recon_{stat}_mm"), _num(r, f"bcps_{stat}_mm")
        if a is not None and b is not None and b > 0:
            per_value[r["value"]].append((a, b))
    ratios = [float(np.mean([a for a, _ in ab]) / np.mean([b for _, b in ab])) for ab in per_value.values() if ab]
    return (min(ratios), max(ratios)) if ratios else None


def _fmt_range(rng: tuple[float, float] | None) -> str:
    if rng is None:
        return "—"
    a, b = rng

    def f(x: float) -> str:
        return f"{x:.3g}" if x < 100 else f"{x:.0f}"

    return f"[{f(a)}]" if f(a) == f(b) else f"[{f(a)}–{f(b)}]"


# --------------------------------------------------------------------------- plots

_COLOURS = {
    ("recon", "mean"): "tab:orange", ("recon", "max"): "tab:red",
    ("ray", "mean"): "tab:blue", ("ray", "max"): "tab:green",
    ("surface", "mean"): "tab:purple", ("surface", "max"): "tab:olive",
}


def write_plots(rows: Sequence[Mapping[str, Any]], out: Path, cases: Iterable[Case], *, band: str = "minmax") -> list[Path]:
    """One PNG per (case, part): mean and max error of the reconstruction and of each BCPS
    method against the swept value; a grey band up to one pixel's footprint; a shaded band
    over the orientations (``minmax`` or ``std``). Log-y when the errors span > 30x.
    """
    import numpy as np
    from matplotlib.figure import Figure

    paths = []
    groups = _groups(rows)
    for case in cases:
        for part in case.parts:
            rs = groups.get((case.name, part))
            if not rs:
                continue
            values = _values_in_order(case, rs)
            methods = [m for m in METHODS if any(r["method"] == m for r in rs)]
            x = np.array([float(v) for v in values]) if case.numeric else np.arange(len(values), dtype=float)
            fig = Figure(figsize=(8.0, 5.6), dpi=110)
            ax = fig.add_subplot(1, 1, 1)
            curves = [("recon", None, "reconstruction")] + [(m, m, f"BCPS {m}" + (" (paper's)" if m == "surface" else "")) for m in methods]
            positives: list[float] = []
            n_or = len({r["orientation"] for r in rs})
            for who, method, label in curves:
                for stat in ("mean", "max"):
                    col = "recon" if method is None else "bcps"
                    s = _series(rs, values, method, f"{col}_{stat}_mm")
                    y = np.array(s["mean"])
                    if np.all(np.isnan(y)):
                        continue
                    lo, hi = (np.array(s["min"]), np.array(s["max"])) if band == "minmax" else (y - np.array(s["std"]), y + np.array(s["std"]))
                    colour = _colours(who, stat)
                    style = "--" if who == "surface" else "-"
                    if case.numeric:
                        ax.plot(x, y, style, marker="o", ms=3.5, color=colour, label=f"{label}, {stat} error")
                        ax.fill_between(x, lo, hi, color=colour, alpha=0.18, linewidth=0)
                    else:
                        off = {"recon": -0.2, "ray": 0.0, "surface": 0.2}[who] + (0.05 if stat == "max" else -0.05)
                        ax.errorbar(x + off, y, yerr=[np.maximum(y - lo, 0), np.maximum(hi - y, 0)], fmt="o" if stat == "mean" else "s",
                                    ms=4.5, color=colour, capsize=3, label=f"{label}, {stat} error")
                    positives += [v for v in np.concatenate([lo, y, hi]) if np.isfinite(v) and v > 0]
            fps = [f for r in rs if (f := _num(r, "footprint_mm"))]
            fp = float(np.median(fps)) if fps else None
            log = bool(positives) and max(positives) / max(min(positives), 1e-9) > 30
            if log:
                ax.set_yscale("log")
                bottom = min(min(positives) * 0.5, fp * 0.5 if fp else math.inf)
                ax.set_ylim(bottom=bottom)
            else:
                ax.set_ylim(bottom=0)
            if fp:
                ax.axhspan(ax.get_ylim()[0] if log else 0, fp, color="0.6", alpha=0.3, linewidth=0,
                           label=f"one pixel ({fp:.3g} mm)", zorder=0)
            if case.numeric:
                ref = 1.0 if case.variable == "scale" else 0.0
                ax.axvline(ref, color="0.4", lw=0.8, ls=":")
            else:
                ax.set_xticks(x)
                ax.set_xticklabels([str(v) for v in values])
            ax.set_xlabel(case.xlabel)
            ax.set_ylabel("distance to the true surface, mm" + (" (log)" if log else ""))
            bandtxt = "min–max" if band == "minmax" else "±1 std"
            ax.set_title(f"{case.title}\n{part}: {n_or} orientation(s) per value, {'shaded' if case.numeric else 'bars'} {bandtxt}", fontsize=10)
            ax.grid(True, which="both", alpha=0.3)
            handles, labels = ax.get_legend_handles_labels()
            fig.legend(handles, labels, fontsize=7, loc="lower center", ncol=3, frameon=False)
            fig.tight_layout(rect=(0, 0.03 * (1 + (len(labels) + 2) // 3), 1, 1))
            path = out / f"{case.stem}_{part}.png"
            fig.savefig(path)
            paths.append(path)
    return paths


def _colours(who: str, stat: str) -> str:
    return _COLOURS[(who, stat)]


# --------------------------------------------------------------------------- summary


def write_summary(rows: Sequence[Mapping[str, Any]], out: Path, cases: Sequence[Case], config: Mapping[str, Any]) -> Path:
    """``summary.md``: Table-1-style improvement ratios beside the paper's, then the errors."""
    groups = _groups(rows)
    methods = [m for m in METHODS if any(r["method"] == m for r in rows)]
    rig = config.get("rig", {})
    lines = [
        "# BCPS experiments",
        "",
        f"Preset `{config.get('preset')}`: {rig.get('cameras')} cameras, {rig.get('width')}x{rig.get('height')} px, "
        f"{rig.get('mm_per_px')} mm/px at the rig centre; methods: {', '.join(methods) or 'none'}; "
        f"{config.get('tasks', '?')} runs in {config.get('elapsed_s', float('nan')):.0f} s.",
        "Errors are distances of points to the true (simulated) surface. *Improvement* = reconstruction error / BCPS error "
        "(errors averaged over the orientations at each value), min–max over the sweep, as in the paper's Table 1. "
        "`ray` is this product's BCPS (exact rays, sub-pixel contours); `surface` is the paper's (reconstruction's surface points).",
        "",
        "## Improvement (Table 1 style)",
        "",
    ]
    head = ["sweep", "paper column (figure)", "runs ok"]
    for stat in ("mean", "max"):
        head += [f"{stat} error, {m}" for m in methods] + [f"{stat} error, paper"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for case in cases:
        for part in case.parts:
            rs = groups.get((case.name, part))
            if not rs:
                continue
            paper = PAPER_TABLE1.get((case.name, part))
            ok = sum(r["status"] == "ok" for r in rs)
            cells = [f"{case.number} {case.name}: {part}", f"{paper['label']} ({paper['figure']})" if paper else "— (not in Table 1)", f"{ok}/{len(rs)}"]
            for stat in ("mean", "max"):
                cells += [_fmt_range(ratio_ranges(rs, m, stat)) for m in methods]
                cells.append(_fmt_range(paper[stat]) if paper else "—")
            lines.append("| " + " | ".join(cells) + " |")
    lines += [
        "",
        "Paper columns Gauge, Blade and Cube-Sphere are measured on *real* objects in the paper (simulated here). "
        "Paper numbers: Pérez Soler et al. 2023, Table 1 (see docs/bcps-notes.md).",
        "",
        "## Errors, mm (mean over orientations; reconstruction / BCPS)",
        "",
    ]
    head = ["case", "part", "value", "n", "recon mean", "recon max"]
    for m in methods:
        head += [f"{m} mean", f"{m} max"]
    head += ["1 px, mm"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for case in cases:
        for part in case.parts:
            rs = groups.get((case.name, part))
            if not rs:
                continue
            values = _values_in_order(case, rs)
            rec = {s: _series(rs, values, None, f"recon_{s}_mm") for s in ("mean", "max")}
            per = {(m, s): _series(rs, values, m, f"bcps_{s}_mm") for m in methods for s in ("mean", "max")}
            fps = _series(rs, values, None, "footprint_mm")
            for i, v in enumerate(values):
                n = len({r["orientation"] for r in rs if r["value"] == v})
                cells = [str(case.number), part, f"{v:g}" if isinstance(v, float) else str(v), str(n),
                         _f(rec["mean"]["mean"][i]), _f(rec["max"]["mean"][i])]
                for m in methods:
                    cells += [_f(per[(m, "mean")]["mean"][i]), _f(per[(m, "max")]["mean"][i])]
                cells.append(_f(fps["mean"][i]))
                lines.append("| " + " | ".join(cells) + " |")
    bad = [r for r in rows if r["status"] != "ok"]
    lines += ["", "## Failed runs", ""]
    if not bad:
        lines.append("None.")
    else:
        lines.append(f"{len(bad)} of {len(rows)} rows (see the `error` column of the CSVs):")
        lines.append("")
        for r in sorted(bad, key=_sort_key)[:30]:
            lines.append(f"- case {r['case']}, {r['part']}, {r['variable']}={r['value']}, orientation {r['orientation']}, "
                         f"{r['method']}: {r.get('error') or 'error'}")
        if len(bad) > 30:
            lines.append(f"- ... and {len(bad) - 30} more")
    lines += ["", "## Files", ""]
    for case in cases:
        pngs = [f"`{case.stem}_{p}.png`" for p in case.parts if (case.name, p) in groups]
        lines.append(f"- `{case.stem}.csv`" + (": plots " + ", ".join(pngs) if pngs else ""))
    lines.append("")
    path = out / "summary.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def _f(x: float) -> str:
    return "—" if x is None or not math.isfinite(x) else f"{x:.4f}"


# --------------------------------------------------------------------------- CLI


def add_parser(subparsers: Any) -> None:
    """Add the ``experiment`` sub-command to ``subparsers`` (from ``add_subparsers``)."""
    e = subparsers.add_parser(
        "experiment",
        help="reproduce the paper's experiments (cases 1-3) with plots and a Table-1 summary (Dask)",
        description="Simulate, inspect and measure against the truth: case 1 scale (cube, sphere), case 2 impulse defects "
        "with image noise, case 3 objects with excess/missing material. Writes CSVs, PNG plots and summary.md.",
    )
    e.add_argument("cases", nargs="*", metavar="CASE", help="1|scale, 2|defects, 3|objects, or all (default all)")
    e.add_argument("--out", required=True, metavar="DIR", help="output folder (CSV, PNG, summary.md)")
    e.add_argument("--quick", action="store_true", help="quick preset: 512x512 px at 0.2 mm/px, fewer values and orientations")
    e.add_argument("--orientations", type=int, metavar="N", help="random orientations per value (default: 5 full, 1-2 quick)")
    e.add_argument("--scheduler", metavar="ADDRESS", help="connect to this Dask scheduler (e.g. tcp://host:8786) instead of starting a local cluster")
    e.add_argument("--workers", type=int, default=2, metavar="N", help="local cluster worker processes, one thread each (default 2)")
    e.add_argument("--parts", nargs="+", metavar="PART", help="only these parts of the chosen cases")
    e.add_argument("--values", nargs="+", metavar="V", help="override the swept values (scales, defect sizes in mm, or variants "
                   + "|".join(OBJECT_VARIANTS) + ")")
    e.add_argument("--methods", nargs="+", default=["ray", "surface"], choices=list(METHODS), help="BCPS methods (default: ray surface)")
    e.add_argument("--recipe", metavar="TOML", help="take the stages and tolerance from this recipe (its bcps stage is replaced by each method)")
    e.add_argument("--seed", type=int, default=0, help="seed of orientation 0 (orientation i uses seed + i; default 0)")
    e.add_argument("--band", choices=["minmax", "std"], default="minmax", help="shaded band over orientations in the plots (default minmax)")
    e.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


def run(args: argparse.Namespace) -> int:
    """Run ``inspector experiment``. Exit 0 if every run succeeded, 3 if some failed (rows kept)."""
    from inspector.errors import RecipeError

    try:
        import distributed  # noqa: F401
        import matplotlib  # noqa: F401
    except ImportError as e:
        raise RecipeError(f"experiment needs {e.name} (pip install 'dask[distributed]' matplotlib tqdm)") from None
    if args.orientations is not None and args.orientations < 1:
        raise RecipeError("experiment --orientations: expected a number >= 1")
    if args.workers < 1:
        raise RecipeError("experiment --workers: expected a number >= 1")
    preset = "quick" if args.quick else "full"
    cases = _resolve_cases(args.cases)
    stages, tolerance = _pipeline(args.recipe, preset)
    methods = list(dict.fromkeys(args.methods))
    specs = make_specs(cases, preset=preset, orientations=args.orientations, values=args.values, parts=args.parts,
                       methods=methods, seed=args.seed, stages=stages, tolerance=tolerance)
    _check_pipeline(stages, tolerance, methods)
    cases = [c for c in cases if any(s["case"] == c.name for s in specs)]

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    config = {
        "cases": [c.name for c in cases], "preset": preset, "rig": PRESETS[preset]["rig"], "methods": methods,
        "orientations": args.orientations, "values": args.values, "parts": args.parts, "seed": args.seed,
        "scheduler": args.scheduler, "workers": None if args.scheduler else args.workers, "stages": stages,
        "tolerance": tolerance, "tasks": len(specs), "case_sim": {c.name: c.sim for c in cases},
    }
    t0 = time.perf_counter()
    sink = _CsvSink(out, cases)
    rows: list[dict[str, Any]] = []
    client = cluster = None
    where = args.scheduler or f"a local cluster of {args.workers} worker process(es)"
    print(f"experiment: {len(specs)} runs ({', '.join(c.stem for c in cases)}; preset {preset}) on {where}", flush=True)
    try:
        client, cluster = start_client(args.scheduler, args.workers)
        rows = execute(specs, client, on_rows=sink.add, progress=not args.no_progress)
    finally:
        sink.close()
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
        config["elapsed_s"] = time.perf_counter() - t0
        if rows:
            write_csvs(rows, out, cases)
            write_plots(rows, out, cases, band=args.band)
            write_summary(rows, out, cases, config)
        (out / "experiment.json").write_text(json.dumps(config, indent=2, default=str), encoding="utf-8")
    bad = sum(r["status"] != "ok" for r in rows)
    print(f"experiment: {len(rows) - bad}/{len(rows)} inspections OK ({len(specs)} runs x {len(methods)} method(s)) in "
          f"{config['elapsed_s']:.0f} s; results in {out.resolve()} (summary.md, CSV, PNG)", flush=True)
    if bad or len(rows) < len(specs) * len(methods):
        print(f"inspector: error: {bad} inspection(s) failed; see the 'error' column of the CSVs and summary.md", file=sys.stderr)
        return 3
    return 0


# --------------------------------------------------------------------------- plugin
@hookimpl
def inspector_register_commands(registry: CommandRegistry) -> None:
    """``inspector experiment``: a built-in plugin (entry point ``experiment``), like any command."""
    from inspector.registry import CommandSpec

    registry.add(CommandSpec("experiment", add_parser, run, "the paper's experiments (cases 1-3) on Dask"))
