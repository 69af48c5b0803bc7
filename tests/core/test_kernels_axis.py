"""Turns about an axis of near-symmetry (:mod:`inspector.kernels.axis`): the turn zone on an
exact D-shaft (``dshaft``), scans and their confidence on synthetic arrays, the axis of a
mesh, the zone kept with its reference. The scans of sampled discs are in
``test_kernels_registration.py``."""

from __future__ import annotations

import dataclasses

import dshaft as S
import numpy as np
import pytest
import trimesh

from inspector.kernels.axis import AMBIGUOUS_POINTS, AxisScan, near_axis, pose_confidence, turn_zone
from inspector.kernels.rigid import RefMesh
from inspector.reference import Reference


def _scan(cost, *, symmetric=(0,), poke=None, n_points=1000) -> AxisScan:
    """A scan of ``len(cost)`` turns, evenly spaced from 0, of a part of radius 10 mm."""
    cost = np.asarray(cost, float)
    moved = np.ones(len(cost))
    moved[list(symmetric)] = 0.0
    return AxisScan(axis=np.array([0.0, 0.0, 1.0]), centre=np.zeros(3), angles_deg=np.arange(len(cost)) * 360.0 / len(cost),
                    cost=cost, moved=moved, cutoff_mm=0.1, radius_mm=10.0, n_points=n_points,
                    poke=None if poke is None else np.asarray(poke, float))


def _valley(n: int, minima: dict[int, float]) -> np.ndarray:
    """(n,) cost rising away from the nearest of ``minima`` (index -> value), circular."""
    i = np.arange(n)
    gap = np.min([np.minimum(np.abs(i - k), n - np.abs(i - k)) for k in minima], axis=0)
    cost = 0.5 + 0.01 * gap
    for k, v in minima.items():
        cost[k] = v
    return cost


def test_the_turn_zone_of_a_flat_is_the_ring_it_sweeps():
    zone = turn_zone(S.sdf, S.EXTENT, S.AXIS, S.CENTRE, cell_mm=0.5)
    pts = np.array([[0.0, S.R, 0.0],        # on the rim: a turn brings the flat here
                    [S.H - 0.5, 0.0, 5.0],   # inside, under the flat
                    [0.0, 0.0, 0.0],         # on the axis, far from any surface that turns
                    [0.0, 2.0, 0.0],         # near the axis
                    [0.0, S.R, 20.0],        # beyond the end
                    [0.0, 30.0, 0.0]])       # far outside
    np.testing.assert_array_equal(zone.hits(pts), [True, True, False, False, False, False])
    plain = turn_zone(lambda X: S.sdf(X, False), S.EXTENT, S.AXIS, S.CENTRE, cell_mm=0.5)
    assert not plain.variable.any() and not plain.hits(pts).any()


def test_minima_are_circular_and_lowest_first():
    scan = _scan(_valley(36, {0: 0.2, 10: 0.05, 35: 0.1}))
    # 35 is next to 0 (circular): 0 is not a minimum, 35 is
    assert scan.minima(5).tolist() == [10, 35]


def test_symmetries_distinct_turns_and_the_hull():
    scan = _scan(np.zeros(36), symmetric=(0, 18), poke=np.r_[np.zeros(10), np.full(26, 0.01)])
    assert scan.symmetric.tolist() == [i in (0, 18) for i in range(36)]
    # within 10 degrees of 0 or of the half turn: not distinct
    assert np.flatnonzero(~scan.distinct(10.0)).tolist() == [0, 1, 17, 18, 19, 35]
    assert scan.inside_hull.tolist() == [i < 10 for i in range(36)]


def test_pose_confidence_names_the_runner_up_and_its_margin():
    scan = _scan(_valley(36, {0: 0.1, 9: 0.13, 20: 0.3}), n_points=2000)
    conf = pose_confidence(scan)
    assert conf.runner_up_deg == 90.0 and conf.margin == pytest.approx(0.03)
    assert conf.margin_points == 60 and not conf.ambiguous and conf.margin_points >= AMBIGUOUS_POINTS
    assert conf.axis == (0.0, 0.0, 1.0) and conf.symmetry_deg == () and conf.hull_range_deg == (-180.0, 170.0)  # every turn inside the hull
    close = pose_confidence(dataclasses.replace(scan, n_points=500))
    assert close.margin_points == 15 and close.ambiguous


def test_pose_confidence_without_a_competitor_or_an_axis():
    # the only other minimum leaves the hull; the half turn is a symmetry
    scan = _scan(_valley(36, {0: 0.1, 9: 0.12, 18: 0.1}), symmetric=(0, 18), poke=[0.05 if i == 9 else 0.0 for i in range(36)])
    conf = pose_confidence(scan)
    assert conf.runner_up_deg is None and conf.margin is None and not conf.ambiguous
    assert conf.symmetry_deg == (180.0,) and conf.hull_range_deg == (-180.0, 80.0)  # out of the hull at 90
    assert pose_confidence(None).axis is None


def test_near_axis_of_a_shaft_and_none_of_a_block():
    m = S.mesh()
    axis, centre = near_axis(RefMesh(np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)))
    assert abs(axis[2]) > 1 - 1e-6 and np.abs(centre[:2] - [(S.R - S.H) / 2, 0.0]).max() < 0.05  # internal frame
    box = trimesh.creation.box((40.0, 24.0, 12.0))
    assert near_axis(RefMesh(np.asarray(box.vertices, float), np.asarray(box.faces, np.int64))) is None


def test_the_reference_keeps_its_turn_zone():
    m = S.mesh(sections=32)
    ref = Reference.from_mesh("dshaft", m)
    zone = ref.turn_zone(S.AXIS, S.CENTRE)
    assert zone.variable.any()
    assert ref.turn_zone(S.AXIS.copy(), S.CENTRE.copy()) is zone  # the same axis: kept
    other = ref.turn_zone(np.array([1.0, 0.0, 0.0]), S.CENTRE)
    assert other is not zone and not np.array_equal(other.axis, zone.axis)
    assert Reference.from_mesh("dshaft", m).turn_zone(S.AXIS, S.CENTRE) is not zone  # not shared between references
