"""Stage ``evaluate.characteristics`` (issue 28) on hand-made contexts: the rows it puts in
``extras`` (``result.json``), the verdict it leaves (a NOK characteristic fails a passed part,
an error stays an error), and the DFQ/QIF files of a run read back."""

from __future__ import annotations

import dataclasses
import json
import sys
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest
import trimesh

from inspector.characteristics.measure import Characteristic
from inspector.kernels.features import find_features
from inspector.model import Alignment, BcpsPoints, Capture, Evaluation, EvaluationSummary, Rig
from inspector.parts import make_part
from inspector.pipeline import InspectionContext
from inspector.reference import Reference

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))
from test_characteristics import _true_bracket

from inspector_plugins.characteristics import (
    CharacteristicsParams,
    characteristic_rows,
    run_characteristics,
)

SCALE = 1.002
KEYS = {"id", "kind", "features", "nominal", "measured", "deviation", "lower", "upper", "u", "U", "points", "verdict",
        "reason", "unit", "criticality", "description"}


@pytest.fixture(scope="module")
def context():
    ref = Reference.from_mesh("builtin:bracket", make_part("bracket"))  # centred, as the true bracket
    true = _true_bracket(SCALE)
    rng = np.random.default_rng(8)
    P, fid = trimesh.sample.sample_surface(true, 20000, seed=9)
    P = P + (0.003 * rng.standard_normal(len(P)))[:, None] * true.face_normals[fid]
    n = len(P)
    bc = BcpsPoints(P, np.zeros(n), np.arange(n) % 4, np.zeros((n, 2)), np.ones(n), "ray")
    summary = EvaluationSummary(n, None, (-0.1, 0.1), 1.0, 0)
    ev = Evaluation("pass", {"warnings": ["earlier"]}, (), np.zeros(n, bool), summary=summary)
    return InspectionContext(capture=Capture("x", Rig(()), {}), reference=ref, bcps=bc,
                             alignment=Alignment(np.eye(4), 1.0, 0.0), evaluation=ev)


def _with(ctx, chars):
    return ctx.evolve(settings={"characteristics": tuple(chars)})


def test_rows_in_extras_and_a_passed_part_stays_passed(context):
    chars = [Characteristic("1", "diameter", ("F14",), -0.05, 0.05, criticality="key", description="Ø8"),
             Characteristic("2", "distance", ("F01", "F04"), -0.05, 0.05)]
    out = run_characteristics(_with(context, chars), CharacteristicsParams())
    rows = out.extras["characteristics"]
    assert [r["id"] for r in rows] == ["1", "2"] and all(set(r) == KEYS for r in rows)
    assert rows[0]["criticality"] == "key" and rows[0]["description"] == "Ø8" and rows[1]["unit"] == "mm"
    assert rows[1]["measured"] == pytest.approx(6 * SCALE, abs=3 * rows[1]["u"] + 2e-4)
    assert out.evaluation.verdict == "pass"
    assert out.evaluation.stats["characteristics"] == {"ok": 2, "nok": 0, "not_measurable": 0, "nok_ids": [],
                                                       "not_measurable_ids": []}
    assert out.evaluation.summary is context.evaluation.summary  # the evaluate contract is untouched
    assert characteristic_rows({"extras": out.extras}) == rows


def test_a_nok_characteristic_fails_the_part_and_an_error_stays(context):
    # the part is 0.2 % large: its 6 mm plate is 0.012 thick over, beyond +0.005
    chars = [Characteristic("2", "distance", ("F01", "F04"), -0.005, 0.005)]
    out = run_characteristics(_with(context, chars), CharacteristicsParams())
    assert out.extras["characteristics"][0]["verdict"] == "nok"
    assert out.evaluation.verdict == "fail" and out.evaluation.stats["characteristics"]["nok_ids"] == ["2"]
    err = context.evolve(evaluation=dataclasses.replace(context.evaluation, verdict="error", error="pose uncertain"))
    out = run_characteristics(_with(err, chars), CharacteristicsParams())
    assert out.evaluation.verdict == "error" and out.evaluation.error == "pose uncertain"


def test_not_measurable_is_reported_and_fails_only_when_asked(context):
    # a flatness tolerance of 10 nm: U (~ 2 x the 3 um noise) cannot decide it
    chars = [Characteristic("7", "flatness", ("F01",), 0.0, 1e-5)]
    out = run_characteristics(_with(context, chars), CharacteristicsParams())
    row = out.extras["characteristics"][0]
    assert row["verdict"] == "not_measurable" and row["measured"] is None and "cannot decide" in row["reason"]
    assert out.evaluation.verdict == "pass"
    assert out.evaluation.stats["warnings"] == ["earlier", f"characteristic 7: not measurable: {row['reason']}"]
    out = run_characteristics(_with(context, chars), CharacteristicsParams(fail_not_measurable=True))
    assert out.evaluation.verdict == "fail"


def test_no_characteristics_leaves_the_evaluation(context):
    out = run_characteristics(context, CharacteristicsParams())
    assert out.extras["characteristics"] == [] and out.evaluation.verdict == "pass"


def test_run_records_write_dfq_and_qif_read_back(context, tmp_path):
    aqdef = pytest.importorskip("aqdefreader")
    from inspector.characteristics.formats import RunRecords
    from inspector.model import InspectionResult
    from inspector.recipe import Recipe

    chars = (Characteristic("1", "diameter", ("F14",), -0.05, 0.05), Characteristic("2", "distance", ("F01", "F04"), -0.05, 0.05))
    recipe = Recipe("bracket", None, "builtin:bracket", None, (), None, characteristics=chars)  # type: ignore[arg-type]
    rec = RunRecords.open(recipe, context.reference, dfq=str(tmp_path / "run.dfq"), qif=str(tmp_path / "run.qif"))
    measured = []
    for k in range(3):
        out = run_characteristics(_with(context, chars), CharacteristicsParams())
        rows = [dict(r, measured=r["measured"] + 0.001 * k) for r in out.extras["characteristics"]]
        measured.append([r["measured"] for r in rows])
        rec.add(InspectionResult(f"part-{k}", "bracket", "pass", None, {}, extras={"characteristics": rows},
                                 metadata={"timestamp": datetime(2026, 1, 2, 3, 4, 5 + k).isoformat()}))
    rec.add(InspectionResult("broken", "bracket", "error", "stage x", {}))  # no rows: no value line
    paths = rec.write()
    assert [p.name for p in paths] == ["run.dfq", "run.qif"]
    dfq = aqdef.read_dfq_file(str(tmp_path / "run.dfq"))
    part = dfq.get_part(0)
    got = [[m.value for m in ch.get_measurements()] for ch in part.get_characteristics()]
    assert np.allclose(np.array(got).T, np.round(measured, 4), atol=1e-9)
    batches = [m.batch_no for m in part.get_characteristics()[0].get_measurements()]
    assert batches == ["part-0", "part-1", "part-2"]
    assert "part-2" in (tmp_path / "run.qif").read_text()


@pytest.fixture(scope="module")
def big_cube(tmp_path_factory):
    """A 16-camera capture of a 30 mm cube 1 % larger than the reference (the simulator's
    own renderer), and a recipe measuring its three thicknesses, with and without the edges
    snapped."""
    from inspector.capture_folder import save_capture
    from inspector.params import build_params
    from inspector_drivers.sim.simulate import SimParams, simulate

    root = tmp_path_factory.mktemp("bigcube")
    cap = save_capture(simulate(build_params(SimParams, {"part": "cube30", "seed": 4, "scale": 1.01}, "test"), 0,
                               name="cube"), root / "cube", overwrite=True)
    ref = Reference.from_mesh("builtin:cube30", make_part("cube30"))
    feats = find_features(ref.vertices, ref.faces)
    ids = {tuple(np.round(f.nominal["normal"]).astype(int)): f.id for f in feats}
    chars = "".join(f'[[characteristics]]\nid = "T{a}"\nkind = "distance"\nfeatures = ["{ids[tuple(-np.eye(3, dtype=int)[a])]}", '
                    f'"{ids[tuple(np.eye(3, dtype=int)[a])]}"]\nlower = -0.5\nupper = 0.5\n' for a in range(3))
    recipes = {}
    for snap in (True, False):
        path = root / f"snap-{snap}.toml"
        path.write_text(f'[recipe]\nname = "snap-{snap}"\nreference = "builtin:cube30"\n'
                        '[[stages]]\nuse = "segment.threshold"\n[[stages]]\nuse = "carve.hull"\n'
                        '[[stages]]\nuse = "align.global_icp"\n[[stages]]\nuse = "bcps.ray"\n'
                        '[[stages]]\nuse = "evaluate.tolerance"\n[[stages]]\nname = "characteristics"\nuse = "evaluate.characteristics"\n'
                        f'params = {{ snap_edges = {str(snap).lower()} }}\n'
                        '[tolerance]\ndefault = { lower = -1.0, upper = 1.0 }\n' + chars)
        recipes[snap] = path
    return cap, recipes, root


def test_a_cube_thickness_from_its_edges_rays_on_a_real_capture(big_cube):
    """End to end on rendered images: with the points snapped onto the edges the rays show,
    every thickness of a cube 1 % large is within 5 um of 30.3 mm and the truth within +-U;
    the hull's own points (snap_edges = false) give other values."""
    from inspector_frontends.cli import main

    cap, recipes, root = big_cube
    got = {}
    for snap, recipe in recipes.items():
        assert main(["run", str(recipe), "--capture", str(cap), "--out", str(root / f"out-{snap}"), "-q"]) == 0
        res = json.loads((root / f"out-{snap}" / "cube" / "result.json").read_text())
        got[snap] = {r["id"]: r for r in res["extras"]["characteristics"]}
    for cid, r in got[True].items():
        assert r["verdict"] == "ok", r
        assert abs(r["measured"] - 30.3) <= 0.005, r
        assert abs(r["measured"] - 30.3) <= r["U"], r
        other = got[False][cid]["measured"]
        assert other is None or abs(other - r["measured"]) > 1e-4
