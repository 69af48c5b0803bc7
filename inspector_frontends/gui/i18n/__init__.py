"""The operator window's languages: English (the source texts), German and Spanish.

Every text the GUI shows goes through Qt's translation system (``self.tr`` in a widget,
``QCoreApplication.translate(context, text)`` elsewhere; the Qt-free modules
:mod:`inspector_frontends.gui.viewmodel` and :mod:`inspector.shift` call a ``translate(context, text)``
hook that :func:`install` points at Qt's). The sources are ``inspector_de.ts`` and
``inspector_es.ts`` beside this file (Qt Linguist files: ``pyside6-linguist`` edits them);
``inspector_de.qm`` and ``inspector_es.qm`` are what Qt loads, made from them by
``python -m inspector_frontends.gui.i18n.build`` (``pyside6-lupdate`` collects the texts from the GUI's
sources, ``pyside6-lrelease`` compiles). Qt's own translations (``qtbase_*.qm``, shipped with
PySide6) translate the standard buttons (OK, Cancel) and the file dialogs.

The language is ``--lang``, else the cell's ``[gui] lang``, else the system locale
(``QLocale.system()``: ``LANG``/``LC_ALL``/``LC_MESSAGES``); one that is not available is
English. Numbers and dates follow the chosen language's locale (``QLocale.setDefault``).
"""

from __future__ import annotations

from pathlib import Path

from inspector import shift
from inspector.locale import set_language
from inspector_frontends.gui import viewmodel

__all__ = ["LANGUAGES", "FOLDER", "choose", "install", "number", "percent"]

#: Languages with a complete translation (English is the source).
LANGUAGES = ("en", "de", "es")
FOLDER = Path(__file__).resolve().parent

#: The translators installed (Qt keeps only a pointer: they must stay alive).
_INSTALLED: list[object] = []


def choose(requested: str | None, system: str | None = None) -> str:
    """The language to use: ``requested`` (``--lang`` or the cell's setting: ``de``,
    ``de_DE``, ``es-ES`` ...) when given, else the system locale's ``system`` (a name like
    ``de_DE``; None: asks Qt); English when the language has no translation.

    Raises ValueError (one line) for a requested language that is not available."""
    if requested:
        lang = requested.replace("-", "_").split("_")[0].lower()
        if lang not in LANGUAGES:
            raise ValueError(f"language {requested!r} is not available (available: {', '.join(LANGUAGES)})")
        return lang
    if system is None:
        from PySide6.QtCore import QLocale

        system = QLocale.system().name()
    lang = (system or "").replace("-", "_").split("_")[0].split(".")[0].lower()
    return lang if lang in LANGUAGES else "en"


def install(lang: str) -> str:
    """Install the translators of ``lang`` (and remove those installed before) in the running
    QApplication, make its locale the default for numbers and dates, and point the Qt-free
    modules' ``translate`` at Qt's, and make it the language of the headless texts too
    (:func:`inspector.locale.set_language`: the PDF report). Returns the language installed
    ("en": none needed)."""
    from PySide6.QtCore import QCoreApplication, QLibraryInfo, QLocale, QTranslator

    app = QCoreApplication.instance()
    assert app is not None, "create the QApplication first"
    for t in _INSTALLED:
        QCoreApplication.removeTranslator(t)  # type: ignore[arg-type]
    _INSTALLED.clear()
    locale = QLocale({"en": "en_US", "de": "de_DE", "es": "es_ES"}.get(lang, "en_US"))
    locale.setNumberOptions(QLocale.NumberOption.OmitGroupSeparator)  # 1234,5 mm, not 1.234,5
    QLocale.setDefault(locale)
    if lang != "en":
        ours = QTranslator(app)
        if not ours.load(str(FOLDER / f"inspector_{lang}.qm")):
            raise FileNotFoundError(f"{FOLDER / f'inspector_{lang}.qm'}: missing (python -m inspector_frontends.gui.i18n.build)")
        QCoreApplication.installTranslator(ours)
        _INSTALLED.append(ours)
        qt = QTranslator(app)
        if qt.load(locale, "qtbase", "_", QLibraryInfo.path(QLibraryInfo.LibraryPath.TranslationsPath)):
            QCoreApplication.installTranslator(qt)
            _INSTALLED.append(qt)
    viewmodel.set_text(QCoreApplication.translate, number)
    shift.set_translator(QCoreApplication.translate)
    set_language(lang if lang in LANGUAGES else "en")  # the PDF export (Ctrl+E), Qt-free: inspector.locale
    return lang


def number(value: float, decimals: int, *, sign: bool = False) -> str:
    """``value`` with ``decimals`` decimals in the default locale's format (``0,125`` in
    German); ``sign``: a ``+`` before a positive number (deviations)."""
    from PySide6.QtCore import QLocale

    text = QLocale().toString(float(value), "f", decimals)
    return ("+" + text) if sign and value >= 0 and not text.startswith(("-", "\u2212")) else text


def percent(share: float, decimals: int = 1) -> str:
    """A share (0..1) as a percentage in the default locale's format: ``97.5%`` in English,
    ``97,5 %`` in German and Spanish (a no-break space: never wrapped apart)."""
    from PySide6.QtCore import QLocale

    spaced = (QLocale.Language.German, QLocale.Language.Spanish)  # English and C: 97.5%
    space = "\u00a0" if QLocale().language() in spaced else ""
    return f"{number(100.0 * share, decimals)}{space}%"
