"""Make the GUI's translation files: ``python -m inspector_frontends.gui.i18n.build [--check]``.

1. ``pyside6-lupdate`` collects every text marked for translation (``self.tr``,
   ``QCoreApplication.translate``, ``QT_TRANSLATE_NOOP``, the Qt-free modules' ``translate``)
   from the GUI's sources and :mod:`inspector.shift` into ``inspector_LANG.ts``, keeping the
   translations already there (a text no longer in the sources is marked vanished);
2. ``pyside6-lrelease`` compiles each ``.ts`` into the ``.qm`` Qt loads.

Translate the texts marked unfinished in between (``pyside6-linguist inspector_de.ts``).
``--check`` changes nothing: it says which texts of the sources have no finished translation
(exit 1), what ``tests/gui/test_i18n.py`` checks too.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

from inspector import shift
from inspector_frontends.gui.i18n import FOLDER, LANGUAGES

__all__ = ["SOURCES", "tool", "collect", "untranslated", "update", "release", "main"]

_GUI = FOLDER.parent  # inspector_frontends/gui/


def SOURCES() -> list[Path]:
    """The files whose texts are translated: the GUI's modules (every ``*.py`` of
    ``inspector_frontends/gui/``: a new module is listed by itself) and the shift counters
    (:mod:`inspector.shift`)."""
    return sorted(_GUI.glob("*.py")) + [Path(shift.__file__)]


def tool(name: str) -> str:
    """``pyside6-lupdate`` / ``pyside6-lrelease``: beside the running Python (a venv), else on PATH."""
    here = Path(sys.executable).parent / name
    found = str(here) if here.is_file() else shutil.which(name)
    if found is None:
        raise FileNotFoundError(f"{name}: not found (it comes with PySide6)")
    return found


def _run(args: list[str]) -> None:
    done = subprocess.run(args, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{Path(args[0]).name} failed: {done.stderr.strip() or done.stdout.strip()}")


def collect(ts: Path) -> None:
    """Run lupdate over :func:`SOURCES` into ``ts`` (created or updated)."""
    _run([tool("pyside6-lupdate"), "-no-obsolete", "-locations", "none", *map(str, SOURCES()), "-ts", str(ts)])


def messages(ts: Path) -> dict[tuple[str, str], str | None]:
    """``(context, source) -> translation`` of a .ts file (None: unfinished or empty)."""
    out: dict[tuple[str, str], str | None] = {}
    for ctx in ET.parse(ts).getroot().iter("context"):
        name = ctx.findtext("name") or ""
        for msg in ctx.iter("message"):
            tr = msg.find("translation")
            text = None if tr is None or tr.get("type") in ("unfinished", "vanished", "obsolete") else (tr.text or None)
            out[(name, msg.findtext("source") or "")] = text
    return out


def untranslated(lang: str) -> list[tuple[str, str]]:
    """The texts of the sources without a finished translation in ``inspector_LANG.ts``."""
    with tempfile.TemporaryDirectory() as tmp:
        fresh = Path(tmp) / "fresh.ts"
        collect(fresh)
        wanted = set(messages(fresh))
    have = messages(FOLDER / f"inspector_{lang}.ts") if (FOLDER / f"inspector_{lang}.ts").is_file() else {}
    return sorted(k for k in wanted if not have.get(k))


def update() -> None:
    for lang in LANGUAGES[1:]:
        collect(FOLDER / f"inspector_{lang}.ts")


def release() -> None:
    for lang in LANGUAGES[1:]:
        _run([tool("pyside6-lrelease"), str(FOLDER / f"inspector_{lang}.ts"), "-qm", str(FOLDER / f"inspector_{lang}.qm")])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m inspector_frontends.gui.i18n.build", description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="only say which texts are not translated (exit 1)")
    args = ap.parse_args(argv)
    if args.check:
        missing = {lang: untranslated(lang) for lang in LANGUAGES[1:]}
        for lang, keys in missing.items():
            for ctx, text in keys:
                print(f"{lang}: {ctx}: {text!r} is not translated")
        return 1 if any(missing.values()) else 0
    update()
    release()
    return 0


if __name__ == "__main__":
    sys.exit(main())
