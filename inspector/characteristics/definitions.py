"""A recipe's ``[[characteristics]]``: read, checked against the reference's features, kept.

The recipe loader (:func:`inspector.recipe.parse_recipe`) calls :func:`parse_characteristics`
with the document's array and the reference; every problem is one
:class:`~inspector.errors.RecipeError` line naming the recipe file, the entry and the key or
feature -- an unknown key, a kind the feature does not have, a distance between
non-parallel planes, a feature id the reference does not have (a reference changed since
the recipe was written renumbers or drops features: the line says which id and which ids
exist).

The features of a reference are found once per mesh and process (:func:`features_for`,
keyed by a digest of its vertex and face arrays): the recipe loader and the stage that
measures (``evaluate.characteristics``) share them.

Layout::

    [[characteristics]]
    id = "1"                 # the balloon number, unique in the recipe
    kind = "diameter"        # diameter radius distance angle position flatness roundness cylindricity
    feature = "F14"          # or features = ["F01", "F04"] (distance, angle)
    lower = -0.05            # deviation from the nominal, mm (degrees for an angle); form/position: the value
    upper = 0.05
    nominal = 8.0            # optional: default from the CAD (0 for form and position)
    criticality = "key"      # minor, major (default), critical, key
    description = "Ø8 hole" # optional: the DFQ's K2002
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from inspector.characteristics.edges import plane_edges
from inspector.characteristics.measure import Characteristic
from inspector.errors import InspectorError, RecipeError
from inspector.kernels.features import find_features
from inspector.reference import Reference

__all__ = ["SETTINGS_KEY", "features_and_edges", "features_for", "features_of_reference", "measured_in", "parse_characteristics", "rows_of"]

#: The key under which the recipe's characteristics reach the stages (``context.settings``):
#: the name of the plugin that measures them.
SETTINGS_KEY = "characteristics"

#: Meshes whose features and edges are kept (a cell runs one reference; a GUI may switch
#: between a few): two entries a mesh.
_CACHE_SIZE = 16
_cache: OrderedDict[str, Any] = OrderedDict()
_lock = threading.Lock()


def _digest(vertices: np.ndarray, faces: np.ndarray) -> str:
    h = hashlib.sha1(usedforsecurity=False)
    for a in (np.ascontiguousarray(vertices, np.float64), np.ascontiguousarray(faces, np.int64)):
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _cached(key: str, make: Callable[[], Any]) -> Any:
    """``make()``, once per ``key`` and process (the least recently used dropped first)."""
    with _lock:
        if key in _cache:
            _cache.move_to_end(key)
            return _cache[key]
    value = make()
    with _lock:
        _cache[key] = value
        while len(_cache) > _CACHE_SIZE:
            _cache.popitem(last=False)
    return value


def features_for(vertices: np.ndarray, faces: np.ndarray) -> list[Any]:
    """The features of a mesh (:func:`inspector.kernels.features.find_features`, default
    tolerances), found once per mesh and process.

    Parameters
    ----------
    vertices : (V, 3) float
        mm.
    faces : (F, 3) int

    Returns
    -------
    list of Feature
        Shared: do not modify.
    """
    return _cached("features:" + _digest(vertices, faces), lambda: find_features(vertices, faces))


def features_and_edges(vertices: np.ndarray, faces: np.ndarray) -> tuple[list[Any], tuple[Any, ...]]:
    """The features of a mesh (:func:`features_for`) and the convex edges between its plane
    features (:func:`inspector.characteristics.edges.plane_edges`), found once per mesh and
    process; the mesh is hashed once (the stage asks for both on every part).

    Returns
    -------
    features : list of Feature
    edges : tuple of PlaneEdge
        Both shared: do not modify.
    """
    key = _digest(vertices, faces)
    feats = _cached("features:" + key, lambda: find_features(vertices, faces))
    return feats, _cached("edges:" + key, lambda: plane_edges(vertices, faces, feats))


def features_of_reference(spec: str) -> list[Any]:
    """The features of the reference ``spec`` (``builtin:NAME`` or a mesh file); RecipeError
    naming it when it cannot be read."""
    try:
        ref = Reference.load(spec)
    except InspectorError as e:
        raise RecipeError(str(e)) from None
    return features_for(ref.vertices, ref.faces)


def parse_characteristics(raw: Any, where: str, reference: str | None) -> tuple[Any, ...]:
    """The ``[[characteristics]]`` array of a recipe, validated.

    Parameters
    ----------
    raw : list of tables or None
        The TOML value (None: the recipe has none).
    where : str
        ``"FILE: characteristics"``, the start of every message.
    reference : str or None
        The recipe's reference (``builtin:NAME`` or an absolute path): the features the
        characteristics name must exist there.

    Returns
    -------
    tuple of Characteristic
        In the recipe's order.

    Raises
    ------
    RecipeError
        One line naming the entry (``characteristics[2]`` and its id) and the problem.
    """
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise RecipeError(f"{where}: expected an array of tables ([[characteristics]]), got {type(raw).__name__}")
    out: list[Characteristic] = []
    seen: dict[str, int] = {}
    for i, entry in enumerate(raw):
        w = f"{where}[{i}]"
        if not isinstance(entry, Mapping):
            raise RecipeError(f"{w}: expected a table, got {entry!r}")
        c = Characteristic.from_dict(entry, w)
        if c.id in seen:
            raise RecipeError(f"{w}: id {c.id!r} is already used by characteristics[{seen[c.id]}] (ids are balloon "
                              "numbers: one per characteristic)")
        seen[c.id] = i
        out.append(c)
    if not out:
        return ()
    if reference is None:
        raise RecipeError(f"{where}: characteristics need a reference mesh (recipe.reference or --reference)")
    feats = features_of_reference(reference)
    by_id = {f.id: f for f in feats}
    for i, c in enumerate(out):
        try:
            c.validate(by_id)
        except RecipeError as e:
            raise RecipeError(f"{where}[{i}]: {e} [reference {_short(reference)}]") from None
    return tuple(out)


def _short(spec: str) -> str:
    from pathlib import Path

    return spec if spec.startswith("builtin:") else Path(spec).name


def measured_in(steps: Sequence[Any]) -> bool:
    """Whether a recipe's steps hold a stage that measures characteristics."""
    return any(getattr(s.spec, "name", "") == "evaluate.characteristics" for s in steps)


def rows_of(result: Any) -> list[dict[str, Any]]:
    """The characteristics rows of one result: an :class:`~inspector.model.InspectionResult`
    or a ``result.json`` document (dict); [] when it has none.

    For the front ends (history, GUI, OPC UA, PDF report), which may import this module
    (it is not a plugin): each row is a dict ``{id, kind, features, nominal, measured,
    deviation, lower, upper, u, U, points, verdict, reason, unit, criticality,
    description}``; ``measured``, ``deviation``, ``u`` and ``U`` are None when the verdict
    is ``not_measurable``; ``lower``/``upper`` are deviations from ``nominal`` (form and
    position: limits of the value, nominal 0).
    """
    extras = result.get("extras", {}) if isinstance(result, Mapping) else getattr(result, "extras", {})
    found = (extras or {}).get(SETTINGS_KEY, [])
    return [dict(r) for r in found if isinstance(r, Mapping)] if isinstance(found, list) else []
