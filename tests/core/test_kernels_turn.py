"""The turn judge (:mod:`inspector.kernels.turn`) on exact synthetic rays: a D-shaft's analytic
distance and the rays that graze it (``dshaft``), no capture."""

from __future__ import annotations

import dataclasses

import dshaft as S
import numpy as np
import pytest

from inspector.kernels.axis import AxisScan, turn_zone
from inspector.kernels.prior import SizePrior
from inspector.kernels.rigid import rotation_deg
from inspector.kernels.turn import TurnJudge, TurnOptions, basins, judge_turns, polish_turn, turn, turned

#: Every ray judged (the few synthetic rays are all the evidence), a coarser scan.
OPTIONS = TurnOptions(stride=1, fine_stride=1, step_deg=10.0)
TRUTH = np.eye(4)
TRUTH[:3, 3] = (1.0, -2.0, 3.0)


@pytest.fixture(scope="module")
def zone():
    return turn_zone(S.sdf, S.EXTENT, S.AXIS, S.CENTRE, cell_mm=1.0)


def _judge(zone, pose, *, flat=True, prior=None, fine=False):
    return TurnJudge(S.rays(TRUTH), lambda X: S.sdf(X, flat), zone, pose, prior or SizePrior(), S.AXIS, S.CENTRE,
                     stride=1, fine=fine, options=OPTIONS)


def _scan(n: int = 360) -> AxisScan:
    """A scan of every degree about the shaft's axis: no symmetry but the identity, all
    inside the hull (the judge computes its own cost)."""
    return AxisScan(axis=S.AXIS, centre=S.CENTRE, angles_deg=np.arange(n) * (360.0 / n), cost=np.zeros(n),
                    moved=np.r_[0.0, np.ones(n - 1)], cutoff_mm=1.0, radius_mm=S.R)


def test_the_rays_graze_the_true_pose_and_a_turn_shows_the_flat(zone):
    judge = _judge(zone, TRUTH)
    assert judge.n == 6 * 2 * 5 and abs(judge.median) < 1e-6
    at = {a: judge.loss(a) for a in (0.0, 2.0, 10.0, 40.0, 180.0)}
    assert at[0.0] < 1e-3
    assert min(at[a] for a in (2.0, 10.0, 40.0, 180.0)) > 0.05


def test_rays_outside_the_zone_weigh_the_same_at_every_turn():
    """A plain cylinder: no cell varies with the turn, so no ray is re-evaluated and every
    turn has the pose's own loss, exactly."""
    plain = turn_zone(lambda X: S.sdf(X, False), S.EXTENT, S.AXIS, S.CENTRE, cell_mm=1.0)
    assert not plain.variable.any()
    judge = _judge(plain, TRUTH, flat=False)
    assert judge.n == 60
    assert judge.loss(17.0) == judge.loss(0.0) == judge.loss(-123.0)


def test_judge_turns_finds_the_true_turn_from_forty_degrees_off(zone):
    off = TRUTH @ turn(S.AXIS, S.CENTRE, 40.0)
    judge = _judge(zone, off)
    angle, conf = judge_turns(judge, _scan())
    assert angle == pytest.approx(-40.0, abs=0.1)
    assert rotation_deg(judge.turned(angle), TRUTH) < 0.1
    # the runner-up is another basin, clearly worse; the margin counts the rays judged
    assert conf.runner_up_deg is not None and abs(conf.runner_up_deg) > 5.0
    assert conf.margin > 0.02 and conf.margin_points == round(conf.margin * judge.n * OPTIONS.stride)
    assert conf.cutoff_mm == OPTIONS.cutoff_mm and conf.axis == (0.0, 0.0, 1.0)


def test_polish_turn_settles_a_small_turn_on_the_fine_rays(zone):
    judge = _judge(zone, TRUTH @ turn(S.AXIS, S.CENTRE, 0.7), fine=True)
    angle, loss = polish_turn(judge, 0.0, OPTIONS.polish_deg)
    assert angle == pytest.approx(-0.7, abs=0.05)
    assert loss < judge.loss(0.0)


def test_a_turn_is_made_before_the_size_model():
    """``turned`` keeps the size model's shift and tilt where they were fitted:
    placement(turned) = placement(pose) @ turn."""
    prior = SizePrior(scale=0.98, shift_mm=(0.1, -0.2, 0.05), rotation=(0.01, -0.02, 0.03), centre=(0.0, 0.0, 1.0))
    T = turned(TRUTH, prior, S.AXIS, S.CENTRE, 30.0)
    np.testing.assert_allclose(prior.placement(T), prior.placement(TRUTH) @ turn(S.AXIS, S.CENTRE, 30.0), atol=1e-12)
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)  # still rigid


def test_basins_skip_the_neighbours_of_a_symmetry():
    """Minima at 0, 60, 120 and 185 degrees, 180 a symmetry of the reference: 0 and
    the two others (lowest first), none within 1.5 steps of the symmetry."""
    a = np.arange(0.0, 360.0, 5.0)
    minima = {0.0: 0.1, 60.0: 0.3, 120.0: 0.2, 185.0: 0.05}
    # rising away from the nearest minimum: no plateau
    cost = 1.0 + 1e-3 * np.min([np.abs((a - m + 180.0) % 360.0 - 180.0) for m in minima], axis=0)
    for at, c in minima.items():
        cost[a == at] = c
    moved = np.ones(len(a))
    moved[[0, 36]] = 0.0  # the identity and the half turn
    sil = dataclasses.replace(_scan(), angles_deg=a, cost=cost, moved=moved)
    assert basins(sil, 5.0) == [0.0, 120.0, 60.0]
    flat = dataclasses.replace(sil, cost=np.full(len(a), np.inf))
    assert basins(flat, 5.0) == [0.0]
