"""``inspector experiment``: the cases (the paper's sweeps, the rig presets, the pipeline) and
the task specs made from them (:func:`make_specs`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from inspector.errors import InspectorError, RecipeError
from inspector.manager import create_plugin_manager

__all__ = ["CASES", "PRESETS", "PAPER_TABLE1", "CSV_COLUMNS", "Case", "make_specs", "resolve_cases", "pipeline",
           "check_pipeline", "prefix_len", "err_line"]

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


def err_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text if isinstance(exc, InspectorError) else f"internal error {type(exc).__name__}: {text}"


# --------------------------------------------------------------------------- task specs


def resolve_cases(names: Sequence[str]) -> list[Case]:
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


def pipeline(recipe_path: str | None, preset: str = "full") -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Stages and tolerance of the experiment (from ``--recipe`` or the built-in pipeline).

    The built-in pipeline carves at the preset's pixel footprint: the paper's method selects
    among the reconstruction's points, so its error is the voxel's (cube, 0.5 mm voxels: mean
    0.149 mm, max 2.2 mm; 0.1 mm: 0.016 / 0.90), while ours, on exact rays, does not depend
    on it. The product's default recipe carves at 0.5 mm for speed.
    """
    import tomllib

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
        raise RecipeError("experiment: the recipe has no bcps stage")
    return out


def prefix_len(stages: list[dict[str, Any]]) -> int:
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


def check_pipeline(stages: list[dict[str, Any]], tolerance: Mapping[str, Any], methods: Sequence[str]) -> None:
    """Validate the pipeline for every method here, before anything is submitted."""
    from inspector.recipe import parse_recipe

    pm = create_plugin_manager()
    for m in methods:
        parse_recipe({"recipe": {"name": f"experiment-{m}", "reference": "builtin:cube30"},
                      "stages": _method_stages(stages, m), "tolerance": dict(tolerance)}, pm)

