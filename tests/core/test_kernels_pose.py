"""The pose search (:mod:`inspector.kernels.pose`) around a stand-in selection: exact points on
the true part and, for the D-shaft, its exact contour rays (``dshaft``); no capture."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import dshaft as S
import numpy as np
import pytest
import trimesh

from inspector.kernels.meshdist import MeshDistance
from inspector.kernels.pose import PoseOptions, search_pose
from inspector.kernels.prior import SizePrior
from inspector.kernels.rigid import rotation_deg
from inspector.kernels.turn import TurnOptions, turn
from inspector.model import Alignment, BcpsPoints, PoseConfidence
from inspector.reference import Reference

TRUTH = np.eye(4)
TRUTH[:3, :3] = trimesh.transformations.rotation_matrix(0.4, (1.0, 2.0, 3.0))[:3, :3]
TRUTH[:3, 3] = (1.0, -2.0, 3.0)


class Selection:
    """A stand-in selection rule: the same exact points of the true part whatever the pose,
    every third one when sparse; records each call (sparse, prior)."""

    def __init__(self, points: np.ndarray, ref: Reference) -> None:
        self.points, self.ref, self.calls = points, ref, []

    def __call__(self, pose: np.ndarray, *, sparse: bool = False, prior: SizePrior | None = None) -> BcpsPoints:
        self.calls.append((sparse, prior))
        P = self.points[::3] if sparse else self.points
        n = len(P)
        return BcpsPoints(P, self.ref.signed_distance(P, pose), np.zeros(n, np.int32), np.zeros((n, 2)), np.ones(n), "ray")


def _world(P: np.ndarray) -> np.ndarray:
    return P @ TRUTH[:3, :3].T + TRUTH[:3, 3]


def _start(deg: float, shift_mm: float) -> np.ndarray:
    """The truth turned by ``deg`` about a skew axis and shifted: a global alignment's error."""
    T = TRUTH @ trimesh.transformations.rotation_matrix(np.radians(deg), (0.3, -1.0, 0.5))
    T[:3, 3] += shift_mm * np.array([0.6, 0.0, -0.8])
    return T


@pytest.fixture(scope="module")
def block():
    """A 40 x 24 x 12 mm block (no axis of near-symmetry; its faces at different distances
    from the centre tell a scale from an offset) and 3000 points on it."""
    box = trimesh.creation.box((40.0, 24.0, 12.0))
    P, _ = trimesh.sample.sample_surface(box, 3000, seed=1)
    return Reference.from_mesh("block", box), np.asarray(P)


def _search(select, ref, start, hull, rays=list, **kw):
    return search_pose(select, ref, Alignment(start, 0.9, 0.1, "global+icp"), hull, 0.5, rays, robust_mm=0.1,
                       start_mm=1.0, **kw)


def test_a_nominal_part_settles_on_its_points(block):
    ref, P = block
    select = Selection(_world(P), ref)
    aligned, bcps = _search(select, ref, _start(1.0, 0.5), _world(P), sized=False)
    assert rotation_deg(aligned.pose, TRUTH) < 1e-3 and np.abs(aligned.pose[:3, 3] - TRUTH[:3, 3]).max() < 1e-3
    assert aligned.method == "global+icp+bcps-refine" and aligned.fitness == 1.0
    assert aligned.confidence == PoseConfidence()  # a block has no axis of near-symmetry
    # sparse selections feed the fits; the last is the full one at the final pose
    assert all(c == (True, None) for c in select.calls[:-1]) and select.calls[-1] == (False, None)
    assert len(select.calls) <= 1 + PoseOptions().attempts
    np.testing.assert_array_equal(bcps.points, select.points)


def test_a_small_part_gets_its_size_model_and_stays_centred(block):
    ref, P = block
    select = Selection(_world(0.98 * P), ref)
    aligned, bcps = _search(select, ref, _start(1.0, 0.5), _world(0.98 * P), sized=True)
    assert bcps.size is not None and bcps.size.scale == pytest.approx(0.98, abs=5e-4)
    assert aligned.method == "global+icp+bcps-refine+size"
    assert rotation_deg(aligned.pose, TRUTH) < 0.01 and np.abs(aligned.pose[:3, 3] - TRUTH[:3, 3]).max() < 0.01
    # the final selection is made against the fitted size model, and so is a re-fit's
    assert select.calls[-1] == (False, bcps.size)
    assert any(sparse and prior is not None for sparse, prior in select.calls[:-1])


class _ExactShaft:
    """The D-shaft mesh's distance index, with the analytic shaft's distance for the rays
    (which are exact for it, not for its 64-sided tessellation)."""

    def __init__(self, index: MeshDistance) -> None:
        self._index = index

    def __call__(self, X: np.ndarray) -> np.ndarray:
        return self._index(X)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._index, name)

    @staticmethod
    def near(X: np.ndarray) -> np.ndarray:
        return S.sdf(X)


@dataclass(frozen=True, eq=False)
class _ShaftReference(Reference):
    @cached_property
    def distance(self) -> Any:
        return _ExactShaft(MeshDistance(self.vertices, self.faces))


def test_the_silhouettes_turn_a_shaft_its_points_cannot():
    """The points lie on the round part and the end faces only and the hull shows no flat:
    nothing but the contour rays tells the turn. From 40 degrees off, the search judges the turn on the
    rays, settles the points there and polishes: the true pose."""
    m = S.mesh()
    ref = _ShaftReference("dshaft", np.asarray(m.vertices, float), np.asarray(m.faces, np.int64))
    rng = np.random.default_rng(0)
    phi, z = rng.uniform(0.0, 2.0 * np.pi, 3000), rng.uniform(-14.0, 14.0, 3000)
    round_ = np.column_stack([S.R * np.cos(phi), S.R * np.sin(phi), z])
    r, psi = S.R * np.sqrt(rng.uniform(0.0, 0.6, 400)), rng.uniform(0.0, 2.0 * np.pi, 400)
    ends = np.column_stack([r * np.cos(psi), r * np.sin(psi), np.where(np.arange(400) % 2, 1.0, -1.0) * S.L / 2])
    select = Selection(_world(np.concatenate([round_[round_[:, 0] < S.H - 1.0], ends])), ref)
    rays = S.rays(TRUTH, heights=41)
    start = TRUTH @ turn(S.AXIS, S.CENTRE, 40.0)
    start[:3, 3] += (0.2, 0.1, 0.0)
    options = PoseOptions(turn=TurnOptions(stride=1, fine_stride=1, step_deg=10.0))
    aligned, _ = _search(select, ref, start, _world(round_), lambda: rays, sized=False, options=options)
    assert rotation_deg(aligned.pose, TRUTH) < 0.02 and np.abs(aligned.pose[:3, 3] - TRUTH[:3, 3]).max() < 0.01
    conf = aligned.confidence
    assert conf.axis is not None and abs(conf.axis[2]) > 0.999 and conf.runner_up_deg is not None and conf.margin > 0.02
    assert not conf.ambiguous  # so the fine rays polished the turn
