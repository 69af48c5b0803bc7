"""The model behind the engineer's recipe editor: one form section per recipe table.

:func:`form_for` reads a valid recipe and describes, for its driver and for each stage,
every parameter of the plugin's parameter dataclass (from
:func:`inspector.params.describe_params`: name, type, doc, default, bounds; plus the
choices of a ``Literal`` and the recipe's current value), and the recipe's tolerance table.
A GUI generates one widget per :class:`Field`; edits make new forms
(:meth:`RecipeForm.with_value`), :func:`validate` judges a form with exactly the code that
loads recipes (so the error line is the one ``inspector recipe check`` prints), and
:func:`save_new` writes a new recipe file, never over an existing one.

Plain Python: no Qt here, and the numerical stack is imported only when a form is built.
"""

from __future__ import annotations

import dataclasses
import os
import re
import tempfile
import tomllib
import types
import typing
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, get_args, get_origin

from inspector.errors import RecipeError
from inspector.params import describe_params

if TYPE_CHECKING:
    from inspector.manager import PluginManager

__all__ = ["Field", "Section", "RecipeForm", "form_for", "validate", "save_new"]


@dataclass(frozen=True)
class Field:
    """One editable value of a recipe.

    Attributes
    ----------
    name : str
        The key in the recipe table (``params`` key, or ``lower``/``upper``/... for
        tolerances).
    type : str
        The type in words, as ``inspector plugins`` shows it (``"float"``,
        ``"'auto' | 'dark-object'"``, ``"list of float"``, ``"float or none"``).
    doc : str
        One line saying what it does.
    default : object
        The value when the recipe does not set it (None for a required tolerance-region key).
    min, max : float or None
        Numeric bounds the recipe loader enforces.
    choices : tuple or None
        The allowed values of a choice (a ``Literal``), else None.
    value : object
        The current value (the recipe's, validated, else the default).
    explicit : bool
        Whether the recipe sets it (a field left at its default is not written).
    kind : str
        The widget to use: ``"bool"``, ``"int"``, ``"float"``, ``"str"``, ``"choice"``,
        ``"list"`` (a TOML array), ``"table"`` (a TOML table) or ``"any"``.
    optional : bool
        Whether ``None`` is allowed (meaning: not set in the recipe).
    """

    name: str
    type: str
    doc: str
    default: Any
    min: float | None
    max: float | None
    choices: tuple[Any, ...] | None
    value: Any
    explicit: bool
    kind: str
    optional: bool = False


@dataclass(frozen=True)
class Section:
    """The fields of one recipe table.

    Attributes
    ----------
    key : str
        How :meth:`RecipeForm.with_value` names it: ``"driver"``, ``"stages.NAME"`` (NAME is
        the stage's name in the recipe, by default its kind), ``"tolerance"`` (the default
        band) or ``"tolerance.regions[I]"``.
    kind : str
        ``"driver"``, ``"stage"``, ``"tolerance"`` or ``"region"``.
    title : str
        A heading, e.g. ``"carve (carve.hull)"``.
    use : str or None
        The driver or stage a ``driver``/``stage`` section configures.
    doc : str
        The plugin's one-line description (or what a tolerance section is).
    fields : tuple of Field
    index : int or None
        Position of a stage in ``[[stages]]`` or of a region in ``tolerance.regions``.
    """

    key: str
    kind: str
    title: str
    use: str | None
    doc: str
    fields: tuple[Field, ...]
    index: int | None = None

    def field(self, name: str) -> Field:
        """The field called ``name``; KeyError naming the known ones otherwise."""
        for f in self.fields:
            if f.name == name:
                return f
        raise KeyError(f"{self.key}: no field {name!r} (known: {', '.join(f.name for f in self.fields) or 'none'})")


@dataclass(frozen=True)
class RecipeForm:
    """A recipe as an editable form; immutable (edits return a new form).

    Attributes
    ----------
    path : Path or None
        The recipe file the form was read from (relative ``reference`` paths are relative to
        its folder).
    name : str
        ``[recipe] name`` as it will be written.
    driver : Section
    stages : tuple of Section
        In recipe order.
    tolerance : Section
        The default band (``lower``, ``upper``).
    regions : tuple of Section
        The tolerance regions, in order.
    source_toml : str
        The original file's text: every key the form does not describe is written back
        from it unchanged.
    """

    path: Path | None
    name: str
    driver: Section
    stages: tuple[Section, ...]
    tolerance: Section
    regions: tuple[Section, ...]
    source_toml: str

    @property
    def sections(self) -> tuple[Section, ...]:
        """Every section, in order: driver, stages, tolerance, regions."""
        return (self.driver, *self.stages, self.tolerance, *self.regions)

    def section(self, key: str) -> Section:
        """The section ``key`` (a stage may also be named by its bare recipe name)."""
        for s in self.sections:
            if s.key == key:
                return s
        bare = [s for s in self.stages if s.key == f"stages.{key}"]
        if len(bare) == 1:
            return bare[0]
        raise KeyError(f"no section {key!r} (known: {', '.join(s.key for s in self.sections)})")

    def value(self, section: str, name: str) -> Any:
        """The current value of field ``name`` of ``section``."""
        return self.section(section).field(name).value

    def with_value(self, section: str, name: str, value: Any) -> RecipeForm:
        """A new form with ``section.name`` set to ``value`` (then written explicitly).

        The value is not judged here: :func:`validate` does that with the recipe loader,
        so an out-of-range value gives the loader's own error line.

        Raises
        ------
        KeyError
            No such section or field.
        ValueError
            ``None`` for a field whose default is not None (a TOML file cannot say "none";
            use :meth:`with_default` to drop a value).
        """
        sec = self.section(section)
        f = sec.field(name)
        if value is None and f.default is not None:
            raise ValueError(f"{sec.key}.{name}: cannot be none (use with_default to go back to {f.default!r})")
        return self._replace_field(sec, dataclasses.replace(f, value=_plain(value), explicit=True))

    def with_default(self, section: str, name: str) -> RecipeForm:
        """A new form where ``section.name`` is no longer set: the plugin's default applies.

        Raises
        ------
        KeyError
            No such section or field.
        ValueError
            A tolerance-region key (required: it has no default).
        """
        sec = self.section(section)
        f = sec.field(name)
        if sec.kind == "region":
            raise ValueError(f"{sec.key}.{name}: a region needs every key (no default)")
        return self._replace_field(sec, dataclasses.replace(f, value=f.default, explicit=False))

    def with_name(self, name: str) -> RecipeForm:
        """A new form whose recipe is called ``name`` (``[recipe] name``)."""
        return dataclasses.replace(self, name=name)

    def _replace_field(self, sec: Section, new: Field) -> RecipeForm:
        fields = tuple(new if f.name == new.name else f for f in sec.fields)
        new_sec = dataclasses.replace(sec, fields=fields)
        if sec.kind == "driver":
            return dataclasses.replace(self, driver=new_sec)
        if sec.kind == "tolerance":
            return dataclasses.replace(self, tolerance=new_sec)
        if sec.kind == "region":
            return dataclasses.replace(self, regions=tuple(new_sec if s.key == sec.key else s for s in self.regions))
        return dataclasses.replace(self, stages=tuple(new_sec if s.key == sec.key else s for s in self.stages))

    def to_document(self, name: str | None = None, *, dest: str | os.PathLike[str] | None = None) -> dict[str, Any]:
        """The recipe as a TOML document (a dict), with the form's values.

        Parameters
        ----------
        name : str, optional
            ``[recipe] name`` to write (default: :attr:`name`).
        dest : path, optional
            Where the file will be saved: a relative ``reference`` is rewritten relative to
            that folder so that it still names the same mesh.
        """
        doc = tomllib.loads(self.source_toml)
        head = dict(doc.get("recipe", {}))
        head["name"] = self.name if name is None else name
        ref = head.get("reference")
        if dest is not None and isinstance(ref, str) and self.path is not None:
            head["reference"] = _rebase(ref, Path(self.path).parent, Path(dest).parent)
        out: dict[str, Any] = {"recipe": head}

        driver = doc.get("driver")
        params = _params(driver.get("params") if isinstance(driver, Mapping) else None, self.driver)
        if isinstance(driver, Mapping):
            out["driver"] = {**driver, "params": params} if params or "params" in driver else dict(driver)
        elif params:
            out["driver"] = {"use": self.driver.use, "params": params}

        stages = [dict(s) for s in doc.get("stages", [])]
        for sec in self.stages:
            assert sec.index is not None  # a stage section always has its index
            st = stages[sec.index]
            params = _params(st.get("params"), sec)
            if params or "params" in st:
                st["params"] = params
        out["stages"] = stages

        tol = dict(doc.get("tolerance", {}))
        if "default" in tol or any(f.explicit for f in self.tolerance.fields):
            default = dict(tol.get("default", {}))
            default.update({f.name: f.value for f in self.tolerance.fields})
            tol["default"] = default
        if self.regions:
            raw = [dict(r) for r in tol.get("regions", [])]
            for sec in self.regions:
                assert sec.index is not None
                raw[sec.index].update({f.name: f.value for f in sec.fields})
            tol["regions"] = raw
        if tol:
            out["tolerance"] = tol
        for key, value in doc.items():  # anything else, as it was (the loader will say)
            out.setdefault(key, value)
        return _plain(out)

    def to_toml(self, name: str | None = None, *, dest: str | os.PathLike[str] | None = None) -> str:
        """The recipe file's text with the form's values (see :meth:`to_document`).

        Comments of the original file are not kept; every key is.
        """
        import tomli_w

        return tomli_w.dumps(self.to_document(name, dest=dest))


# --------------------------------------------------------------------------- building a form


def _plain(value: Any) -> Any:
    """Tuples as lists, recursively (what TOML writes), mappings as dicts; a path parameter
    as its text, an Enum choice as its value."""
    import enum

    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, enum.Enum):
        return value.value
    return value


def _params(raw: Any, sec: Section) -> dict[str, Any]:
    """The ``params`` table of a section: the original keys the form does not describe, then
    every explicit field (a None value stays unwritten: the default, None, applies)."""
    known = {f.name for f in sec.fields}
    out = {k: v for k, v in dict(raw or {}).items() if k not in known}
    out.update({f.name: f.value for f in sec.fields if f.explicit and f.value is not None})
    return out


def _rebase(ref: str, old_dir: Path, new_dir: Path) -> str:
    """A relative reference path, rewritten from ``old_dir`` to ``new_dir``."""
    if ref.startswith("builtin:") or Path(ref).expanduser().is_absolute():
        return ref
    old, new = old_dir.resolve(), new_dir.resolve()
    if old == new:
        return ref
    return Path(os.path.relpath(old / ref, new)).as_posix()


def _widget(tp: Any) -> tuple[str, tuple[Any, ...] | None, bool]:
    """(kind, choices, optional) of a parameter annotation."""
    optional = False
    if get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in get_args(tp) if a is not type(None)]
        optional = len(args) < len(get_args(tp))
        if len(args) != 1:
            return "any", None, optional
        tp = args[0]
    origin = get_origin(tp)
    if origin is Literal:
        return "choice", tuple(get_args(tp)), optional
    if origin is tuple or tp is tuple:
        return "list", None, optional
    if origin is dict or tp is dict:
        return "table", None, optional
    for t, kind in ((bool, "bool"), (int, "int"), (float, "float"), (str, "str")):
        if tp is t:
            return kind, None, optional
    return "any", None, optional


def _fields(cls: type, params: Any, raw: Any) -> tuple[Field, ...]:
    """The fields of a parameter dataclass, valued from the validated ``params``."""
    hints = typing.get_type_hints(cls)
    given = dict(raw or {})
    out = []
    for d in describe_params(cls):
        kind, choices, optional = _widget(hints[d["name"]])
        out.append(Field(
            name=d["name"], type=d["type"], doc=d["doc"], default=d["default"], min=d["min"], max=d["max"],
            choices=choices, value=getattr(params, d["name"]), explicit=d["name"] in given, kind=kind,
            optional=optional,
        ))
    return tuple(out)


def _table(value: Any) -> Mapping[str, Any]:
    return value if isinstance(value, Mapping) else {}


def form_for(recipe_path: str | os.PathLike[str], pm: PluginManager) -> RecipeForm:
    """The form of a recipe file.

    Parameters
    ----------
    recipe_path : path
        A recipe TOML file.
    pm : inspector.manager.PluginManager
        Gives the stages' and drivers' parameter dataclasses.

    Returns
    -------
    RecipeForm

    Raises
    ------
    inspector.errors.RecipeError
        The recipe is not valid (the form describes only valid recipes: fix it as text).
    """
    # lazy: pipeline and recipe load numpy, which `import inspector.recipe_form` must not
    # (tests/core/test_recipe_form.py::test_module_is_qt_free_and_light)
    from inspector.pipeline import Tolerance
    from inspector.recipe import load_recipe

    path = Path(recipe_path)
    recipe = load_recipe(path, pm)
    text = path.read_text(encoding="utf-8")
    doc = tomllib.loads(text)

    raw_driver = _table(doc.get("driver"))
    dspec = recipe.driver.spec
    driver = Section("driver", "driver", f"driver ({dspec.name})", dspec.name, dspec.doc,
                     _fields(dspec.params, recipe.driver.params, raw_driver.get("params")))

    raw_stages = doc.get("stages", [])
    stages = tuple(
        Section(f"stages.{step.name}", "stage", f"{step.name} ({step.spec.name})", step.spec.name, step.spec.doc,
                _fields(step.spec.params, step.params, _table(raw_stages[i]).get("params")), index=i)
        for i, step in enumerate(recipe.steps)
    )

    raw_tol = _table(doc.get("tolerance"))
    given = _table(raw_tol.get("default"))
    band, dflt = recipe.tolerance.default, Tolerance().default
    tolerance = Section("tolerance", "tolerance", "tolerance (default band)", None,
                        "allowed signed deviation of a BCPS point, mm, where no region applies", (
        Field("lower", "float", "lowest allowed deviation, mm (missing material; <= 0)", dflt.lower,
              None, 0.0, None, band.lower, "lower" in given, "float"),
        Field("upper", "float", "highest allowed deviation, mm (excess material; >= 0)", dflt.upper,
              0.0, None, None, band.upper, "upper" in given, "float"),
    ))
    regions = tuple(
        Section(f"tolerance.regions[{i}]", "region", f"region {r.name}", None,
                "a box of the reference frame with its own band (the last region containing a point wins)", (
            Field("name", "str", "region name (shown with its defects)", None, None, None, None, r.name, True, "str"),
            Field("box_min", "list of float", "box corner with the smallest x, y, z, mm (reference frame)", None,
                  None, None, None, list(r.box_min), True, "list"),
            Field("box_max", "list of float", "box corner with the largest x, y, z, mm (reference frame)", None,
                  None, None, None, list(r.box_max), True, "list"),
            Field("lower", "float", "lowest allowed deviation in the box, mm (<= 0)", None, None, 0.0, None,
                  r.band.lower, True, "float"),
            Field("upper", "float", "highest allowed deviation in the box, mm (>= 0)", None, 0.0, None, None,
                  r.band.upper, True, "float"),
        ), index=i)
        for i, r in enumerate(recipe.tolerance.regions)
    )
    return RecipeForm(path=path, name=recipe.name, driver=driver, stages=stages, tolerance=tolerance,
                      regions=regions, source_toml=text)


# --------------------------------------------------------------------------- checking and saving


def _target(form: RecipeForm, path: str | os.PathLike[str] | None, name: str | None) -> Path:
    if path is not None:
        return Path(path).absolute()
    if form.path is not None:
        return Path(form.path).absolute()
    return Path.cwd() / f"{_slug(name or form.name)}.toml"


def validate(form: RecipeForm, pm: PluginManager, *, path: str | os.PathLike[str] | None = None,
             name: str | None = None) -> str | None:
    """The error line of the form's recipe, or None when it is valid.

    The recipe text is written to a temporary folder under the file name it will have and
    read back with :func:`inspector.recipe.load_recipe`: the same code, and so the same line,
    as ``inspector recipe check`` on the saved file. A relative ``reference`` is made
    absolute in that copy (the loader reads it relative to the recipe's folder, so it is
    resolved against the folder the file will be saved in).

    Parameters
    ----------
    form : RecipeForm
    pm : inspector.manager.PluginManager
    path : path, optional
        Where the recipe will be saved (default: the file the form was read from).
    name : str, optional
        A new ``[recipe] name``.
    """
    # lazy: pipeline and recipe load numpy, which `import inspector.recipe_form` must not
    # (tests/core/test_recipe_form.py::test_module_is_qt_free_and_light)
    from inspector.recipe import load_recipe

    target = _target(form, path, name)
    doc = form.to_document(name, dest=target)
    ref = doc["recipe"].get("reference")
    if isinstance(ref, str) and not ref.startswith("builtin:") and not Path(ref).expanduser().is_absolute():
        doc["recipe"]["reference"] = str(target.parent / ref)
    import tomli_w

    with tempfile.TemporaryDirectory(prefix="inspector-recipe-") as tmp:
        probe = Path(tmp) / target.name
        probe.write_text(tomli_w.dumps(doc), encoding="utf-8")
        try:
            load_recipe(probe, pm)
        except RecipeError as e:
            return str(e)
    return None


def _slug(name: str) -> str:
    """A file name stem for a recipe name."""
    s = re.sub(r"[^A-Za-z0-9._-]+", "-", name).strip("-.")
    return s or "recipe"


def _write_new(path: Path, text: str) -> None:
    """Write ``path``, which must not exist, completely or not at all (FileExistsError)."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        try:
            os.link(tmp, path)  # atomic, and never replaces an existing file
        except FileExistsError:
            raise
        except OSError:  # a file system without hard links
            with open(path, "x", encoding="utf-8") as f:
                f.write(text)
    finally:
        try:
            os.unlink(tmp)
        except OSError:
            pass


def save_new(form: RecipeForm, folder_or_path: str | os.PathLike[str], pm: PluginManager, *,
             name: str | None = None) -> Path:
    """Validate the form, then write it as a NEW recipe file; never overwrites one.

    Parameters
    ----------
    form : RecipeForm
    folder_or_path : path
        A folder: the file is ``<name>.toml`` there, or ``<name>-2.toml``, ``-3``... when
        taken. A file path: written there, refused if it exists.
    pm : inspector.manager.PluginManager
    name : str, optional
        A new ``[recipe] name`` (default: the form's); it also names the file in a folder.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    inspector.errors.RecipeError
        The recipe is not valid (the line :func:`validate` returns).
    FileExistsError
        ``folder_or_path`` is an existing file.
    FileNotFoundError
        The folder to write in does not exist.
    OSError
        The file cannot be written.
    """
    dest = Path(folder_or_path)
    in_folder = dest.is_dir()
    folder = dest if in_folder else dest.parent
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such folder to save the recipe in")
    if in_folder:
        stem = _slug(name or form.name)
        candidates: Iterator[Path] = (dest / (stem + (f"-{k}" if k > 1 else "") + ".toml") for k in range(1, 10_000))
    else:
        if dest.exists():
            raise FileExistsError(f"{dest}: already exists; a recipe is never overwritten (save it under a new name)")
        candidates = iter([dest])
    for target in candidates:
        if target.exists():
            continue
        error = validate(form, pm, path=target, name=name)
        if error is not None:
            raise RecipeError(error)
        try:
            _write_new(target, form.to_toml(name, dest=target.absolute()))
        except FileExistsError:
            if not in_folder:
                raise FileExistsError(
                    f"{dest}: already exists; a recipe is never overwritten (save it under a new name)") from None
            continue  # taken meanwhile: the next name
        return target
    raise FileExistsError(f"{dest}: no free file name for {stem!r}")
