"""Parameter types a plugin may declare (issue 16, item 2): supported ones work in recipes;
an unsupported or inconsistent one is refused when the plugin registers, naming the field."""

from __future__ import annotations

import enum
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import pytest

from inspector import hookimpl
from inspector.errors import PluginError, RecipeError
from inspector.manager import create_plugin_manager
from inspector.params import build_params, check_param_class, describe_params, param
from inspector.recipe import parse_recipe
from inspector.registry import StageSpec


class Mode(enum.Enum):
    FAST = "fast"
    FINE = "fine"


@dataclass(frozen=True)
class Rich:
    weights: list[float] = param((1.0, 2.0), "weights", min=0.0)
    origin: tuple[float, float, float] = param((0.0, 0.0, 0.0), "a point, mm")
    counts: tuple[int, ...] = param((), "counts", min=1, max=10)
    model: Path = param(Path("model.onnx"), "model file (relative to the recipe)")
    mode: Mode = param(Mode.FAST, "speed")
    side: Literal["left", "right"] = param("left", "side")
    gains: dict[str, float] | None = param(None, "per camera")
    limit: float | None = param(None, "optional limit", min=0.0)


def _stage(params: type, name: str = "classify.rich"):
    class Plugin:
        @hookimpl
        def inspector_register_stages(self, registry):
            registry.add(StageSpec(name=name, run=lambda c, p: c, params=params))

    return Plugin()


def test_supported_types_come_from_a_recipe(tmp_path):
    check_param_class(Rich)
    pm = create_plugin_manager(plugins=[_stage(Rich)])
    recipe_file = tmp_path / "sub" / "r.toml"
    recipe_file.parent.mkdir()
    table = {"weights": [0.5, 3], "origin": [1, 2, 3.5], "counts": [1, 2], "model": "models/m.onnx", "mode": "fine",
             "side": "right", "gains": {"cam00": 1.5}, "limit": 2}
    r = parse_recipe({"stages": [{"use": "classify.rich", "params": table}]}, pm, path=recipe_file)
    p = r.steps[0].params
    assert p.weights == (0.5, 3.0) and p.origin == (1.0, 2.0, 3.5) and p.counts == (1, 2)
    assert p.model == tmp_path / "sub" / "models" / "m.onnx"  # relative to the recipe's folder
    assert p.mode is Mode.FINE and p.side == "right" and p.gains == {"cam00": 1.5} and p.limit == 2.0
    types = {d["name"]: d["type"] for d in describe_params(Rich)}
    assert types["weights"] == "list of float" and types["origin"] == "list of 3: float, float, float"
    assert types["model"] == "path" and types["mode"] == "'fast' | 'fine'"


@pytest.mark.parametrize("table, message", [
    ({"weights": [1, -2]}, r"params.weights\[1\]: expected a value >= 0.0, got -2.0"),
    ({"origin": [1, 2]}, r"params.origin: expected 3 items, got 2"),
    ({"counts": [11]}, r"params.counts\[0\]: expected a value <= 10, got 11"),
    ({"model": 3}, r"params.model: expected a path, got 3"),
    ({"mode": "slow"}, r"params.mode: expected one of 'fast' \| 'fine', got 'slow'"),
    ({"gains": {"cam00": "high"}}, r"params.gains: expected table of float or none"),
    ({"limit": float("nan")}, r"params.limit: expected a finite number, got nan"),
])
def test_recipe_values_are_checked_against_those_types(table, message):
    pm = create_plugin_manager(plugins=[_stage(Rich)])
    with pytest.raises(RecipeError, match=message):
        parse_recipe({"stages": [{"use": "classify.rich", "params": table}]}, pm)


def test_a_field_without_default_must_be_given():
    @dataclass(frozen=True)
    class Required:
        model: Path

    check_param_class(Required)
    with pytest.raises(RecipeError, match=r"^here: missing parameter 'model' \(it has no default\)$"):
        build_params(Required, {}, "here")


def _frozen(**annotations):
    """A frozen parameter dataclass: field name -> (annotation, default, param() bounds)."""
    ns = {"__annotations__": {k: v[0] for k, v in annotations.items()}}
    ns.update({k: param(v[1], "doc", **v[2]) for k, v in annotations.items()})
    return dataclass(frozen=True)(type("Bad", (), ns))


@pytest.mark.parametrize("params, message", [
    (_frozen(weights=(set[int], frozenset(), {})), "parameter 'weights': type set[int] is not supported"),
    (_frozen(pairs=(tuple[complex, ...], (), {})), "parameter 'pairs': type tuple[complex, ...] is not supported "
                                                   "(complex cannot come from a recipe)"),
    (_frozen(table=(dict[int, float], None, {})), "parameter 'table': type dict[int, float] is not supported "
                                                  "(table keys are strings)"),
    (_frozen(name=(str, "a", {"min": 1})), "parameter 'name': min/max given, but type str holds no number"),
    (_frozen(x=(float, 1.0, {"min": 2, "max": 1})), "parameter 'x': min=2 is above max=1"),
    (_frozen(x=(float, 5.0, {"max": 1.0})), "parameter 'x' default: expected a value <= 1.0, got 5.0"),
    (_frozen(x=(int, 1.5, {})), "parameter 'x' default: expected int, got 1.5"),
    (_frozen(x=(float, 1.0, {"min": float("nan")})), "parameter 'x': min=nan is not a finite number"),
    (dataclass(type("Loose", (), {"__annotations__": {"x": float}, "x": 1.0})), "params Loose is not frozen"),
    (dict, "params <class 'dict'> is not a dataclass"),
])
def test_a_bad_parameter_class_is_refused_when_the_plugin_registers(params, message):
    with pytest.raises(PluginError, match=re.escape(f"plugin 'Plugin': stage 'classify.bad': {message}")):
        create_plugin_manager(load_entrypoints=False, plugins=[_stage(params, "classify.bad")])


def test_the_recipe_editor_saves_path_and_enum_parameters(tmp_path):
    import tomllib

    from inspector.recipe_form import form_for

    pm = create_plugin_manager(plugins=[_stage(Rich)])
    path = tmp_path / "r.toml"
    path.write_text('[[stages]]\nuse = "classify.rich"\nparams = { model = "m.onnx", mode = "fine", origin = [1, 2, 3] }\n')
    doc = tomllib.loads(form_for(path, pm).to_toml())
    params = doc["stages"][0]["params"]
    assert params["mode"] == "fine" and params["origin"] == [1.0, 2.0, 3.0]
    assert Path(params["model"]) == tmp_path / "m.onnx"
