"""``inspector bench``: the issue's performance targets, measured in one command.

Targets (16 cameras, the 2-core production machine; :func:`cycle_target_s`):

1. cycle: a full inspection in the batch runner (read the capture folder, every stage of
   the recipe, write the outputs), median, interpreter start excluded: **<= 0.5 s** for
   images up to 1024x1024 (1 MP), **<= 1.0 s** up to 2448x2048 (5 MP; issue 26); other
   camera counts: the target scaled with the count (the cost must be linear in it);
2. memory: peak resident memory of the process **<= 1.5 GB** (1.5e9 bytes) up to 1 MP,
   **<= 2.5 GB** up to 5 MP;
3. carving: :func:`inspector.kernels.carving.carve` at 0.1 mm at least **10x faster**
   than Open3D's ``VoxelGrid.carve_silhouette`` at 0.25 mm on the same masks.

How it is measured
------------------
- A capture is simulated (``--part``, ``--seed``, ``--cameras``, ``--size`` ``N`` or
  ``WxH`` (non-square, e.g. ``2448x2048``), ``--mm-per-px``) in a child process, so its rendering never counts in this process's
  peak memory, and written to a temporary capture folder without ``truth/`` (a production
  capture has none). ``--capture DIR`` uses an existing folder instead (its ``truth/``, if
  any, is dropped after reading, so truth statistics never count in the cycle).
- The batch path of ``inspector run`` (:func:`inspector.runner.run_batch`) inspects that
  folder ``1 + --runs`` times in this process, writing the outputs to a temporary folder;
  the first run (Numba compilation, lazy imports, caches) is left out of the statistics.
  Per run: ``load`` and each stage (``result.timings_s``), ``outputs`` (writing the result
  folder and the ``on_result`` hook: the rest of the run) and ``cycle`` (the whole run),
  with the machine's 1-minute load average before and after it (``loadavg``) and the share
  of its CPU time the hypervisor gave other guests meanwhile (``steal``, from ``/proc/stat``):
  on a shared machine other jobs' load stands beside every figure.
- Memory: ``resource.getrusage(RUSAGE_SELF).ru_maxrss`` after the runs (the process's
  high-water mark, imports included), and its increase over the warm-up and timed runs.
- Carving comparison, after the memory figure is taken: the capture's images are
  segmented with :func:`inspector_plugins.segment.segment_image` (the recipe's segment
  parameters); both carvers get the same masks and the same box
  (:func:`~inspector.kernels.carving.default_bounds`). Ours: ``carve(...)`` at
  ``--carve-voxel``, median of ``--carve-runs``. Open3D: ``VoxelGrid.create_dense`` over
  the box at ``--open3d-voxel`` then ``carve_silhouette`` per camera (float32 mask images,
  ``keep_voxels_outside_image=False``), once. The ratio (the target) uses Open3D's
  ``carve_silhouette`` calls only (not ``create_dense``) against the whole ``carve`` call
  (distance transforms, cell tests, surface points with normals and display mesh; the
  box is given): the conservative ratio, since Open3D only produces an occupancy grid. An
  informative ratio without our display mesh (Open3D against our cells and surface
  points, the median of ``time_s["carve"] + time_s["points"]``) is reported beside it;
  our cell tests alone are not timed apart (the finest level is tested together with
  the surface points). A grid that would need more than ``--open3d-max-gb`` (about 100
  bytes per voxel) is refused with a message. As a sanity check, the fraction of our
  surface points that fall in a voxel Open3D kept is reported (about 1 when both use the
  cameras alike).

Exit status: 0 every measured target met, 1 a target not met, 3 an inspection failed.
Importing this module is cheap: numpy, Open3D and the pipeline are imported when used (the
measurements live beside it: :mod:`~inspector_tools.bench.cycles`, :mod:`~inspector_tools.bench.carving`,
:mod:`~inspector_tools.bench.throughput` (``--dask``), :mod:`~inspector_tools.bench.gui` (``--gui``),
:mod:`~inspector_tools.bench.opcua` (``--opcua``), :mod:`~inspector_tools.bench.characteristics`
(``--characteristics``: issue 28's 50 ms for 20 characteristics); the targets and the 5 MP sizes in
:mod:`~inspector_tools.bench.targets`, the shared helpers in :mod:`~inspector_tools.bench.common`).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

from inspector import hookimpl
from inspector.errors import InspectorError
from inspector_tools.bench.common import (
    check_args,
    compile_kernels,
    default_reference,
    machine,
    recipes_dir,
    simulate_capture,
    write_figures,
)
from inspector_tools.bench.report import print_report
from inspector_tools.bench.targets import (
    CARVE_RATIO_TARGET,
    CYCLE_TARGET_5MP_S,
    CYCLE_TARGET_S,
    MEMORY_TARGET_5MP_MB,
    MEMORY_TARGET_MB,
    SizeAction,
    cycle_target_s,
    image_size,
    memory_target_mb,
    parse_size,
    targets,
)

if TYPE_CHECKING:
    from inspector.registry import CommandRegistry

__all__ = [
    "CYCLE_TARGET_S",
    "MEMORY_TARGET_MB",
    "CARVE_RATIO_TARGET",
    "CYCLE_TARGET_5MP_S",
    "MEMORY_TARGET_5MP_MB",
    "cycle_target_s",
    "memory_target_mb",
    "parse_size",
    "image_size",
    "add_parser",
    "run",
    "acquisition_latency",
]


def add_parser(subparsers: Any) -> None:
    """Add the ``bench`` sub-command to ``subparsers`` (from ``add_subparsers``)."""
    b = subparsers.add_parser(
        "bench",
        help="measure the cycle time, peak memory and carving speed against Open3D (the performance targets)",
        description="Simulate (or read) one capture, inspect it 1 + RUNS times with the batch runner in this process "
        "(first run left out), report per-stage medians and peak memory, then compare our carving with Open3D's "
        "VoxelGrid.carve_silhouette on the same masks. Exit 0 when every measured target is met, 1 otherwise.",
    )
    b.add_argument("--recipe", default=str(recipes_dir() / "default.toml"), metavar="TOML",
                   help="recipe to run (default recipes/default.toml)")
    b.add_argument("--reference", metavar="MESH", help="reference mesh or builtin:NAME (default: the recipe's, else builtin:PART)")
    b.add_argument("--part", default="cube30", help="simulated part, built-in name (default cube30)")
    b.add_argument("--seed", type=int, default=0, help="simulation seed (default 0)")
    b.add_argument("--cameras", type=int, default=16, help="simulated cameras (default 16)")
    b.add_argument("--size", action=SizeAction, default=1024, metavar="N|WxH",
                   help="simulated image size, px: N (N x N) or WxH, e.g. 2448x2048 for 5 MP (default 1024)")
    b.set_defaults(height=None)
    b.add_argument("--mm-per-px", type=float, default=0.1, help="simulated pixel footprint at the rig centre, mm (default 0.1)")
    b.add_argument("--capture", metavar="DIR", help="use this capture folder instead of simulating one")
    b.add_argument("--no-first-run", dest="first_run", action="store_false",
                   help="skip the first-run compile time (a child compiling every kernel into an empty cache, about a minute)")
    b.add_argument("--runs", type=int, default=5, help="timed runs after the warm-up (default 5)")
    b.add_argument("--json", metavar="OUT.json", help="write every figure to this JSON file")
    b.add_argument("--no-open3d", action="store_true", help="skip the Open3D carving comparison")
    b.add_argument("--open3d-voxel", type=float, default=0.25, metavar="MM", help="Open3D voxel, mm (default 0.25)")
    b.add_argument("--open3d-max-gb", type=float, default=4.0, metavar="GB",
                   help="refuse an Open3D dense grid needing more memory than this (default 4)")
    b.add_argument("--carve-voxel", type=float, default=0.1, metavar="MM", help="our carving voxel, mm (default 0.1)")
    b.add_argument("--carve-runs", type=int, default=3, help="runs of our carving; the median is compared (default 3)")
    b.add_argument("--keep", metavar="DIR", help="write the capture and the outputs here instead of a temporary folder")
    b.add_argument("--acquisition", type=int, default=0, metavar="N",
                   help="also measure the trigger-to-all-frames latency of N emulated GigE Vision cameras "
                        "(aravis driver; needs root and the aravis packages), e.g. 16")
    b.add_argument("--triggers", type=int, default=40, help="timed triggers for --acquisition (default 40)")
    b.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    b.add_argument("--gui", action="store_true",
                   help="measure the operator window instead (needs a display; --recipe defaults to recipes/demo.toml "
                        "there): trigger to verdict shown against the headless cycle (median of --runs), event-loop "
                        "stall during inspections, memory growth over --gui-inspections (inspector_tools.bench.gui)")
    b.add_argument("--dask", action="store_true",
                   help="measure archive re-inspection throughput instead, captures per minute: in this process, then "
                        "on local Dask clusters (inspector run --workers N) of --dask-workers; --dask-captures copies of 4 "
                        "simulated captures (--part, --cameras, --size, --mm-per-px, --seed)")
    b.add_argument("--dask-captures", type=int, default=20, metavar="N", help="with --dask: captures in the archive (default 20)")
    b.add_argument("--dask-workers", type=int, nargs="+", default=[1, 2], metavar="N",
                   help="with --dask: the local clusters' worker counts (default 1 2)")
    b.add_argument("--gui-inspections", type=int, default=200, metavar="N",
                   help="with --gui: inspections in one window; memory is sampled after 20 and after N (default 200)")
    b.add_argument("--opcua", action="store_true",
                   help="measure `inspector serve` instead: trigger-to-verdict latency seen by an OPC UA client (median, "
                        "p99) against the headless cycle of the same parts (--recipe defaults to recipes/demo.toml "
                        "there; inspector_tools.bench.opcua)")
    b.add_argument("--opcua-parts", type=int, default=100, metavar="N", help="with --opcua: timed parts (default 100)")
    b.add_argument("--characteristics", action="store_true",
                   help="time the characteristics stage's measurement instead: 20 characteristics of the bracket, "
                        "target 50 ms (process CPU time, median; inspector_tools.bench.characteristics)")
    b.add_argument("--characteristics-points", type=int, default=15000, metavar="N",
                   help="with --characteristics: points of the part (default 15000)")
    b.add_argument("--characteristics-runs", type=int, default=20, metavar="N",
                   help="with --characteristics: timed runs after a warm-up (default 20)")
    b.add_argument("--characteristics-cameras", type=int, default=16, metavar="N",
                   help="with --characteristics: also time the BCPS points of a simulated N-camera capture of the "
                        "bracket (rays, edges snapped; default 16, 0: not)")


def run(args: argparse.Namespace) -> int:
    """Run ``inspector bench``; see the module docstring. Exit 0 targets met, 1 not met, 3 inspection error."""
    special = _run_special_mode(args)
    if special is not None:
        return special
    from inspector.session import Session

    check_args(args)
    figures_machine = machine()
    say = (lambda s: None) if args.quiet else (lambda s: print(s, flush=True))
    session = Session.open(args.recipe, ".", reference=args.reference or default_reference(args.recipe, args.part),
                           pm=getattr(args, "plugin_manager", None))
    pm, recipe, ref = session.pm, session.recipe, session.reference

    with tempfile.TemporaryDirectory(prefix="inspector-bench-") as tmp:
        work = Path(args.keep) if args.keep else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        if args.capture:
            folder = Path(args.capture)
            source = str(folder.resolve())
        else:
            width, height = image_size(args)
            table = {"part": args.part, "seed": args.seed, "cameras": args.cameras, "width": width,
                     "height": height, "mm_per_px": args.mm_per_px}
            say(f"Simulating {args.part}: {args.cameras} cameras, {width}x{height} px at {args.mm_per_px} mm/px ...")
            folder = simulate_capture(work / "captures" / f"{args.part}-s{args.seed:04d}", table)
            source = f"simulated: part {args.part}, seed {args.seed}, {args.mm_per_px} mm/px"
        from inspector.capture_folder import RIG_FILE, read_rig

        try:
            cams = list(read_rig(folder / RIG_FILE).cameras)
        except InspectorError:
            cams = []  # the inspection reports the problem
        cap_info: dict[str, Any] = {"name": folder.name, "source": source, "cameras": len(cams),
                    "width": cams[0].width if cams else None, "height": cams[0].height if cams else None}
        say("Compiling the kernels in a child process (once per install; seconds when cached) ...")
        compiled = compile_kernels(args.recipe, recipe.reference, folder, work / "compile")
        from inspector_tools.precompile import cold_start, first_run

        startup: dict[str, Any] = {}
        if args.first_run:
            say("First run: compiling every kernel into an empty Numba cache in a child process (about a minute) ...")
            startup["first_run"] = first_run(work / "first-run")
        say("Cold process: a new `inspector run` on the capture ...")
        startup["cold_start"] = cold_start(args.recipe, folder, work / "cold",
                                           reference=args.reference or default_reference(args.recipe, args.part))
        say(f"Inspecting {folder.name} {1 + args.runs} times (first = warm-up) with {recipe.name} ...")
        from inspector_tools.bench.cycles import bench_cycles

        cycles = bench_cycles(recipe, ref, pm, folder, work / "results", args.runs, progress=say)
        failed = [r for r in [cycles["warmup"], *cycles["runs"]] if r["verdict"] == "error"]
        if failed:
            print(f"inspector: error: bench: the inspection failed: {failed[0]['error']}", file=sys.stderr)
            return 3
        say("Carving comparison on the same capture ...")
        from inspector.capture_folder import read_capture
        from inspector_tools.bench.carving import compare_carving

        carving = compare_carving(read_capture(folder), recipe, carve_voxel=args.carve_voxel, open3d_voxel=args.open3d_voxel,
                                  carve_runs=args.carve_runs, use_open3d=not args.no_open3d,
                                  open3d_max_gb=args.open3d_max_gb, progress=say)
    acquisition = acquisition_latency(args.acquisition, args.triggers, progress=say) if args.acquisition else None
    doc: dict[str, Any] = {
        "acquisition": acquisition,
        "config": {
            "recipe": str(args.recipe), "recipe_name": recipe.name, "reference": recipe.reference, "capture": cap_info,
            "runs": args.runs, "warmup_runs": 1, "carve_runs": args.carve_runs, "carve_voxel_mm": args.carve_voxel,
            "open3d_voxel_mm": args.open3d_voxel, "open3d": not args.no_open3d,
        },
        "machine": figures_machine,
        "compile": compiled,
        "startup": startup,
        "cycles": cycles,
        "carving": carving,
    }
    sim_w, sim_h = image_size(args)
    doc["targets"] = targets(cycles, carving, startup, size=(int(cap_info["width"] or sim_w), int(cap_info["height"] or sim_h)),
                              cameras=int(cap_info["cameras"] or args.cameras))
    verdicts = [r["verdict"] for r in cycles["runs"]]
    doc["verdicts"] = verdicts
    if not args.quiet:
        print_report(doc)
        if acquisition is not None:
            _print_acquisition(acquisition)
    if args.json:
        say(f"\n  figures written to {write_figures(args.json, doc)}")
    measured = [t["met"] for t in doc["targets"].values() if t["met"] is not None]
    return 0 if all(measured) else 1


def _run_special_mode(args: argparse.Namespace) -> int | None:
    """Run ``--gui``, ``--opcua``, ``--characteristics`` or ``--dask`` when asked (its exit
    status); None: the pipeline's bench. Each mode's libraries are imported in its module."""
    if args.gui:  # Qt is imported there, never by this module
        from inspector_tools.bench.gui import run_gui_bench

        return run_gui_bench(args)
    if getattr(args, "opcua", False):  # asyncua is imported there, never by this module
        from inspector_tools.bench.opcua import run_opcua_bench

        return run_opcua_bench(args)
    if getattr(args, "characteristics", False):  # numpy, trimesh and the core are imported there
        from inspector_tools.bench.characteristics import run_characteristics_bench

        return run_characteristics_bench(args)
    if getattr(args, "dask", False):
        from inspector_tools.bench.throughput import dask_throughput

        return dask_throughput(args)
    return None


def _print_acquisition(acquisition: dict[str, Any]) -> None:
    if "skipped" in acquisition:
        print(f"\n  acquisition latency: not measured ({acquisition['skipped']})")
    else:
        print(f"\n  acquisition: {acquisition['cameras']} emulated GigE Vision cameras, trigger -> all frames: "
              f"median {acquisition['median_ms']:.1f} ms (p10 {acquisition['p10_ms']:.1f}, p90 {acquisition['p90_ms']:.1f}; "
              f"camera {acquisition['camera_median_ms']:.1f} + driver {acquisition['overhead_median_ms']:.1f} ms), "
              f"{acquisition['ok']} ok / {acquisition['failed']} failed")


def acquisition_latency(n: int, triggers: int, progress=lambda s: None) -> dict[str, Any]:
    """Median trigger-to-all-frames latency of ``n`` emulated GigE Vision cameras.

    Starts ``n`` ``arv-fake-gv-camera-0.8`` emulators in a private network namespace
    (:class:`inspector_tools.emulators.aravis.EmulatedRig`) and drives them with the
    ``aravis`` driver; returns ``{"skipped": reason}`` where that is not possible here.
    """
    from inspector_tools.emulators.aravis import EmulatedRig, missing_requirements, write_rig

    why = missing_requirements()
    if why:
        return {"skipped": why}
    with tempfile.TemporaryDirectory(prefix="inspector-acq-") as tmp:
        root = Path(tmp)
        write_rig(root / "rig.json", n)
        progress(f"Starting {n} emulated cameras ...")
        with EmulatedRig(n, log_dir=root / "logs") as rig:  # started on entry
            with rig.client() as client:
                params = {"rig": str(root / "rig.json"), "serials": rig.serials_table(), "count": 0, "timeout_s": 1.0}
                r = client.request({"cmd": "open", "driver": "aravis", "params": params}, timeout=120)
                if not r.get("ok"):
                    return {"skipped": f"could not open the emulated cameras: {r.get('error')}"}
                progress(f"Triggering {triggers} times ...")
                stats = client.request({"cmd": "latency", "triggers": triggers, "warmup": 3}, timeout=600)
    keys = ("cameras", "ok", "failed", "median_ms", "p10_ms", "p90_ms", "min_ms", "max_ms", "camera_median_ms", "overhead_median_ms")
    return {k: stats.get(k) for k in keys}


# --------------------------------------------------------------------------- plugin
@hookimpl
def inspector_register_commands(registry: CommandRegistry) -> None:
    """``inspector bench``: a built-in plugin (entry point ``bench``), like any command."""
    # lazy: inspector.registry loads numpy (inspector.model), and importing this
    # module stays free of numpy (tests/tools/test_bench.py::test_import_is_light).
    from inspector.registry import CommandSpec

    registry.add(CommandSpec("bench", add_parser, run, "cycle time per stage, memory, carving vs Open3D"))
