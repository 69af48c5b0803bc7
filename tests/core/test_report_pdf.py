"""report.pdf: the one-page inspection report, read back with a PDF reader (pypdf)."""

from __future__ import annotations

import hashlib
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from pypdf import PdfReader

from inspector.errors import InputError
from inspector.report import render_pdf
from inspector_frontends.cli import main

DEMO = Path(__file__).resolve().parents[2] / "recipes" / "demo.toml"
DEMO_SHA = hashlib.sha256(DEMO.read_bytes()).hexdigest()


def read_pdf(path: Path) -> tuple[int, str]:
    """(number of pages, text of the first page, whitespace runs as one space)."""
    reader = PdfReader(path)
    return len(reader.pages), " ".join(reader.pages[0].extract_text().split())


@pytest.fixture(scope="module")
def notched(sim_captures, tmp_path_factory) -> Path:
    """The result folder of the demo recipe on the notched cube (a real FAIL)."""
    out = tmp_path_factory.mktemp("pdf")
    assert main(["run", str(DEMO), "--capture", str(sim_captures["notched"]), "--out", str(out), "-q"]) == 1
    return out / "notched"


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _edit(folder: Path, **changes) -> dict:
    """Apply ``changes`` to the folder's result.json (``...`` removes a key); the new document."""
    res = json.loads((folder / "result.json").read_text())
    res.update(changes)
    res = {k: v for k, v in res.items() if v is not ...}
    (folder / "result.json").write_text(json.dumps(res))
    return res


def _result_folder(folder: Path, **changes) -> Path:
    """A small result folder as `inspector run` writes it, with ``changes`` to result.json."""
    from inspector.outputs import write_ply

    folder.mkdir(parents=True)
    rng = np.random.default_rng(5)
    xyz = rng.uniform(-15.0, 15.0, (2000, 3)).astype(np.float32)
    write_ply(folder / "bcps_points.ply", {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2],
                                           "deviation": rng.normal(0.0, 0.02, 2000).astype(np.float32)})
    res = {"capture": folder.name, "recipe": "demo-cube30", "verdict": "pass", "error": None,
           "timings_s": {"segment": 0.1, "carve": 0.2, "total": 0.3}, "pose": np.eye(4).tolist(),
           "stats": {"n_points": 2000, "deviation_mm": {"mean": 0.0, "min": -0.06, "max": 0.06, "p01": -0.05,
                                                        "p99": 0.05},
                     "within_tolerance": 1.0, "tolerance_mm": {"lower": -0.1, "upper": 0.1}},
           "defects": [], "metadata": {"part_id": "P-0042", "timestamp": "2026-03-04T05:06:07+00:00"},
           "points": {"bcps": "bcps_points.ply", "reconstruction": None}}
    res.update(changes)
    (folder / "result.json").write_text(json.dumps(res))
    return folder


def _defect(i: int) -> dict:
    return {"kind": "excess", "position": [float(i), 2.0, 3.0], "extent": [1.0, 2.0, 0.5], "n_points": 30 + i,
            "worst_mm": 0.9 - 0.01 * i, "region": "default"}


# -- a real inspection -----------------------------------------------------------------------
@pytest.mark.slow
def test_a_failed_part_has_a_one_page_report_with_reason_defects_and_recipe(notched, tmp_path):
    pdf = render_pdf(notched, tmp_path / "r.pdf", recipe=DEMO)
    assert pdf == tmp_path / "r.pdf"
    pages, text = read_pdf(pdf)
    assert pages == 1
    box = PdfReader(pdf).pages[0].mediabox
    assert abs(float(box.width) - 595.3) < 1 and abs(float(box.height) - 841.7) < 1  # A4 portrait, points
    res = json.loads((notched / "result.json").read_text())
    d = res["defects"][0]
    assert "FAIL" in text and "part out of tolerance" in text and "notched" in text
    # The reason: the worst defect and the tolerance limit it breaks.
    assert (f"missing material in region 'default': worst {d['worst_mm']:+.3f} mm, below the lower limit -0.100 mm"
            in text)
    # Its row of the defect table: number, kind, region, points, worst.
    assert f"1 missing default {d['n_points']:,d} {d['worst_mm']:+.3f}" in text
    assert DEMO_SHA in text and 'name = "demo-cube30"' in text
    assert f"{res['stats']['n_points']:,d}" in text and "bcps" in text and "total" in text


@pytest.mark.slow
def test_the_recipe_named_by_result_json_is_shown_and_a_lost_one_keeps_its_hash(notched, tmp_path):
    folder = _copy(notched, tmp_path / "notched")
    recipe = tmp_path / "line3.toml"
    shutil.copyfile(DEMO, recipe)
    _edit(folder, recipe_path=str(recipe), recipe_sha256=DEMO_SHA)
    assert render_pdf(folder) == folder / "report.pdf"
    _, text = read_pdf(folder / "report.pdf")
    assert DEMO_SHA in text and str(recipe) in text and "[tolerance]" in text

    recipe.write_text(DEMO.read_text() + "# edited after the inspection\n")
    _, text = read_pdf(render_pdf(folder))
    assert DEMO_SHA in text and "changed since the inspection" in text and "[tolerance]" not in text

    recipe.unlink()
    _, text = read_pdf(render_pdf(folder))
    assert DEMO_SHA in text and "(recipe file not found)" in text


@pytest.mark.slow
def test_cli_report_pdf_writes_the_picture_and_the_report(notched, tmp_path, capsys):
    folder = _copy(notched, tmp_path / "notched")
    assert main(["report", str(folder), "--pdf", "--recipe", str(DEMO)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out == [f"wrote {folder / 'deviation.png'}", f"wrote {folder / 'report.pdf'}"]
    pages, text = read_pdf(folder / "report.pdf")
    assert pages == 1 and "FAIL" in text and DEMO_SHA in text


@pytest.mark.slow
def test_a_given_picture_replaces_the_three_views(notched, tmp_path):
    import matplotlib.image

    png = tmp_path / "view3d.png"
    matplotlib.image.imsave(png, np.tile(np.linspace(0, 1, 64), (48, 1)), cmap="viridis")
    pdf = render_pdf(notched, tmp_path / "r.pdf", picture=png)
    images = PdfReader(pdf).pages[0].images
    assert [im.image.size for im in images] == [(64, 48)]  # the picture only, no scatter bitmap
    pages, text = read_pdf(pdf)
    assert pages == 1 and "top (X-Y)" not in text


# -- every verdict, and what does not fit --------------------------------------------------------
def test_an_inspection_error_has_its_report(tmp_path):
    # A real error result: the capture folder does not exist.
    assert main(["run", str(DEMO), "--capture", str(tmp_path / "gone"), "--out", str(tmp_path / "o"), "-q"]) == 3
    folder = tmp_path / "o" / "gone"
    error = json.loads((folder / "result.json").read_text())["error"]
    pages, text = read_pdf(render_pdf(folder))
    assert pages == 1
    assert "ERROR" in text and "inspection not completed" in text and " ".join(error.split()) in text
    assert "no deviation map" in text and "Defects (0)" in text


def test_aborted_and_passed_parts_say_so_in_words(tmp_path):
    aborted = _result_folder(tmp_path / "cancelled", verdict="aborted", error="cancelled before stage bcps",
                             pose=None, stats={}, points={"bcps": None, "reconstruction": None})
    _, text = read_pdf(render_pdf(aborted))
    assert "ABORTED" in text and "cancelled before stage bcps" in text

    passed = _result_folder(tmp_path / "ok")
    _, text = read_pdf(render_pdf(passed))
    assert "PASS" in text and "P-0042" in text and "2026-03-04T05:06:07+00:00" in text
    assert "100.00 % of 2,000 BCPS points within the tolerance [-0.100, +0.100] mm" in text
    assert "recipe file not recorded" in text


def test_many_defects_and_a_long_recipe_still_fit_one_page(tmp_path):
    folder = _result_folder(tmp_path / "rough", verdict="fail", defects=[_defect(i) for i in range(40)])
    recipe = tmp_path / "long.toml"
    recipe.write_text("".join(f"# line {i:03d} {'x' * (i % 150)}\n" for i in range(400)))
    pages, text = read_pdf(render_pdf(folder, recipe=recipe))
    assert pages == 1
    # As many rows as fit (at most 15, at least 5), then a count of the others.
    more = int(re.search(r"and (\d+) more", text).group(1))
    rows = 40 - more
    assert "Defects (40)" in text and 5 <= rows <= 15
    assert f"{rows} excess default {30 + rows - 1}" in text and f"{rows + 1} excess default" not in text
    assert "excess material in region 'default': worst +0.900 mm, above the upper limit +0.100 mm" in text
    assert "# line 000" in text and "# line 399" not in text and "more line(s)" in text


def test_a_region_defect_names_the_region_band_from_the_recipe(tmp_path):
    recipe = tmp_path / "flange.toml"
    recipe.write_text(DEMO.read_text() + '\n[[tolerance.regions]]\nname = "flange"\nbox_min = [-15, -15, 10]\n'
                                          'box_max = [15, 15, 15]\nlower = -0.05\nupper = 0.05\n')
    folder = _result_folder(tmp_path / "r", verdict="fail", defects=[{**_defect(0), "region": "flange"}])
    _, text = read_pdf(render_pdf(folder, recipe=recipe))
    assert "above the upper limit +0.050 mm of the region 'flange' tolerance [-0.050, +0.050] mm" in text


# -- bad input: one line naming the file ---------------------------------------------------------
def test_a_damaged_or_missing_result_is_an_input_error(tmp_path):
    cut = _result_folder(tmp_path / "cut")
    data = (cut / "result.json").read_bytes()
    (cut / "result.json").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"result\.json: cannot read \(JSONDecodeError\)$"):
        render_pdf(cut)
    with pytest.raises(InputError, match=r"nothing[/\\]result\.json: cannot read \(FileNotFoundError\)$"):
        render_pdf(tmp_path / "nothing")
    bad = _result_folder(tmp_path / "bad", defects=[{"kind": "missing", "region": "default"}])
    with pytest.raises(InputError, match=r"defects\[0\]: missing key 'n_points'$"):
        render_pdf(bad)
    assert not (cut / "report.pdf").exists() and not (bad / "report.pdf").exists()


DAMAGED = [
    ("pose-text", {"pose": [["a"] * 4] * 4}, "pose must be a 4x4 matrix"),
    ("stats-list", {"stats": []}, "stats must be an object"),
    ("tolerance-text", {"stats": {"tolerance_mm": {"lower": "-0.1", "upper": 0.1}}},
     "stats.tolerance_mm must have numbers lower and upper"),
    ("defects-object", {"defects": {"kind": "missing"}}, "defects must be a list"),
    ("defect-position", {"defects": [{**_defect(0), "position": [1, 2]}]}, "defects[0]: position must be 3 numbers"),
    ("verdict-number", {"verdict": 1}, "verdict must be a string"),
    ("not-an-object", None, "not a result (a JSON object is expected)"),
]


@pytest.mark.parametrize("name, changes, message", DAMAGED, ids=[d[0] for d in DAMAGED])
def test_a_damaged_result_is_one_line_naming_the_file(name, changes, message, tmp_path, capsys):
    folder = _result_folder(tmp_path / name, **(changes or {}))
    if changes is None:
        (folder / "result.json").write_text("[1, 2]")
    assert main(["report", str(folder), "--pdf"]) == 3
    assert capsys.readouterr().err == f"inspector: error: {folder / 'result.json'}: {message}\n"


def test_cli_report_pdf_exit_status(tmp_path, capsys):
    good = _result_folder(tmp_path / "r" / "a-good")
    cut = _result_folder(tmp_path / "r" / "b-cut")
    (cut / "result.json").write_text('{"capture": "b-cut", "verd')
    assert main(["report", str(good), "--pdf"]) == 0
    assert capsys.readouterr().out.splitlines() == [f"wrote {good / 'deviation.png'}", f"wrote {good / 'report.pdf'}"]

    assert main(["report", str(tmp_path / "r"), "--pdf"]) == 3
    out, err = capsys.readouterr()
    assert out.splitlines() == [f"wrote {good / 'deviation.png'}", f"wrote {good / 'report.pdf'}"]
    assert err == f"inspector: error: {cut / 'result.json'}: cannot read (JSONDecodeError)\n"

    assert main(["report", str(good), "--pdf", "--recipe", str(tmp_path / "none.toml")]) == 3
    err = capsys.readouterr().err
    assert err.startswith(f"inspector: error: {tmp_path / 'none.toml'}: cannot read (") and err.count("\n") == 1


def test_without_pdf_the_report_command_is_unchanged(tmp_path, capsys):
    good = _result_folder(tmp_path / "a")
    assert main(["report", str(good)]) == 0
    assert capsys.readouterr().out == f"wrote {good / 'deviation.png'}\n"
    assert not (good / "report.pdf").exists()


def test_the_characteristics_are_listed_with_their_uncertainty(tmp_path):
    rows = [{"id": "1", "kind": "diameter", "nominal": 36.0, "measured": 35.982, "deviation": -0.018, "lower": -0.05,
             "upper": 0.05, "U": 0.0031, "verdict": "ok"},
            {"id": "2", "kind": "distance", "nominal": 6.0, "measured": 6.071, "deviation": 0.071, "lower": -0.05,
             "upper": 0.05, "U": 0.0022, "verdict": "nok"},
            {"id": "3", "kind": "flatness", "nominal": 0.0, "measured": None, "deviation": None, "lower": 0.0,
             "upper": 0.01, "U": None, "verdict": "not_measurable", "reason": "12 points"}]
    folder = _result_folder(tmp_path / "chars", verdict="fail", extras={"characteristics": rows})
    pages, text = read_pdf(render_pdf(folder))
    assert pages == 1 and "Characteristics (3, 1 NOK)" in text
    assert "1 diameter 36.0000 35.9820 -0.0180 -0.050 / +0.050 0.0031 OK" in text
    assert "2 distance 6.0000 6.0710 +0.0710 -0.050 / +0.050 0.0022 NOK" in text
    assert "3 flatness 0.0000 — — +0.000 / +0.010 — NOT MEASURABLE" in text
    _, without = read_pdf(render_pdf(_result_folder(tmp_path / "none")))
    assert "Characteristics" not in without
