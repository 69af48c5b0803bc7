"""Make the headless texts' catalogues: ``python -m inspector.locale.build [--check]``.

1. Babel's extractor collects every text marked ``_("...")`` in :func:`SOURCES` (the PDF
   report, :mod:`inspector.report`) and updates ``LANG/LC_MESSAGES/inspector.po`` for each
   language, keeping the translations already there (a new text is added untranslated, one
   no longer in the sources is dropped);
2. each ``.po`` is compiled into the ``.mo`` that :func:`inspector.locale.set_language` loads.

Translate the texts left empty in between (edit the ``.po``: ``msgstr``). ``--check`` changes
nothing: it says which texts of the sources have no translation, and which ``.mo`` is not
compiled from its ``.po`` (exit 1), what ``tests/core/test_report_i18n.py`` checks too.
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path

from babel.messages.catalog import Catalog
from babel.messages.extract import extract_from_file
from babel.messages.mofile import write_mo
from babel.messages.pofile import read_po, write_po

from inspector import __version__
from inspector.locale import DOMAIN, FOLDER, LANGUAGES

__all__ = ["SOURCES", "po_file", "mo_file", "collect", "untranslated", "stale", "update", "release", "main"]

_PACKAGE = FOLDER.parent  # inspector/
_ROOT = _PACKAGE.parent


def SOURCES() -> list[Path]:
    """The files whose texts are translated: the PDF report (its page and the reading of its
    result folder too), `inspector run`'s lines, the shift counters' text (``translate("Shift",
    ...)``, which the GUI's Qt files hold too) and the shift report."""
    return [_PACKAGE / "report.py", _PACKAGE / "report_pdf.py", _PACKAGE / "report_read.py", _PACKAGE / "outputs.py",
            _ROOT / "inspector_frontends" / "cli.py", _PACKAGE / "shift.py", _PACKAGE / "shift_report.py"]


def po_file(lang: str) -> Path:
    return FOLDER / lang / "LC_MESSAGES" / f"{DOMAIN}.po"


def mo_file(lang: str) -> Path:
    return FOLDER / lang / "LC_MESSAGES" / f"{DOMAIN}.mo"


def collect() -> Catalog:
    """The texts marked ``_("...")`` in :func:`SOURCES`, as a template catalogue."""
    template = Catalog(domain=DOMAIN, project="Inspector", fuzzy=False)
    for path in SOURCES():
        where = path.relative_to(_ROOT).as_posix()
        for lineno, message, comments, context in extract_from_file("python", path, keywords={"_": None, "translate": (2,)}):
            template.add(message, locations=[(where, lineno)], auto_comments=comments, context=context)
    return template


def _read(lang: str) -> Catalog | None:
    path = po_file(lang)
    if not path.is_file():
        return None
    with path.open("rb") as f:
        return read_po(f, locale=lang, domain=DOMAIN)


def untranslated(lang: str, template: Catalog | None = None) -> list[str]:
    """The texts of the sources without a translation (absent, empty or fuzzy) in ``lang``'s .po."""
    template = template if template is not None else collect()
    have = _read(lang)
    missing = []
    for m in template:
        if not m.id:
            continue
        got = have.get(m.id) if have is not None else None
        if got is None or not got.string or got.fuzzy:
            missing.append(str(m.id))
    return sorted(missing)


def _compiled(catalogue: Catalog) -> bytes:
    buf = io.BytesIO()
    write_mo(buf, catalogue, use_fuzzy=False)
    return buf.getvalue()


def stale(lang: str) -> bool:
    """Whether ``lang``'s .mo is missing or not what its .po compiles to."""
    have = _read(lang)
    return have is None or not mo_file(lang).is_file() or mo_file(lang).read_bytes() != _compiled(have)


def update(template: Catalog | None = None) -> None:
    """Bring every language's .po up to the sources' texts, keeping its translations."""
    template = template if template is not None else collect()
    for lang in LANGUAGES[1:]:
        catalogue = _read(lang) or Catalog(
            locale=lang, domain=DOMAIN, project="Inspector", version=__version__, msgid_bugs_address="", fuzzy=False,
            header_comment=f"# {lang} translations of Inspector's headless texts (the PDF report, inspector/report.py).\n"
                           "# Made by python -m inspector.locale.build (it keeps these translations);\n"
                           "# a new text is added with an empty msgstr: translate it, then run the build again.\n#")
        catalogue.update(template, no_fuzzy_matching=True, update_creation_date=False)
        catalogue.obsolete.clear()  # a text no longer in the sources
        po_file(lang).parent.mkdir(parents=True, exist_ok=True)
        buf = io.BytesIO()
        write_po(buf, catalogue, width=0, ignore_obsolete=True, include_lineno=False)
        if not po_file(lang).is_file() or po_file(lang).read_bytes() != buf.getvalue():
            po_file(lang).write_bytes(buf.getvalue())


def release() -> None:
    """Compile every language's .po into its .mo (untranslated and fuzzy texts left out)."""
    for lang in LANGUAGES[1:]:
        have = _read(lang)
        if have is None:
            raise FileNotFoundError(f"{po_file(lang)}: missing (run python -m inspector.locale.build)")
        data = _compiled(have)
        if not mo_file(lang).is_file() or mo_file(lang).read_bytes() != data:
            mo_file(lang).write_bytes(data)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m inspector.locale.build", description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--check", action="store_true",
                    help="change nothing: only say which texts are not translated and which .mo is stale (exit 1)")
    args = ap.parse_args(argv)
    if args.check:
        template = collect()
        bad = False
        for lang in LANGUAGES[1:]:
            for text in untranslated(lang, template):
                print(f"{lang}: {text!r} is not translated")
                bad = True
            if stale(lang):
                print(f"{lang}: {mo_file(lang)} is not compiled from {po_file(lang).name} (run python -m inspector.locale.build)")
                bad = True
        return 1 if bad else 0
    update()
    release()
    return 0


if __name__ == "__main__":
    sys.exit(main())
