"""``inspector bench --dask`` (issue 17): archive re-inspection throughput, captures per minute
(:func:`dask_throughput`)."""

from __future__ import annotations

import argparse
import os
import pickle
import shutil
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from inspector.errors import RecipeError
from inspector.runner import Outcome, record_outcome
from inspector.session import Session, Source
from inspector_frontends.distributed import connect, inspect_folder, run_on_cluster, worker_setup
from inspector_tools.bench.common import check_args, compile_kernels, default_reference, machine, simulate_capture, write_figures
from inspector_tools.bench.targets import image_size

__all__ = ["dask_throughput"]


def dask_throughput(args: argparse.Namespace) -> int:
    """``inspector bench --dask`` (issue 17): archive re-inspection throughput, captures per
    minute, in this process (``inspector run``), then on a local Dask cluster of each
    ``--dask-workers`` count (``inspector run --workers N``, one thread per worker).

    The archive holds ``--dask-captures`` copies of 4 simulated captures. Each cluster is
    started, and each of its workers inspects one capture, before the clock starts (imports,
    the kernels' cache, the reference's index: once per worker process): the figures are the
    steady rate of a running cluster, result folders and history rows written. Also measured,
    for a cluster of N machines: the client's own time per capture (its result folder and
    history row, :func:`inspector.runner.record_outcome`), and the bytes a worker reads
    (the capture folder) and sends back (the pickled result). Exit 0, or 3 if a capture failed.
    """
    check_args(args)
    if args.dask_captures < 1 or any(w < 1 for w in args.dask_workers):
        raise RecipeError("bench --dask-captures and --dask-workers: expected numbers >= 1")
    say = (lambda s: None) if args.quiet else (lambda s: print(s, flush=True))
    ref = args.reference or default_reference(args.recipe, args.part)
    session = Session.open(args.recipe, ".", reference=ref, pm=getattr(args, "plugin_manager", None))
    doc: dict[str, Any] = {"machine": machine(), "captures": args.dask_captures, "recipe": str(args.recipe),
                           "capture": {"part": args.part, "cameras": args.cameras, "size": list(image_size(args)),
                                       "mm_per_px": args.mm_per_px},
                           "runs": []}
    with tempfile.TemporaryDirectory(prefix="inspector-bench-dask-") as tmp:
        work = Path(args.keep) if args.keep else Path(tmp)
        distinct, archive = _archive(args, work, say)
        doc["capture"]["bytes"] = sum(f.stat().st_size for f in distinct[0].rglob("*") if f.is_file())
        compile_kernels(args.recipe, session.recipe.reference, distinct[0], work / "compile")
        setup = worker_setup(session)
        result, _ = inspect_folder(setup, str(distinct[0]))  # warm, in this process
        doc["result_bytes"] = len(pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL))
        rec = []
        for _ in range(5):
            t0 = time.perf_counter()
            record_outcome(Outcome(result, None), session.recipe, session.pm, work / "out-record")
            rec.append(time.perf_counter() - t0)
        doc["client_record_s"] = statistics.median(rec)
        failed = 0
        for workers in [0, *args.dask_workers]:
            row, summary = _throughput(args, session, setup, distinct[0], archive, work, workers, say)
            failed += summary.counts.get("error", 0)
            doc["runs"].append(row)
    say(f"  client, per capture: result folder and history row {1000 * doc['client_record_s']:.0f} ms (one client: at most "
        f"{60 / doc['client_record_s']:.0f} captures/min); a worker reads {doc['capture']['bytes'] / 1e6:.1f} MB per capture "
        f"and sends back {doc['result_bytes'] / 1e6:.2f} MB")
    if args.json:
        say(f"  figures written to {write_figures(args.json, doc)}")
    return 3 if failed else 0


def _archive(args: argparse.Namespace, work: Path, say: Any) -> tuple[list[Path], Path]:
    """Up to 4 simulated captures, and the archive of ``--dask-captures`` copies of them."""
    distinct = []
    for i in range(min(4, args.dask_captures)):
        say(f"Simulating capture {i + 1} of {min(4, args.dask_captures)} ...")
        table = {"part": args.part, "seed": args.seed + i, "cameras": args.cameras, "width": image_size(args)[0],
                 "height": image_size(args)[1], "mm_per_px": args.mm_per_px}
        distinct.append(simulate_capture(work / "src" / f"{args.part}-s{args.seed + i:04d}", table))
    archive = work / "archive"
    for i in range(args.dask_captures):
        shutil.copytree(distinct[i % len(distinct)], archive / f"c{i:04d}")
    return distinct, archive


def _throughput(args: argparse.Namespace, session: Session, setup: Any, first: Path, archive: Path, work: Path,
                workers: int, say: Any) -> tuple[dict[str, Any], Any]:
    """The archive inspected in this process (``workers`` 0) or on a local cluster of
    ``workers``: (its row of figures, the run's summary)."""
    label = "in this process" if not workers else f"on a local cluster of {workers} worker{'s' if workers > 1 else ''}"
    run_session = Session(session.recipe, session.reference, session.pm, work / f"out-{workers}")
    row: dict[str, Any] = {"workers": workers, "label": label}
    client: Any = None
    cluster: Any = None
    try:
        if workers:
            say(f"Starting a local Dask cluster of {workers} worker process(es) ...")
            t0 = time.perf_counter()
            client, cluster = connect(None, workers)
            row["start_s"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            client.run(inspect_folder, setup, str(first))  # every worker, once
            row["warmup_s"] = time.perf_counter() - t0
        say(f"Inspecting {args.dask_captures} captures {label} ...")
        row["loadavg_before"] = os.getloadavg()[0]  # a shared machine: other jobs' load beside each figure
        # CPU seconds (this process, and each worker's): what a capture costs whatever else the machine runs.
        cpu0 = client.run(time.process_time) if workers else {}
        t0, c0 = time.perf_counter(), time.process_time()
        if workers:
            summary = run_on_cluster(run_session, [str(archive)], client=client)
        else:
            summary = run_session.run(Source(captures=(str(archive),)))
        row["seconds"] = time.perf_counter() - t0
        n = max(summary.inspected, 1)
        row["cpu_s_per_capture"] = (time.process_time() - c0) / n  # in this process (the client's, for a cluster)
        if workers:
            cpu1 = client.run(time.process_time)
            row["worker_cpu_s_per_capture"] = sum(cpu1[a] - cpu0[a] for a in cpu1 if a in cpu0) / n
        row["loadavg_after"] = os.getloadavg()[0]
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    row["captures_per_min"] = 60.0 * summary.inspected / row["seconds"]
    row["counts"] = dict(summary.counts)
    cpu = row.get("worker_cpu_s_per_capture", row["cpu_s_per_capture"])
    say(f"  {label}: {row['captures_per_min']:.1f} captures/min ({row['seconds'] / summary.inspected:.2f} s per capture; "
        f"CPU {cpu:.2f} s per capture" + (f", client {row['cpu_s_per_capture']:.3f} s" if workers else "") + ")"
        + (f"; cluster start {row['start_s']:.1f} s and warm-up {row['warmup_s']:.1f} s not counted" if workers else "")
        + f" (load {row['loadavg_before']:.1f} -> {row['loadavg_after']:.1f})")
    return row, summary
