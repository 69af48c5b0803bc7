"""Production recipes: an engineer's approval, stored with the recipe's content hash, and the
check that ``run``, ``serve`` and the GUI make in the operator role.

``inspector recipe approve RECIPE`` (the engineer password asked) stores an approval in
``approvals.json`` beside ``roles.json`` (:func:`inspector.roles_password.config_dir`; mode 0600, written
atomically) and a ``recipe-approve`` row in the station's audit trail. An approval is of the
recipe's *content*: :func:`recipe_digest`, the SHA-256 of the recipe file's bytes together with
its reference mesh (the mesh file's bytes, or the ``builtin:NAME``), so a recipe whose file or
mesh changed after the approval is no longer approved, wherever it lies.

The station's mode (:func:`inspector.roles.production_mode`, ``inspector roles production on``)
decides whether the check applies: on a production station the operator role (``run`` and
``serve``, which have no login, and the GUI until an engineer logs in) runs only approved
recipes; :func:`approval_problem` says why a recipe may not run (one line, None when it may), and
:func:`require_approved` is what ``inspector run`` calls (``--unapproved`` runs it anyway, with a
warning and an ``unapproved-run`` row in the run's audit). Off (the default), nothing is checked.
Whoever can write ``approvals.json`` can approve: the protection is the operating system's
account separation, as for ``roles.json``; every approval is in the hash-chained station audit.
"""

from __future__ import annotations

import hashlib
import json
import os
import sqlite3
import sys
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from inspector import roles
from inspector.errors import RecipeError
from inspector.roles_audit import record_audit, record_station_audit
from inspector.roles_password import config_dir as station_config_dir
from inspector.roles_password import read_config, roles_file, write_config

if TYPE_CHECKING:
    from inspector.recipe import Recipe

__all__ = ["APPROVALS_FILE", "Approval", "approvals_file", "recipe_digest", "approve", "find_approval",
           "approval_problem", "require_approved", "add_approve_parser", "run_approve"]

APPROVALS_FILE = "approvals.json"


def approvals_file(config_dir: str | os.PathLike[str] | None = None) -> Path:
    """``approvals.json`` in the configuration folder (:func:`inspector.roles_password.config_dir`)."""
    return station_config_dir(config_dir) / APPROVALS_FILE


@dataclass(frozen=True)
class Approval:
    """One approval: the recipe's content hash and who approved it when."""

    digest: str
    recipe: str
    name: str
    recipe_sha256: str
    reference: str | None
    approved_by: str | None
    approved_at: str


def _sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _reference_id(recipe: Recipe) -> str | None:
    """What the recipe's reference is, as hashed: ``builtin:NAME``, ``sha256:HEX`` of the mesh
    file, None without one."""
    ref = recipe.reference
    if ref is None:
        return None
    if str(ref).startswith("builtin:"):
        return str(ref)
    try:
        return f"sha256:{_sha256_file(Path(ref))}"
    except OSError as e:
        raise RecipeError(f"{ref}: the reference mesh cannot be read ({e.strerror or e})") from None


def recipe_digest(recipe: Recipe) -> tuple[str, str, str | None]:
    """(the approval digest, the recipe file's SHA-256, the reference's id) of a loaded recipe.

    The digest is the SHA-256 (hex) of ``{"recipe": FILE_SHA256, "reference": REFERENCE}`` as
    canonical JSON; ``REFERENCE`` is ``builtin:NAME``, ``sha256:HEX`` of the mesh file, or null.

    Raises
    ------
    RecipeError
        A recipe not loaded from a file, or whose reference mesh cannot be read.
    """
    if recipe.sha256 is None or recipe.path is None:
        raise RecipeError(f"recipe {recipe.name!r}: not read from a file, so it cannot be approved")
    ref = _reference_id(recipe)
    doc = json.dumps({"recipe": recipe.sha256, "reference": ref}, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(doc.encode("utf-8")).hexdigest(), recipe.sha256, ref


def _read(config_dir: str | os.PathLike[str] | None) -> list[dict[str, Any]]:
    path = approvals_file(config_dir)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return []
    except (OSError, ValueError) as e:
        raise RecipeError(f"{path}: cannot be read ({e}); approve the recipes again") from None
    rows = data.get("approvals") if isinstance(data, dict) else None
    return [r for r in rows if isinstance(r, dict)] if isinstance(rows, list) else []


def _approval(row: dict[str, Any]) -> Approval | None:
    """An entry of ``approvals.json`` read (None: not one this version wrote)."""
    text = {k: row.get(k) for k in ("digest", "recipe", "name", "recipe_sha256", "approved_at")}
    if not all(isinstance(v, str) for v in text.values()):
        return None
    ref, who = row.get("reference"), row.get("approved_by")
    return Approval(str(text["digest"]), str(text["recipe"]), str(text["name"]), str(text["recipe_sha256"]),
                    ref if isinstance(ref, str) else None, who if isinstance(who, str) else None,
                    str(text["approved_at"]))


def find_approval(recipe: Recipe, *, config_dir: str | os.PathLike[str] | None = None) -> tuple[Approval | None, Approval | None]:
    """(the approval of this recipe's content, or None; the latest approval of a recipe at the
    same path, or None: what a changed recipe had)."""
    digest, _, _ = recipe_digest(recipe)
    here = str(Path(recipe.path).resolve()) if recipe.path is not None else None
    same: Approval | None = None
    at_path: Approval | None = None
    for row in _read(config_dir):
        a = _approval(row)
        if a is None:
            continue
        if a.digest == digest:
            same = a
        if a.recipe == here:
            at_path = a
    return same, at_path


def approve(recipe: Recipe, who: str | None, *, config_dir: str | os.PathLike[str] | None = None) -> Approval:
    """Store an approval of ``recipe``'s content (an earlier one of the same path is replaced)
    and audit it (``recipe-approve`` in the station's audit, the digest as ``hash_after``). The
    caller checks the engineer password (:func:`inspector.roles.check_password`).

    Raises
    ------
    RecipeError
        The recipe cannot be hashed; OSError: the file cannot be written.
    """
    digest, file_sha, ref = recipe_digest(recipe)
    assert recipe.path is not None
    here = str(Path(recipe.path).resolve())
    entry = Approval(digest, here, recipe.name, file_sha, ref, who,
                     datetime.now(UTC).isoformat(timespec="milliseconds"))
    rows = [r for r in _read(config_dir) if r.get("recipe") != here]
    rows.append(dict(entry.__dict__))
    write_config(approvals_file(config_dir), {"version": 1, "approvals": rows})
    record_station_audit("recipe-approve", who=who, role_before=roles.ENGINEER, role_after=roles.ENGINEER,
                         recipe=here, digest=digest, config_dir=config_dir)
    return entry


def approval_problem(recipe: Recipe, *, role: str = roles.OPERATOR,
                     config_dir: str | os.PathLike[str] | None = None) -> str | None:
    """Why ``recipe`` may not run in ``role`` on this station (one line), None when it may.

    The check the OPC UA server (always the operator role) and the GUI (its
    :class:`~inspector.roles.RoleSession`'s role) make before a run: off production mode
    (:func:`inspector.roles.production_mode`) or as engineer, every valid recipe runs; in
    production mode as operator, only a recipe whose content (file and reference mesh) an
    engineer approved. A ``roles.json`` that cannot be read refuses (fails closed).
    """
    if role == roles.ENGINEER:
        return None
    path = roles_file(config_dir)
    try:
        production = read_config(path).get("production") is True
    except (OSError, ValueError) as e:  # fail closed: whether this is a production station is unknown
        return (f"{path}: cannot be read ({e}), so whether this station is in production mode is unknown: the "
                "operator role runs no recipe until an engineer repairs it (inspector roles set-password --reset, "
                "then inspector roles production on|off)")
    if not production:
        return None
    try:
        same, at_path = find_approval(recipe, config_dir=config_dir)
    except RecipeError as e:
        return f"production mode: {e}"
    if same is not None:
        return None
    where = recipe.path or recipe.name
    if at_path is not None:
        what = "its file" if at_path.recipe_sha256 != recipe.sha256 else "its reference mesh"
        return (f"{where}: changed since it was approved ({what} differs from the one {at_path.approved_by or '?'} "
                f"approved at {at_path.approved_at[:19]}); production mode runs only approved recipes: an engineer "
                f"approves it again with `inspector recipe approve`")
    return (f"{where}: not approved; production mode runs only approved recipes: an engineer approves it with "
            f"`inspector recipe approve`")


def require_approved(recipe: Recipe, *, outdir: str | os.PathLike[str] | None, unapproved: bool = False,
                     config_dir: str | os.PathLike[str] | None = None) -> None:
    """What ``inspector run`` does before inspecting, in the operator role: nothing when the
    recipe may run (:func:`approval_problem`); else a RecipeError (one line, exit 2), or with
    ``unapproved`` a warning line and an ``unapproved-run`` row in ``outdir``'s audit."""
    problem = approval_problem(recipe, role=roles.OPERATOR, config_dir=config_dir)
    if problem is None:
        return
    if not unapproved:
        raise RecipeError(f"{problem} (or --unapproved runs it anyway, recorded in the audit)")
    print(f"inspector: warning: {problem.split('; production mode')[0]}: run anyway (--unapproved), recorded in the audit",
          file=sys.stderr, flush=True)
    if outdir is not None:
        try:
            record_audit(outdir, "unapproved-run", who=roles.login_name(), role_before=roles.OPERATOR,
                         role_after=roles.OPERATOR, recipe_after=recipe.path)
        except (OSError, sqlite3.Error) as e:  # the audit never stops the run
            print(f"inspector: warning: {outdir}: audit row 'unapproved-run' not recorded ({e})", file=sys.stderr)


# --------------------------------------------------------------------------- inspector recipe approve


def add_approve_parser(recipe_subparsers: Any) -> None:
    """``inspector recipe approve RECIPE [--reference MESH] [--who NAME]``."""
    ap = recipe_subparsers.add_parser(
        "approve", help="approve a recipe for production (engineer password asked): its content hash (file and "
                        "reference mesh) is stored; in production mode the operator role runs only approved recipes")
    ap.add_argument("recipe")
    ap.add_argument("--reference", metavar="MESH", help="the reference mesh it runs with, when not the recipe's own")
    ap.add_argument("--who", metavar="NAME", help="who approves, for the audit (default: the login name)")


def run_approve(args: Any) -> int:
    """``inspector recipe approve``: 0 approved; 2 an invalid recipe or a wrong password; 3 not written."""
    from inspector.recipe import load_recipe

    recipe = load_recipe(args.recipe, args.plugin_manager, reference=args.reference)  # RecipeError: exit 2
    digest, _, _ = recipe_digest(recipe)
    who = args.who or roles.login_name()
    if not roles.ask_engineer(f"approve {args.recipe}", who):
        return 2
    try:
        entry = approve(recipe, who)
    except OSError as e:
        print(f"inspector: error: {approvals_file()}: cannot write ({e.strerror or e})", file=sys.stderr)
        return 3
    mode = "" if roles.production_mode() else " (production mode is off: `inspector roles production on` enforces it)"
    print(f"approved {entry.recipe}: recipe {entry.name!r}, digest {digest[:16]}, by {who or '?'}{mode}")
    return 0
