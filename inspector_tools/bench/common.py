"""Helpers every ``inspector bench`` mode shares (the pipeline, ``--gui``, ``--opcua``,
``--dask``): the machine and its memory, the default recipe and reference, a simulated
capture and the kernels' compilation in child processes, the argument checks, the JSON
figures. Light: the standard library and the light core only.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from inspector.errors import InspectorError, RecipeError
from inspector.resources import recipes_dir
from inspector_tools.bench.targets import image_size

__all__ = [
    "loadavg",
    "cpu_jiffies",
    "steal_share",
    "recipes_dir",
    "maxrss_mb",
    "rss_mb",
    "stats",
    "machine",
    "simulate_capture",
    "compile_kernels",
    "default_reference",
    "check_args",
    "write_figures",
]

_MB = 1e6


def cpu_jiffies() -> tuple[int, int] | None:
    """The machine's CPU time stolen by its hypervisor and its whole CPU time so far, in
    clock ticks (``/proc/stat``: ``steal`` and the sum of its columns); None where there is
    no such file. On a virtual machine the host's other guests take a share of the cores
    that the load average never shows (measured here: a 16 x 1 MP cycle of 0.55 s in one
    hour, 1.2-1.9 s in another with a fifth of the CPU stolen)."""
    try:
        with open("/proc/stat", encoding="ascii") as f:
            fields = f.readline().split()
    except OSError:
        return None
    if len(fields) < 9 or fields[0] != "cpu":
        return None
    ticks = [int(x) for x in fields[1:]]
    return ticks[7], sum(ticks[:8])  # steal; user .. steal (guest time is inside user's)


def steal_share(before: tuple[int, int] | None, after: tuple[int, int] | None) -> float | None:
    """The share of the machine's CPU time stolen between two :func:`cpu_jiffies` readings."""
    if before is None or after is None or after[1] <= before[1]:
        return None
    return round((after[0] - before[0]) / (after[1] - before[1]), 3)


def loadavg() -> float | None:
    """The 1-minute load average (None where the platform has none)."""
    try:
        return round(os.getloadavg()[0], 2)
    except (OSError, AttributeError):  # pragma: no cover
        return None



def maxrss_mb() -> float | None:
    """``ru_maxrss`` of this process, MB (None where ``resource`` is missing)."""
    try:
        import resource
    except ImportError:  # pragma: no cover - not on Linux/macOS
        return None
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return r / _MB if sys.platform == "darwin" else r * 1024 / _MB


def rss_mb() -> float | None:
    """Current resident memory, MB (Linux ``/proc``; None elsewhere)."""
    try:
        with open("/proc/self/statm", encoding="ascii") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / _MB
    except (OSError, ValueError, IndexError, AttributeError):
        return None


def stats(values: Sequence[float]) -> dict[str, float]:
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


def machine() -> dict[str, Any]:
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except (OSError, AttributeError):  # pragma: no cover
        load = None
    try:
        usable: int | None = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover
        usable = os.cpu_count()
    return {
        "cpu_count": os.cpu_count(),
        "usable_cpus": usable,
        "loadavg_1_5_15": load,
        "python": platform.python_version(),
        "platform": platform.platform(),
        "numba_threads": os.environ.get("NUMBA_NUM_THREADS"),
    }


_SIM_CHILD = """
import json, sys
from inspector.params import build_params
from inspector.capture_folder import write_capture
from inspector_drivers.sim.simulate import SimParams, simulate
folder, name, table = sys.argv[1], sys.argv[2], json.loads(sys.argv[3])
p = build_params(SimParams, table, "bench")
cap = simulate(p, 0, name=name)
write_capture(folder, cap.rig, cap.images, metadata=dict(cap.metadata), polarity=cap.polarity, overwrite=True)
"""


def simulate_capture(folder: Path, table: dict[str, Any]) -> Path:
    """Simulate one capture (:class:`SimParams` ``table``) into ``folder``, in a child
    process (its memory never counts here); written without ``truth/``."""
    proc = subprocess.run(
        [sys.executable, "-c", _SIM_CHILD, str(folder), Path(folder).name, json.dumps(table)],
        capture_output=True,
        text=True,
        check=False,
    )
    if proc.returncode != 0:
        lines = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()]
        raise InspectorError(f"bench: simulation failed: {lines[-1] if lines else f'exit status {proc.returncode}'}")
    return Path(folder)


_COMPILE_CHILD = """
import sys
from inspector_frontends.cli import main
sys.exit(main(sys.argv[1:]))
"""


def compile_kernels(recipe_path: str, reference: str | None, folder: Path, outdir: Path) -> dict[str, Any]:
    """Inspect ``folder`` once in a child process, so that the compiled kernels are in
    Numba's on-disk cache before the measured runs.

    The first inspection after an install compiles every kernel (minutes, and about 3 GB
    of LLVM memory, once); a production line then always runs with the cache. Compiling
    here would put that one-time peak into this process's ``ru_maxrss``.

    Returns ``{"seconds": wall time of the child, "exit": its exit status}``.
    """
    cmd = [sys.executable, "-c", _COMPILE_CHILD, "run", str(recipe_path), "--capture", str(folder),
           "--out", str(outdir), "-q"]
    if reference is not None:
        cmd += ["--reference", str(reference)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    return {"seconds": time.perf_counter() - t0, "exit": proc.returncode}


def default_reference(recipe_path: str, part: str) -> str | None:
    """``builtin:PART`` when the recipe names no reference (None: keep the recipe's)."""
    import tomllib

    try:
        with open(recipe_path, "rb") as f:
            head = tomllib.load(f).get("recipe", {})
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError):
        return None  # load_recipe reports the problem
    return None if isinstance(head, dict) and head.get("reference") else f"builtin:{part}"


def check_args(args: argparse.Namespace) -> None:
    """The options every bench mode reads: RecipeError for the first one out of range."""
    if args.runs < 1:
        raise RecipeError("bench --runs: expected a number >= 1")
    if args.carve_runs < 1:
        raise RecipeError("bench --carve-runs: expected a number >= 1")
    for flag, v in (("--open3d-voxel", args.open3d_voxel), ("--carve-voxel", args.carve_voxel),
                    ("--mm-per-px", args.mm_per_px), ("--open3d-max-gb", args.open3d_max_gb)):
        if not (v > 0 and math.isfinite(v)):
            raise RecipeError(f"bench {flag}: expected a positive number")
    if args.cameras < 3:
        raise RecipeError("bench --cameras: expected a number >= 3")
    if min(image_size(args)) < 16:
        raise RecipeError("bench --size: expected a width and height >= 16 px")
    if args.capture is not None and not Path(args.capture).is_dir():
        raise RecipeError(f"bench --capture {args.capture}: not a folder")


def write_figures(path: str | Path, doc: Any) -> Path:
    """Write a benchmark's figures as indented JSON (numpy values as lists and numbers),
    creating the folder; returns the path."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(doc, indent=2, default=_json_default) + "\n", encoding="utf-8")
    return p


def _json_default(o: Any) -> Any:
    try:
        import numpy as np

        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, np.generic):
            return o.item()
    except ImportError:  # pragma: no cover
        pass
    return repr(o)
