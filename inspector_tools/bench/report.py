"""``inspector bench``: the report printed after the pipeline's figures."""

from __future__ import annotations

from typing import Any

from inspector_tools.bench.targets import CARVE_RATIO_TARGET, COLD_START_TARGET_S, FIRST_RUN_TARGET_S, word

__all__ = ["print_report"]


def print_report(doc: dict[str, Any]) -> None:
    cfg, cyc = doc["config"], doc["cycles"]
    cap = cfg["capture"]
    m = doc["machine"]
    print()
    print(f"inspector bench: recipe {cfg['recipe']} ({cfg['recipe_name']}), reference {cfg['reference']}")
    print(f"  capture {cap['name']}: {cap['cameras']} cameras, {cap['width']}x{cap['height']} px ({cap['source']})")
    print(f"  machine: {m['usable_cpus']} usable CPUs, load average {m['loadavg_1_5_15']} at start "
          "(timings depend on other jobs on this machine)")
    comp = doc.get("compile")
    if comp:
        print(f"  kernels compiled/loaded in a child process first: {comp['seconds']:.1f} s (exit {comp['exit']}; "
              "the first inspection after an install compiles them, once)")
    st = doc.get("startup") or {}
    if st.get("first_run"):
        fr = st["first_run"]
        print(f"  first run (empty Numba cache, `python -m inspector_tools.precompile`): {fr['seconds']:.1f} s, "
              f"{fr['kernels']} kernels compiled (exit {fr['exit']})")
    if st.get("cold_start"):
        cs = st["cold_start"]
        shown = f"{cs['verdict_s']:.2f} s" if cs["verdict_s"] is not None else "no verdict"
        print(f"  cold process (new `inspector run`, kernels cached): start -> verdict {shown}, exit after {cs['exit_s']:.2f} s")
    ld, sl = cyc.get("loadavg"), cyc.get("steal")
    print(f"  warm-up run {cyc['warmup_s']:.3f} s (left out); {len(cyc['runs'])} timed run(s)"
          + (f"; 1-minute load average during them {ld['min']:.2f}-{ld['max']:.2f} (median {ld['median']:.2f}) "
             f"on {m['usable_cpus']} CPUs" if ld else "")
          + (f"; CPU stolen by the hypervisor {100 * sl['min']:.0f}-{100 * sl['max']:.0f} % (median "
             f"{100 * sl['median']:.0f} %)" if sl else ""))
    if cyc["stages"]:
        print()
        print(f"  {'stage':<18}{'median s':>10}{'min s':>10}{'max s':>10}")
        for name, s in cyc["stages"].items():
            if name in ("total", "cycle", "cycle_cpu"):
                continue
            print(f"  {name:<18}{s['median']:>10.3f}{s['min']:>10.3f}{s['max']:>10.3f}")
        for name, label in (("total", "load+stages"), ("cycle", "cycle (all)"), ("cycle_cpu", "cycle CPU s")):
            s = cyc["stages"].get(name)
            if s:
                print(f"  {label:<18}{s['median']:>10.3f}{s['min']:>10.3f}{s['max']:>10.3f}")
    mem = cyc["memory"]
    if mem.get("peak_mb") is not None:
        print(f"\n  memory: peak RSS {mem['peak_mb']:.0f} MB (ru_maxrss); before the runs {mem['maxrss_before_mb']:.0f} MB, "
              f"+{mem['increase_mb']:.0f} MB over warm-up and runs (+{mem.get('increase_timed_mb', 0.0):.0f} MB over the timed runs)")
    c = doc.get("carving")
    if c:
        o = c["ours"]
        print(f"\n  carving on the same masks, box {' x '.join(f'{b - a:.1f}' for a, b in zip(*c['bounds_mm']))} mm:")
        print(f"    ours   carve() at {c['carve_voxel_mm']} mm: median {o['median_s']:.3f} s (min {o['min_s']:.3f}, "
              f"max {o['max_s']:.3f}), {o['n_points']} surface points, {o['n_finest_evaluated']} finest cells tested")
        br = o.get("time_breakdown_s") or {}
        if br:
            print(f"           last run: distance transforms and cell tests {br.get('carve', 0):.3f} s, finest cells "
                  f"and surface points {br.get('points', 0):.3f} s, display mesh {br.get('mesh', 0):.3f} s")
        o3 = c["open3d"]
        if "refused" in o3 or "skipped" in o3:
            print(f"    open3d: {o3.get('refused') or 'skipped: ' + o3['skipped']}")
        else:
            print(f"    open3d VoxelGrid at {c['open3d_voxel_mm']} mm: {'x'.join(map(str, o3['grid']))} = {o3['n_voxels']:,} voxels"
                  f" (~{o3.get('grid_rss_mb', float('nan')):.0f} MB); create_dense {o3['create_dense_s']:.2f} s, "
                  f"carve_silhouette x{len(o3['per_camera_s'])} {o3['carve_silhouette_s']:.2f} s")
            kept = o3.get("n_voxels_kept")
            inside = o3.get("our_points_in_kept_voxels")
            print(f"    open3d kept {kept if kept is not None else '?'} voxels; our surface points in kept voxels: "
                  f"{'n/a' if inside is None else f'{100 * inside:.2f} %'}")
            for note in o3.get("notes", []):
                print(f"    note: {note}")
            print(f"    ratio (carve_silhouette / our whole carve()): {c['ratio']:.1f}x; with create_dense: "
                  f"{c['ratio_with_create']:.1f}x"
                  + (f"; against ours without the display mesh: {c['ratio_without_mesh']:.1f}x (informative)"
                     if c.get("ratio_without_mesh") else ""))
    print("\n  targets:")
    t = doc["targets"]
    cv, ct, ld = t["cycle"]["value_s"], t["cycle"].get("target_s"), t["cycle"].get("loadavg")
    print(f"    cycle <= {ct if ct is not None else float('nan'):.3g} s (median, {cap['cameras']} x {cap['width']}x{cap['height']}):  "
          f"{word(t['cycle']['met'])}" + (f" ({cv:.3f} s" if cv is not None else "")
          + (f"; load average {ld['min']:.1f}-{ld['max']:.1f} on {m['usable_cpus']} CPUs" if cv is not None and ld else "")
          + (f"; {100 * t['cycle']['steal']['median']:.0f} % of the CPU stolen" if cv is not None and t["cycle"].get("steal")
             else "") + (")" if cv is not None else ""))
    mv, mt = t["memory"]["value_mb"], t["memory"].get("target_mb")
    print(f"    peak memory <= {(mt or float('nan')) / 1000:g} GB:   {word(t['memory']['met'])}"
          + (f" ({mv / 1000:.2f} GB)" if mv is not None else ""))
    rv = t["carve_ratio"]["value"]
    print(f"    carve ratio >= {CARVE_RATIO_TARGET:g}x:     {word(t['carve_ratio']['met'])}"
          + (f" ({rv:.1f}x: Open3D {c['open3d_voxel_mm']} mm vs ours {c['carve_voxel_mm']} mm)" if rv is not None and c else ""))
    for key, label in (("cold_start", f"new process -> verdict <= {COLD_START_TARGET_S:g} s"),
                       ("first_run", f"first compile <= {FIRST_RUN_TARGET_S:g} s")):
        got = t.get(key) or {}
        v = got.get("value_s")
        print(f"    {label}: {word(got.get('met'))}" + (f" ({v:.2f} s)" if v is not None else ""))
