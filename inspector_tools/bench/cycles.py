"""``inspector bench``: the timed cycles of the batch runner (:func:`bench_cycles`)."""

from __future__ import annotations

import dataclasses
import statistics
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from inspector.capture_folder import read_capture
from inspector.registry import Acquisition
from inspector.runner import run_batch
from inspector_tools.bench.common import cpu_jiffies, loadavg, maxrss_mb, rss_mb, stats, steal_share

if TYPE_CHECKING:
    from inspector.manager import PluginManager
    from inspector.recipe import Recipe
    from inspector.reference import Reference

__all__ = ["acquisition", "bench_cycles"]


def acquisition(folder: Path) -> Any:
    """One replay :class:`Acquisition` of ``folder`` (truth dropped: production captures have none)."""
    def load() -> Any:
        cap = read_capture(folder)
        return dataclasses.replace(cap, truth=None) if cap.truth is not None else cap

    return Acquisition(folder.name, load)


def bench_cycles(recipe: Recipe, reference: Reference | None, pm: PluginManager, folder: Path, outdir: Path, runs: int,
                 progress: Any = None) -> dict[str, Any]:
    """Inspect ``folder`` ``1 + runs`` times with :func:`run_batch` (first run = warm-up).

    Returns a dict: ``warmup_s``, ``warmup`` (the warm-up run's record), ``runs`` (per run: ``verdict``, ``error``, ``cycle_s``,
    ``timings_s`` with ``outputs`` added, ``loadavg``: the 1-minute load average before and after, ``steal``: the
    share of the machine's CPU time its hypervisor gave other guests during the run (None off Linux), ``cpu_s``: this
    process's CPU time, every thread), ``loadavg`` and ``steal`` (min,
    median, max of those over the timed runs), ``stages`` (name -> median/min/max over the
    timed runs, ``load``, the stages, ``outputs``, ``total``: timings' total,
    ``cycle`` and ``cycle_cpu``), ``memory`` (MB).
    """
    mem: dict[str, Any] = {"rss_before_mb": rss_mb(), "maxrss_before_mb": maxrss_mb()}
    records: list[dict[str, Any]] = []
    warmup_s, warmup = 0.0, None
    for i in range(runs + 1):
        it = run_batch(recipe, [acquisition(folder)], pm, reference=reference, outdir=outdir / f"run{i:02d}")
        load0, jiffies0 = loadavg(), cpu_jiffies()
        t0, c0 = time.perf_counter(), time.process_time()
        outcome = next(it)
        cycle, cpu = time.perf_counter() - t0, time.process_time() - c0
        load1, jiffies1 = loadavg(), cpu_jiffies()
        for _ in it:  # pragma: no cover - one acquisition
            pass
        res = outcome.result
        timings = dict(res.timings_s)
        timings["outputs"] = max(cycle - timings.get("total", cycle), 0.0)
        rec = {"verdict": res.verdict, "error": res.error, "cycle_s": cycle, "timings_s": timings,
               "loadavg": [load0, load1], "steal": steal_share(jiffies0, jiffies1), "cpu_s": cpu}
        if i == 0:
            warmup_s, warmup = cycle, rec
            mem["maxrss_after_warmup_mb"] = maxrss_mb()
        else:
            records.append(rec)
        if progress is not None:
            label = "warm-up" if i == 0 else f"run {i}/{runs}"
            progress(f"  {label}: {res.verdict} in {cycle:.3f} s (load {load0} -> {load1})"
                     + (f" ({res.error})" if res.error else ""))
        if res.verdict == "error":
            break
    mem["maxrss_after_mb"] = maxrss_mb()
    mem["rss_after_mb"] = rss_mb()
    if mem["maxrss_after_mb"] is not None:
        mem["peak_mb"] = mem["maxrss_after_mb"]
        mem["increase_mb"] = mem["maxrss_after_mb"] - mem["maxrss_before_mb"]
        if mem.get("maxrss_after_warmup_mb") is not None:
            mem["increase_timed_mb"] = mem["maxrss_after_mb"] - mem["maxrss_after_warmup_mb"]
    stages: dict[str, dict[str, float]] = {}
    if records:
        names = [k for k in records[0]["timings_s"] if k not in ("total", "outputs") and not k.startswith("hook:")]
        names += ["outputs", "total"]  # lifecycle hooks' times ("hook:PLUGIN:HOOK") are not stages
        for name in names:
            vals = [r["timings_s"][name] for r in records if name in r["timings_s"]]
            if vals:
                stages[name] = stats(vals)
        stages["cycle"] = stats([r["cycle_s"] for r in records])
        # CPU seconds of this process (every thread): what a cycle costs whatever else runs.
        stages["cycle_cpu"] = stats([r["cpu_s"] for r in records])
    loads = [x for r in records for x in r["loadavg"] if x is not None]
    load = {"min": min(loads), "max": max(loads), "median": statistics.median(loads)} if loads else None
    steals = [r["steal"] for r in records if r["steal"] is not None]
    steal = {"min": min(steals), "max": max(steals), "median": statistics.median(steals)} if steals else None
    return {"warmup_s": warmup_s, "warmup": warmup, "runs": records, "stages": stages, "memory": mem, "loadavg": load,
            "steal": steal}
