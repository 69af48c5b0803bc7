"""The server's settings: a ``[server]`` table, the command line and the environment.

Why not in the recipe: the recipe loader refuses tables it does not know, and a plugin's
``[plugins.NAME]`` settings would be part of every recipe (defaults included) while these
belong to the cell, not to a part: the endpoint, the certificates and the PLC's credentials.
A recipe is hashed into every result, copied by the GUI's editor into ``OUTDIR/recipes/`` and
switched by the PLC (``RecipeName``); a password hash has no place there. So the settings
live in their own TOML file (``inspector serve RECIPE --config cell.toml``)::

    [server]
    endpoint = "opc.tcp://0.0.0.0:4840"
    security = "sign-encrypt"        # "sign-encrypt" | "both" | "none"
    pki = "pki"                      # made by `inspector serve --make-cert pki`
    user = "plc"
    password_hash = "pbkdf2_sha256$200000$..."   # `inspector serve --hash-password`
    anonymous_write = false
    recipes = "recipes"

validated like a recipe's parameters (:func:`inspector.params.build_params`: unknown key,
type, choice; one line naming the file and the key), relative paths from the file's folder.
Command-line options replace the file's values; the user and the password may also come
from ``INSPECTOR_OPCUA_USER`` and ``INSPECTOR_OPCUA_PASSWORD`` (a plain password, never
printed, never written anywhere).

Nothing here imports asyncua.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import os
import secrets
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal
from urllib.parse import urlsplit

from inspector.cell import load_cell
from inspector.errors import RecipeError
from inspector.params import build_params, param

__all__ = ["ServerSettings", "USER_ENV", "PASSWORD_ENV", "load_settings", "parse_endpoint", "hash_password",
           "verify_password", "Credentials", "credentials", "SERVER_CERT", "SERVER_KEY", "CLIENT_CERT", "CLIENT_KEY",
           "TRUSTED", "pki_files"]

USER_ENV = "INSPECTOR_OPCUA_USER"
PASSWORD_ENV = "INSPECTOR_OPCUA_PASSWORD"

#: Files of a PKI folder (``inspector serve --make-cert DIR``).
SERVER_CERT, SERVER_KEY = "server-cert.der", "server-key.pem"
CLIENT_CERT, CLIENT_KEY = "plc-cert.der", "plc-key.pem"
#: The client certificates the server trusts (DER or PEM), a folder of the PKI folder.
TRUSTED = "trusted"

#: The ``security`` settings: the endpoints a server offers.
Security = Literal["sign-encrypt", "both", "none"]

_HASH = "pbkdf2_sha256"
_ITERATIONS = 200_000


@dataclass(frozen=True)
class ServerSettings:
    """The ``[server]`` table of ``inspector serve --config FILE``."""

    endpoint: str = param("", "opc.tcp://HOST:PORT to listen on (--opcua replaces it)")
    security: Literal["sign-encrypt", "both", "none"] = param(
        "sign-encrypt", "endpoints offered: Basic256Sha256 sign-and-encrypt only; that and an unsecured one (the "
        "password is still encrypted); or only an unsecured one (no password can be used: read-only unless "
        "anonymous_write)")
    pki: Path | None = param(None, "folder made by `inspector serve --make-cert`: server-cert.der, server-key.pem and "
                                   "trusted/ (the client certificates accepted)")
    user: str = param("", "the user allowed to write the inputs and call the methods (else $INSPECTOR_OPCUA_USER)")
    password_hash: str = param("", "that user's password, as `inspector serve --hash-password` prints it "
                                   "(else the plain $INSPECTOR_OPCUA_PASSWORD)")
    anonymous_write: bool = param(False, "clients without a user may write the inputs and call the methods too "
                                         "(off: they only read and subscribe)")
    recipes: Path | None = param(None, "folder of the recipes RecipeName may name (NAME.toml); none: the served "
                                       "recipe's folder")


def load_settings(path: str | os.PathLike[str] | None) -> ServerSettings:
    """The settings of ``path``'s ``[server]`` table (defaults without a file).

    Raises
    ------
    RecipeError
        The file is missing, not TOML, has another table or an invalid value (one line naming
        the file and the key).
    """
    if path is None:
        return ServerSettings()
    p = Path(path)
    table = load_cell(p).get("server", {})  # the file checked whole; [gui] and [shifts] are others'
    settings: ServerSettings = build_params(ServerSettings, table, f"{p.name}: server", p.resolve().parent)
    return settings


def with_options(settings: ServerSettings, *, endpoint: str | None = None, security: Security | None = None,
                 pki: str | os.PathLike[str] | None = None,
                 recipes: str | os.PathLike[str] | None = None) -> ServerSettings:
    """``settings`` with each option that is not None replacing its value (the command line)."""
    if endpoint is None and security is None and pki is None and recipes is None:
        return settings
    return replace(settings, endpoint=settings.endpoint if endpoint is None else endpoint,
                   security=settings.security if security is None else security,
                   pki=settings.pki if pki is None else Path(pki),
                   recipes=settings.recipes if recipes is None else Path(recipes))


def parse_endpoint(url: str) -> tuple[str, int]:
    """``(host, port)`` of ``opc.tcp://HOST:PORT[/path]``; RecipeError in one line otherwise."""
    if not url:
        raise RecipeError("no endpoint: give --opcua opc.tcp://HOST:PORT (or endpoint in the [server] table)")
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError as e:
        raise RecipeError(f"endpoint {url!r}: {e}") from None
    if parts.scheme != "opc.tcp" or not parts.hostname:
        raise RecipeError(f"endpoint {url!r}: expected opc.tcp://HOST:PORT")
    if port is None or not 1 <= port <= 65535:
        raise RecipeError(f"endpoint {url!r}: expected a port between 1 and 65535")
    return parts.hostname, port


def pki_files(pki: Path) -> tuple[Path, Path, Path]:
    """The server certificate, its key and the trusted folder of ``pki``; RecipeError naming
    the first one missing."""
    cert, key, trusted = pki / SERVER_CERT, pki / SERVER_KEY, pki / TRUSTED
    for f in (cert, key):
        if not f.is_file():
            raise RecipeError(f"--pki {pki}: {f.name} not found (make the folder with `inspector serve --make-cert {pki}`)")
    if not trusted.is_dir():
        raise RecipeError(f"--pki {pki}: no {TRUSTED}/ folder of trusted client certificates")
    return cert, key, trusted


# --------------------------------------------------------------------------- passwords
def hash_password(password: str, *, iterations: int = _ITERATIONS) -> str:
    """``pbkdf2_sha256$ITERATIONS$SALT$HASH`` (salt and hash in base64) of ``password``."""
    salt = secrets.token_bytes(16)
    digest = hashlib.pbkdf2_hmac("sha256", password.encode("utf-8"), salt, iterations)
    return f"{_HASH}${iterations}${base64.b64encode(salt).decode()}${base64.b64encode(digest).decode()}"


def _parse_hash(text: str) -> tuple[int, bytes, bytes]:
    try:
        algorithm, iterations, salt, digest = text.split("$")
        if algorithm != _HASH:
            raise ValueError
        n = int(iterations)
        if not 1_000 <= n <= 10_000_000:
            raise ValueError
        return n, base64.b64decode(salt, validate=True), base64.b64decode(digest, validate=True)
    except ValueError:
        raise RecipeError(f"password_hash: expected {_HASH}$ITERATIONS$SALT$HASH as `inspector serve --hash-password` "
                          "prints it") from None


def verify_password(password: str, stored: str) -> bool:
    """Whether ``password`` matches ``stored`` (a :func:`hash_password` text), in constant time."""
    n, salt, digest = _parse_hash(stored)
    return hmac.compare_digest(hashlib.pbkdf2_hmac("sha256", password.encode("utf-8"), salt, n), digest)


@dataclass(frozen=True)
class Credentials:
    """The one user allowed to write; ``check(user, password)``. Its repr shows no secret."""

    user: str
    _plain: str | None = None
    _hash: str | None = None

    def __repr__(self) -> str:
        return f"Credentials(user={self.user!r})"

    def check(self, user: str | None, password: str | bytes | None) -> bool:
        if user is None or password is None:
            return False
        if isinstance(password, bytes):
            try:
                password = password.decode("utf-8")
            except UnicodeDecodeError:
                return False
        same_user = hmac.compare_digest(user.encode("utf-8"), self.user.encode("utf-8"))
        if self._hash is not None:
            ok = verify_password(password, self._hash)
        else:
            ok = hmac.compare_digest(password.encode("utf-8"), (self._plain or "").encode("utf-8"))
        return same_user and ok


def credentials(settings: ServerSettings, env: dict[str, str] | None = None) -> Credentials | None:
    """The writing user of ``settings`` and the environment (None: no user); RecipeError when
    a user has no password or a password has no user."""
    env = dict(os.environ) if env is None else env
    user = settings.user or env.get(USER_ENV, "")
    plain = env.get(PASSWORD_ENV) or None
    if settings.password_hash:
        _parse_hash(settings.password_hash)  # refused now, not at the first login
    if not user:
        if settings.password_hash or plain:
            raise RecipeError(f"a password is set but no user: set user in the [server] table or {USER_ENV}")
        return None
    if not settings.password_hash and not plain:
        raise RecipeError(f"user {user!r} has no password: set {PASSWORD_ENV} or password_hash in the [server] table")
    if settings.password_hash:
        return Credentials(user, _hash=settings.password_hash)
    return Credentials(user, _plain=plain)
