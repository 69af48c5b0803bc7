"""`inspector run --lang`: the operator's lines (each part's line, the summary) in German or
Spanish, from the same gettext catalogues as the PDF report; English unless asked, whatever
the system locale (plant scripts parse these lines)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from inspector_frontends.cli import main

ROOT = Path(__file__).resolve().parents[2]
DEMO = ROOT / "recipes" / "demo.toml"


def _run(capsys, tmp_path, sim_captures, *extra: str) -> list[str]:
    code = main(["run", str(DEMO), "--capture", str(sim_captures["good"]), str(sim_captures["notched"]),
                 "--out", str(tmp_path / "out"), *extra])
    assert code == 1  # the notched cube fails, whatever the language
    return capsys.readouterr().out.strip().splitlines()


@pytest.mark.parametrize(("lang", "words"), [
    ("de", ("IO", "NIO", "Abweichung Mittel", "Fehlstelle", "geprüft", "Ergebnisse in")),
    ("es", ("CONFORME", "RECHAZADA", "desviación media", "defecto", "inspeccionadas", "Resultados en")),
])
def test_the_lines_in_the_operators_language(capsys, tmp_path, sim_captures, monkeypatch, lang, words):
    monkeypatch.setenv("LANG", "en_US.UTF-8")  # the system locale is not followed
    lines = _run(capsys, tmp_path, sim_captures, "--lang", lang)
    text = "\n".join(lines)
    for w in words:
        assert w in text, (w, text)
    assert re.search(r"[+-]\d+,\d{4}", lines[0]), lines[0]  # decimal comma
    assert not re.search(r"\b(PASS|FAIL|deviation|inspected|defects?)\b", text), text


def test_english_unless_asked_and_the_environment_variable(capsys, tmp_path, sim_captures, monkeypatch):
    monkeypatch.setenv("LANG", "de_DE.UTF-8")
    monkeypatch.delenv("INSPECTOR_LANG", raising=False)
    lines = _run(capsys, tmp_path / "en", sim_captures)
    assert ": PASS" in lines[0] and "deviation mean" in lines[0] and ": FAIL" in lines[1]
    assert lines[-1].startswith("2 inspected: 1 pass, 1 fail, 0 error.")
    monkeypatch.setenv("INSPECTOR_LANG", "es_ES.UTF-8")
    lines = _run(capsys, tmp_path / "es", sim_captures)
    assert "CONFORME" in lines[0] and lines[-1].startswith("2 inspeccionadas: 1 conformes, 1 rechazadas")


def test_an_unknown_language_is_one_line(capsys, tmp_path, sim_captures):
    code = main(["run", str(DEMO), "--capture", str(sim_captures["good"]), "--out", str(tmp_path / "o"), "--lang", "fr"])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert err == "inspector: error: --lang: language 'fr' is not available (available: en, de, es)"
    assert not (tmp_path / "o").exists()


def test_the_shift_in_the_operators_language(capsys, tmp_path, monkeypatch):
    """`inspector history OUTDIR --shift --lang de --pdf`: the lines and the PDF in German, even
    in a process where a window installed its (English) Qt translator for the shift texts."""
    from datetime import UTC, datetime

    from pypdf import PdfReader

    from inspector import shift
    from inspector.history_store import record
    from inspector.model import InspectionResult

    monkeypatch.setattr(shift, "_translator", lambda context, text: text)  # as the GUI's install("en") leaves it

    now = datetime.now(UTC)
    record(InspectionResult("p1", "r", "pass", None, {}), tmp_path, now=now)
    record(InspectionResult("p2", "r", "error", "rig.json: not valid JSON", {}), tmp_path, now=now)
    cell = tmp_path / "cell.toml"
    cell.write_text('[shifts]\nstarts = ["00:00"]\nnames = ["day"]\ntimezone = "UTC"\n')
    pdf = tmp_path / "schicht.pdf"
    assert main(["history", str(tmp_path), "--shift", "--config", str(cell), "--lang", "de", "--pdf", str(pdf)]) == 0
    out = capsys.readouterr().out
    assert "Schicht day" in out and "2 geprüft: 1 IO, 0 NIO, 1 Störungen; Ausbeute 100,0 %" in out, out
    assert "Störungen nach Grund:" in out
    text = PdfReader(pdf).pages[0].extract_text()
    for word in ("Schichtbericht", "geprüft", "Ausbeute", "100,0 %", "Störungen nach Grund", "keine Fehlstelle in dieser Schicht"):
        assert word in text, word
    assert main(["history", str(tmp_path), "--shift", "--lang", "xx"]) == 2
    assert capsys.readouterr().err.strip().startswith("inspector: error: --lang: language 'xx' is not available")
