"""``inspector feasibility REFERENCE --out DIR``: qualify a part before the cell is built.

The nominal part is simulated falling through the rig in N random poses, and N more
captures carry dents and bumps of a range of sizes placed at random in each region; the
recipe's own pipeline inspects every capture (:func:`inspector.runner.inspect_capture`, as
``inspector run`` does). :mod:`.analysis` turns the records into the observability map, the
probability of detection per region and kind of defect, the false-reject rate and a type-1
gauge study; :mod:`.report` writes them.

Simulations run on Dask as ``inspector experiment``'s do (its :func:`~inspector_tools.experiment_execution.execute`
and :func:`~inspector_tools.experiment_execution.start_client`): a LocalCluster by default, an existing cluster
with ``--scheduler``, a progress bar. Each simulation's seed is derived from the study's seed,
its kind and its index, so the same command gives the same numbers; each one's record is kept
in ``DIR/sims/`` as it arrives, and a re-run (after an interrupt, or with more poses) runs only
what is missing. With ``--scheduler``, the workers must see the reference file (and the
recipe's files) at the same paths, as with ``inspector experiment``.

Every bad input is refused before anything runs, in one line (exit 2): a reference that is
not watertight, a rig that does not see the part, a region the recipe does not have, a
tolerance narrower than the rig's pixel footprint allows.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import os
import sys
import time
import traceback
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from inspector import hookimpl
from inspector.errors import CaptureError, InspectorError, RecipeError, ReferenceMeshError
from inspector.jsonio import json_default
from inspector.manager import create_plugin_manager
from inspector.params import build_params
from inspector.reference import Reference
from inspector.registry import CommandRegistry, CommandSpec
from inspector.resources import recipe_path
from inspector_drivers.sim.simulate import SimParams, sim_rig, simulate
from inspector_plugins.evaluate import capability_warning
from inspector_tools.experiment_cases import PRESETS
from inspector_tools.experiment_execution import execute, start_client

if TYPE_CHECKING:
    from inspector.model import Rig
    from inspector.recipe import Recipe
    from inspector_tools.feasibility.surface import Regions, SurfaceMap

__all__ = ["Study", "add_parser", "run", "prepare", "make_specs", "run_sim", "SimCache", "sim_seed",
           "rig_blind_cameras"]

#: Version of a simulation record: a record of another version is simulated again.
RECORD_VERSION = 1

#: Simulator parameters that belong to one capture (set per simulation), not to the rig and
#: its imaging: a recipe's ``sim`` driver gives the rest.
PER_CAPTURE = ("part", "count", "seed", "scale", "bumps", "random_bumps", "defect_every", "bump_radius_mm",
               "bump_kind", "pose")

#: Kinds of simulation, and the code each one's seeds are derived with.
KINDS = {"nominal": 1, "defect": 2}
_PLACEMENT = 3

#: Largest defect size the default range goes to, mm (and at most 1/15 of the part's diagonal).
MAX_DEFAULT_SIZE_MM = 3.0


# --------------------------------------------------------------------------- the study


@dataclass(frozen=True, eq=False)
class Study:
    """A validated study: what every simulation needs (``config``, JSON-safe, hashed into
    ``key``) and what the orchestrator keeps for the analysis.

    Attributes
    ----------
    config : dict
        Reference, recipe document, simulator table, rig (rig.json content or None for the
        simulated rig), seed, counts, defect sizes, studied regions.
    key : str
        SHA-256 (16 hex digits) of ``config``: a record made for another key is redone.
    recipe : Recipe
    rig : Rig
    regions : Regions
    map : SurfaceMap
        The reference's surface elements.
    vertices, faces : arrays
        The reference (its own frame, mm).
    offset_mm : (3,) float
        The simulator's part frame minus the reference's (the simulator centres a mesh file
        on its bounding box).
    rig_label : str
        Where the rig comes from, in words.
    """

    config: dict[str, Any]
    key: str
    recipe: Recipe
    rig: Rig
    regions: Regions
    map: SurfaceMap
    vertices: np.ndarray
    faces: np.ndarray
    offset_mm: np.ndarray
    rig_label: str

    @property
    def footprint_mm(self) -> float:
        return float(self.rig.footprint_mm())

    @property
    def studied(self) -> list[str]:
        return list(self.config["regions"])


def sim_seed(seed: int, kind: str, index: int) -> int:
    """The simulator seed of simulation ``index`` of ``kind`` in a study seeded ``seed``
    (independent streams: adding poses never changes the earlier ones)."""
    return int(np.random.SeedSequence([int(seed), KINDS[kind], int(index)]).generate_state(1)[0] % (2**31 - 1))


def _resolve_reference(text: str) -> str:
    from inspector.parts import part_names

    if text.startswith("builtin:"):
        return text
    p = Path(text).expanduser()
    if p.exists():
        return str(p.resolve())
    if text in part_names():
        return f"builtin:{text}"
    raise RecipeError(f"reference {text!r}: no such file, nor a built-in part ({', '.join(part_names())})")


def _part_arg(ref: str) -> str:
    """The simulator's ``part`` for a reference spec."""
    return ref[len("builtin:"):] if ref.startswith("builtin:") else ref


def rig_blind_cameras(rig: Rig, radius_mm: float, *, samples: int = 400) -> list[str]:
    """Cameras whose image cannot hold a sphere of ``radius_mm`` about the rig centre (the
    world origin): a point of it projects outside the image or lies behind the camera.

    Parameters
    ----------
    rig : Rig
    radius_mm : float
        The part's bounding radius plus how far it may fall from the centre, mm.
    """
    i = np.arange(samples) + 0.5
    phi = np.arccos(1 - 2 * i / samples)
    theta = np.pi * (1 + 5**0.5) * i
    pts = radius_mm * np.column_stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)])
    blind = []
    for cam in rig.cameras:
        uv, depth = cam.project(pts)
        inside = (depth > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= cam.width - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= cam.height - 0.5)
        if not np.all(inside):
            blind.append(cam.name)
    return blind


def _axes_meet(rig: Rig) -> np.ndarray:
    """The point nearest to every camera's optical axis (least squares), world mm."""
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for cam in rig.cameras:
        d = cam.R[2]  # the optical axis in world coordinates
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ cam.centre
    return np.linalg.lstsq(A, b, rcond=None)[0]


def _sim_table(recipe: Recipe) -> dict[str, Any]:
    """The simulator's rig and imaging parameters from a recipe's ``sim`` driver ({} otherwise)."""
    if recipe.driver.spec.name != "sim":
        return {}
    table = dataclasses.asdict(recipe.driver.params)
    out = {}
    for k, v in table.items():
        if k in PER_CAPTURE:
            continue
        out[k] = list(v) if isinstance(v, tuple) else v
    return out


def _rig_file(path: str, flag: str) -> tuple[Rig, str]:
    from inspector.capture_folder import read_rig

    p = Path(path).expanduser()
    if p.is_dir():
        p = p / "rig.json"
    try:
        return read_rig(p), str(p)
    except CaptureError as e:
        raise RecipeError(f"{flag}: {e}") from None


def prepare(args: argparse.Namespace) -> Study:
    """Validate the command's inputs; RecipeError in one line for anything wrong (exit 2)."""
    from inspector.parts import load_reference
    from inspector.recipe import parse_recipe, read_recipe_toml
    from inspector_tools.feasibility.surface import build_map, default_element_mm

    for flag, value, least in (("--poses", args.poses, 2), ("--defect-captures", args.defect_captures, 0),
                               ("--defects-per-capture", args.defects_per_capture, 1), ("--workers", args.workers, 1),
                               ("--keep-captures", args.keep_captures, 0)):
        if value is not None and value < least:
            raise RecipeError(f"{flag}: expected a number >= {least}, got {value}")
    if args.defects_per_capture > 10:
        raise RecipeError(f"--defects-per-capture: at most 10, got {args.defects_per_capture}")

    ref = _resolve_reference(args.reference)
    try:
        mesh = load_reference(ref, recentre=False)
    except ReferenceMeshError as e:
        raise RecipeError(str(e)) from None
    V, F = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
    offset = np.zeros(3) if ref.startswith("builtin:") else -(V.max(axis=0) + V.min(axis=0)) / 2

    rpath = Path(args.recipe) if args.recipe else recipe_path("default.toml")
    table = read_recipe_toml(rpath)
    pm = getattr(args, "plugin_manager", None) or create_plugin_manager()
    recipe = parse_recipe(table, pm, path=rpath, reference=ref)
    kinds = [s.spec.kind for s in recipe.steps]
    if "bcps" not in kinds or "evaluate" not in kinds:
        raise RecipeError(f"{rpath.name}: feasibility needs a recipe with a bcps and an evaluate stage (it has: {', '.join(kinds)})")
    evaluate = next(s for s in recipe.steps if s.spec.kind == "evaluate")
    cluster_mm = float(getattr(evaluate.params, "cluster_radius_mm", 1.0))

    tol = recipe.tolerance
    regions = _regions(recipe, args.region, rpath)

    sim, rig, rig_label, rig_json = _study_rig(args, recipe, ref, rpath, V, offset)
    footprint = float(rig.footprint_mm())
    warning = capability_warning(tol, footprint)
    if warning is not None:
        raise RecipeError(f"{rpath.name}: {warning}")

    element = float(args.element_mm) if args.element_mm else default_element_mm(V, footprint)
    if not (math.isfinite(element) and element > 0):
        raise RecipeError(f"--element-mm: expected a size > 0 mm, got {args.element_mm}")
    smap = build_map(V, F, element, regions, seed=int(args.seed))
    area = smap.region_area()
    studied = list(args.region) if args.region else [n for i, n in enumerate(regions.names) if area[i] > 0]
    for name in studied:
        if area[regions.names.index(name)] <= 0:
            raise RecipeError(f"--region {name!r}: its box in {rpath.name} holds none of the reference's surface")

    bands = [regions.bands[regions.names.index(n)] for n in studied]
    narrow = min(min(-lo, hi) for lo, hi in bands)
    diag = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
    if args.sizes:
        lo_mm, hi_mm = (float(x) for x in args.sizes)
        if not (0 < lo_mm < hi_mm <= 50):
            raise RecipeError(f"--sizes: expected 0 < MIN < MAX <= 50 mm, got {args.sizes[0]} {args.sizes[1]}")
    else:
        lo_mm = max(0.5 * narrow, 0.02)
        hi_mm = max(min(MAX_DEFAULT_SIZE_MM, diag / 15.0), 4 * lo_mm)
    n_def = args.poses if args.defect_captures is None else args.defect_captures
    config = {
        "version": RECORD_VERSION,
        "reference": ref,
        "recipe_path": str(rpath.resolve()),
        "recipe": table,
        "sim": sim,
        "rig": rig_json,
        "seed": int(args.seed),
        "poses": int(args.poses),
        "defect_captures": int(n_def),
        "defects_per_capture": int(args.defects_per_capture),
        "sizes_mm": [lo_mm, hi_mm],
        "regions": studied,
        "cluster_radius_mm": cluster_mm,
    }
    key = hashlib.sha256(json.dumps(config, sort_keys=True, default=json_default).encode()).hexdigest()[:16]
    return Study(config, key, recipe, rig, regions, smap, V, F, offset, rig_label)



def _regions(recipe: Recipe, wanted: Iterable[str] | None, rpath: Path) -> Regions:
    """The recipe's tolerance regions (or the six surface patches when it has none); RecipeError
    for a ``--region`` it does not have."""
    from inspector_tools.feasibility.surface import PATCHES, Regions

    tol = recipe.tolerance
    if tol.regions:
        regions = Regions(("default", *(r.name for r in tol.regions)),
                          tuple((r.box_min, r.box_max) for r in tol.regions),
                          ((tol.default.lower, tol.default.upper), *((r.band.lower, r.band.upper) for r in tol.regions)))
    else:
        regions = Regions(PATCHES, (), ((tol.default.lower, tol.default.upper),) * len(PATCHES))
    for name in wanted or ():
        if name not in regions.names:
            have = (f"its regions: {', '.join(regions.names[1:])}" if not regions.patches
                    else f"it has no regions; the surface patches are {', '.join(PATCHES)}")
            raise RecipeError(f"--region {name!r}: no such region in {rpath.name} ({have})")
    return regions


def _study_rig(args: argparse.Namespace, recipe: Recipe, ref: str, rpath: Path, V: np.ndarray,
               offset: np.ndarray) -> tuple[dict[str, Any], Rig, str, Any]:
    """The simulator table, the rig (``--rig``, the recipe's, or the simulated one), its label
    and JSON (None for the simulated rig); RecipeError when its cameras cannot see the part."""
    sim = _sim_table(recipe)
    if args.quick:
        if args.rig:
            raise RecipeError("--quick and --rig: --quick is the simulated rig at 512x512 px, 0.2 mm/px; give one")
        sim |= {k: v for k, v in PRESETS["quick"]["rig"].items()}
    rig_json = None
    drv_rig = str(getattr(recipe.driver.params, "rig", "") or "")
    if args.rig:
        rig, where = _rig_file(args.rig, "--rig")
        rig_label, rig_json = f"rig {where}", rig.to_json()
    elif drv_rig:
        rig, where = _rig_file(drv_rig, f"{rpath.name}: driver.params.rig")
        rig_label, rig_json = f"the recipe's rig {where}", rig.to_json()
    else:
        try:
            p0 = build_params(SimParams, {**sim, "part": _part_arg(ref)}, f"{rpath.name}: driver.params")
        except ValueError as e:
            raise RecipeError(f"{rpath.name}: driver.params: {e}") from None
        rig = sim_rig(p0)
        rig_label = (f"the simulated rig ({p0.cameras} cameras, {p0.width}x{p0.height} px, {p0.mm_per_px:g} mm/px at the "
                     f"centre{', from the recipe' if recipe.driver.spec.name == 'sim' else ''})")
    sim_offset = float(sim.get("offset_mm", SimParams.offset_mm))
    radius = float(np.max(np.linalg.norm(V + offset, axis=1))) + sim_offset
    blind = rig_blind_cameras(rig, radius)
    if blind:
        meet = _axes_meet(rig)
        hint = (f"; its cameras' axes meet near ({meet[0]:.0f}, {meet[1]:.0f}, {meet[2]:.0f}) mm, the part falls through "
                "the origin" if np.linalg.norm(meet) > radius else "; aim them at the rig centre or widen their view")
        raise RecipeError(f"{rig_label} does not see the part: camera(s) {', '.join(blind[:6])}"
                          f"{' ...' if len(blind) > 6 else ''} cannot hold its {2 * radius:.0f} mm bounding sphere "
                          f"(the part in any pose, up to {sim_offset:g} mm off the rig centre) in their image{hint}")
    return sim, rig, rig_label, rig_json


# --------------------------------------------------------------------------- simulations


def _place_defects(study: Study, index: int) -> list[dict[str, Any]]:
    """The defects of defect capture ``index``: a dent and a bump in each region in turn,
    log-uniform sizes, centres uniform on the region's surface and apart from each other."""
    from inspector_tools.feasibility.surface import sample_surface

    cfg = study.config
    rng = np.random.default_rng(np.random.SeedSequence([cfg["seed"], _PLACEMENT, index]))
    pts, nrm = sample_surface(study.vertices, study.faces, 4000, rng)
    label = study.regions.label(pts, nrm)
    names = cfg["regions"]
    lo, hi = cfg["sizes_mm"]
    k = cfg["defects_per_capture"]
    gap = 2 * cfg["cluster_radius_mm"] + 1.0
    placed: list[dict[str, Any]] = []
    for j in range(k):
        g = index * k + j
        region = names[(g // 2) % len(names)]
        kind = ("remove", "add")[g % 2]
        size = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
        cand = np.flatnonzero(label == study.regions.names.index(region))
        rng.shuffle(cand)
        for c in cand[:200]:
            at = pts[c]
            if all(np.linalg.norm(at - np.asarray(d["at"])) >= size + d["radius_mm"] + gap for d in placed):
                placed.append({"at": [float(x) for x in at], "radius_mm": size, "kind": kind, "region": region})
                break
    return placed


def make_specs(study: Study, *, keep_captures: int = 0, out: Path | None = None) -> list[dict[str, Any]]:
    """One small, picklable spec per simulation: N nominal captures, then the defect ones."""
    cfg = study.config
    specs: list[dict[str, Any]] = []
    for kind, count in (("nominal", cfg["poses"]), ("defect", cfg["defect_captures"])):
        for i in range(count):
            spec: dict[str, Any] = {"name": f"{kind}-{i:04d}", "kind": kind, "index": i, "seed": sim_seed(cfg["seed"], kind, i),
                                    "key": study.key, "study": cfg, "offset_mm": [float(x) for x in study.offset_mm],
                                    "placed": _place_defects(study, i) if kind == "defect" else []}
            # What makes this simulation what it is: a record of another one is redone.
            spec["sim_key"] = hashlib.sha256(json.dumps(
                [study.key, spec["name"], spec["seed"], spec["placed"]], sort_keys=True, default=json_default).encode()).hexdigest()[:16]
            if kind == "nominal" and i < keep_captures and out is not None:
                spec["save_to"] = str((out / "captures").resolve())
            specs.append(spec)
    return specs


_WORKER: dict[str, Any] = {}


def _worker_context(spec: Mapping[str, Any]) -> dict[str, Any]:
    """Plugin manager, recipe, reference and rig of a study, built once per worker process."""
    key = spec["key"]
    if key in _WORKER:
        return _WORKER[key]
    from inspector.capture_folder import parse_rig
    from inspector.recipe import parse_recipe

    cfg = spec["study"]
    pm = create_plugin_manager()
    table = dict(cfg["recipe"])
    table["driver"] = {"use": "replay"}  # the study simulates: only the stages and tolerances matter
    recipe = parse_recipe(table, pm, path=Path(cfg["recipe_path"]), reference=cfg["reference"])
    reference = Reference.load(cfg["reference"])
    part = _part_arg(cfg["reference"])
    rig = parse_rig(cfg["rig"], "rig.json") if cfg["rig"] else sim_rig(build_params(SimParams, {**cfg["sim"], "part": part}, "feasibility"))
    _WORKER.clear()  # one study at a time per process
    _WORKER[key] = {"pm": pm, "recipe": recipe, "reference": reference, "rig": rig, "part": part}
    return _WORKER[key]


def _err_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    if isinstance(exc, InspectorError):
        return text
    where = traceback.format_exc().strip().splitlines()
    return f"internal error {type(exc).__name__}: {text}" + (f" | {where[-3].strip()}" if len(where) >= 3 else "")


def _base(spec: Mapping[str, Any]) -> dict[str, Any]:
    return {"name": spec["name"], "kind": spec["kind"], "index": spec["index"], "seed": spec["seed"],
            "sim_key": spec["sim_key"], "version": RECORD_VERSION, "status": "error", "error": ""}


def task_error_rows(spec: Mapping[str, Any], message: str) -> list[dict[str, Any]]:
    """The record of a simulation whose task failed (never kept: it runs again on a re-run)."""
    return [_base(spec) | {"error": message}]


def run_sim(spec: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Simulate one capture, inspect it with the study's recipe; one record. Never raises.

    The record holds the verdict, the reported defects (positions in the reference frame,
    through the true pose), and per BCPS point its position (reference frame), signed
    deviation and, for a nominal part, its distance to the true surface.
    """
    t0 = time.perf_counter()
    row = _base(spec)
    try:
        from inspector.runner import inspect_capture

        try:
            from distributed import get_worker

            row["worker"] = str(get_worker().name)
        except Exception:  # noqa: BLE001 - not in a worker (direct call)
            row["worker"] = ""
        ctx = _worker_context(spec)
        cfg = spec["study"]
        offset = np.asarray(spec["offset_mm"], float)
        bumps = [{"at": [float(x) for x in np.asarray(d["at"]) + offset], "radius_mm": d["radius_mm"], "kind": d["kind"]}
                 for d in spec["placed"]]
        p = build_params(SimParams, {**cfg["sim"], "part": ctx["part"], "seed": spec["seed"], "count": 1, "bumps": bumps},
                         "feasibility")
        t = time.perf_counter()
        capture = simulate(p, 0, ctx["rig"], name=spec["name"])
        row["t_simulate_s"] = time.perf_counter() - t
        if spec.get("save_to"):
            from inspector.capture_folder import save_capture

            save_capture(capture, Path(spec["save_to"]) / spec["name"], overwrite=True)
        assert capture.truth is not None
        pose = np.asarray(capture.truth.info["pose"], float)  # simulator part frame -> world
        shift = np.eye(4)
        shift[:3, 3] = offset
        pose = pose @ shift  # reference frame -> world
        res = inspect_capture(capture, ctx["recipe"], ctx["reference"], ctx["pm"]).result
        ref = ctx["reference"]
        row |= {"verdict": res.verdict, "error": res.error or "", "pose": pose.tolist(),
                "t_inspect_s": float(res.timings_s.get("total", math.nan)),
                "defects": [{"kind": d.kind, "at": ref.to_reference_frame(np.asarray([d.position]), pose)[0].tolist(),
                             "span_mm": float(np.linalg.norm(d.extent)), "worst_mm": d.worst_mm, "n_points": d.n_points,
                             "region": d.region} for d in res.defects],
                "placed": list(spec["placed"])}
        truth = (res.stats.get("truth") or {}).get("bcps") or {}
        row["truth_mean_mm"], row["truth_p99_mm"] = truth.get("mean_mm"), truth.get("p99_mm")
        row["footprint_mm"] = float(capture.rig.footprint_mm())
        if res.bcps is not None and len(res.bcps.points):
            pts = ref.to_reference_frame(res.bcps.points, pose)
            row["points"] = pts.astype(np.float32)
            row["deviation"] = np.asarray(res.bcps.deviation, np.float32)
            if spec["kind"] == "nominal":  # the true part is the reference: its surface, exactly
                row["dist_true"] = np.abs(ref.signed_distance(pts)).astype(np.float32)
        row["n_points"] = int(len(row.get("points", ())))
        row["status"] = "ok"
    except Exception as exc:  # noqa: BLE001 - a simulation never raises: its failure is a record
        row["error"] = _err_line(exc)
    row["t_run_s"] = time.perf_counter() - t0
    return [row]


# --------------------------------------------------------------------------- records


ARRAYS = ("points", "deviation", "dist_true")


class SimCache:
    """One file per finished simulation, ``DIR/sims/NAME.npz``: its record (JSON) and arrays.

    Written whole or not at all (a temporary file renamed); a record made for another
    simulation (another study, seed or defects: the spec's ``sim_key``) or another record
    version is not used: the simulation runs again and replaces it.
    """

    def __init__(self, out: Path) -> None:
        self.dir = Path(out) / "sims"

    def path(self, name: str) -> Path:
        return self.dir / f"{name}.npz"

    def _meta(self, name: str) -> dict[str, Any] | None:
        p = self.path(name)
        if not p.is_file():
            return None
        try:
            with np.load(p, allow_pickle=False) as z:
                meta = json.loads(str(z["meta"]))
        except Exception:  # noqa: BLE001 - a damaged file is a simulation to redo
            return None
        return meta if isinstance(meta, dict) else None

    def state(self, spec: Mapping[str, Any]) -> str:
        """``"done"``, ``"stale"`` (a record of another simulation or version) or ``"missing"``."""
        meta = self._meta(spec["name"])
        if meta is None:
            return "missing"
        return "done" if meta.get("sim_key") == spec["sim_key"] and meta.get("version") == RECORD_VERSION else "stale"

    def load(self, spec: Mapping[str, Any]) -> dict[str, Any] | None:
        """The record of ``spec`` with its arrays, or None when it is not done."""
        if self.state(spec) != "done":
            return None
        with np.load(self.path(spec["name"]), allow_pickle=False) as z:
            row = json.loads(str(z["meta"]))
            for k in ARRAYS:
                if k in z.files:
                    row[k] = np.asarray(z[k])
        return row

    def save(self, row: Mapping[str, Any]) -> None:
        """Keep a finished simulation's record (records of failed tasks are not kept)."""
        if row.get("status") != "ok":
            return
        self.dir.mkdir(parents=True, exist_ok=True)
        meta = {k: v for k, v in row.items() if k not in ARRAYS}
        arrays = {k: np.asarray(row[k]) for k in ARRAYS if k in row}
        tmp = self.dir / f".{row['name']}.{os.getpid()}.tmp.npz"
        try:
            np.savez_compressed(tmp, meta=np.asarray(json.dumps(meta, default=json_default)), **arrays)  # type: ignore[arg-type]
            os.replace(tmp, self.path(row["name"]))
        finally:
            tmp.unlink(missing_ok=True)

    def save_rows(self, rows: Iterable[Mapping[str, Any]]) -> None:
        for r in rows:
            self.save(r)


# --------------------------------------------------------------------------- CLI


def add_parser(subparsers: Any) -> None:
    """Add the ``feasibility`` sub-command to ``subparsers``."""
    f = subparsers.add_parser(
        "feasibility",
        help="qualify a part from its CAD: observability map, probability of detection, gauge study (Dask)",
        description="Simulate the nominal part falling through the rig in N random poses, and N captures with dents and "
        "bumps of a range of sizes in each region; inspect each with the recipe's pipeline. Writes the observability "
        "map (PLY, pictures), POD curves (MIL-HDBK-1823A), a type-1 gauge study and feasibility.md / .html.",
    )
    f.add_argument("reference", metavar="REFERENCE", help="the part's CAD: STL/PLY/OBJ in mm, or builtin:NAME (or a built-in NAME)")
    f.add_argument("--out", required=True, metavar="DIR", help="output folder (kept simulations in DIR/sims: a re-run resumes)")
    f.add_argument("--recipe", metavar="R", help="the recipe whose stages and tolerances are studied (default recipes/default.toml); "
                   "its sim driver's rig and imaging, or its driver's rig file, are the rig")
    f.add_argument("--rig", metavar="RIG.json", help="the rig to study (rig.json, or a capture folder holding one)")
    f.add_argument("--quick", action="store_true", help="the simulated rig at 512x512 px, 0.2 mm/px (about 3x faster)")
    f.add_argument("--poses", type=int, default=100, metavar="N", help="nominal captures in random poses (default 100); "
                   "also the gauge study's repeats")
    f.add_argument("--defect-captures", type=int, metavar="N", help="captures with defects (default: as many as --poses)")
    f.add_argument("--defects-per-capture", type=int, default=3, metavar="K", help="defects placed apart in each (default 3)")
    f.add_argument("--sizes", type=float, nargs=2, metavar=("MIN", "MAX"), help="range of defect sizes, mm (sphere radius: the "
                   "depth of a dent, the height of a bump); default half the narrowest limit to min(3 mm, diagonal/15)")
    f.add_argument("--region", action="append", metavar="NAME", help="study only this region of the recipe (repeatable; default "
                   "all; a recipe without regions has the patches +x -x +y -y +z -z)")
    f.add_argument("--element-mm", type=float, metavar="MM", help="surface element size of the map (default diagonal/60)")
    f.add_argument("--seed", type=int, default=0, help="study seed: every simulation's seed derives from it (default 0)")
    f.add_argument("--keep-captures", type=int, default=0, metavar="K", help="also write the first K nominal captures to "
                   "DIR/captures (replayable with inspector run)")
    f.add_argument("--scheduler", metavar="ADDRESS", help="run on this Dask scheduler (e.g. tcp://host:8786) instead of a local cluster")
    f.add_argument("--workers", type=int, default=2, metavar="N", help="local cluster worker processes (default 2)")
    f.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


def run(args: argparse.Namespace) -> int:
    """Run ``inspector feasibility``: 0 when every simulation ran, 3 when some failed (the
    report is made from the others; a re-run retries them)."""
    try:
        import distributed  # noqa: F401
        import matplotlib  # noqa: F401
        import statsmodels  # noqa: F401
    except ImportError as e:
        raise RecipeError(f"feasibility needs {e.name} (pip install 'dask[distributed]' matplotlib statsmodels)") from None
    from inspector_tools.feasibility.analysis import analyse
    from inspector_tools.feasibility.report import write_report

    t0 = time.perf_counter()
    study = prepare(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    specs = make_specs(study, keep_captures=args.keep_captures, out=out)
    cache = SimCache(out)
    states = {s["name"]: cache.state(s) for s in specs}
    todo = [s for s in specs if states[s["name"]] != "done"]
    stale = sum(v == "stale" for v in states.values())
    cfg = study.config
    where = args.scheduler or f"a local cluster of {args.workers} worker process(es)"
    print(f"feasibility: {_part_arg(cfg['reference'])}, {cfg['poses']} nominal + {cfg['defect_captures']} defect captures "
          f"({cfg['defects_per_capture']} defects each, {cfg['sizes_mm'][0]:.3g}-{cfg['sizes_mm'][1]:.3g} mm) on {study.rig_label}; "
          f"{len(specs) - len(todo)} already done in {cache.dir}" + (f" ({stale} of another study, redone)" if stale else "")
          + (f", {len(todo)} to run on {where}" if todo else ""), flush=True)
    (out / "study.json").write_text(json.dumps({"key": study.key, **cfg}, indent=2, default=json_default), encoding="utf-8")
    failed: list[dict[str, Any]] = []
    if todo:
        client = cluster = None
        try:
            client, cluster = start_client(args.scheduler, args.workers, "feasibility")
            rows = execute(todo, client, fn=run_sim, on_rows=cache.save_rows, progress=not args.no_progress,
                           label=lambda s: str(s["name"]), errors=task_error_rows, desc="feasibility")
        finally:
            if client is not None:
                client.close()
            if cluster is not None:
                cluster.close()
        failed = [r for r in rows if r["status"] != "ok"]
    records = [r for s in specs if (r := cache.load(s)) is not None]
    results = analyse(study, records, elapsed_s=time.perf_counter() - t0, ran=len(todo))
    paths = write_report(results, out)
    for line in results.conclusions():
        print(f"  {line}")
    print(f"feasibility: {len(records)}/{len(specs)} simulations in {time.perf_counter() - t0:.0f} s; report "
          f"{paths['md']} and {paths['html'].name}, map {paths['ply'].name}, pictures {paths['observability'].name}", flush=True)
    if failed:
        for r in failed[:5]:
            print(f"inspector: error: {r['name']}: {r['error']}", file=sys.stderr)
        print(f"inspector: error: {len(failed)} simulation(s) failed; the report is made from the others, a re-run retries them",
              file=sys.stderr)
        return 3
    return 0


@hookimpl
def inspector_register_commands(registry: CommandRegistry) -> None:
    """``inspector feasibility``: a built-in plugin (entry point ``feasibility``), like ``experiment``."""
    registry.add(CommandSpec("feasibility", add_parser, run,
                             "qualify a part from its CAD: observability, POD, gauge study, report (Dask)"))
