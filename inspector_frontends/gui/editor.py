"""The engineer's dialogs: log in, and the recipe editor.

The editor is a form generated from the stages' and the driver's parameter dataclasses
(:mod:`inspector.recipe_form`: doc, default, min/max, choices) and validated by the same
code as ``inspector recipe check``; it saves a NEW recipe file, never the one it opened.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias

from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDialog,
    QDialogButtonBox,
    QDoubleSpinBox,
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QScrollArea,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

from inspector.errors import RecipeError
from inspector.recipe_form import Field, RecipeForm, form_for, save_new, validate

if TYPE_CHECKING:
    from inspector.manager import PluginManager

__all__ = ["LoginDialog", "RecipeEditor"]

_BIG = 1e12  # a spin box needs finite bounds

#: The widget that edits one parameter (see :meth:`RecipeEditor._editor`).
_Editor: TypeAlias = QCheckBox | QComboBox | QSpinBox | QDoubleSpinBox | QLineEdit


class LoginDialog(QDialog):
    """Name and password of an engineer."""

    def __init__(self, parent: QWidget | None = None, problem: str | None = None) -> None:
        super().__init__(parent)
        self.setWindowTitle(self.tr("Engineer login"))
        self.who = QLineEdit()
        self.who.setObjectName("who")
        self.password = QLineEdit()
        self.password.setObjectName("password")
        self.password.setEchoMode(QLineEdit.EchoMode.Password)
        form = QFormLayout()
        form.addRow(self.tr("Name"), self.who)
        form.addRow(self.tr("Password"), self.password)
        self.message = QLabel(problem or "")
        self.message.setWordWrap(True)
        self.message.setStyleSheet("color: #b3141b; font-weight: bold;")
        buttons = QDialogButtonBox(QDialogButtonBox.StandardButton.Ok | QDialogButtonBox.StandardButton.Cancel)
        buttons.accepted.connect(self.accept)
        buttons.rejected.connect(self.reject)
        lay = QVBoxLayout(self)
        lay.addLayout(form)
        lay.addWidget(self.message)
        lay.addWidget(buttons)
        self.setStyleSheet("QLineEdit { min-height: 36px; font-size: 14pt; } QPushButton { min-height: 40px; min-width: 110px; }")


def _parse(text: str) -> Any:
    """A list or table typed as TOML (``[1, 2]``, ``{ a = 1 }``) or JSON."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return json.loads(text)


def _show(value: Any) -> str:
    if isinstance(value, (list, tuple, dict)):
        return json.dumps(value)
    return "" if value is None else str(value)


class RecipeEditor(QDialog):
    """Every parameter of the recipe as a form; Check and Save as new.

    After ``exec()`` returns Accepted, :attr:`saved` is the new recipe file.
    """

    def __init__(self, recipe: Path, pm: PluginManager, save_dir: Path, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.pm = pm
        self.save_dir = Path(save_dir)
        self.form: RecipeForm = form_for(recipe, pm)
        self.saved: Path | None = None
        self.setWindowTitle(self.tr("Recipe editor: {name} ({file})").format(name=self.form.name, file=Path(recipe).name))
        self.resize(900, 760)
        self.editors: dict[tuple[str, str], _Editor] = {}
        body = QWidget()
        col = QVBoxLayout(body)
        for sec in self.form.sections:
            box = QGroupBox(sec.title + (f"  ({sec.use})" if sec.use else ""))
            box.setToolTip(sec.doc)
            lay = QFormLayout(box)
            for f in sec.fields:
                w = self._editor(f)
                w.setObjectName(f"{sec.key}.{f.name}")
                w.setToolTip(f.doc + "\n" + self.tr("type {type}; default {default}").format(type=f.type, default=repr(f.default))
                             + (self.tr("; min {min}").format(min=f.min) if f.min is not None else "")
                             + (self.tr("; max {max}").format(max=f.max) if f.max is not None else ""))
                self.editors[(sec.key, f.name)] = w
                label = QLabel(f.name + ("" if not f.explicit else " \u25cf"))
                label.setToolTip(f.doc)
                lay.addRow(label, w)
            col.addWidget(box)
        col.addStretch(1)
        scroll = QScrollArea()
        scroll.setWidgetResizable(True)
        scroll.setWidget(body)
        self.name = QLineEdit(f"{self.form.name}-edited")
        self.name.setObjectName("recipe-name")
        self.status = QLabel(self.tr("Values marked \u25cf are set by the recipe; the others are defaults."))
        self.status.setWordWrap(True)
        check = QPushButton(self.tr("Check"))
        check.clicked.connect(self.check)
        save = QPushButton(self.tr("Save as new recipe"))
        save.setObjectName("save")
        save.clicked.connect(self.save)
        cancel = QPushButton(self.tr("Cancel"))
        cancel.clicked.connect(self.reject)
        row = QHBoxLayout()
        row.addWidget(QLabel(self.tr("New recipe name")))
        row.addWidget(self.name, 1)
        row.addWidget(check)
        row.addWidget(save)
        row.addWidget(cancel)
        outer = QVBoxLayout(self)
        outer.addWidget(scroll, 1)
        outer.addWidget(self.status)
        outer.addLayout(row)
        self.setStyleSheet("QPushButton { min-height: 40px; min-width: 110px; font-size: 12pt; }")

    def _editor(self, f: Field) -> _Editor:
        w: _Editor
        if f.kind == "bool":
            check = QCheckBox()
            check.setChecked(bool(f.value))
            w = check
        elif f.kind == "choice" and f.choices:
            combo = QComboBox()
            for c in f.choices:
                combo.addItem(str(c), c)
            combo.setCurrentIndex(max(0, list(f.choices).index(f.value)) if f.value in f.choices else 0)
            w = combo
        elif f.kind == "int" and f.value is not None:
            spin = QSpinBox()
            spin.setRange(int(max(f.min, -2**31)) if f.min is not None else -2**31,
                          int(min(f.max, 2**31 - 1)) if f.max is not None else 2**31 - 1)
            spin.setValue(int(f.value))
            w = spin
        elif f.kind == "float" and f.value is not None:
            real = QDoubleSpinBox()
            real.setDecimals(4)
            # The loader judges the range (one line, the same as recipe check): the box
            # lets any number through so its message, not a silent clamp, answers.
            real.setRange(-_BIG, _BIG)
            real.setValue(float(f.value))
            w = real
        else:
            w = QLineEdit(_show(f.value))
        w.setMinimumHeight(34)
        return w

    def _read(self, sec: str, f: Field) -> Any:
        w = self.editors[(sec, f.name)]
        if isinstance(w, QCheckBox):
            return w.isChecked()
        if isinstance(w, QComboBox):
            return w.currentData()
        if isinstance(w, (QSpinBox, QDoubleSpinBox)):
            return w.value()
        text = w.text().strip()
        if f.kind in ("list", "table", "any") and text:
            return _parse(text)
        if text == "" and f.optional:
            return None
        if f.kind == "int":
            return int(text)
        if f.kind == "float":
            return float(text)
        return text

    def edited(self) -> RecipeForm:
        """The form with every widget's value (only changed values become explicit)."""
        form = self.form
        for sec in self.form.sections:
            for f in sec.fields:
                try:
                    v = self._read(sec.key, f)
                except (ValueError, json.JSONDecodeError) as e:
                    raise ValueError(self.tr("{key}: cannot read {error}").format(key=f"{sec.key}.{f.name}", error=f"{type(e).__name__}: {e}")) from None
                if v != f.value:
                    form = form.with_value(sec.key, f.name, v) if v is not None else form.with_default(sec.key, f.name)
        return form

    def check(self) -> str | None:
        """Validate with the recipe loader; the error line (None: valid), also shown."""
        try:
            problem = validate(self.edited(), self.pm, path=self.save_dir / "check.toml", name=self.name.text().strip() or None)
        except ValueError as e:
            problem = str(e)
        self.status.setText(problem or self.tr("Valid: `inspector recipe check` accepts it."))
        self.status.setStyleSheet("color: #b3141b; font-weight: bold;" if problem else "color: #1b7f3b; font-weight: bold;")
        return problem

    def save(self) -> None:
        if self.check() is not None:
            return
        try:
            self.saved = save_new(self.edited(), self.save_dir, self.pm, name=self.name.text().strip() or None)
        except (RecipeError, OSError, ValueError) as e:
            self.status.setText(str(e))
            self.status.setStyleSheet("color: #b3141b; font-weight: bold;")
            return
        self.accept()
