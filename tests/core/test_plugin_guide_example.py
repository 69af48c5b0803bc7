"""The plugin guide's example (docs/plugin-guide.md) works as printed."""

from __future__ import annotations

import re
import sys
import types
from pathlib import Path

from inspector.manager import create_plugin_manager
from inspector.recipe import parse_recipe


def test_plugin_guide_stage_example_registers_and_validates(monkeypatch):
    text = (Path(__file__).resolve().parents[2] / "docs" / "plugin-guide.md").read_text()
    code = re.search(r"```python\n(# my_package/classify.py.*?)```", text, re.S).group(1)
    module = types.ModuleType("my_package_classify")
    monkeypatch.setitem(sys.modules, module.__name__, module)  # dataclasses look modules up
    exec(compile(code, "docs/plugin-guide.md", "exec"), module.__dict__)
    pm = create_plugin_manager(plugins=[module])
    assert "classify.size" in pm.stages
    recipe = parse_recipe(
        {
            "recipe": {"reference": "builtin:cube30"},
            "stages": [
                {"use": "segment.threshold"},
                {"use": "carve.hull"},
                {"use": "classify.size", "params": {"max_volume_mm3": 1000.0}},
            ],
        },
        pm,
    )
    assert recipe.steps[2].params.max_volume_mm3 == 1000.0
