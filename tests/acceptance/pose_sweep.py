"""Pose sweep (issue 14): is the pose right on near-symmetric parts, in random poses, at small scale errors?

Independent of the product (imports nothing from ``inspector``, ``inspector_plugins`` or
``inspector_drivers``): captures are written by ``foreign_capture.py`` (cached under
``--work``), inspected by the real ``inspector run RECIPE --capture CAP [CAP ...] --reference
NOMINAL.stl --out OUT -q`` in a subprocess (one process per batch of captures of one part),
and measured here against the truth, which the product never sees.

Per capture:

* **pose error** up to the part's own symmetry group ``G`` (``foreign_capture.SYMMETRY``,
  rotations in the part frame, verified on the mesh by ``foreign_capture.py selfcheck``).
  Conventions: truth.json ``pose`` and result.json ``pose`` are both part (reference) ->
  world, ``x_world = R @ x_part + t``; the reference is the nominal mesh in the part frame
  (bounding-box centred, which every symmetry fixes). ``R_true @ S`` places the part exactly
  as ``R_true`` does for every ``S`` in ``G``, so the error is
  ``min over S of angle(R_est^T @ R_true @ S)``; the residual ``E = S^T @ R_true^T @ R_est``
  (``R_est = (R_true @ S) @ E``, part frame) is split into a turn about the part's axis (z)
  and a tilt of that axis. ``--selftest`` checks the composition on known rotations and
  against the mesh itself.
* **shift**: ``|t_est - t_true|`` mm (the symmetries fix the origin, so it needs no minimum).
* **size fit**: result.json ``stats.size_fit.scale`` when present; ``fitness``: ``stats.alignment``.
* **BCPS accuracy**: mean / p99 / max distance of ``bcps_points.ply`` to the true surface in
  pixel footprints (``measure.py``), against the condition's bar (grey: mean <= 0.1 px and
  p99 <= 0.5 px; binary: mean <= 0.25; strong: mean <= 0.3).
* **verdict** against the expected one: *fail* when the true (scaled) surface leaves the
  recipe's default tolerance band somewhere (every scale of the default set on these parts:
  2 % of a 25 mm radius is 0.5 mm, the band is +-0.1 mm), else *pass*.
* **false defects**: a reported defect cluster is *explained* when the true surface itself
  deviates from the nominal (placed by the true pose) beyond the band, in the same direction,
  within the cluster's box (+1 mm), and the reported worst deviation is no larger than the
  true one plus ``--explain-mm`` (a lower bound is fine: excess material may hide in the
  hull). Every cluster on a nominal part is false; on a scaled part, one at a bolt hole of
  -2.9 mm where the part is 0.4 mm small is false too.

CLI::

    .venv/bin/python tests/acceptance/pose_sweep.py --parts flange keyshaft --scales 1.00 0.98 \\
        --poses 2 --cameras 16 --work out/pose_sweep
    .venv/bin/python tests/acceptance/pose_sweep.py --capture-only --parts disc5 gear --poses 4
    .venv/bin/python tests/acceptance/pose_sweep.py --measure-only ...   # re-measure existing results
    .venv/bin/python tests/acceptance/pose_sweep.py --selftest
    # the documented sweep (``make pose-sweep``): resumable, summary into docs/acceptance.md
    .venv/bin/python tests/acceptance/pose_sweep.py --parts flange hub keyshaft flatshaft gear disc5 \\
        --cameras 16 12 8 --poses 3 --batch 4 --resume --md-section docs/acceptance.md

Writes ``WORK/pose_sweep.json`` (every metric, one row per capture; ``--json`` elsewhere) and
``WORK/pose_sweep.md``, and prints a markdown table (``--md`` also writes it).
``--md-section FILE`` writes a summary (one line per part and rig: captures meeting every
bar, worst pose error, false defects; then the captures that miss a bar) between the
markers ``<!-- pose-sweep:begin -->`` and ``<!-- pose-sweep:end -->`` of FILE (appended
when absent), so a rerun replaces it.

Caching: a capture is written once (``truth/<name>/sweep.json`` records what it was made
from). With ``--resume`` an inspection is reused when its result folder carries a
``sweep-run.json`` stamp of the same capture and the same product (a hash of the sources
under ``inspector/`` (but its GUI), ``inspector_plugins/`` and ``inspector_drivers/``, ``pyproject.toml`` and the recipe), and its
measurement when ``sweep-row.json`` matches that stamp and this instrument's sources too: an
interrupted sweep continues where it stopped, and one rerun after the product changed
inspects everything again. Exit status: 0 every row meets every bar,
1 some row does not, 2 a run failed (an ``inspector run`` exit status other than 0/1, or a
capture without result), 3 the self-test failed.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import time
import tomllib
import zlib
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent))  # siblings, when run as a script

import foreign_capture as fc
import measure as ms

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_RECIPE = ROOT / "recipes" / "default.toml"
DEFAULT_PARTS = ("disc2", "disc3", "disc5", "disc8", "flange", "hub", "keyshaft", "flatshaft", "gear")
#: The issue's bars: pose within 0.1 degree; BCPS (mean px, p99 px or None) per condition.
POSE_BAR_DEG = 0.1
BARS: dict[str, tuple[float, float | None]] = {"grey": (0.1, 0.5), "binary": (0.25, None), "strong": (0.3, None),
                                               "exact": (0.1, 0.5)}


def _find_inspector() -> Path:
    for cand in (Path(sys.executable).parent / "inspector", ROOT / ".venv" / "bin" / "inspector"):
        if cand.exists():
            return cand
    return Path("inspector")


INSPECTOR = _find_inspector()


# --------------------------------------------------------------------------- pose error


def pose_error(R_est: np.ndarray, R_true: np.ndarray, group: list[np.ndarray] | None) -> dict[str, Any]:
    """Rotation error of an estimated pose up to the part's symmetry group.

    Parameters
    ----------
    R_est, R_true : (3, 3)
        Part -> world rotations (``x_world = R @ x_part + t``): the product's and the truth's.
    group : list of (3, 3), or None
        The part's symmetries ``S`` (part frame: ``S @ part == part``); None: identity only.

    Returns
    -------
    dict
        ``deg``: ``min over S of angle(R_est^T R_true S)``; ``raw_deg``: the angle without
        symmetry; ``sym``: index of the minimising ``S``; ``about_axis_deg`` (signed turn about
        the part's z axis, the twist of the residual ``E = S^T R_true^T R_est``) and
        ``tilt_deg`` (the rest: how far the axis itself is off).
    """
    G = group or [np.eye(3)]
    E0 = R_true.T @ R_est
    angles = [Rotation.from_matrix(S.T @ E0).magnitude() for S in G]
    k = int(np.argmin(angles))
    q = Rotation.from_matrix(G[k].T @ E0).as_quat()  # x, y, z, w
    twist = 2.0 * math.atan2(q[2], q[3])  # swing-twist about z
    twist = (twist + math.pi) % (2.0 * math.pi) - math.pi
    swing = Rotation.from_matrix(G[k].T @ E0) * Rotation.from_rotvec([0.0, 0.0, -twist])
    return {"deg": math.degrees(angles[k]), "raw_deg": math.degrees(Rotation.from_matrix(E0).magnitude()), "sym": k,
            "about_axis_deg": math.degrees(twist), "tilt_deg": math.degrees(swing.magnitude())}


def placement_gap(part: str, T_true: np.ndarray, T_est: np.ndarray, tol_mm: float, n: int = 4000) -> tuple[bool, float]:
    """Whether the nominal surface placed by ``T_est`` (4, 4) lies ``tol_mm`` or more from the
    one placed by ``T_true`` somewhere (exact, on ``n`` seeded samples), and that distance (a
    lower bound of the largest when True, the largest when False). Distances are rigid
    invariants, so the samples are brought back by ``T_true^-1 @ T_est`` and measured against
    the nominal mesh in its own frame."""
    from measure import TriangleIndex

    mesh = fc.make_part(part)
    P = fc._surface_samples(mesh, n, np.random.default_rng(3))
    M = np.linalg.inv(T_true) @ T_est
    return fc._farthest(P @ M[:3, :3].T + M[:3, 3], tol_mm, TriangleIndex(mesh.vertices, mesh.faces))


def selftest(verbose: bool = True) -> None:
    """The pose-error composition on known rotations, and against the meshes themselves.

    Raises AssertionError on any failure.
    """
    rng = np.random.default_rng(2024)
    for part in ("flange", "hub", "disc5", "keyshaft", "gear"):
        G = fc.symmetry_group(part)
        R_true = Rotation.random(random_state=rng).as_matrix()
        # Identity and every symmetry, composed on the right (part frame): no error.
        for S in G:
            e = pose_error(R_true @ S, R_true, G)
            assert e["deg"] < 1e-6 and e["tilt_deg"] < 1e-6, (part, e)
        # A known turn about the part's axis: its angle, reduced by the nearest symmetry.
        for th in (0.05, 1.0, 22.0, 100.0, -143.0):
            e = pose_error(R_true @ Rotation.from_euler("z", th, degrees=True).as_matrix(), R_true, G)
            zturns = [math.degrees(math.atan2(S[1, 0], S[0, 0])) for S in G if abs(S[2, 2] - 1.0) < 1e-9]
            want = min(abs((th - z + 180.0) % 360.0 - 180.0) for z in zturns)
            assert abs(e["deg"] - want) < 1e-6 and e["tilt_deg"] < 1e-6, (part, th, want, e)
            if want == abs(th):
                assert abs(e["about_axis_deg"] - th) < 1e-6, (part, th, e)
        # A known tilt of the axis (about x, in the part frame).
        e = pose_error(R_true @ Rotation.from_euler("x", 0.2, degrees=True).as_matrix(), R_true, G)
        assert abs(e["deg"] - 0.2) < 1e-6 and abs(e["tilt_deg"] - 0.2) < 1e-6 and abs(e["about_axis_deg"]) < 1e-6, e
        # The same rotation in the world frame has the same size when there is no symmetry.
        W = Rotation.from_rotvec(rng.normal(size=3) * 0.01).as_matrix()
        e = pose_error(W @ R_true, R_true, [np.eye(3)])
        assert abs(e["deg"] - math.degrees(Rotation.from_matrix(W).magnitude())) < 1e-6, e
        # Against the mesh, with the transforms make_capture applies (part -> world pose on
        # the mesh): R_true S puts the surface where R_true does; S R_true (the symmetry
        # wrongly applied in the world frame) does not, and neither does a non-symmetry.
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R_true, rng.uniform(-3, 3, 3)
        for S in G:
            Te = T.copy()
            Te[:3, :3] = R_true @ S
            assert not placement_gap(part, T, Te, 1e-3)[0], (part, "R_true S")
        nonsym = [S for S in G if not np.allclose(S, np.eye(3))]
        if nonsym:
            Te = T.copy()
            Te[:3, :3] = nonsym[0] @ R_true
            assert placement_gap(part, T, Te, 0.1)[0], (part, "S R_true")
        Te = T.copy()
        Te[:3, :3] = R_true @ Rotation.from_euler("z", 7.0, degrees=True).as_matrix()
        assert placement_gap(part, T, Te, 0.1)[0], (part, "7 deg")
        if verbose:
            print(f"selftest {part:9s} |G| = {len(G):2d}: pose error composition and mesh check ok")


# --------------------------------------------------------------------------- captures (cached)


def _sha_files(paths: list[Path]) -> str:
    h = hashlib.sha1()
    for f in paths:
        h.update(str(f.relative_to(ROOT) if f.is_relative_to(ROOT) else f).encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def product_stamp(recipe: Path) -> str:
    """What an inspection's result depends on besides the capture: the product's sources
    (``inspector/``, ``inspector_plugins/``, ``inspector_drivers/``: every ``.py`` but the GUI's, which ``inspector
    run`` never imports), ``pyproject.toml`` and the recipe."""
    files = sorted(f for d in ("inspector", "plugins", "drivers") for f in (ROOT / d).rglob("*.py")
                   if "__pycache__" not in f.parts and not f.is_relative_to(ROOT / "inspector" / "gui"))
    return _sha_files(files + [ROOT / "pyproject.toml", Path(recipe).resolve()])


def instrument_stamp() -> str:
    """The measurement's own sources: a cached measurement is redone when they change."""
    here = Path(__file__).resolve().parent
    return _sha_files([here / "pose_sweep.py", here / "measure.py", here / "foreign_capture.py"])


def capture_seed(base: int, part: str, k: int) -> int:
    """Seed of pose ``k`` of ``part``: stable across runs and part lists, the same for every
    scale, rig and condition (so a nominal and a scaled capture share their pose)."""
    return base + 1000 * (zlib.crc32(part.encode()) % 100_000) + k


def capture_name(part: str, condition: str, cameras: int, scale: float, seed: int) -> str:
    return f"{part}-{condition}-c{cameras}-x{scale:.3f}-s{seed}"


def _mesh_sha(part: str) -> str:
    m = fc.make_part(part)
    h = hashlib.sha1(np.ascontiguousarray(m.vertices, np.float64).tobytes())
    h.update(np.ascontiguousarray(m.faces, np.int64).tobytes())
    return h.hexdigest()


def _spec(job: dict[str, Any], mesh_sha: str) -> dict[str, Any]:
    return {k: job[k] for k in ("part", "condition", "cameras", "scale", "seed", "polarity")} | {"mesh_sha1": mesh_sha}


def _cached(work: Path, job: dict[str, Any], mesh_sha: str) -> bool:
    side = work / "truth" / job["name"] / "sweep.json"
    cap = work / "captures" / job["name"]
    if not (side.is_file() and (cap / "rig.json").is_file()):
        return False
    try:
        return json.loads(side.read_text()) == _spec(job, mesh_sha)
    except (OSError, json.JSONDecodeError):
        return False


def _write_one(work: str, job: dict[str, Any], mesh_sha: str) -> dict[str, Any]:
    """Write one capture (a worker process); the sidecar ``sweep.json`` marks it complete."""
    work_p = Path(work)
    for d in (work_p / "captures" / job["name"], work_p / "truth" / job["name"]):
        shutil.rmtree(d, ignore_errors=True)
    scaled = abs(job["scale"] - 1.0) > 1e-12
    made = fc.make_capture(work_p, job["part"], job["condition"], "scale" if scaled else "none", seed=job["seed"],
                           polarity=job["polarity"], name=job["name"], cameras=job["cameras"],
                           scale=job["scale"] if scaled else 0.98)
    (work_p / "truth" / job["name"] / "sweep.json").write_text(json.dumps(_spec(job, mesh_sha)))
    return {"name": job["name"], "render_s": made["render_s"]}


def write_captures(work: Path, jobs: list[dict[str, Any]], n_proc: int,
                   shas: dict[str, str] | None = None) -> dict[str, float]:
    """Write the captures of ``jobs`` not already cached under ``work``; returns render seconds by name.
    ``shas``: :func:`_mesh_sha` by part, when already known."""
    shas = shas or {p: _mesh_sha(p) for p in {j["part"] for j in jobs}}
    todo = [j for j in jobs if not _cached(work, j, shas[j["part"]])]
    print(f"captures: {len(jobs) - len(todo)} cached, {len(todo)} to write", file=sys.stderr, flush=True)
    out: dict[str, float] = {}
    if not todo:
        return out
    if n_proc <= 1:
        for j in todo:
            r = _write_one(str(work), j, shas[j["part"]])
            out[r["name"]] = r["render_s"]
            print(f"  wrote {r['name']} ({r['render_s']:.1f} s)", file=sys.stderr, flush=True)
        return out
    with ProcessPoolExecutor(n_proc, mp_context=get_context("spawn")) as ex:
        for r in ex.map(_write_one, [str(work)] * len(todo), todo, [shas[j["part"]] for j in todo]):
            out[r["name"]] = r["render_s"]
            print(f"  wrote {r['name']} ({r['render_s']:.1f} s)", file=sys.stderr, flush=True)
    return out


# --------------------------------------------------------------------------- inspection (batched)


def inspect_batches(work: Path, out_root: Path, jobs: list[dict[str, Any]], recipe: Path, n_proc: int,
                    batch: int, threads: int | None) -> dict[str, dict[str, Any]]:
    """Run ``inspector run`` once per batch (captures of one part, at most ``batch`` each),
    ``n_proc`` batches at a time. Returns, by capture name, the result folder, the batch's exit
    status, its wall time and the tail of its stderr."""
    by_part: dict[str, list[dict[str, Any]]] = {}
    for j in jobs:
        by_part.setdefault(j["part"], []).append(j)
    batches = []
    for part, js in by_part.items():
        size = batch if batch > 0 else len(js)
        if n_proc > 1 and batch <= 0:  # spread one part's captures over the processes too
            size = max(1, math.ceil(len(js) / n_proc))
        for i in range(0, len(js), size):
            batches.append((f"{part}-{i // size}", js[i:i + size]))
    env = dict(os.environ)
    if threads:
        for k in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            env[k] = str(threads)

    def run(b: tuple[str, list[dict[str, Any]]]) -> dict[str, dict[str, Any]]:
        tag, js = b
        out = out_root / tag
        for j in js:  # no stale result is ever measured (nor found by --resume elsewhere)
            for old in [out / j["name"], *out_root.glob(f"*/{j['name']}")]:
                shutil.rmtree(old, ignore_errors=True)
        ref = work / "truth" / js[0]["name"] / "reference.stl"
        cmd = [str(INSPECTOR), "run", str(recipe), "--capture", *[str(work / "captures" / j["name"]) for j in js],
               "--out", str(out), "--reference", str(ref), "-q"]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
        wall = time.perf_counter() - t0
        print(f"  inspected batch {tag} ({len(js)} captures): exit {proc.returncode}, {wall:.0f} s",
              file=sys.stderr, flush=True)
        err = "\n".join(proc.stderr.strip().splitlines()[-5:])
        return {j["name"]: {"result_dir": out / j["name"], "exit": proc.returncode, "batch": tag,
                            "batch_s": wall, "batch_n": len(js), "stderr": err} for j in js}

    res: dict[str, dict[str, Any]] = {}
    with ThreadPoolExecutor(max(1, n_proc)) as ex:
        for r in ex.map(run, batches):
            res.update(r)
    return res


def find_results(out_root: Path, jobs: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """``--measure-only``: the newest existing result folder of each capture under ``out_root``."""
    res: dict[str, dict[str, Any]] = {}
    for j in jobs:
        cands = sorted(out_root.glob(f"*/{j['name']}/result.json"), key=lambda p: p.stat().st_mtime)
        if cands:
            res[j["name"]] = {"result_dir": cands[-1].parent, "exit": None, "batch": cands[-1].parent.parent.name}
    return res


# --------------------------------------------------------------------------- measurement


def _tolerance(recipe: Path) -> tuple[float, float]:
    t = tomllib.loads(recipe.read_text()).get("tolerance", {}).get("default", {})
    return float(t.get("lower", -0.1)), float(t.get("upper", 0.1))


def real_deviation(truth_dir: Path, n: int = 30000) -> tuple[np.ndarray, np.ndarray]:
    """Samples of the true surface (world, (n, 3) mm) and their signed distance to the nominal
    placed by the true pose (mm, negative inside: missing material): what a correct pose and
    exact points would report there."""
    truth = json.loads((truth_dir / "truth.json").read_text())
    tw = np.load(truth_dir / "true_world.npz")
    import trimesh

    true_mesh = trimesh.Trimesh(tw["vertices"], tw["faces"], process=False)
    X = fc._surface_samples(true_mesh, n, np.random.default_rng(7))
    nominal = trimesh.load_mesh(truth_dir / "reference.stl")
    pose = np.asarray(truth["pose"])
    Vn = np.asarray(nominal.vertices, float) @ pose[:3, :3].T + pose[:3, 3]
    return X, ms.distances_to_mesh(X, Vn, np.asarray(nominal.faces))[1]


def judge_defects(defects: list[dict[str, Any]], X: np.ndarray, d_real: np.ndarray, band: tuple[float, float],
                  explain_mm: float, margin_mm: float = 1.0) -> list[dict[str, Any]]:
    """Each reported defect with ``real_mm`` (the true surface's extreme deviation in its box)
    and ``explained`` (see the module docstring)."""
    lower, upper = band
    out = []
    for d in defects:
        c, e = np.asarray(d["position"], float), np.asarray(d["extent"], float)
        inside = np.all(np.abs(X - c) <= e / 2.0 + margin_mm, axis=1)
        missing = d["kind"] == "missing"
        real = float(d_real[inside].min() if missing else d_real[inside].max()) if inside.any() else float("nan")
        beyond = (real < lower) if missing else (real > upper)
        explained = bool(inside.any() and beyond and abs(d["worst_mm"]) <= abs(real) + explain_mm)
        out.append({"kind": d["kind"], "n_points": d["n_points"], "worst_mm": d["worst_mm"], "real_mm": real,
                    "explained": explained, "position": d["position"]})
    return out


def measure_one(job: dict[str, Any], run: dict[str, Any] | None, work: Path, band: tuple[float, float],
                explain_mm: float) -> dict[str, Any]:
    """Every metric of one capture (see the module docstring)."""
    truth_dir = work / "truth" / job["name"]
    truth = json.loads((truth_dir / "truth.json").read_text())
    row: dict[str, Any] = {k: job[k] for k in ("part", "scale", "pose", "seed", "cameras", "condition", "name")}
    X, d_real = real_deviation(truth_dir)
    row["real_dev_mm"] = [float(d_real.min()), float(d_real.max())]
    row["expected"] = "fail" if (d_real.min() < band[0] or d_real.max() > band[1]) else "pass"
    if run is None or not (Path(run["result_dir"]) / "result.json").is_file():
        row.update({"verdict": "missing", "run_failed": True,
                    "error": (run or {}).get("stderr") or "no result.json", "exit": (run or {}).get("exit")})
        return row
    rdir = Path(run["result_dir"])
    res = json.loads((rdir / "result.json").read_text())
    row.update({"exit": run.get("exit"), "batch": run.get("batch"), "result_dir": str(rdir)})
    m = {k: v for k, v in ms.measure(rdir, truth_dir).items() if k not in ("worst", "per_camera")}
    m["misfit"] = m.pop("pose", None)  # measure.pose_misfit: surface-based, symmetry-proof
    row.update(m)
    # A batch's exit status 3 says that *some* capture could not be inspected: that one has
    # verdict "error"; any other status but 0/1 is a failure of the whole batch.
    # An "error" verdict that still has a pose is the product declining to judge (e.g. a
    # pose it reports as uncertain): a verdict that misses the expected one, not a failed run.
    row["run_failed"] = (res.get("verdict") == "error" and res.get("pose") is None) \
        or run.get("exit") not in (0, 1, 3, None)
    if row["run_failed"] or res.get("verdict") == "error":
        row["error"] = res.get("error") or run.get("stderr")
    stats = res.get("stats") or {}
    row["size_fit"] = (stats.get("size_fit") or {}).get("scale")
    al = stats.get("alignment")
    row["fitness"] = al.get("fitness") if isinstance(al, dict) else None
    row["timings_total_s"] = (res.get("timings_s") or {}).get("total")
    # Whatever the product reports about its pose's certainty (issue 14, item 2), kept as is.
    row["pose_stats"] = {k: v for k, v in stats.items() if "pose" in k.lower() or "confidence" in k.lower()}
    G = fc.symmetry_group(job["part"]) if fc.SYMMETRY.get(job["part"]) is not None else None
    if res.get("pose") is not None:
        P_est, P_true = np.asarray(res["pose"], float), np.asarray(truth["pose"], float)
        row["pose_err"] = pose_error(P_est[:3, :3], P_true[:3, :3], G) if G is not None else None
        row["shift_mm"] = float(np.linalg.norm(P_est[:3, 3] - P_true[:3, 3]))
    defects = judge_defects(res.get("defects") or [], X, d_real, band, explain_mm)
    row["defects"] = defects
    false = [d for d in defects if not d["explained"]]
    row["n_false"] = len(false)
    row["false_worst_mm"] = max((d["worst_mm"] for d in false), key=abs) if false else None
    mean_bar, p99_bar = BARS.get(job["condition"], (math.inf, None))
    pe = row.get("pose_err")
    row["ok"] = {
        "pose": pe is not None and pe["deg"] < POSE_BAR_DEG,
        "bcps": bool(row.get("n_points")) and row["mean_px"] <= mean_bar and (p99_bar is None or row["p99_px"] <= p99_bar),
        "verdict": res.get("verdict") == row["expected"],
        "no_false_defect": not false,
    }
    return row


# --------------------------------------------------------------------------- report


def _f(x: Any, nd: int = 3) -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{nd}f}"


def to_markdown(rows: list[dict[str, Any]], meta: dict[str, Any]) -> str:
    lines = [
        "# Pose sweep (issue 14)",
        "",
        f"Recipe `{meta['recipe']}`, tolerance band {meta['band']} mm; pose bar {POSE_BAR_DEG} deg "
        "(up to the part's symmetry group); BCPS bars per condition "
        + ", ".join(f"{c}: mean <= {m}" + (f", p99 <= {p}" if p else "") for c, (m, p) in BARS.items()
                    if c in {r['condition'] for r in rows}) + ".",
        "",
        "| part | scale | pose (seed) | cams | cond | pose err deg | about axis deg | tilt deg | shift mm | size fit "
        "| fitness | misfit mm | n | mean px | p99 px | verdict (exp) | defects | false | false worst mm | bars |",
        "|---|---:|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---|",
    ]
    for r in rows:
        pe = r.get("pose_err") or {}
        ok = r.get("ok") or {}
        miss = [k for k, v in ok.items() if not v]
        bars = "RUN FAILED" if r.get("run_failed") else ("all met" if ok and not miss else "**" + ", ".join(miss) + "**")
        nd = len(r.get("defects") or [])
        lines.append(
            f"| {r['part']} | {r['scale']:.2f} | {r['pose']} ({r['seed']}) | {r['cameras']} | {r['condition']} | "
            f"{_f(pe.get('deg'), 3)} | {_f(pe.get('about_axis_deg'), 3)} | {_f(pe.get('tilt_deg'), 3)} | "
            f"{_f(r.get('shift_mm'), 3)} | {_f(r.get('size_fit'), 4)} | {_f(r.get('fitness'), 3)} | "
            f"{_f((r.get('misfit') or {}).get('mean_mm'), 4)} | {r.get('n_points', 0)} | "
            f"{_f(r.get('mean_px'))} | {_f(r.get('p99_px'))} | {r.get('verdict')} ({r['expected']}) | {nd} | "
            f"{r.get('n_false', '-')} | {_f(r.get('false_worst_mm'), 2)} | {bars} |")
    n = len(rows)

    def count(key: str) -> int:
        return sum(bool((r.get("ok") or {}).get(key)) for r in rows)

    lines += [
        "",
        f"Pose within {POSE_BAR_DEG} deg: {count('pose')}/{n}; BCPS bars met: {count('bcps')}/{n}; verdict as expected: "
        f"{count('verdict')}/{n}; no false defect: {count('no_false_defect')}/{n}; every bar: "
        f"{sum(bool(r.get('ok')) and all(r['ok'].values()) for r in rows)}/{n}.",
        "",
        "Pose error: min over the part's symmetries S of angle(R_est^T R_true S); about axis / tilt: the residual "
        "split into a turn about the part's axis (z) and a tilt of the axis. Misfit: mean distance of the nominal "
        "surface placed by the product's pose from the one placed by the true pose (measure.pose_misfit; near 0 "
        "whenever the pose error is, whatever the group). False defects: clusters the true "
        "surface does not explain (every cluster on a nominal part). Size fit: result.json stats.size_fit.scale.",
        "",
        f"{meta['n_captures']} captures ({meta['written']} written, {meta['render_s']:.0f} s rendering), "
        f"{meta['n_batches']} `inspector run` batch(es), {meta['inspect_s']:.0f} s inspecting; "
        f"wall {meta['total_s']:.0f} s ({platform.node()}, Python {platform.python_version()}).",
        "",
    ]
    failed = [r for r in rows if r.get("run_failed")]
    if failed:
        lines += ["Runs failed (verdict error, or no result):", ""] + [
            f"- {r['name']}: exit {r.get('exit')}, {r.get('error')}" for r in failed] + [""]
    return "\n".join(lines)


SECTION = "pose-sweep"
#: At most this many captures that miss a bar are listed in the ``--md-section`` summary.
MAX_MISSES = 40


def summary_markdown(rows: list[dict[str, Any]], meta: dict[str, Any]) -> str:
    """The ``--md-section`` block: one line per part and rig, then the captures missing a bar."""
    a = meta["sweep"]
    lines = [
        f"<!-- {SECTION}:begin -->",
        "## Pose sweep: near-symmetric parts, scale errors and smaller rigs (issue 14)",
        "",
        "Generated by `make pose-sweep` (`tests/acceptance/pose_sweep.py`; rerunning it replaces this",
        f"section) on {time.strftime('%Y-%m-%d')} ({platform.node()}): parts {', '.join(a['parts'])}; scales "
        f"{', '.join(f'{x:.2f}' for x in a['scales'])}; {a['poses']} random pose(s) per part (the same for every "
        f"scale and rig); rigs of {', '.join(map(str, a['cameras']))} cameras (golden spiral, radius 400 mm, "
        f"1024x1024 px, f = 4000 px); condition {', '.join(a['condition'])}, {a['polarity']}; recipe "
        f"`{meta['recipe']}`, tolerance band {meta['band']} mm.",
        f"Bars per capture: pose error below {POSE_BAR_DEG} deg up to the part's symmetry group; BCPS "
        + ", ".join(f"{c}: mean <= {m} px" + (f", p99 <= {p} px" if p else "") for c, (m, p) in BARS.items()
                    if c in a["condition"])
        + "; verdict as expected (*fail* when the true surface leaves the band: every scale but 1.00);"
        " no false defect (a cluster the true surface does not explain).",
        "The full per-capture table is written to `WORK/pose_sweep.md` (default `out/pose_sweep/`).",
        "",
        "| part | cams | captures | every bar | pose | BCPS | verdict | no false defect | worst pose err deg "
        "(scale, pose) | false defects: captures / clusters (worst mm) | runs failed |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    groups: dict[tuple[str, int], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["part"], r["cameras"]), []).append(r)
    for (part, cams), rs in groups.items():
        n = len(rs)

        def c(key: str, rs: list[dict[str, Any]] = rs) -> str:
            return f"{sum(bool((r.get('ok') or {}).get(key)) for r in rs)}/{len(rs)}"

        every = sum(bool(r.get("ok")) and all(r["ok"].values()) for r in rs)
        pe = [r for r in rs if r.get("pose_err")]
        if pe:
            w = max(pe, key=lambda r: r["pose_err"]["deg"])
            worst = f"{w['pose_err']['deg']:.3f} ({w['scale']:.2f}, {w['pose']})"
        else:
            worst = "-"
        fr = [r for r in rs if r.get("n_false")]
        fw = max((r["false_worst_mm"] for r in fr), key=abs, default=None)
        false = f"{len(fr)} / {sum(r['n_false'] for r in fr)}" + (f" ({fw:+.2f})" if fw is not None else "")
        lines.append(f"| {part} | {cams} | {n} | {'**' if every < n else ''}{every}/{n}{'**' if every < n else ''} | "
                     f"{c('pose')} | {c('bcps')} | {c('verdict')} | {c('no_false_defect')} | {worst} | {false} | "
                     f"{sum(bool(r.get('run_failed')) for r in rs)} |")
    n_all = len(rows)
    every_all = sum(bool(r.get("ok")) and all(r["ok"].values()) for r in rows)
    lines += ["", f"**{every_all}/{n_all} captures meet every bar.** {meta['n_captures']} captures "
              f"({meta['written']} written now), {meta['n_inspected']} inspected now and {meta['n_reused']} reused "
              f"(`--resume`), {meta['inspect_s']:.0f} s inspecting; wall {meta['total_s']:.0f} s.", ""]
    miss = [r for r in rows if r.get("run_failed") or not (r.get("ok") and all(r["ok"].values()))]
    if miss:
        lines += [f"Captures missing a bar ({len(miss)}" + (f", the first {MAX_MISSES}" if len(miss) > MAX_MISSES else "")
                  + "):", "",
                  "| part | cams | scale | pose (seed) | pose err deg | about axis deg | size fit | mean px | p99 px "
                  "| verdict (exp) | false defects (worst mm) | missed |",
                  "|---|---:|---:|---|---:|---:|---:|---:|---:|---|---:|---|"]
        for r in miss[:MAX_MISSES]:
            pe = r.get("pose_err") or {}
            missed = "run failed: " + str(r.get("error") or "")[:80].replace("|", "/").replace("\n", " ") \
                if r.get("run_failed") else ", ".join(k for k, v in r["ok"].items() if not v)
            nf = r.get("n_false")
            false = "-" if nf is None else str(nf) + (f" ({r['false_worst_mm']:+.2f})" if nf else "")
            lines.append(f"| {r['part']} | {r['cameras']} | {r['scale']:.2f} | {r['pose']} ({r['seed']}) | "
                         f"{_f(pe.get('deg'))} | {_f(pe.get('about_axis_deg'))} | {_f(r.get('size_fit'), 4)} | "
                         f"{_f(r.get('mean_px'))} | {_f(r.get('p99_px'))} | {r.get('verdict')} ({r['expected']}) | "
                         f"{false} | {missed} |")
        lines.append("")
    lines.append(f"<!-- {SECTION}:end -->")
    return "\n".join(lines) + "\n"


def write_section(path: Path, block: str) -> None:
    """Put ``block`` (markers included) in place of the marked section of ``path``, or append it."""
    import re

    text = path.read_text() if path.is_file() else ""
    pat = re.compile(rf"<!-- {SECTION}:begin -->.*?<!-- {SECTION}:end -->\n?", re.S)
    if pat.search(text):
        text = pat.sub(lambda _: block, text, count=1)
    else:
        text = text.rstrip("\n") + ("\n\n" if text else "") + block
    path.write_text(text)


# --------------------------------------------------------------------------- main


def keyway_visibility(cameras: int, poses: int, *, radius_mm: float = 10.0, half_width_mm: float = 3.0,
                      footprint_mm: float = 0.1, seed: int = 0) -> np.ndarray:
    """How deep the keyed shaft's keyway shows in the deepest of a rig's silhouettes, over
    random poses (px, shape (poses,)).

    A camera sees a shaft of radius ``r`` with two contour generators at azimuths
    ``alpha +- acos(r / rho)`` about its axis (``alpha``, ``rho``: the camera centre's azimuth
    and distance from the axis); a generator ``g`` degrees from the keyway's centre line, the
    keyway ``2 beta`` wide (``beta = asin(half_width / r)``), shows a notch
    ``r (1 - cos(max(0, beta - |g|)))`` deep (the keyway's edges, not its floor, make the
    contour). Analytic, on the sweep's golden-spiral rigs and ``foreign_capture.random_pose``.
    """
    cams = fc.fibonacci_rig(cameras)
    rng = np.random.default_rng(seed)
    return np.array([keyway_depth_px(fc.random_pose(rng), cams, radius_mm=radius_mm, half_width_mm=half_width_mm,
                                     footprint_mm=footprint_mm) for _ in range(poses)])


def keyway_depth_px(T: np.ndarray, cams: list[Any], *, radius_mm: float = 10.0, half_width_mm: float = 3.0,
                    footprint_mm: float = 0.1) -> float:
    """The deepest the keyway (on the part's +x, axis z) shows in the silhouettes of ``cams``
    with the part at pose ``T`` (4, 4), px (see :func:`keyway_visibility`)."""
    beta = math.asin(half_width_mm / radius_mm)
    depth = 0.0
    for c in cams:
        p = T[:3, :3].T @ (np.asarray(c.centre, float) - T[:3, 3])
        alpha, rho = math.atan2(p[1], p[0]), math.hypot(p[0], p[1])
        if rho <= radius_mm:  # looking along the axis: no contour on the shaft's side
            continue
        for g in (alpha + math.acos(radius_mm / rho), alpha - math.acos(radius_mm / rho)):
            off = abs((g + math.pi) % (2.0 * math.pi) - math.pi)
            depth = max(depth, radius_mm * (1.0 - math.cos(max(0.0, beta - off))))
    return depth / footprint_mm


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--parts", nargs="+", default=list(DEFAULT_PARTS), choices=list(fc.PARTS), metavar="PART",
                    help=f"parts of foreign_capture.PARTS ({', '.join(fc.PARTS)})")
    ap.add_argument("--scales", nargs="+", type=float, default=[0.97, 0.98, 1.00, 1.02])
    ap.add_argument("--poses", type=int, default=4, help="random poses K per part (seeded)")
    ap.add_argument("--cameras", nargs="+", type=int, default=[16], help="rig sizes (golden-spiral rigs)")
    ap.add_argument("--condition", nargs="+", default=["grey"], choices=fc.CONDITIONS)
    ap.add_argument("--polarity", choices=("dark-object", "bright-object"), default="dark-object")
    ap.add_argument("--seed", type=int, default=0, help="base seed: pose k of a part uses a seed derived from it")
    ap.add_argument("--work", type=Path, default=ROOT / "out" / "pose_sweep", help="captures, truth (cached) and results")
    ap.add_argument("--out", type=Path, default=None, help="inspector results (None: WORK/out)")
    ap.add_argument("--recipe", type=Path, default=DEFAULT_RECIPE)
    ap.add_argument("--jobs", type=int, default=1, help="processes writing captures and inspector run batches at once")
    ap.add_argument("--batch", type=int, default=0, help="captures per inspector run (0: all captures of a part)")
    ap.add_argument("--threads", type=int, default=None,
                    help="NUMBA/OMP/BLAS threads of each inspector run (None: inherited)")
    ap.add_argument("--explain-mm", type=float, default=0.1,
                    help="a defect is explained when its worst deviation exceeds the true one by no more than this")
    ap.add_argument("--capture-only", action="store_true", help="write (or find cached) captures, then stop")
    ap.add_argument("--measure-only", action="store_true", help="measure the existing results, run nothing")
    ap.add_argument("--selftest", action="store_true", help="check the pose-error composition, then stop")
    ap.add_argument("--keyway-visibility", type=int, default=0, metavar="N",
                    help="print how deep the keyed shaft's keyway shows on each --cameras rig over N random poses, then stop")
    ap.add_argument("--json", type=Path, default=None, help="metrics JSON (None: WORK/pose_sweep.json)")
    ap.add_argument("--md", type=Path, default=None, help="also write the markdown table here")
    ap.add_argument("--md-section", type=Path, default=None,
                    help=f"write the summary between the <!-- {SECTION}:begin/end --> markers of this file")
    ap.add_argument("--resume", action="store_true",
                    help="reuse inspections (and measurements) of the same capture by the same product")
    args = ap.parse_args(argv)

    if args.selftest:
        try:
            selftest()
        except AssertionError as e:
            print(f"selftest FAILED: {e}", file=sys.stderr)
            return 3
        return 0
    if args.keyway_visibility:
        print("| cameras | poses | deepest notch: median px | share >= 0.25 px | >= 0.5 px | >= 1 px |")
        print("|---:|---:|---:|---:|---:|---:|")
        for n in args.cameras:
            d = keyway_visibility(n, args.keyway_visibility, seed=args.seed)
            print(f"| {n} | {len(d)} | {np.median(d):.2f} | " + " | ".join(f"{np.mean(d >= x):.0%}" for x in (0.25, 0.5, 1.0))
                  + " |")
        return 0
    t0 = time.perf_counter()
    args.work = args.work.resolve()
    args.work.mkdir(parents=True, exist_ok=True)
    out_root = args.out or args.work / "out"
    jobs = []
    for part in args.parts:
        for k in range(args.poses):
            seed = capture_seed(args.seed, part, k)
            for scale in args.scales:
                for cams in args.cameras:
                    for cond in args.condition:
                        jobs.append({"part": part, "pose": k, "seed": seed, "scale": round(scale, 6), "cameras": cams,
                                     "condition": cond, "polarity": args.polarity,
                                     "name": capture_name(part, cond, cams, scale, seed)})
    shas = {p: _mesh_sha(p) for p in args.parts}
    render = {} if args.measure_only else write_captures(args.work, jobs, args.jobs, shas)
    if args.capture_only:
        print(json.dumps({j["name"]: str(args.work / "captures" / j["name"]) for j in jobs}, indent=1))
        return 0
    t1 = time.perf_counter()
    pstamp = product_stamp(args.recipe)

    def run_key(j: dict[str, Any]) -> dict[str, Any]:
        return {"capture": _spec(j, shas[j["part"]]), "product": pstamp}

    reused: dict[str, dict[str, Any]] = {}
    if args.resume and not args.measure_only:
        for j in jobs:
            for st in sorted(out_root.glob(f"*/{j['name']}/sweep-run.json"), key=lambda p: p.stat().st_mtime):
                try:
                    stamp = json.loads(st.read_text())
                except (OSError, json.JSONDecodeError):
                    continue
                if stamp.get("key") == run_key(j) and (st.parent / "result.json").is_file():
                    reused[j["name"]] = {"result_dir": st.parent, "exit": stamp.get("exit"),
                                         "batch": st.parent.parent.name, "reused": True}
    if args.measure_only:
        runs = find_results(out_root, jobs)
    else:
        todo = [j for j in jobs if j["name"] not in reused]
        print(f"inspections: {len(reused)} reused, {len(todo)} to run", file=sys.stderr, flush=True)
        runs = inspect_batches(args.work, out_root, todo, args.recipe, args.jobs, args.batch, args.threads) if todo else {}
        for j in todo:  # stamp every result, so that a later --resume can reuse it
            r = runs.get(j["name"])
            if r and (Path(r["result_dir"]) / "result.json").is_file():
                (Path(r["result_dir"]) / "sweep-run.json").write_text(json.dumps(
                    {"key": run_key(j), "exit": r["exit"], "batch_s": r.get("batch_s"), "batch_n": r.get("batch_n"),
                     "date": time.strftime("%Y-%m-%dT%H:%M:%S")}))
        runs.update(reused)
    t2 = time.perf_counter()
    band = _tolerance(args.recipe)
    istamp = instrument_stamp()
    rows = []
    for j in jobs:
        run = runs.get(j["name"])
        cache = Path(run["result_dir"]) / "sweep-row.json" if run else None
        mkey = {"run": run_key(j), "instrument": istamp, "band": list(band), "explain_mm": args.explain_mm}
        row = None
        if args.resume and run and run.get("reused") and cache.is_file():
            try:
                c = json.loads(cache.read_text())
                row = c["row"] if c.get("key") == mkey else None
            except (OSError, json.JSONDecodeError, KeyError):
                row = None
        if row is None:
            row = measure_one(j, run, args.work, band, args.explain_mm)
            if cache is not None and (cache.parent / "sweep-run.json").is_file():
                cache.write_text(json.dumps({"key": mkey, "row": row}, default=str))
        rows.append(row)
        r = rows[-1]
        pe = r.get("pose_err") or {}
        print(f"  {j['name']}: verdict {r.get('verdict')} ({r['expected']}), pose {_f(pe.get('deg'))} deg, "
              f"mean {_f(r.get('mean_px'))} px, p99 {_f(r.get('p99_px'))} px, {len(r.get('defects') or [])} defects "
              f"({r.get('n_false', '-')} false)", file=sys.stderr, flush=True)
    meta = {"recipe": str(args.recipe.relative_to(ROOT) if args.recipe.is_relative_to(ROOT) else args.recipe),
            "band": list(band), "n_captures": len(jobs), "written": len(render), "render_s": sum(render.values()),
            "n_batches": len({r.get("batch") for n, r in runs.items() if n not in reused}), "inspect_s": t2 - t1,
            "n_inspected": len(runs) - len(reused), "n_reused": len(reused),
            "sweep": {"parts": list(args.parts), "scales": list(args.scales), "poses": args.poses,
                      "cameras": list(args.cameras), "condition": list(args.condition), "polarity": args.polarity},
            "total_s": time.perf_counter() - t0, "args": {k: str(v) for k, v in vars(args).items()}}
    md = to_markdown(rows, meta)
    (args.json or args.work / "pose_sweep.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1, default=str))
    (args.work / "pose_sweep.md").write_text(md)
    if args.md:
        args.md.parent.mkdir(parents=True, exist_ok=True)
        args.md.write_text(md)
    if args.md_section:
        write_section(args.md_section, summary_markdown(rows, meta))
    print(md)
    if any(r.get("run_failed") for r in rows):
        return 2
    return 0 if all(r.get("ok") and all(r["ok"].values()) for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
