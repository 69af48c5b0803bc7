"""The cell's settings file (``cell.toml``): one reader for every table in it (Qt-free).

One file per cell holds what is the cell's, not a recipe's::

    [server]   # inspector serve: the OPC UA endpoint, security, users (inspector_frontends/opcua/config.py)
    [gui]      # the operator window: kiosk, language (inspector_frontends/gui/app.py)
    [shifts]   # the shift times (inspector/shift.py)

:func:`load_cell` reads and checks the file as a whole (size, UTF-8, TOML, known tables);
each reader then checks its own table with :func:`inspector.params.build_params`. Every
problem is a :class:`~inspector.errors.RecipeError` in one line naming the file.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from inspector.errors import RecipeError
from inspector.roles_password import config_dir

__all__ = ["CELL_FILE", "CELL_TABLES", "MAX_CELL_BYTES", "load_cell", "cell_file"]

#: The cell's settings file in the configuration folder (beside ``roles.json``).
CELL_FILE = "cell.toml"

#: Tables a cell's settings file may hold.
CELL_TABLES = ("server", "gui", "shifts")

#: A settings file is small; a larger file is not one (and is not parsed).
MAX_CELL_BYTES = 1 << 20


def load_cell(path: str | Path | None) -> dict[str, dict[str, Any]]:
    """The tables of the cell's settings file ``path`` ({} without a file): only
    :data:`CELL_TABLES` are allowed, each a table. RecipeError in one line naming the file
    otherwise."""
    if path is None:
        return {}
    p = Path(path)
    try:
        if p.stat().st_size > MAX_CELL_BYTES:
            raise RecipeError(f"{p}: larger than {MAX_CELL_BYTES} bytes: not a cell settings file")
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise RecipeError(f"{p}: file not found") from None
    except OSError as e:
        raise RecipeError(f"{p}: cannot be read ({e.strerror or e})") from None
    except UnicodeDecodeError:
        raise RecipeError(f"{p}: not a UTF-8 text file") from None
    except tomllib.TOMLDecodeError as e:
        raise RecipeError(f"{p}: not valid TOML ({e})") from None
    for key, value in data.items():
        if key not in CELL_TABLES:
            raise RecipeError(f"{p}: unknown table {key!r} (expected {', '.join(CELL_TABLES)})")
        if not isinstance(value, dict):
            raise RecipeError(f"{p}: {key}: expected a table")
    return data


def cell_file(given: str | Path | None) -> Path | None:
    """The cell's settings file: ``given`` (``--config``), else :data:`CELL_FILE` of the
    configuration folder (``$INSPECTOR_CONFIG_DIR``, else ``~/.config/inspector``, where
    ``roles.json`` lives) when it exists, else None."""
    if given:
        return Path(given)
    default = config_dir() / CELL_FILE
    return default if default.is_file() else None
