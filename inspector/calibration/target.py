"""Calibration targets: a ChArUco board, or a body of several boards at known poses.

A target is described by a TOML file (``inspector calibrate TARGET.toml``)::

    [target]
    kind = "charuco"             # one planar board, printed on one side
    dictionary = "DICT_5X5_1000" # an OpenCV predefined dictionary name
    squares = [8, 8]             # squares along x and y
    square_mm = 8.0
    marker_mm = 6.0

    # or a cube with a board on each of its six faces (every camera of a spherical rig sees
    # one to three of them at once); face k's markers have ids k*m ... (k+1)*m - 1 where m is
    # the markers of one board, so the six boards differ:
    kind = "charuco_cube"
    side_mm = 44.0               # the cube's edge; each board is centred on its face

The board is exactly OpenCV's ``cv2.aruco.CharucoBoard((X, Y), square_mm, marker_mm,
dictionary, ids)``. Its frame is OpenCV's: origin at the board's top-left outer corner, x
along the first row, y down the board, z = x × y, i.e. *into* the board: the printed side
faces -z. A body's frame has its origin at the cube's centre; each board's printed side
faces outwards.

Everything here is a pure description (no images): :func:`load_target` validates the file
and names the key that is wrong in one line (:class:`~inspector.errors.RecipeError`, exit 2).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from inspector.errors import RecipeError

__all__ = ["Target", "load_target", "parse_target", "KINDS"]

#: Target kinds and their keys (besides ``kind``): required, optional.
KINDS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "charuco": (("dictionary", "squares", "square_mm", "marker_mm"), ()),
    "charuco_cube": (("dictionary", "squares", "square_mm", "marker_mm", "side_mm"), ()),
}

# Outward normals of the cube's faces and each board's x axis on it (any axis in the face
# would do; these are fixed so a face's board is always placed the same way).
_CUBE_FACES = (
    ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    ((-1.0, 0.0, 0.0), (0.0, -1.0, 0.0)),
    ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    ((0.0, -1.0, 0.0), (0.0, 0.0, -1.0)),
    ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0)),
    ((0.0, 0.0, -1.0), (-1.0, 0.0, 0.0)),
)


@dataclass(frozen=True, eq=False)
class Target:
    """A calibration target: one or more ChArUco boards fixed to one rigid body.

    Attributes
    ----------
    kind : str
        ``"charuco"`` or ``"charuco_cube"``.
    dictionary : str
        OpenCV predefined dictionary name, e.g. ``"DICT_5X5_1000"``.
    squares : (int, int)
        Squares along the board's x and y.
    square_mm, marker_mm : float
        Chessboard square and ArUco marker side, mm.
    faces : (B, 4, 4) float
        Board -> target-body transform of each board (mm).
    source : str
        The file it was read from (for messages).
    """

    kind: str
    dictionary: str
    squares: tuple[int, int]
    square_mm: float
    marker_mm: float
    faces: np.ndarray
    source: str = "target"
    side_mm: float | None = None
    _cache: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    # -- geometry ------------------------------------------------------------------------------
    @property
    def n_boards(self) -> int:
        return int(len(self.faces))

    @property
    def corners_per_board(self) -> int:
        """Inner chessboard corners of one board: ``(X - 1) * (Y - 1)``."""
        return (self.squares[0] - 1) * (self.squares[1] - 1)

    @property
    def markers_per_board(self) -> int:
        """ArUco markers of one board: the white squares, ``X * Y // 2``."""
        return (self.squares[0] * self.squares[1]) // 2

    @property
    def board_size_mm(self) -> tuple[float, float]:
        return self.squares[0] * self.square_mm, self.squares[1] * self.square_mm

    def board_corners(self) -> np.ndarray:
        """(C, 3) float: one board's inner corners in its own frame (OpenCV's order, mm)."""
        return np.asarray(self.board(0).getChessboardCorners(), float).reshape(-1, 3)

    def object_points(self) -> np.ndarray:
        """(B * C, 3) float: every corner in the target's body frame, mm. Row
        ``b * C + c`` is board ``b``'s corner ``c`` (:meth:`corner_ids`)."""
        local = self.board_corners()
        out = [local @ T[:3, :3].T + T[:3, 3] for T in self.faces]
        return np.concatenate(out, axis=0)

    def corner_ids(self, board: int, local_ids: np.ndarray) -> np.ndarray:
        """Global corner ids (rows of :meth:`object_points`) of board ``board``'s local ids."""
        return board * self.corners_per_board + np.asarray(local_ids, int).ravel()

    def board_normals(self) -> np.ndarray:
        """(B, 3) float: each board's outward normal (the side its print faces), body frame."""
        return -self.faces[:, :3, 2]

    # -- OpenCV objects ------------------------------------------------------------------------
    def cv_dictionary(self) -> Any:
        import cv2

        key = "dictionary"
        if key not in self._cache:
            self._cache[key] = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return self._cache[key]

    def board(self, b: int) -> Any:
        """OpenCV's ``CharucoBoard`` of board ``b`` (its marker ids offset by ``b`` boards)."""
        import cv2

        key = f"board{b}"
        if key not in self._cache:
            m = self.markers_per_board
            ids = np.arange(b * m, (b + 1) * m, dtype=np.int32)
            self._cache[key] = cv2.aruco.CharucoBoard(tuple(self.squares), float(self.square_mm),
                                                      float(self.marker_mm), self.cv_dictionary(), ids)
        return self._cache[key]

    def board_image(self, px_per_mm: float, b: int = 0) -> np.ndarray:
        """(H, W) uint8: board ``b`` printed at ``px_per_mm`` (white 255, black 0), its
        pixel ``(i, j)`` covering board coordinates ``[j, j+1) x [i, i+1)`` / px_per_mm."""
        w, h = self.board_size_mm
        size = (int(round(w * px_per_mm)), int(round(h * px_per_mm)))
        return np.asarray(self.board(b).generateImage(size, marginSize=0, borderBits=1), np.uint8)

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {"kind": self.kind, "dictionary": self.dictionary, "squares": list(self.squares),
                             "square_mm": self.square_mm, "marker_mm": self.marker_mm}
        if self.side_mm is not None:
            d["side_mm"] = self.side_mm
        return d


def _cube_faces(board_w: float, board_h: float, side: float) -> np.ndarray:
    faces = []
    for n, x in _CUBE_FACES:
        n_ = np.asarray(n)
        z = -n_  # the board's z points into the cube: its printed side faces out
        x_ = np.asarray(x)
        y = np.cross(z, x_)
        R = np.stack([x_, y, z], axis=1)
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = 0.5 * side * n_ - R @ np.array([board_w / 2.0, board_h / 2.0, 0.0])
        faces.append(T)
    return np.stack(faces)


def parse_target(data: Any, label: str = "target") -> Target:
    """Validate a target table (the TOML's ``[target]``) and build the :class:`Target`.

    Raises
    ------
    RecipeError
        One line naming ``label`` and the key that is missing, unknown or out of range.
    """
    import cv2

    if not isinstance(data, dict) or "target" not in data or not isinstance(data["target"], dict):
        raise RecipeError(f"{label}: expected a [target] table")
    extra = sorted(set(data) - {"target"})
    if extra:
        raise RecipeError(f"{label}: unknown table or key {extra[0]!r} (expected only [target])")
    t = data["target"]
    kind = t.get("kind")
    if kind not in KINDS:
        raise RecipeError(f"{label}: target.kind must be one of {', '.join(map(repr, KINDS))}, not {kind!r}")
    required, optional = KINDS[kind]
    for key in t:
        if key != "kind" and key not in required and key not in optional:
            raise RecipeError(f"{label}: unknown key target.{key} for kind {kind!r} (expected {', '.join(required + optional)})")
    for key in required:
        if key not in t:
            raise RecipeError(f"{label}: missing key target.{key}")
    name = t["dictionary"]
    if not (isinstance(name, str) and name.startswith("DICT_") and isinstance(getattr(cv2.aruco, name, None), int)):
        raise RecipeError(f"{label}: target.dictionary {name!r} is not an OpenCV predefined dictionary (e.g. 'DICT_5X5_1000')")
    sq = t["squares"]
    if not (isinstance(sq, list) and len(sq) == 2 and all(isinstance(v, int) and not isinstance(v, bool) and 3 <= v <= 100 for v in sq)):
        raise RecipeError(f"{label}: target.squares must be [X, Y], two whole numbers 3..100")

    def positive(key: str) -> float:
        v = t[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not 0.01 <= v <= 10000:
            raise RecipeError(f"{label}: target.{key} must be a number of mm in 0.01..10000, not {v!r}")
        return float(v)

    square, marker = positive("square_mm"), positive("marker_mm")
    if marker >= square:
        raise RecipeError(f"{label}: target.marker_mm ({marker:g}) must be smaller than target.square_mm ({square:g})")
    w, h = sq[0] * square, sq[1] * square
    side = None
    if kind == "charuco":
        faces = np.eye(4)[None]
    else:
        side = positive("side_mm")
        if side < max(w, h):
            raise RecipeError(f"{label}: target.side_mm ({side:g}) is smaller than the board ({w:g} x {h:g} mm)")
        faces = _cube_faces(w, h, side)
    target = Target(kind=kind, dictionary=name, squares=(sq[0], sq[1]), square_mm=square, marker_mm=marker,
                    faces=faces, source=label, side_mm=side)
    dict_size = int(target.cv_dictionary().bytesList.shape[0])
    need = target.markers_per_board * target.n_boards
    if need > dict_size:
        raise RecipeError(f"{label}: the target needs {need} markers but {name} has {dict_size}")
    return target


def load_target(path: str | Path) -> Target:
    """Read and validate a target TOML file (one line naming the file and key on error)."""
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise RecipeError(f"{p}: no such target file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise RecipeError(f"{p}: cannot read the target file ({e.__class__.__name__})") from None
    except tomllib.TOMLDecodeError as e:
        raise RecipeError(f"{p}: not valid TOML ({e})") from None
    return parse_target(data, str(p))
