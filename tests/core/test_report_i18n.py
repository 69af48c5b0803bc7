"""report.pdf in the operator's language (German, Spanish): the catalogues are complete, the
pages of real results come out translated with decimal commas, English is left as it was."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest
from babel.messages.pofile import read_po
from pypdf import PdfReader

from inspector import locale
from inspector.locale import build
from inspector.report import render_pdf
from inspector_frontends.cli import main

DEMO = Path(__file__).resolve().parents[2] / "recipes" / "demo.toml"

#: Words that mean the result failed or did not finish, in each language (as the GUI's .ts say them).
WORDS = {
    "de": {"fail": ["NIO", "Teil außerhalb der Toleranz", "Grund", "Fehlstellen (", "Abweichungskarte", "Statistik",
                    "Prüfplan", "Seite 1 von 1", "Draufsicht (X-Y)"],
           "error": ["STÖRUNG", "Prüfung nicht abgeschlossen", "Störung", "keine Abweichungskarte", "Fehlstellen (0)",
                     "keine Fehlstelle", "(Prüfplandatei nicht gefunden)", "Seite 1 von 1"]},
    "es": {"fail": ["RECHAZADA", "pieza fuera de tolerancia", "Motivo", "Defectos (", "Mapa de desviaciones",
                    "Estadística", "Receta", "página 1 de 1", "vista superior (X-Y)"],
           "error": ["ERROR", "inspección no completada", "sin mapa de desviaciones", "Defectos (0)", "ningún defecto",
                     "(archivo de receta no encontrado)", "página 1 de 1"]},
}


def read_pdf(path: Path) -> str:
    """The text of the PDF's only page, whitespace runs as one space."""
    reader = PdfReader(path)
    assert len(reader.pages) == 1
    return " ".join(reader.pages[0].extract_text().split())


def catalogue(lang: str) -> dict[str, str]:
    """msgid -> msgstr of a language's .po."""
    with build.po_file(lang).open("rb") as f:
        return {str(m.id): str(m.string) for m in read_po(f) if m.id}


def english_left(text: str, lang: str) -> list[str]:
    """The English texts of the catalogue (the parts between placeholders, with a word of three
    letters or more) found in ``text`` as whole words, for every text whose translation differs:
    a text or part the same in both languages (RMSE, SHA-256, "ERROR" in Spanish, the product's
    name) may stay."""
    found = []
    for msgid, msgstr in catalogue(lang).items():
        if msgstr == msgid:
            continue
        for part in re.split(r"\{\w+\}", msgid):
            part = part.strip(" ,;.:")
            if part in msgstr:  # the same in both (the product's name "inspector")
                continue
            if re.search(r"[A-Za-z]{3}", part) and re.search(rf"(?<!\w){re.escape(part)}(?!\w)", text):
                found.append(part)
    return found


def _without_recipe_path(folder: Path) -> dict:
    """No recipe text on the page (its TOML keys are English); the recorded hash stays."""
    res = json.loads((folder / "result.json").read_text())
    res.pop("recipe_path", None)
    (folder / "result.json").write_text(json.dumps(res))
    return res


@pytest.fixture(scope="module")
def notched(sim_captures, tmp_path_factory) -> Path:
    """The result folder of the demo recipe on the notched cube (a real FAIL)."""
    out = tmp_path_factory.mktemp("i18n")
    assert main(["run", str(DEMO), "--capture", str(sim_captures["notched"]), "--out", str(out), "-q"]) == 1
    return out / "notched"


@pytest.fixture(scope="module")
def failed(tmp_path_factory) -> Path:
    """A real ERROR result: the capture folder does not exist."""
    out = tmp_path_factory.mktemp("i18n")
    assert main(["run", str(DEMO), "--capture", str(out / "gone"), "--out", str(out / "o"), "-q"]) == 3
    return out / "o" / "gone"


# -- (a) every text of the report has its translation ---------------------------------------------
def test_every_text_of_the_report_is_translated_and_compiled(capsys):
    assert build.main(["--check"]) == 0, capsys.readouterr().out
    assert capsys.readouterr().out == ""
    wanted = {str(m.id) for m in build.collect() if m.id}
    assert len(wanted) > 90  # the extractor found the report's texts
    for lang in ("de", "es"):
        have = catalogue(lang)
        assert wanted == set(have) and all(have.values())
        for msgid, msgstr in have.items():  # the same placeholders, or .format() fails at run time
            assert sorted(re.findall(r"\{\w+\}", msgid)) == sorted(re.findall(r"\{\w+\}", msgstr)), (lang, msgid)


def test_the_check_fails_on_a_new_english_text(tmp_path, monkeypatch, capsys):
    new = tmp_path / "new.py"
    new.write_text('from inspector.locale import _\n\nLABEL = _("a new text of the report")\n')
    monkeypatch.setattr(build, "SOURCES", lambda: [build._PACKAGE / "report.py", new])
    monkeypatch.setattr(build, "_ROOT", Path(tmp_path.anchor))  # locations relative to a folder above both
    assert build.main(["--check"]) == 1
    out = capsys.readouterr().out.splitlines()
    assert out == ["de: 'a new text of the report' is not translated", "es: 'a new text of the report' is not translated"]


# -- (b) German and Spanish pages of real results ---------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("lang", ["de", "es"])
def test_a_failed_part_in_german_and_spanish(lang, notched, tmp_path, monkeypatch, capsys):
    folder = tmp_path / "notched"
    shutil.copytree(notched, folder)
    res = _without_recipe_path(folder)
    # German with --lang, Spanish from $INSPECTOR_LANG; the command's own lines stay English.
    if lang == "de":
        assert main(["report", str(folder), "--pdf", "--lang", "de"]) == 0
    else:
        monkeypatch.setenv("INSPECTOR_LANG", "es_ES.UTF-8")
        assert main(["report", str(folder), "--pdf"]) == 0
    assert capsys.readouterr().out.splitlines() == [f"wrote {folder / 'deviation.png'}", f"wrote {folder / 'report.pdf'}"]
    assert locale.language() == "en"  # the command's language was for its own work only
    text = read_pdf(folder / "report.pdf")
    for word in WORDS[lang]["fail"]:
        assert word in text, word
    d = res["defects"][0]
    worst = f"{d['worst_mm']:+.3f}".replace(".", ",")  # a decimal comma
    head = {"de": f"fehlendes Material im Bereich 'default': max. {worst} mm, unter der unteren Grenze -0,100 mm",
            "es": f"falta material en la zona 'default': peor {worst} mm, por debajo del límite inferior -0,100 mm"}
    assert head[lang] in text
    row = {"de": "fehlt", "es": "falta"}[lang]  # the worst defect's row: number, kind, region, points, worst
    assert re.search(rf"1 {row} default [\d.]+ {re.escape(worst)}", text)
    assert re.search(r"\[-0,100; \+0,100\] mm", text)
    assert english_left(text, lang) == []
    title = PdfReader(folder / "report.pdf").metadata.title
    assert title == {"de": "Prüfbericht: notched NIO", "es": "Informe de inspección: notched RECHAZADA"}[lang]


@pytest.mark.parametrize("lang", ["de", "es"])
def test_an_error_in_german_and_spanish(lang, failed, tmp_path):
    folder = tmp_path / "gone"
    shutil.copytree(failed, folder)
    res = _without_recipe_path(folder)
    text = read_pdf(render_pdf(folder, lang=lang))
    assert locale.language() == "en"
    for word in WORDS[lang]["error"]:
        assert word in text, word
    error = " ".join(res["error"].split())  # the inspection's own message: not translated
    assert error in text
    assert re.search(r"\d,\d{2} s", text)  # the cycle time, with a decimal comma
    assert english_left(text.replace(error, ""), lang) == []


# -- (c) the language is chosen, never guessed ------------------------------------------------------
@pytest.mark.parametrize("how", ["--lang", "env"])
def test_an_unknown_language_is_refused_in_one_line(how, failed, tmp_path, monkeypatch, capsys):
    folder = tmp_path / "gone"
    shutil.copytree(failed, folder)
    if how == "env":
        monkeypatch.setenv("INSPECTOR_LANG", "fr")
        args = ["report", str(folder), "--pdf"]
    else:
        args = ["report", str(folder), "--pdf", "--lang", "fr"]
    assert main(args) == 2
    out, err = capsys.readouterr()
    assert out == "" and err == "inspector: error: language 'fr' is not available (available: en, de, es)\n"
    assert not (folder / "report.pdf").exists() and not (folder / "deviation.png").exists()


def test_the_language_is_lang_then_inspector_lang_then_english_never_the_system_locale():
    assert locale.choose("de_DE", {}) == "de" and locale.choose("es-ES", {}) == "es" and locale.choose("EN", {}) == "en"
    assert locale.choose(None, {"INSPECTOR_LANG": "es"}) == "es"
    assert locale.choose("de", {"INSPECTOR_LANG": "es"}) == "de"
    assert locale.choose(None, {"LANG": "de_DE.UTF-8", "LC_ALL": "de_DE.UTF-8", "LC_MESSAGES": "de_DE"}) == "en"
    with pytest.raises(ValueError, match=r"^language 'fr_FR' is not available \(available: en, de, es\)$"):
        locale.choose("fr_FR", {})


def test_numbers_follow_the_language():
    cases = [(-0.1, "+.3f"), (0.0125, "+.4f"), (12345, ",d"), (98.7654, ".2f"), (1030, "d")]
    with locale.using("de"):
        assert [locale.number(x, spec) for x, spec in cases] == ["-0,100", "+0,0125", "12.345", "98,77", "1030"]
        assert locale.gettext("FAIL") == "NIO"
    with locale.using("es"):
        assert locale.gettext("FAIL") == "RECHAZADA" and locale.number(-0.1, "+.3f") == "-0,100"
    assert locale.language() == "en"
    assert [locale.number(x, spec) for x, spec in cases] == [f"{x:{spec}}" for x, spec in cases]
    assert locale.gettext("FAIL") == "FAIL"
