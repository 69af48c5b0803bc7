"""The bcps stages' per-inspection rays: the coarse hull table shared by every selection."""

from __future__ import annotations

import numpy as np

from inspector.capture_folder import read_capture
from inspector.kernels import bcps as bk
from inspector.params import build_params
from inspector.pipeline import InspectionContext
from inspector.reference import Reference


def test_an_inspection_tests_its_coarse_samples_once_and_selects_what_testing_them_selects(small_capture, monkeypatch):
    """The ray stage with its pose search hull-tests the rays' coarse samples once, for all
    its selections (sparse and final, at several poses), and ends with the same points, pose
    and segment lengths as when every selection tests them itself."""
    from inspector_plugins.align import AlignParams, run_align
    from inspector_plugins.bcps import RayParams, _run, select_rays
    from inspector_plugins.bcps_rays import ContourRays
    from inspector_plugins.carve import CarveParams, run_carve
    from inspector_plugins.segment import SegmentParams, run_segment

    capture = read_capture(small_capture)
    ctx = run_segment(InspectionContext(capture=capture, reference=None), build_params(SegmentParams, {}, "test"))
    ctx = run_carve(ctx, CarveParams(voxel_mm=0.4))
    ctx = run_align(ctx.evolve(reference=Reference.load("builtin:cube30")), AlignParams())
    made, selections = [], []
    real_hull, real_select = bk.coarse_hull, bk.select_on_camera_rays

    def hull(*a, **k):
        made.append(1)
        return real_hull(*a, **k)

    def select(*a, **k):
        selections.append(k.get("coarse") is not None)
        return real_select(*a, **k)

    monkeypatch.setattr(bk, "coarse_hull", hull)
    monkeypatch.setattr(bk, "select_on_camera_rays", select)
    read = _run(select_rays)(ctx, RayParams())
    assert made == [1] and len(selections) >= 3 and all(selections)
    first = len(selections)
    monkeypatch.setattr(ContourRays, "coarse", lambda self, *a: None)
    tested = _run(select_rays)(ctx, RayParams())
    assert made == [1] and len(selections) > first and not any(selections[first:])
    np.testing.assert_array_equal(read.alignment.pose, tested.alignment.pose)
    for name in ("points", "deviation", "camera", "pixel", "segment_mm"):
        np.testing.assert_array_equal(getattr(read.bcps, name), getattr(tested.bcps, name))
    assert len(read.bcps.points) > 500 and np.isfinite(read.bcps.segment_mm).all()
