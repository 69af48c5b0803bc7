"""The language of the headless texts (the PDF report): English (the source), German, Spanish.

Qt-free, so ``inspector report --pdf`` works without PySide6: the texts of
:mod:`inspector.report` are marked ``_("...")`` and translated with Python's :mod:`gettext`
from the catalogues beside this file (``de/LC_MESSAGES/inspector.po``, the source a
translator edits, and the ``.mo`` compiled from it, which is what is loaded). Numbers go
through :func:`number`: Python's format in English, the locale's (decimal comma, its digit
grouping, through Babel) in German and Spanish; Babel is imported only then.

The language is process-wide: :func:`set_language` (the GUI's
:func:`inspector_frontends.gui.i18n.install` calls it, so its PDF export is in the operator's
language), or :func:`using` for one piece of work. ``inspector report --lang LANG`` chooses
it with :func:`choose`: ``--lang``, else ``$INSPECTOR_LANG``, else English (never the system
locale: the command's lines are parsed by plant scripts).

After changing a text of the report: ``python -m inspector.locale.build`` collects the texts
into the ``.po`` files (new ones untranslated), translate them, and run it again to compile;
``--check`` lists what is not translated.
"""

from __future__ import annotations

import gettext as _gettext
import os
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__ = ["LANGUAGES", "DOMAIN", "FOLDER", "ENV", "choose", "set_language", "language", "using", "gettext", "_",
           "number", "list_separator"]

#: Languages with a complete translation (English is the source).
LANGUAGES = ("en", "de", "es")
#: The catalogues' name: ``LANG/LC_MESSAGES/inspector.mo``.
DOMAIN = "inspector"
FOLDER = Path(__file__).resolve().parent
#: The environment variable ``inspector report`` reads when ``--lang`` is not given.
ENV = "INSPECTOR_LANG"

#: Babel's locale of each translated language (numbers).
_LOCALES = {"de": "de_DE", "es": "es_ES"}

_lang = "en"
_catalogue: _gettext.NullTranslations = _gettext.NullTranslations()


def choose(requested: str | None, environ: Mapping[str, str] | None = None) -> str:
    """The language of a headless command: ``requested`` (``--lang``: ``de``, ``de_DE``,
    ``es-ES`` ...) when given, else ``$INSPECTOR_LANG``, else English. The system locale is
    not followed.

    Raises ValueError (one line naming it and the available ones) for a language that is
    not available."""
    env = os.environ if environ is None else environ
    value = requested or env.get(ENV) or ""
    if not value.strip():
        return "en"
    lang = value.strip().replace("-", "_").split("_")[0].split(".")[0].lower()
    if lang not in LANGUAGES:
        raise ValueError(f"language {value!r} is not available (available: {', '.join(LANGUAGES)})")
    return lang


def set_language(lang: str) -> str:
    """Make ``lang`` (one of :data:`LANGUAGES`) the language of the headless texts; returns it.

    Raises ValueError for another language, FileNotFoundError when its catalogue is missing."""
    global _lang, _catalogue
    if lang not in LANGUAGES:
        raise ValueError(f"language {lang!r} is not available (available: {', '.join(LANGUAGES)})")
    if lang == "en":
        catalogue: _gettext.NullTranslations = _gettext.NullTranslations()
    else:
        mo = FOLDER / lang / "LC_MESSAGES" / f"{DOMAIN}.mo"
        if not mo.is_file():
            raise FileNotFoundError(f"{mo}: missing (python -m inspector.locale.build)")
        with mo.open("rb") as f:
            catalogue = _gettext.GNUTranslations(f)
    _lang, _catalogue = lang, catalogue
    return lang


def language() -> str:
    """The language of the headless texts now."""
    return _lang


@contextmanager
def using(lang: str | None) -> Iterator[str]:
    """``lang`` (None: the current one) for the duration of a ``with`` block, then the one before."""
    before = _lang
    if lang is None or lang == before:
        yield before
        return
    set_language(lang)
    try:
        yield lang
    finally:
        set_language(before)


def gettext(message: str) -> str:
    """``message`` in the current language (itself in English or when it has no translation)."""
    return _catalogue.gettext(message)


_ = gettext


def list_separator() -> str:
    """What separates the numbers of a list (``x, y, z``; ``[lower, upper]``): ``", "`` in
    English, ``"; "`` where the comma is the decimal sign."""
    return ", " if _lang == "en" else "; "


def number(value: Any, spec: str) -> str:
    """``value`` written with the format spec ``spec`` (``".3f"``, ``"+.4f"``, ``",d"``,
    ``"d"``) in the current language: Python's format in English; in German and Spanish the
    same digits (rounded as Python rounds) with the locale's decimal sign, digit grouping
    (``","`` in ``spec``) and signs."""
    text = format(value, spec)
    if _lang == "en":
        return text
    from decimal import Decimal, InvalidOperation

    from babel.numbers import format_decimal

    sign = "+" in spec
    group = "," in spec
    decimals = len(text.split(".")[1]) if "." in text else 0
    digits = text.replace(",", "")
    try:
        exact = Decimal(digits)
    except InvalidOperation:  # nan, inf: as Python writes them
        return text
    body = ("#,##0" if group else "0") + ("." + "0" * decimals if decimals else "")
    pattern = f"+{body};-{body}" if sign else body
    out = format_decimal(exact, format=pattern, locale=_LOCALES[_lang], decimal_quantization=True, group_separator=group)
    if sign and digits.startswith("-") and not out.startswith(("-", "\u2212")):  # -0.000 keeps its sign
        out = "-" + out.lstrip("+")
    return out
