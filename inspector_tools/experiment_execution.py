"""``inspector experiment``: the execution: one task (:func:`run_task`, on a Dask worker), the
CSV rows as they arrive, and the scheduling on a Dask cluster (:func:`execute`,
:func:`start_client`). Dask and tqdm are imported when used."""

from __future__ import annotations

import csv
import sys
import time
import traceback
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from inspector.errors import InspectorError
from inspector.manager import create_plugin_manager
from inspector.params import build_params
from inspector.reference import Reference
from inspector_drivers.sim.simulate import SimParams, simulate
from inspector_tools.experiment_cases import (
    CASES,
    CSV_COLUMNS,
    METHODS,
    OBJECT_VARIANTS,
    Case,
    _method_stages,
    err_line,
    prefix_len,
)

__all__ = ["run_task", "error_rows", "CsvSink", "write_csvs", "sort_key", "execute", "start_client"]

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
        from inspector.recipe import parse_recipe
        from inspector.runner import inspect_capture
        from inspector.truth import truth_stats
        try:
            from distributed import get_worker

            common["worker"] = str(get_worker().name)
        except Exception:  # noqa: BLE001 - not in a worker (direct call)
            common["worker"] = ""
        pm = create_plugin_manager()
        ref_spec = f"builtin:{spec['part']}"
        stages = spec["stages"]
        k = prefix_len(stages)
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
        msg = err_line(exc)
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
            row["error"] = err_line(exc)
        row["t_run_s"] = shared_s + (time.perf_counter() - t_m)  # this method's result from scratch
        rows.append(row)
    return rows


# --------------------------------------------------------------------------- scheduling


class CsvSink:
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


def sort_key(r: Mapping[str, Any]) -> tuple:
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
            for r in sorted((r for r in rows if r["case"] == c.name), key=sort_key):
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
        try:
            return Client(scheduler, timeout="30s"), None
        except (OSError, TimeoutError) as e:
            raise InspectorError(f"{command} --scheduler {scheduler}: cannot connect ({' '.join(str(e).split())})") from None
    import logging

    # ":0": any free port for the scheduler's HTTP server (8787 may be taken on a shared machine).
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                           silence_logs=logging.ERROR)
    return Client(cluster), cluster

