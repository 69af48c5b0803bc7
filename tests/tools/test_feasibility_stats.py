"""``inspector feasibility``'s statistics on known data: POD fit (MIL-HDBK-1823A hit/miss),
type-1 gauge study, observability accumulation; and the surface map's regions."""

from __future__ import annotations

import math

import numpy as np
import pytest

from inspector_tools.feasibility import stats


def _hit_miss(b0: float, b1: float, n: int, seed: int, lo: float = 0.05, hi: float = 3.0):
    rng = np.random.default_rng(seed)
    a = np.exp(rng.uniform(math.log(lo), math.log(hi), n))
    p = 1 / (1 + np.exp(-(b0 + b1 * np.log(a))))
    return a, rng.random(n) < p


def test_a_logistic_pod_fit_recovers_a90_and_its_bound_lies_above():
    pytest.importorskip("statsmodels", reason="statsmodels is not installed (pip install statsmodels)")
    b0, b1 = 4.0, 3.0  # a50 = exp(-4/3) = 0.264 mm, a90 = exp((ln 9 - 4) / 3) = 0.547 mm
    a90_true = math.exp((math.log(9) - b0) / b1)
    errs = []
    for seed in range(3):
        a, hit = _hit_miss(b0, b1, 400, seed)
        fit = stats.pod_fit(a, hit)
        assert fit.status == "fit" and fit.n == 400 and fit.hits == int(hit.sum())
        assert fit.a50 < fit.a90 < fit.a90_95 < 3.0 and not fit.extrapolated
        assert float(fit.lower(np.array([fit.a90_95]))[0]) == pytest.approx(0.9, abs=1e-6)  # the bound's 0.9 crossing
        assert float(fit.pod(np.array([fit.a90]))[0]) == pytest.approx(0.9, abs=1e-9)
        grid = np.geomspace(0.05, 3, 50)
        assert np.all(fit.lower(grid) <= fit.pod(grid) + 1e-12)
        errs.append(fit.a90 / a90_true - 1)
    assert abs(float(np.mean(errs))) < 0.08 and max(abs(e) for e in errs) < 0.2
    # more data, tighter bound
    a, hit = _hit_miss(b0, b1, 3000, 11)
    big = stats.pod_fit(a, hit)
    assert big.a90 == pytest.approx(a90_true, rel=0.06)
    assert big.a90_95 / big.a90 < fit.a90_95 / fit.a90


def test_pod_fit_says_why_when_no_curve_can_be_fitted():
    none = stats.pod_fit(np.array([0.1, 0.5, 1.0]), np.array([False, False, False]))
    assert none.status == "all-missed" and none.a90_95 is None and "none of the 3" in none.note
    assert stats.pod_fit(np.zeros(0), np.zeros(0, bool)).status == "no-data"
    # hits and misses separated by size: 29 of 29 above the last miss -> a90/95 there
    a = np.geomspace(0.05, 3.0, 60)
    sep = stats.pod_fit(a, a > 0.4)
    assert sep.status == "29/29" and sep.a90_95 == pytest.approx(np.sort(a[a > 0.4])[-29])
    few = stats.pod_fit(a[:40], a[:40] > 0.4)
    assert few.status == "separated" and few.a90_95 is None
    with pytest.raises(ValueError, match="> 0"):
        stats.pod_fit(np.array([0.0, 1.0]), np.array([True, False]))


def test_pod_fit_of_a_flat_rate_has_no_a90():
    pytest.importorskip("statsmodels", reason="statsmodels is not installed (pip install statsmodels)")
    rng = np.random.default_rng(3)
    a = np.geomspace(0.1, 3.0, 300)
    flat = stats.pod_fit(a, rng.random(300) < 0.3)  # a dent in a flat face: found when it reaches an edge, whatever its size
    assert flat.a90_95 is None and flat.status in ("flat", "fit")


def test_type1_gauge_study_on_known_samples():
    v = np.array([-0.01, 0.01] * 50)  # mean 0, s = 0.01 * sqrt(100 / 99)
    s = 0.01 * math.sqrt(100 / 99)
    g = stats.gauge_type1(v, -0.1, 0.1)
    assert (g.n, g.mean, g.tolerance) == (100, 0.0, pytest.approx(0.2))
    assert g.s == pytest.approx(s) and g.cg == pytest.approx(0.2 * 0.2 / (6 * s)) and g.cgk == pytest.approx(g.cg)
    assert not g.capable  # 0.66 < 1.33
    b = stats.gauge_type1(v / 4 + 0.005, -0.1, 0.1)  # tighter, biased by +5 um
    assert b.cg == pytest.approx(4 * g.cg) and b.bias == pytest.approx(0.005)
    assert b.cgk == pytest.approx((0.02 - 0.005) / (3 * s / 4)) and b.capable
    assert math.isnan(stats.gauge_type1(np.array([0.1]), -0.1, 0.1).cg)


def test_observability_and_per_element_mean_and_p95():
    ids = [np.array([0, 0, 2]), np.array([2, 3]), np.array([], int), np.array([0])]
    assert stats.observed_fraction(ids, 5).tolist() == [0.5, 0.0, 0.5, 0.25, 0.0]
    rng = np.random.default_rng(0)
    g = rng.integers(0, 7, 500)
    v = rng.normal(size=500)
    mean, p95, count = stats.grouped_mean_quantile(g, v, 8, 95)
    for k in range(7):
        assert mean[k] == pytest.approx(v[g == k].mean()) and p95[k] == pytest.approx(np.percentile(v[g == k], 95))
    assert count[7] == 0 and math.isnan(mean[7]) and math.isnan(p95[7])


def test_rates_and_repeatability():
    assert stats.binomial_upper(0, 29) == pytest.approx(1 - 0.05 ** (1 / 29), rel=1e-6)
    assert stats.binomial_upper(0, 0) == 1.0 and stats.binomial_upper(3, 100) > 0.03
    assert stats.majority_share(["pass", "fail", "pass", "pass"]) == ("pass", 0.75)


def test_regions_label_boxes_last_wins_and_patches_by_normal():
    from inspector_tools.feasibility.surface import PATCHES, Regions

    pts = np.array([[0, 0, 0], [5, 5, 5], [20, 0, 0.0]])
    nrm = np.array([[0, 0, -1], [0.9, 0.1, 0.1], [0, -1, 0.0]])
    boxes = Regions(("default", "a", "b"), (((-1, -1, -1), (6, 6, 6)), ((4, 4, 4), (6, 6, 6))), ((-0.1, 0.1),) * 3)
    assert boxes.label(pts, nrm).tolist() == [1, 2, 0]
    patches = Regions(PATCHES)
    assert [PATCHES[i] for i in patches.label(pts, nrm)] == ["-z", "+x", "-y"]


def test_the_surface_map_partitions_the_reference():
    from inspector.parts import make_part
    from inspector_tools.feasibility.surface import PATCHES, Regions, build_map

    cube = make_part("cube30")
    m = build_map(cube.vertices, cube.faces, 2.0, Regions(PATCHES, (), ((-0.1, 0.1),) * 6), seed=1)
    assert m.area.sum() == pytest.approx(5400.0)
    assert np.allclose(m.region_area(), 900.0, rtol=0.1)  # six faces
    assert 600 < m.n < 2500 and len(m.face_element) == len(m.faces) and len(m.vertex_element) == len(m.vertices)
    assert m.assign(np.array([[15.0, 0, 0], [0, 0, -15.0]])).tolist() == m.tree.query([[15.0, 0, 0], [0, 0, -15.0]])[1].tolist()
    again = build_map(cube.vertices, cube.faces, 2.0, Regions(PATCHES, (), ((-0.1, 0.1),) * 6), seed=1)
    assert np.array_equal(again.centres, m.centres)  # deterministic for a seed
