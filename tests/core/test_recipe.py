from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import pytest

from inspector.errors import RecipeError
from inspector.params import build_params, describe_params, param
from inspector.recipe import load_recipe, parse_recipe


@dataclass(frozen=True)
class P:
    n: int = param(3, "count", min=1)
    x: float = param(0.5, "size", min=0.0, max=2.0)
    mode: Literal["a", "b"] = param("a", "mode")
    flag: bool = param(False, "flag")
    xs: tuple[float, ...] = param((), "list")


def test_build_params_defaults_and_coercion():
    p = build_params(P, {"n": 4, "x": 1, "mode": "b", "flag": True, "xs": [1, 2.5]}, "w")
    assert p == P(4, 1.0, "b", True, (1.0, 2.5))
    assert isinstance(p.x, float)
    assert build_params(P, None, "w") == P()


@pytest.mark.parametrize(
    "table, fragment",
    [
        ({"m": 1}, "w: unknown parameter 'm'"),
        ({"n": 1.5}, "w.n: expected int"),
        ({"n": True}, "w.n: expected int"),
        ({"n": 0}, "w.n: expected a value >= 1"),
        ({"x": 3}, "w.x: expected a value <= 2.0"),
        ({"mode": "c"}, "w.mode: expected one of 'a' | 'b'"),
        ({"flag": "yes"}, "w.flag: expected bool"),
        ({"xs": [1, "a"]}, "w.xs[1]: expected float"),
    ],
)
def test_build_params_errors_name_the_key(table, fragment):
    with pytest.raises(RecipeError) as e:
        build_params(P, table, "w")
    assert fragment in str(e.value)
    assert "\n" not in str(e.value)


def test_describe_params():
    d = {x["name"]: x for x in describe_params(P)}
    assert d["n"]["default"] == 3 and d["n"]["min"] == 1 and d["mode"]["type"] == "'a' | 'b'"


def test_shipped_recipes_are_valid(pm, recipes_dir):
    for path in sorted(recipes_dir.glob("*.toml")):
        r = load_recipe(path, pm, reference="builtin:cube30")
        assert [s.spec.kind for s in r.steps] == ["segment", "carve", "align", "bcps", "evaluate"]


def _doc(**over):
    doc = {
        "recipe": {"name": "t", "reference": "builtin:cube30"},
        "driver": {"use": "replay"},
        "stages": [
            {"use": "segment.threshold"},
            {"use": "carve.hull", "params": {"voxel_mm": 0.5}},
            {"use": "align.global_icp"},
            {"use": "bcps.ray"},
            {"use": "evaluate.tolerance"},
        ],
        "tolerance": {"default": {"lower": -0.1, "upper": 0.1}},
    }
    doc.update(over)
    return doc


def test_parse_valid_recipe(pm):
    r = parse_recipe(_doc(), pm)
    assert r.name == "t" and r.reference == "builtin:cube30"
    assert r.steps[1].params.voxel_mm == 0.5
    assert r.tolerance.default.lower == -0.1


@pytest.mark.parametrize(
    "mutate, fragment",
    [
        (lambda d: d["stages"].append({"use": "carve.nope"}), "stages[5].use: unknown stage 'carve.nope'"),
        (lambda d: d["stages"][1].update(params={"voxel": 1}), "stages.carve.params: unknown parameter 'voxel'"),
        (lambda d: d["stages"][1].update(params={"voxel_mm": "big"}), "stages.carve.params.voxel_mm: expected float"),
        (lambda d: d["stages"][1].update(params={"voxel_mm": 0.01}), "voxel_mm: expected a value >= 0.1"),
        (lambda d: d["stages"].pop(1), "stages.align: align.global_icp needs a 'carve' stage before it"),
        (lambda d: d.update(stages=[]), "stages: expected at least one"),
        (lambda d: d["driver"].update(use="usb"), "driver.use: unknown driver 'usb'"),
        (lambda d: d.update(extra=1), "unknown key 'extra'"),
        (lambda d: d["tolerance"].update(default={"lower": 0.1, "upper": 0.2}), "expected lower <= 0 <= upper"),
        (lambda d: d["tolerance"].update(regions=[{"name": "r", "box_min": [0, 0], "box_max": [1, 1, 1], "lower": -1, "upper": 1}]), "regions[0].box_min: expected 3 numbers"),
        (lambda d: d["recipe"].pop("reference"), "no reference mesh"),
        (lambda d: d["recipe"].update(reference="nowhere.stl"), "recipe.reference: file not found"),
        (lambda d: d["stages"].append({"use": "segment.threshold", "name": "carve"}), "stage name 'carve' is used twice"),
    ],
)
def test_invalid_recipes_are_refused_with_the_key(pm, mutate, fragment):
    d = _doc()
    mutate(d)
    with pytest.raises(RecipeError) as e:
        parse_recipe(d, pm, path=Path("/tmp/x.toml"))
    msg = str(e.value)
    assert fragment in msg, msg
    assert msg.startswith("x.toml") and "\n" not in msg


def test_load_recipe_file_errors(pm, tmp_path):
    with pytest.raises(RecipeError, match="recipe file not found"):
        load_recipe(tmp_path / "none.toml", pm)
    bad = tmp_path / "bad.toml"
    bad.write_text("[recipe\nname=1")
    with pytest.raises(RecipeError, match=r"bad.toml: not valid TOML"):
        load_recipe(bad, pm)


def test_reference_relative_to_recipe(pm, tmp_path):
    import trimesh

    trimesh.creation.box((10, 10, 10)).export(tmp_path / "part.stl")
    (tmp_path / "r.toml").write_text(
        '[recipe]\nreference = "part.stl"\n[[stages]]\nuse = "segment.threshold"\n[[stages]]\nuse="carve.hull"\n[[stages]]\nuse="align.global_icp"\n'
    )
    r = load_recipe(tmp_path / "r.toml", pm)
    assert r.reference == str((tmp_path / "part.stl").resolve())
