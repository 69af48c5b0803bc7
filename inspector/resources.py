"""Files shipped with the product: the recipes.

The recipes live in the repository's top-level ``recipes/`` folder; ``pyproject.toml`` installs
them as package data in ``inspector/recipes/`` (``[tool.setuptools] package-dir``), so an
installed product (``pip install .``, a wheel) finds them without the source tree.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["recipes_dir", "recipe_path"]


def recipes_dir() -> Path:
    """The folder of the shipped recipes: ``inspector/recipes`` when installed as package
    data, else the source tree's ``recipes/`` (a checkout, an editable install)."""
    here = Path(__file__).resolve().parent
    installed = here / "recipes"
    if (installed / "default.toml").is_file():
        return installed
    return here.parent / "recipes"


def recipe_path(name: str) -> Path:
    """A shipped recipe by file name, e.g. ``recipe_path("demo.toml")``."""
    return recipes_dir() / name
