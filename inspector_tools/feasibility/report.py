"""A feasibility study's report: the coloured reference (PLY), its pictures, POD curves in
the style of MIL-HDBK-1823A, the gauge study's histograms, ``feasibility.md`` and a
self-contained ``feasibility.html`` (pictures embedded), CSV of the simulations and defects.

The report is a list of blocks (headings, paragraphs, tables, pictures) written twice, as
Markdown and as HTML, so both always say the same. The pictures are rendered by casting
orthographic rays at the display mesh (Open3D's raycasting scene): correct occlusion for
concave parts, no display needed.
"""

from __future__ import annotations

import base64
import csv
import html
import json
import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from inspector.outputs import write_ply
from inspector_tools.feasibility.analysis import FRR_MAX, pod_words
from inspector_tools.feasibility.stats import CG_MIN

if TYPE_CHECKING:
    from inspector_tools.feasibility.analysis import RegionResult, Results
    from inspector_tools.feasibility.stats import PodFit

__all__ = ["write_report", "render_views", "VIEWS", "NEVER_RGB"]

#: Viewing directions of the pictures (from the part towards the eye), with their names.
VIEWS: tuple[tuple[str, tuple[float, float, float]], ...] = (
    ("+x+y+z", (1, 1, 1)), ("-x-y+z", (-1, -1, 1)), ("+x-y+z", (1, -1, 1)),
    ("-x+y-z", (-1, 1, -1)), ("+x-y-z", (1, -1, -1)), ("-x-y-z", (-1, -1, -1)),
)

#: Colour of the surface never observed (no BCPS point in any pose): outside the viridis scale.
NEVER_RGB = (0.86, 0.08, 0.24)
_GREY = (0.78, 0.78, 0.78)


# --------------------------------------------------------------------------- pictures


def render_views(vertices: np.ndarray, faces: np.ndarray, face_rgb: np.ndarray, *,
                 views: Sequence[tuple[str, tuple[float, float, float]]] = VIEWS, size: int = 320) -> list[np.ndarray]:
    """Orthographic pictures of a coloured mesh, one per view.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
    face_rgb : (F, 3) float
        Colour of each face, 0..1.
    views : sequence of (name, (3,) direction from the part towards the eye)
    size : int
        Pixels per side.

    Returns
    -------
    list of (size, size, 3) float
        Lambert-shaded (light from the eye), white background.
    """
    import open3d as o3d

    V = np.asarray(vertices, np.float32)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(V), o3d.core.Tensor(np.asarray(faces, np.uint32)))
    centre = (V.max(axis=0) + V.min(axis=0)) / 2
    radius = float(np.linalg.norm(V - centre, axis=1).max()) * 1.04
    s = (np.arange(size) + 0.5) / size * 2 - 1
    gu, gv = np.meshgrid(s * radius, -s * radius)
    out = []
    rgb = np.asarray(face_rgb, float)
    for _, eye in views:
        e = np.asarray(eye, float) / np.linalg.norm(eye)
        f = -e
        up0 = np.array([0.0, 0.0, 1.0]) if abs(f[2]) < 0.95 else np.array([0.0, 1.0, 0.0])
        right = np.cross(f, up0)
        right /= np.linalg.norm(right)
        up = np.cross(right, f)
        origins = centre + e * 3 * radius + gu[..., None] * right + gv[..., None] * up
        rays = np.concatenate([origins.reshape(-1, 3), np.broadcast_to(f, (size * size, 3))], axis=1).astype(np.float32)
        ans = scene.cast_rays(o3d.core.Tensor(rays))
        hit = np.isfinite(ans["t_hit"].numpy())
        pid = ans["primitive_ids"].numpy().astype(np.int64)
        nrm = ans["primitive_normals"].numpy()
        img = np.ones((size * size, 3))
        light = -f + 0.55 * up - 0.35 * right  # from above-left of the eye: the faces of a corner differ
        light /= np.linalg.norm(light)
        shade = 0.45 + 0.55 * np.abs(nrm[hit] @ light)
        img[hit] = rgb[pid[hit]] * shade[:, None]
        out.append(img.reshape(size, size, 3))
    return out


def _views_figure(path: Path, images: list[np.ndarray], title: str, note: str, cmap: Any, norm: Any, clabel: str,
                  legend: list[tuple[tuple[float, float, float], str]]) -> Path:
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    fig = Figure(figsize=(9.6, 7.0), dpi=100)
    fig.suptitle(title, fontsize=11)
    # One mosaic in one axes (six axes cost twice the drawing time).
    size, gap, head = images[0].shape[0], 12, 22
    mosaic = np.ones((2 * (size + head), 3 * size + 2 * gap, 3))
    ax = fig.add_axes((0.01, 0.1, 0.89, 0.84))
    for i, (img, (name, _)) in enumerate(zip(images, VIEWS)):
        r, c = divmod(i, 3)
        y, x = r * (size + head) + head, c * (size + gap)
        mosaic[y:y + size, x:x + size] = img
        ax.text(x + size / 2, y - 4, f"seen from {name}", ha="center", va="bottom", fontsize=8)
    ax.imshow(mosaic, interpolation="nearest")
    ax.set_axis_off()
    cax = fig.add_axes((0.925, 0.2, 0.018, 0.6))
    from matplotlib.cm import ScalarMappable

    fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), cax=cax).set_label(clabel, fontsize=8)
    cax.tick_params(labelsize=7)
    if legend:
        fig.legend(handles=[Patch(color=c, label=t) for c, t in legend], loc="lower center", fontsize=8, frameon=False,
                   ncol=len(legend))
    if note:
        fig.text(0.5, 0.06, _wrap(note, 150), ha="center", va="center", fontsize=7.5, color="0.3")
    fig.savefig(path)
    return path


def _face_values(res: Results, values: np.ndarray) -> np.ndarray:
    return np.asarray(values, float)[res.map.face_element]


def observability_picture(res: Results, path: Path) -> Path:
    """Six views of the reference coloured by observability; never observed in red."""
    from matplotlib import colormaps
    from matplotlib.colors import Normalize

    m = res.map
    obs = _face_values(res, res.observability)
    cmap, norm = colormaps["viridis"], Normalize(0.0, 1.0)
    rgb = cmap(norm(obs))[:, :3]
    never = obs <= 0
    rgb[never] = NEVER_RGB
    share = 1 - res.observed_share()
    n = res.nominal["captures"]
    title = (f"Observability of {_part(res)}: share of {n} random poses with a BCPS point on each "
             f"{m.element_mm:.2g} mm element")
    note = (f"{res.study.rig_label}; red: never observed in {n} poses ({100 * share:.1f} % of the surface): "
            "no silhouette contour ever touches it, so no defect there can be measured")
    return _views_figure(path, render_views(m.vertices, m.faces, rgb), title, note, cmap, norm, "share of poses observed",
                         [(NEVER_RGB, f"never observed ({100 * share:.1f} % of the area)")])


def error_picture(res: Results, path: Path) -> Path:
    """Six views coloured by the p95 distance of the BCPS points to the true surface."""
    from matplotlib import colormaps
    from matplotlib.colors import Normalize

    m = res.map
    p95 = _face_values(res, res.err_p95)
    finite = res.err_p95[np.isfinite(res.err_p95)]
    top = float(np.percentile(finite, 99)) if len(finite) else 1.0
    top = max(top, 0.25 * res.study.footprint_mm, 1e-3)
    cmap, norm = colormaps["magma_r"], Normalize(0.0, top)
    rgb = cmap(norm(np.nan_to_num(p95, nan=0.0)))[:, :3]
    rgb[~np.isfinite(p95)] = _GREY
    title = f"Measurement error on {_part(res)}: p95 distance of the BCPS points to the true surface, per element"
    note = (f"pixel footprint {res.study.footprint_mm:.3g} mm at the rig centre; colour scale saturates at {top:.3g} mm; "
            "grey: never observed")
    return _views_figure(path, render_views(m.vertices, m.faces, rgb), title, note, cmap, norm, "p95 error, mm",
                         [(_GREY, "never observed")])


def _pod_panel(ax: Any, fit: PodFit, rows: list[dict[str, Any]], title: str, span: tuple[float, float]) -> None:
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    sizes = np.array([r["size_mm"] for r in rows], float)
    hits = np.array([bool(r["hit"]) for r in rows])
    ax.set_xscale("log")
    lo, hi = span[0] / 1.3, span[1] * 1.3
    ax.set_xlim(lo, hi)
    ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_ylim(-0.08, 1.08)
    ax.set_title(title, fontsize=10)
    ax.set_xlabel("defect size a, mm (sphere radius: dent depth, bump height)", fontsize=8)
    ax.set_ylabel("probability of detection, POD(a)", fontsize=8)
    ax.grid(True, which="both", alpha=0.25)
    ax.tick_params(labelsize=7)
    if not len(sizes):
        ax.text(0.5, 0.5, "no defect placed", ha="center", transform=ax.transAxes)
        return
    ax.axhline(0.9, color="0.45", lw=0.8, ls=":")
    ax.plot(sizes[hits], np.ones(hits.sum()), "o", ms=3.5, mfc="none", color="tab:blue", alpha=0.7, label="hit")
    ax.plot(sizes[~hits], np.zeros((~hits).sum()), "x", ms=3.5, color="tab:red", alpha=0.7, label="miss")
    edges = np.geomspace(sizes.min(), sizes.max() * 1.0001, 7)
    which = np.clip(np.searchsorted(edges, sizes, side="right") - 1, 0, len(edges) - 2)
    classes = [(math.sqrt(edges[b] * edges[b + 1]), hits[which == b].mean()) for b in range(len(edges) - 1)
               if (which == b).sum() >= 3]
    if classes:
        cx, cy = zip(*classes)
        ax.plot(cx, cy, "s", ms=5, mfc="none", color="0.3", label="hit rate per size class")
    a = np.geomspace(lo, hi, 300)
    if fit.b0 is not None and fit.status == "fit":
        ax.plot(a, fit.pod(a), "-", color="k", lw=1.6, label="POD(a), logit on ln a")
        ax.plot(a, fit.lower(a), "--", color="k", lw=1.0, label="95 % lower confidence bound")
    text = [f"n = {fit.n}, hits = {fit.hits}"]
    for lab, v in (("a50", fit.a50), ("a90", fit.a90), ("a90/95", fit.a90_95)):
        if v is not None:
            text.append(f"{lab} = {v:.3g} mm" if v <= fit.a_max * (1 + 1e-9) else f"{lab} > {fit.a_max:.3g} mm, the largest tested")
    if fit.a90 is not None and lo < fit.a90 < hi:
        ax.axvline(fit.a90, color="0.3", lw=0.8)
    if fit.a90_95 is not None and lo < fit.a90_95 < hi:
        ax.axvline(fit.a90_95, color="0.3", lw=0.8, ls="--")
    if fit.status != "fit" or fit.a90_95 is None:
        text.append(_wrap(fit.note or fit.status, 44))
    ax.text(0.03, 0.93, "\n".join(text), transform=ax.transAxes, fontsize=7, va="top",
            bbox={"boxstyle": "round", "fc": "white", "ec": "0.7"})
    ax.legend(fontsize=6.5, loc="center left", bbox_to_anchor=(0.01, 0.45), framealpha=0.9)


def _wrap(text: str, width: int) -> str:
    import textwrap

    return "\n".join(textwrap.wrap(text, width))


def pod_picture(res: Results, region: RegionResult, path: Path) -> Path:
    """MIL-HDBK-1823A style hit/miss POD plots of one region: dents, bumps."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10.0, 4.2), dpi=100)
    fig.suptitle(f"Probability of detection, {_part(res)}, region '{region.name}' (band {region.band})", fontsize=11)
    for i, kind in enumerate(("dent", "bump")):
        ax = fig.add_subplot(1, 2, i + 1)
        rows = [d for d in res.defects if d["region"] == region.name and d["kind"] == kind and d["hit"] is not None]
        _pod_panel(ax, region.pod[kind], rows, f"{kind}s ({'missing' if kind == 'dent' else 'excess'} material)",
                   tuple(res.study.config["sizes_mm"]))
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.13, top=0.84, wspace=0.22)
    fig.savefig(path)
    return path


def gauge_picture(res: Results, path: Path) -> Path:
    """Per region: the deviations of every BCPS point of the nominal part (the type-1 study's
    measurements) against the band, with the mean, ±3 s and the ±0.1 T reference lines."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator

    regs = res.regions
    ncol = min(3, max(1, len(regs)))
    nrow = math.ceil(len(regs) / ncol) or 1
    fig = Figure(figsize=(3.4 * ncol, 2.7 * nrow + 0.5), dpi=100)
    used = res.nominal["judged"] - len(res.nominal["misaligned"])
    fig.suptitle(f"Type-1 gauge study, {_part(res)}: deviation of every BCPS point, {used} nominal captures", fontsize=10)
    devs = res.deviations
    for i, r in enumerate(regs):
        ax = fig.add_subplot(nrow, ncol, i + 1)
        d = devs.get(r.name, np.zeros(0))
        span = max(r.upper - r.lower, 1e-6)
        lim = (r.lower - 0.3 * span, r.upper + 0.3 * span)
        if len(d):
            ax.hist(np.clip(d, *lim), bins=80, range=lim, color="tab:blue", alpha=0.75)
        for x, ls, c in ((r.lower, "-", "tab:red"), (r.upper, "-", "tab:red"), (-0.1 * span, ":", "0.3"), (0.1 * span, ":", "0.3")):
            ax.axvline(x, ls=ls, color=c, lw=1)
        g = r.gauge
        if math.isfinite(g.s):
            for x in (g.mean - 3 * g.s, g.mean + 3 * g.s):
                ax.axvline(x, ls="--", color="tab:green", lw=1)
        if len(d):
            ax.set_yscale("log")
            ax.set_title(f"'{r.name}' {r.band}: Cg {g.cg:.2f}, Cgk {g.cgk:.2f}", fontsize=8)
        else:
            ax.set_title(f"'{r.name}' {r.band}: no point measured", fontsize=8)
            ax.set_yticks([])
        ax.tick_params(labelsize=7)
        ax.xaxis.set_major_locator(MaxNLocator(6))
        ax.set_xlabel("deviation, mm (red: limits; dotted: ±0.1 T; green: mean ±3 s)", fontsize=6.5)
    fig.subplots_adjust(left=0.06, right=0.98, bottom=0.12 / nrow, top=1 - 0.5 / (2.7 * nrow + 0.5) - 0.04,
                        hspace=0.55, wspace=0.25)
    fig.savefig(path)
    return path


# --------------------------------------------------------------------------- PLY


def write_map_ply(res: Results, path: Path) -> Path:
    """The display mesh with per-vertex fields: colour (observability, red never observed),
    observability, poses observed, p95 and mean error (mm, NaN where never observed), points,
    element and region."""
    from matplotlib import colormaps

    m = res.map
    e = m.vertex_element
    obs = res.observability[e]
    rgb = colormaps["viridis"](np.clip(obs, 0, 1))[:, :3]
    rgb[obs <= 0] = NEVER_RGB
    rgb8 = np.round(rgb * 255).astype(np.uint8)
    n = res.nominal["captures"]
    cols = {
        "x": m.vertices[:, 0].astype(np.float32), "y": m.vertices[:, 1].astype(np.float32),
        "z": m.vertices[:, 2].astype(np.float32),
        "red": rgb8[:, 0], "green": rgb8[:, 1], "blue": rgb8[:, 2],
        "observability": obs.astype(np.float32),
        "poses_observed": np.round(obs * n).astype(np.int32),
        "err_mean_mm": res.err_mean[e].astype(np.float32), "err_p95_mm": res.err_p95[e].astype(np.float32),
        "points": res.n_points[e].astype(np.int32), "element": e.astype(np.int32), "region": m.region[e].astype(np.int32),
    }
    write_ply(path, cols, m.faces)
    return path


# --------------------------------------------------------------------------- text


def _part(res: Results) -> str:
    ref = res.study.config["reference"]
    return ref[len("builtin:"):] if ref.startswith("builtin:") else Path(ref).name


def _mm(v: float | None, digits: int = 3) -> str:
    return "—" if v is None or not math.isfinite(v) else f"{v:.{digits}g}"


def _a9095(fit: PodFit) -> str:
    if fit.a90_95 is None or fit.extrapolated:
        return {"no-data": "not studied", "all-missed": f"not found (0/{fit.n})"}.get(
            fit.status, f"> {fit.a_max:.3g} mm ({fit.hits}/{fit.n} found)")
    mark = "29/29: " if fit.status == "29/29" else ""
    return f"{mark}{fit.a90_95:.3g} mm"


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.]", "_", name.replace("+", "p").replace("-", "m")) or "region"


def _blocks(res: Results, files: dict[str, Any]) -> list[tuple]:
    """The report's blocks (markdown and HTML are made from them): the summary, the verdict per
    region and the observability, then the POD and the false rejects, then the gauge study and the files."""
    return _summary_blocks(res, files) + _detection_blocks(res, files) + _gauge_blocks(res, files)


def _summary_blocks(res: Results, files: dict[str, Any]) -> list[tuple]:
    st = res.study
    cfg = st.config
    nom = res.nominal
    sims_ok = sum(s["status"] == "ok" for s in res.sims)
    B: list[tuple] = []
    B.append(("h1", f"Feasibility of inspecting {_part(res)}"))
    B.append(("p", f"Reference `{cfg['reference']}`; recipe `{Path(cfg['recipe_path']).name}`; {st.rig_label}; pixel footprint "
                   f"{st.footprint_mm:.3g} mm at the rig centre. {cfg['poses']} captures of the nominal part in random falling "
                   f"poses, and {cfg['defect_captures']} captures with {cfg['defects_per_capture']} defects each (dents and "
                   f"bumps, spheres of radius {cfg['sizes_mm'][0]:.3g} to {cfg['sizes_mm'][1]:.3g} mm, log-uniform, centred at "
                   f"random on each region's surface), every one inspected by the recipe's own pipeline. {sims_ok} "
                   f"simulations; study seed {cfg['seed']} (key `{st.key}`): the same command gives the same numbers."))
    B.append(("h2", "Verdict per region"))
    head = ["region", "band", "area, mm²", "observable share", "a90/95 dents", "a90/95 bumps", "Cg", "Cgk",
            "false-reject rate", "verdict"]
    rows = []
    for r in res.regions:
        rows.append([f"`{r.name}`", r.band, f"{r.area_mm2:.0f}", f"{100 * r.observable_share:.1f} %",
                     _a9095(r.pod["dent"]), _a9095(r.pod["bump"]), _mm(r.gauge.cg), _mm(r.gauge.cgk),
                     f"{r.frr_k}/{r.frr_n} ({100 * r.frr:.1f} %)" if r.frr_n else "—",
                     "**inspectable**" if r.inspectable else "**not at this tolerance**"])
    B.append(("table", head, rows))
    B.append(("p", f"*Observable share*: the share of the region's area on which a BCPS point landed in at least one of the "
                   f"{nom['captures']} poses. *a90/95*: the defect size found with probability 0.9 at 95 % confidence "
                   f"(MIL-HDBK-1823A hit/miss analysis; \"29/29\": no curve fits, but the 29 largest were all found). "
                   f"*Cg*, *Cgk*: type-1 gauge study of the deviation of the nominal part's points against the band "
                   f"(need {CG_MIN}). *False-reject rate*: nominal captures rejected for a defect in this region. "
                   f"*Inspectable*: Cg and Cgk at least {CG_MIN}, false rejects at most {100 * FRR_MAX:g} %, and both kinds "
                   "of defect found with POD 0.9 at 95 % confidence within the sizes tested."))
    B.append(("ul", [("**" if not r.inspectable else "") + f"region '{r.name}' at {r.band}: "
                     + ("inspectable" if r.inspectable else "not inspectable at this tolerance: " + "; ".join(r.reasons))
                     + ("**" if not r.inspectable else "") for r in res.regions]))

    B.append(("h2", "Observability"))
    B.append(("img", files["observability"].name, "observability map"))
    never = 1 - res.observed_share()
    B.append(("p", f"The reference cut into {res.map.n} elements of about {res.map.element_mm:.2g} mm, coloured by the share of "
                   f"the {nom['captures']} poses in which a BCPS point landed on each. In red, the {100 * never:.1f} % of the surface "
                   "never observed: no silhouette contour touched it in any pose (concavities, and the inside of flat faces, "
                   "which a silhouette sees only at their edges), so a defect there cannot be measured; a bump may still "
                   "show where it sticks out past the silhouette. Per-vertex fields in "
                   f"`{files['ply'].name}` (observability, poses_observed, err_mean_mm, err_p95_mm, points, region)."))
    B.append(("img", files["error"].name, "measurement error map"))
    B.append(("p", f"Distance of the BCPS points of the nominal part to the true surface: mean "
                   f"{_mm(nom['bcps_truth_mean_mm'])} mm over all captures ({_mm(nom['bcps_truth_mean_mm'] / st.footprint_mm)} px)."))
    return B


def _detection_blocks(res: Results, files: dict[str, Any]) -> list[tuple]:
    nom = res.nominal
    B: list[tuple] = []
    B.append(("h2", "Probability of detection"))
    head = ["region", "kind", "defects", "found", "a50, mm", "a90, mm", "a90/95", "note"]
    rows = []
    for r in res.regions:
        for kind in ("dent", "bump"):
            f = r.pod[kind]
            why = pod_words(kind, f)
            rows.append([f"`{r.name}`", kind + "s", str(f.n), str(f.hits), _mm(f.a50) if f.a50 and f.a50 <= f.a_max else "—",
                         _mm(f.a90) if f.a90 and f.a90 <= f.a_max else "—", _a9095(f),
                         why.split(": ", 1)[1] if why else ("29 of 29 found" if f.status == "29/29" else "")])
    B.append(("table", head, rows))
    for r in res.regions:
        B.append(("img", files["pod"][r.name].name, f"POD, region {r.name}"))
    B.append(("p", "Hit: the inspection rejected the part for a cluster of the defect's kind (missing material for a dent, "
                   "excess for a bump) at the defect. Model: logit POD(a) = b0 + b1 ln a, fitted by maximum likelihood "
                   "(binomial GLM); dashed: its one-sided 95 % lower confidence bound (Wald); squares: the hit rate of each "
                   "size class. A dent on a flat face or inside a concavity reaches no contour (the silhouettes' limit, "
                   "measured in docs/acceptance.md): its POD stays low where the map above is red."))

    B.append(("h2", "False rejects of the nominal part"))
    mis = nom["misaligned"]
    B.append(("p", f"{nom['fail']} of {nom['judged']} nominal captures rejected ({100 * nom['frr']:.1f} %; one-sided 95 % upper "
                   f"bound {100 * nom['frr_upper95']:.1f} %); {nom['error']} with verdict `error` (not judged). "
                   + (f"{len(mis)} of them misaligned ({', '.join(f'`{m}`' for m in mis[:5])}{' ...' if len(mis) > 5 else ''}): "
                      f"the recipe's pose was wrong, not the points (pose misfit above "
                      f"{nom['pose_misfit_mm']['limit']:.3g} mm; the correctly posed captures: at most "
                      f"{nom['pose_misfit_mm']['max_posed']:.3g} mm). " if mis else "No capture was misaligned. ")
                   + "Each capture's verdict, and the defects that rejected it, are in `simulations.csv`; "
                   "`--keep-captures K` writes the first K captures, which `inspector run` inspects to the same verdicts."))
    return B


def _gauge_blocks(res: Results, files: dict[str, Any]) -> list[tuple]:
    nom = res.nominal
    mis = nom["misaligned"]
    B: list[tuple] = []
    B.append(("h2", "Gauge study (type 1)"))
    head = ["region", "band", "points", "bias, mm", "s, mm", "Cg", "Cgk", "region mean ± sd, mm", "p01 ± sd, mm",
            "p99 ± sd, mm", "verdict repeatability"]
    rows = []
    for r in res.regions:
        g = r.gauge

        def ms(k: str, r: RegionResult = r) -> str:
            m, s = r.repeat[k]
            return "—" if not math.isfinite(m) else f"{m:+.4f} ± {s:.4f}"

        vv, share = r.verdict_share
        rows.append([f"`{r.name}`", r.band, str(g.n), _mm(g.bias, 2), _mm(g.s, 3), _mm(g.cg), _mm(g.cgk), ms("mean"), ms("p01"),
                     ms("p99"), f"{vv} in {100 * share:.0f} %" if vv else "—"])
    B.append(("table", head, rows))
    B.append(("ul", [r.gauge_sentence() for r in res.regions]))
    B.append(("img", files["gauge"].name, "gauge study"))
    B.append(("p", f"The same nominal part captured {nom['judged'] - len(mis)} times (the misaligned captures left out), a new "
                   "pose and new image noise each time. "
                   "Each BCPS point measures the local deviation, whose true value is 0: over every point of the region in "
                   "every capture, bias = mean, s = standard deviation; Cg = 0.2 T / (6 s), Cgk = (0.1 T − |bias|) / (3 s), "
                   "T = upper − lower (VDA 5, Bosch booklet 10). The ± columns: the region's statistics per capture, their "
                   "mean and standard deviation over the captures."))
    B.append(("h2", "Files"))
    B.append(("ul", [f"`{Path(p).name}`: {what}" for what, p in (
        ("the map: the reference with per-vertex fields (PLY)", files["ply"]),
        ("six views coloured by observability", files["observability"]),
        ("six views coloured by the p95 error", files["error"]),
        ("the gauge study's histograms", files["gauge"]),
        ("one row per simulation", files["sims_csv"]), ("one row per placed defect (hit, shown depth)", files["defects_csv"]),
        ("the numbers of this report", files["json"]), ("the study's configuration", files["study"]),
    )] + [f"`{p.name}`: POD of region '{n}'" for n, p in files["pod"].items()]))
    B.append(("p", f"Wall time {res.elapsed_s:.0f} s ({res.ran} simulations run now, the others kept in `sims/`)."))
    return B


def _md(blocks: list[tuple]) -> str:
    out: list[str] = []
    for b in blocks:
        kind = b[0]
        if kind == "h1":
            out += [f"# {b[1]}", ""]
        elif kind == "h2":
            out += [f"## {b[1]}", ""]
        elif kind == "p":
            out += [b[1], ""]
        elif kind == "ul":
            out += [f"- {x}" for x in b[1]] + [""]
        elif kind == "img":
            out += [f"![{b[2]}]({b[1]})", ""]
        elif kind == "table":
            head, rows = b[1], b[2]
            out += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
            out += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows] + [""]
    return "\n".join(out)


def _inline(text: str) -> str:
    t = html.escape(text)
    t = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", t)
    t = re.sub(r"\*(.+?)\*", r"<i>\1</i>", t)
    return re.sub(r"`(.+?)`", r"<code>\1</code>", t)


def _html(blocks: list[tuple], folder: Path, title: str) -> str:
    out = ["<!DOCTYPE html>", "<html lang='en'><head><meta charset='utf-8'>", f"<title>{html.escape(title)}</title>",
           "<style>body{font-family:sans-serif;max-width:1050px;margin:2em auto;color:#222;line-height:1.4}"
           "table{border-collapse:collapse;margin:1em 0;font-size:.85em}td,th{border:1px solid #bbb;padding:.3em .5em}"
           "th{background:#eee}img{max-width:100%}code{background:#f3f3f3;padding:0 .2em}</style></head><body>"]
    for b in blocks:
        kind = b[0]
        if kind in ("h1", "h2"):
            out.append(f"<{kind}>{_inline(b[1])}</{kind}>")
        elif kind == "p":
            out.append(f"<p>{_inline(b[1])}</p>")
        elif kind == "ul":
            out.append("<ul>" + "".join(f"<li>{_inline(x)}</li>" for x in b[1]) + "</ul>")
        elif kind == "img":
            data = base64.b64encode((folder / b[1]).read_bytes()).decode("ascii")
            out.append(f"<p><img alt='{html.escape(b[2])}' src='data:image/png;base64,{data}'></p>")
        elif kind == "table":
            out.append("<table><tr>" + "".join(f"<th>{_inline(h)}</th>" for h in b[1]) + "</tr>")
            out += ["<tr>" + "".join(f"<td>{_inline(str(c))}</td>" for c in row) + "</tr>" for row in b[2]]
            out.append("</table>")
    out.append("</body></html>")
    return "\n".join(out)


def _csv(path: Path, rows: list[dict[str, Any]]) -> Path:
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    return path


def _json_safe(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def write_report(res: Results, out: Path) -> dict[str, Any]:
    """Write every file of the report into ``out``; their paths by role."""
    out = Path(out)
    files: dict[str, Any] = {
        "ply": write_map_ply(res, out / "observability.ply"),
        "observability": observability_picture(res, out / "observability.png"),
        "error": error_picture(res, out / "error.png"),
        "gauge": gauge_picture(res, out / "gauge.png"),
        "pod": {r.name: pod_picture(res, r, out / f"pod_{i:02d}_{_safe(r.name)}.png") for i, r in enumerate(res.regions)},
        "sims_csv": _csv(out / "simulations.csv", res.sims),
        "defects_csv": _csv(out / "defects.csv", res.defects),
        "study": out / "study.json",
    }
    files["json"] = out / "feasibility.json"
    files["json"].write_text(json.dumps(_json_safe(res.to_json()), indent=2), encoding="utf-8")
    blocks = _blocks(res, files)
    files["md"] = out / "feasibility.md"
    files["md"].write_text(_md(blocks), encoding="utf-8")
    files["html"] = out / "feasibility.html"
    files["html"].write_text(_html(blocks, out, f"Feasibility of inspecting {_part(res)}"), encoding="utf-8")
    return files

