"""The engineer's password in the station's ``roles.json`` (part of :mod:`inspector.roles`).

The password is never stored: ``roles.json`` in the configuration folder
(``$INSPECTOR_CONFIG_DIR``, else ``~/.config/inspector``; mode 0600, written atomically)
holds a salted PBKDF2-HMAC-SHA256 hash (:func:`set_password`, :func:`check_password`), and
the station's other settings (production mode, :func:`inspector.roles.production_mode`).
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import secrets
import tempfile
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

__all__ = [
    "MIN_PASSWORD_LENGTH",
    "PBKDF2_ITERATIONS",
    "config_dir",
    "roles_file",
    "read_config",
    "write_config",
    "password_error",
    "set_password",
    "check_password",
    "password_is_set",
    "password_problem",
]

MIN_PASSWORD_LENGTH = 8
#: PBKDF2-HMAC-SHA256 iterations of a new hash (a stored hash keeps its own count).
PBKDF2_ITERATIONS = 600_000
_ALGORITHM = "pbkdf2_sha256"
_ROLES_FILE = "roles.json"


# --------------------------------------------------------------------------- the password


def config_dir(config_dir: str | os.PathLike[str] | None = None) -> Path:
    """The configuration folder: ``config_dir`` if given, else ``$INSPECTOR_CONFIG_DIR``,
    else ``~/.config/inspector``."""
    if config_dir is not None:
        return Path(config_dir)
    env = os.environ.get("INSPECTOR_CONFIG_DIR")
    if env:
        return Path(env).expanduser()
    return Path.home() / ".config" / "inspector"


def roles_file(config_dir_: str | os.PathLike[str] | None = None) -> Path:
    """The ``roles.json`` of :func:`config_dir`."""
    return config_dir(config_dir_) / _ROLES_FILE


def _hash(password: str, salt: bytes, iterations: int) -> bytes:
    return hashlib.pbkdf2_hmac("sha256", password.encode("utf-8"), salt, iterations)


def read_config(path: Path) -> dict[str, Any]:
    """roles.json as a dict ({} when there is none); ValueError/OSError when unreadable."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return {}
    data = json.loads(text)
    if not isinstance(data, dict):
        raise ValueError("expected a JSON object")
    return data


def write_config(path: Path, data: dict[str, Any]) -> None:
    """Write ``data`` as JSON to ``path``: mode 0600, a temporary file renamed over it."""
    path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")  # mode 0600
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump(data, f, indent=1, sort_keys=True)
            f.write("\n")
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o600)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    try:  # the rename itself survives a power cut
        dfd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    except OSError:
        pass


def password_error(password: str) -> str | None:
    """Why ``password`` cannot be the engineer password (one phrase), or None when it can."""
    if not password:
        return "the password is empty"
    if len(password) < MIN_PASSWORD_LENGTH:
        return f"the password is shorter than {MIN_PASSWORD_LENGTH} characters"
    return None


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def set_password(password: str, *, config_dir: str | os.PathLike[str] | None = None) -> Path:
    """Set the engineer password: store its salted PBKDF2-HMAC-SHA256 hash in ``roles.json``.

    Parameters
    ----------
    password : str
        At least :data:`MIN_PASSWORD_LENGTH` characters.
    config_dir : path, optional
        The configuration folder (default :func:`config_dir`).

    Returns
    -------
    Path
        The ``roles.json`` written (mode 0600; other keys it held are kept).

    Raises
    ------
    ValueError
        Empty or too short a password.
    OSError
        The file cannot be written.
    """
    problem = password_error(password)
    if problem:
        raise ValueError(problem)
    path = roles_file(config_dir)
    try:
        data = read_config(path)
    except (OSError, ValueError):
        data = {}  # an unreadable file is replaced: setting the password is how it is repaired
    salt = secrets.token_bytes(16)
    data["version"] = 1
    data["engineer"] = {
        "algorithm": _ALGORITHM,
        "iterations": PBKDF2_ITERATIONS,
        "salt": salt.hex(),
        "hash": _hash(password, salt, PBKDF2_ITERATIONS).hex(),
        "set_at": _now(),
    }
    write_config(path, data)
    return path


def _engineer_record(config_dir_: str | os.PathLike[str] | None) -> dict[str, Any]:
    """The stored hash, checked; ValueError/OSError saying what is wrong."""
    path = roles_file(config_dir_)
    data = read_config(path)
    rec = data.get("engineer")
    if rec is None:
        raise LookupError("no engineer password is set")
    if not isinstance(rec, dict) or rec.get("algorithm") != _ALGORITHM:
        raise ValueError(f"unknown password algorithm (expected {_ALGORITHM})")
    iterations = rec.get("iterations")
    if not isinstance(iterations, int) or isinstance(iterations, bool) or iterations < 1:
        raise ValueError("bad iteration count")
    salt, digest = bytes.fromhex(str(rec.get("salt", ""))), bytes.fromhex(str(rec.get("hash", "")))
    if not salt or len(digest) != 32:
        raise ValueError("bad salt or hash")
    return {"iterations": iterations, "salt": salt, "hash": digest}


def password_problem(*, config_dir: str | os.PathLike[str] | None = None) -> str | None:
    """Why engineer mode cannot be reached (one line, for the GUI), or None when a password
    is set."""
    path = roles_file(config_dir)
    try:
        _engineer_record(config_dir)
    except LookupError:
        return ("engineer mode is locked: no engineer password is set "
                f"(set one with `inspector roles set-password`; it is stored in {path})")
    except (OSError, ValueError) as e:
        return (f"engineer mode is locked: {path} cannot be read ({e}); "
                "set the password again with `inspector roles set-password`")
    return None


def password_is_set(*, config_dir: str | os.PathLike[str] | None = None) -> bool:
    """Whether a usable engineer password is stored (else :func:`password_problem` says why)."""
    return password_problem(config_dir=config_dir) is None


def check_password(password: str, *, config_dir: str | os.PathLike[str] | None = None) -> bool:
    """Whether ``password`` is the engineer password; False when none is set (or the file
    cannot be read: :func:`password_problem`)."""
    try:
        rec = _engineer_record(config_dir)
    except (LookupError, OSError, ValueError):
        return False
    return hmac.compare_digest(_hash(password, rec["salt"], rec["iterations"]), rec["hash"])

