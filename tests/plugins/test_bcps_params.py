"""The bcps stage's sparse selections (the ones that feed the pose fits): their stride."""

from __future__ import annotations

from inspector.params import build_params
from inspector_plugins.bcps import RayParams, sparse_stride


def test_sparse_stride_keeps_the_rays_per_fit_flat_as_cameras_are_added():
    p = build_params(RayParams, {}, "bcps.ray")
    # 16 cameras of 1 MP on the 30 mm cube (20 875 contour points) and on the 60 mm bracket
    # (33 828): the configured stride, 7 000 and 11 300 rays per fit.
    assert sparse_stride(p, [1305] * 16) == 3
    assert sparse_stride(p, [2114] * 16) == 3
    # 32 cameras on the cube (40 706): every 4th, 10 200 rays, not 13 600.
    assert sparse_stride(p, [1272] * 32) == 4
    for cams in (8, 16, 32, 64, 128):
        counts = [2000] * cams
        s = sparse_stride(p, counts)
        assert s >= p.refine_stride and sum(counts) / s <= p.refine_rays
    # the stride is never below the configured one, however few the points
    assert sparse_stride(build_params(RayParams, {"refine_stride": 5}, "bcps.ray"), [10] * 4) == 5
    assert sparse_stride(build_params(RayParams, {"refine_rays": 1000}, "bcps.ray"), [1000] * 16) == 16
