"""The recipe editor's model: fields from the plugins' parameter dataclasses, immutable
edits, validation by the recipe loader itself, and saving that never overwrites."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from inspector.errors import RecipeError
from inspector.recipe import load_recipe
from inspector.recipe_form import Field, RecipeForm, form_for, save_new, validate
from inspector_frontends.cli import main


@pytest.fixture
def demo(recipes_dir) -> Path:
    return recipes_dir / "demo.toml"


def load_error(path: Path, pm) -> str:
    with pytest.raises(RecipeError) as e:
        load_recipe(path, pm)
    return str(e.value)


def test_form_fields_carry_doc_default_bounds_choices_and_value(demo, pm):
    form = form_for(demo, pm)
    assert isinstance(form, RecipeForm) and form.name == "demo-cube30" and form.path == demo
    assert [s.key for s in form.sections] == ["driver", "stages.segment", "stages.carve", "stages.align",
                                              "stages.bcps", "stages.evaluate", "tolerance"]
    assert form.driver.use == "sim" and [s.use for s in form.stages][:2] == ["segment.threshold", "carve.hull"]

    voxel = form.section("stages.carve").field("voxel_mm")
    assert voxel == Field(name="voxel_mm", type="float", doc=voxel.doc, default=0.5, min=0.1, max=10.0, choices=None,
                          value=0.5, explicit=True, kind="float")
    assert "voxel" in voxel.doc
    coarse = form.section("carve").field("coarse_mm")  # a stage by its bare name too
    assert coarse.explicit is False and coarse.value == coarse.default == 0.0 and coarse.min == 0.0

    polarity = form.section("stages.segment").field("polarity")
    assert polarity.kind == "choice" and polarity.choices == ("auto", "dark-object", "bright-object")
    assert polarity.default == "auto" and polarity.doc

    seed = form.driver.field("seed")
    assert seed.kind == "int" and seed.value == 7 and seed.default == 0 and seed.explicit
    assert form.driver.field("bit_depth").choices == (8, 16)
    assert form.driver.field("bumps").kind == "list"
    assert form.section("stages.bcps").field("refine_pose").kind == "bool"
    min_fitness = form.section("stages.align").field("min_fitness")
    assert (min_fitness.min, min_fitness.max) == (0.0, 1.0)

    for sec in form.sections:
        for f in sec.fields:
            assert f.doc, (sec.key, f.name)
    lower = form.tolerance.field("lower")
    assert lower.value == -0.1 and lower.max == 0.0 and form.tolerance.field("upper").min == 0.0
    assert form.regions == ()


def test_edits_are_immutable_and_written(demo, pm):
    form = form_for(demo, pm)
    edited = form.with_value("stages.carve", "voxel_mm", 0.4).with_value("tolerance", "upper", 0.2)
    assert form.value("stages.carve", "voxel_mm") == 0.5  # the original is unchanged
    assert edited.value("stages.carve", "voxel_mm") == 0.4
    doc = tomllib.loads(edited.to_toml())
    assert doc["stages"][1]["params"] == {"voxel_mm": 0.4}
    assert doc["tolerance"]["default"] == {"lower": -0.1, "upper": 0.2}
    assert doc["recipe"] == {"name": "demo-cube30", "reference": "builtin:cube30"}
    assert doc["driver"] == {"use": "sim", "params": {"part": "cube30", "count": 1, "seed": 7, "noise_sigma": 2.0}}
    assert "params" not in doc["stages"][0]  # nothing set, nothing written

    again = edited.with_value("segment", "polarity", "dark-object").with_default("stages.carve", "voxel_mm")
    doc = tomllib.loads(again.to_toml(name="demo-copy"))
    assert doc["stages"][0]["params"] == {"polarity": "dark-object"}
    assert doc["stages"][1]["params"] == {}
    assert doc["recipe"]["name"] == "demo-copy"
    assert tomllib.loads(again.with_name("renamed").to_toml())["recipe"]["name"] == "renamed"

    with pytest.raises(KeyError, match="no field"):
        form.with_value("stages.carve", "voxel", 1.0)
    with pytest.raises(KeyError, match="no section"):
        form.with_value("stages.nothing", "voxel_mm", 1.0)
    with pytest.raises(ValueError, match="cannot be none"):
        form.with_value("stages.carve", "voxel_mm", None)


def test_unknown_keys_of_the_original_are_kept(tmp_path, pm):
    src = tmp_path / "mesh-ref.toml"
    (tmp_path / "parts").mkdir()
    mesh = tmp_path / "parts" / "cube.stl"
    import trimesh

    trimesh.creation.box(extents=(30, 30, 30)).export(mesh)
    src.write_text(
        "# a comment\n"
        "[recipe]\nname = 'with-regions'\ndescription = 'kept as it is'\nreference = 'parts/cube.stl'\n"
        "[driver]\nuse = 'replay'\n"
        "[[stages]]\nname = 'seg'\nuse = 'segment.threshold'\nparams = { median = 'impulse' }\n"
        "[[stages]]\nuse = 'carve.hull'\n"
        "[tolerance]\ndefault = { lower = -0.1, upper = 0.1 }\n"
        "[[tolerance.regions]]\nname = 'flange'\nbox_min = [-15, -15, 10]\nbox_max = [15, 15, 15]\n"
        "lower = -0.05\nupper = 0.05\n",
        encoding="utf-8",
    )
    form = form_for(src, pm)
    assert [s.key for s in form.sections] == ["driver", "stages.seg", "stages.carve", "tolerance",
                                              "tolerance.regions[0]"]
    region = form.section("tolerance.regions[0]")
    assert region.field("box_min").value == [-15.0, -15.0, 10.0] and region.field("lower").value == -0.05
    edited = form.with_value("tolerance.regions[0]", "upper", 0.07).with_value("seg", "min_area_px", 80)
    doc = tomllib.loads(edited.to_toml())
    assert doc["recipe"]["description"] == "kept as it is"
    assert doc["stages"][0] == {"name": "seg", "use": "segment.threshold",
                                "params": {"median": "impulse", "min_area_px": 80}}
    assert doc["tolerance"]["regions"][0]["upper"] == 0.07 and doc["tolerance"]["regions"][0]["name"] == "flange"
    assert "driver" in doc and "params" not in doc["driver"]
    assert validate(edited, pm) is None

    # Saved elsewhere, the relative reference still names the same mesh.
    elsewhere = tmp_path / "deep" / "er"
    elsewhere.mkdir(parents=True)
    saved = save_new(edited, elsewhere, pm)
    assert saved == elsewhere / "with-regions.toml"
    assert load_recipe(saved, pm).reference == str(mesh.resolve())
    assert tomllib.loads(saved.read_text())["recipe"]["reference"] == "../../parts/cube.stl"


def test_out_of_range_value_gives_the_loaders_own_error_line(demo, tmp_path, pm):
    form = form_for(demo, pm).with_value("stages.carve", "voxel_mm", 0.01)
    # The same recipe edited by hand, checked by the loader: the same line.
    by_hand = tmp_path / "demo.toml"
    by_hand.write_text(demo.read_text().replace("voxel_mm = 0.5", "voxel_mm = 0.01"))
    expected = load_error(by_hand, pm)
    assert expected == "demo.toml: stages.carve.params.voxel_mm: expected a value >= 0.1, got 0.01"
    assert validate(form, pm) == expected
    assert validate(form, pm, path=tmp_path / "demo.toml") == expected

    bad_choice = form_for(demo, pm).with_value("segment", "polarity", "sideways")
    by_hand.write_text(demo.read_text().replace('use = "segment.threshold"',
                                                'use = "segment.threshold"\nparams = { polarity = "sideways" }'))
    assert validate(bad_choice, pm) == load_error(by_hand, pm)

    bad_band = form_for(demo, pm).with_value("tolerance", "lower", 0.05)
    assert "expected lower <= 0 <= upper" in validate(bad_band, pm)
    assert validate(form_for(demo, pm), pm) is None


def test_save_new_writes_a_checked_new_file_and_never_overwrites(demo, tmp_path, pm, capsys):
    form = form_for(demo, pm).with_value("stages.carve", "voxel_mm", 0.4)

    first = save_new(form, tmp_path, pm)
    assert first == tmp_path / "demo-cube30.toml"
    assert main(["recipe", "check", str(first)]) == 0
    assert "OK" in capsys.readouterr().out
    assert load_recipe(first, pm).steps[1].params.voxel_mm == 0.4

    second = save_new(form, tmp_path, pm)  # a folder: a free name
    assert second == tmp_path / "demo-cube30-2.toml"
    assert first.read_text() == second.read_text()

    named = save_new(form, tmp_path, pm, name="cube 30 / fine")
    assert named.name == "cube-30-fine.toml"
    assert tomllib.loads(named.read_text())["recipe"]["name"] == "cube 30 / fine"

    explicit = tmp_path / "chosen.toml"
    assert save_new(form, explicit, pm) == explicit
    assert main(["recipe", "check", str(explicit)]) == 0
    before = explicit.read_bytes()
    with pytest.raises(FileExistsError, match="never overwritten"):
        save_new(form.with_value("stages.carve", "voxel_mm", 0.3), explicit, pm)
    assert explicit.read_bytes() == before

    with pytest.raises(RecipeError, match="voxel_mm: expected a value >= 0.1"):
        save_new(form.with_value("stages.carve", "voxel_mm", 0.01), tmp_path / "bad.toml", pm)
    assert not (tmp_path / "bad.toml").exists()
    with pytest.raises(FileNotFoundError):
        save_new(form, tmp_path / "no-such-folder" / "x.toml", pm)
    leftovers = [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]
    assert leftovers == []


def test_form_of_an_invalid_recipe_is_refused(tmp_path, pm):
    bad = tmp_path / "bad.toml"
    bad.write_text("[recipe]\nname = 'x'\n[[stages]]\nuse = 'carve.nothing'\n")
    with pytest.raises(RecipeError, match="unknown stage"):
        form_for(bad, pm)


def test_module_is_qt_free_and_light():
    import subprocess
    import sys

    import inspector.recipe_form as rf

    src = Path(rf.__file__).read_text()
    for name in ("PySide6", "PyQt", "pyvista"):
        assert name not in src
    code = ("import sys, inspector.recipe_form, inspector.roles; "
            "print(sorted(m for m in ('numpy', 'PySide6', 'pyvista', 'open3d') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "[]", out.stderr
