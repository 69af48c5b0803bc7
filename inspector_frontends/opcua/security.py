"""Who may connect, read and write: certificates, the user, and the permission rules.

* ``inspector serve --make-cert DIR`` (:func:`make_pki`): a self-signed server certificate
  and key, a client certificate and key for the PLC (or the example client), and
  ``DIR/trusted/`` holding the client certificate: the server accepts a secure channel only
  from a client whose certificate is in ``trusted/`` (BadCertificateUntrusted otherwise).
  Copy a real PLC's certificate there to trust it.
* Users (:class:`UserManager`): anonymous clients may connect; the one configured user with
  the right password is a *writer*; a wrong user or password is refused
  (BadUserAccessDenied) when the session is activated.
* Rules (:class:`Rules`): a writer may read, subscribe, write and call; an anonymous client
  may read and subscribe, and write or call only with ``anonymous_write = true``; nobody may
  add or delete nodes. The inputs are the only writable variables (AccessLevel).

Imports asyncua and cryptography: only :mod:`inspector_frontends.opcua.server` (through
:mod:`inspector_frontends.opcua.address_space`) and the ``serve`` command import this module.
"""

from __future__ import annotations

import os
import socket
import sys
from pathlib import Path
from typing import Any

from asyncua import ua
from asyncua.crypto.permission_rules import SimpleRoleRuleset, User, UserRole
from asyncua.server.user_managers import UserManager as AsyncuaUserManager

from inspector.errors import RecipeError
from inspector_frontends.opcua.config import CLIENT_CERT, CLIENT_KEY, SERVER_CERT, SERVER_KEY, TRUSTED, Credentials

__all__ = ["SERVER_URI", "CLIENT_URI", "make_pki", "make_certificate", "UserManager", "Rules", "validator",
           "check_logins_off_the_loop"]

#: The server's application URI (in its certificate's subject alternative names).
SERVER_URI = "urn:inspector-bcps:opcua:server"
#: The example client's (the PLC's) application URI, in the client certificate made with it.
CLIENT_URI = "urn:inspector-bcps:opcua:plc"

_WRITE = {ua.NodeId(ua.Int32(ua.ObjectIds.WriteRequest_Encoding_DefaultBinary)),
          ua.NodeId(ua.Int32(ua.ObjectIds.CallRequest_Encoding_DefaultBinary))}


def make_certificate(cert_file: Path, key_file: Path, *, uri: str, name: str, server: bool,
                     hosts: tuple[str, ...] = (), days: int = 3650) -> None:
    """A self-signed application certificate (DER) and its RSA 2048 key (PEM, mode 0600)
    for ``uri``; ``hosts``: DNS names or IP addresses it is valid for (a server's)."""
    import ipaddress

    from asyncua.crypto.cert_gen import dump_private_key_as_pem, generate_private_key, generate_self_signed_app_certificate
    from cryptography import x509
    from cryptography.hazmat.primitives.serialization import Encoding
    from cryptography.x509.oid import ExtendedKeyUsageOID

    key = generate_private_key()
    alt: list[x509.GeneralName] = [x509.UniformResourceIdentifier(uri)]
    for h in hosts:
        try:
            alt.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            alt.append(x509.DNSName(h))
    use = [ExtendedKeyUsageOID.SERVER_AUTH if server else ExtendedKeyUsageOID.CLIENT_AUTH]
    cert = generate_self_signed_app_certificate(key, name, {"organizationName": "Inspector"}, alt, use, days=days)
    fd = os.open(key_file, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(dump_private_key_as_pem(key))
    with open(cert_file, "xb") as f:
        f.write(cert.public_bytes(Encoding.DER))


def make_pki(folder: str | os.PathLike[str], hosts: tuple[str, ...] = ()) -> list[Path]:
    """``folder`` with a server certificate and key, a client (PLC) certificate and key, and
    ``trusted/`` holding the client certificate; the files written. RecipeError, writing
    nothing, when one of them exists already (a certificate is never replaced silently)."""
    root = Path(folder)
    files = [root / SERVER_CERT, root / SERVER_KEY, root / CLIENT_CERT, root / CLIENT_KEY, root / TRUSTED / CLIENT_CERT]
    taken = [f for f in files if f.exists()]
    if taken:
        raise RecipeError(f"--make-cert {root}: {taken[0]} exists already (remove it to make new certificates)")
    (root / TRUSTED).mkdir(parents=True, exist_ok=True)
    names = tuple(dict.fromkeys((*hosts, socket.gethostname(), "localhost", "127.0.0.1")))
    make_certificate(root / SERVER_CERT, root / SERVER_KEY, uri=SERVER_URI, name="Inspector OPC UA server", server=True,
                     hosts=names)
    make_certificate(root / CLIENT_CERT, root / CLIENT_KEY, uri=CLIENT_URI, name="Inspector PLC client", server=False,
                     hosts=(socket.gethostname(),))  # for the example client on this machine
    (root / TRUSTED / CLIENT_CERT).write_bytes((root / CLIENT_CERT).read_bytes())
    return files


class LoginThrottle:
    """Failed logins slowed, per user name and for everyone together.

    After :attr:`free` failures of a user name, every further attempt with that name within a
    back-off is refused at once, without checking the password: the back-off starts at
    :attr:`first_s` and doubles with each failure up to :attr:`most_s`; a success clears the
    name's record. All names together have the same rule with :attr:`free_all` failures (a
    guesser trying many names). So a guessing client gets a handful of checks a minute instead
    of 48 in 6.4 s, and the PBKDF2 check (about 0.1 s, in a worker thread:
    :func:`check_logins_off_the_loop`) runs at most once per back-off.
    """

    free = 3
    free_all = 10
    first_s = 1.0
    most_s = 60.0

    def __init__(self, clock: Any = None) -> None:
        import time

        self._clock = clock or time.monotonic
        self._failures: dict[str, int] = {}
        self._until: dict[str, float] = {}

    def _key(self, user: str | None) -> str:
        return f"user:{user or ''}"

    def blocked_s(self, user: str | None) -> float:
        """Seconds the next attempt of ``user`` must still wait (0: it may be checked)."""
        now = self._clock()
        return max(0.0, max(self._until.get(k, 0.0) for k in (self._key(user), "*")) - now)

    def failed(self, user: str | None) -> None:
        now = self._clock()
        for key, free in ((self._key(user), self.free), ("*", self.free_all)):
            n = self._failures.get(key, 0) + 1
            self._failures[key] = n
            if n >= free:
                self._until[key] = now + min(self.most_s, self.first_s * 2.0 ** (n - free))

    def succeeded(self, user: str | None) -> None:
        self._failures.pop(self._key(user), None)
        self._until.pop(self._key(user), None)


def _login_key(username: str | None, password: Any) -> bytes:
    """A digest of (user, password): what the verdicts of password checks are kept under."""
    import hashlib

    pw = password.encode("utf-8") if isinstance(password, str) else bytes(password or b"")
    return hashlib.sha256((username or "").encode("utf-8") + b"\0" + pw).digest()


class UserManager(AsyncuaUserManager):
    """asyncua's user manager: anonymous, or the configured user with the right password;
    failed logins slowed (:class:`LoginThrottle`).

    The PBKDF2 check (about 0.1 s) never runs on the server's event loop: asyncua asks
    :meth:`get_user` synchronously, from the loop, so :func:`check_logins_off_the_loop` makes
    the server call :meth:`precheck` first, which runs the check in a worker thread (one at a
    time, the throttle asked before each) and keeps its verdict; :meth:`get_user` then only
    reads it. Reads, subscriptions and the PLC's triggers go on while a password is checked.
    """

    def __init__(self, creds: Credentials | None, log: Any = None, throttle: LoginThrottle | None = None) -> None:
        self._creds = creds
        self._log = log
        self._ok: set[bytes] = set()  # digests of accepted (user, password): PBKDF2 once per password
        #: Verdicts of checks made off the loop by :meth:`precheck`, each read once by get_user.
        self._checked: dict[bytes, bool] = {}
        self._one_check: Any = None  # an asyncio.Lock, made on the loop: one check at a time
        self.throttle = throttle or LoginThrottle()

    async def precheck(self, username: str | None, password: Any) -> None:
        """Check ``password`` in a worker thread and keep the verdict for :meth:`get_user`
        (called on the event loop before the session is activated). Nothing is checked while
        the throttle holds the name back, or for a password accepted before."""
        import asyncio

        if self._creds is None or username is None or password is None:
            return
        if self._one_check is None:
            self._one_check = asyncio.Lock()
        async with self._one_check:  # parallel guesses wait here, then meet the throttle
            key = _login_key(username, password)
            if key in self._ok or key in self._checked or self.throttle.blocked_s(username) > 0:
                return
            if len(self._checked) > 64:  # verdicts of logins whose connection went away
                self._checked.clear()
            self._checked[key] = await asyncio.to_thread(self._creds.check, username, password)

    def get_user(self, iserver: Any, username: str | None = None, password: Any = None, certificate: Any = None) -> User | None:
        if username is None and password is None:
            return User(role=UserRole.Anonymous)
        key = _login_key(username, password)
        verdict = self._checked.pop(key, None)  # read once, whatever happens next
        wait = self.throttle.blocked_s(username)
        if wait > 0:
            if self._log is not None:
                self._log(f"login refused: user {username!r} (too many failed logins: wait {wait:.0f} s)")
            return None
        if self._creds is not None and key not in self._ok and verdict is None:
            # Not checked ahead (a login the server's hook did not see): checked here, on the loop.
            verdict = self._creds.check(username, password)
        if self._creds is not None and (key in self._ok or verdict):
            self._ok.add(key)
            self.throttle.succeeded(username)
            return User(role=UserRole.User, name=username)
        self.throttle.failed(username)
        if self._log is not None:
            self._log(f"login refused: user {username!r} (wrong user or password)")
        return None  # BadUserAccessDenied


_PRECHECK = "_inspector_precheck"
#: Marks asyncua's request handler once wrapped (an attribute of the wrapper function).
_WRAPPED = "_inspector_wrapped"


def check_logins_off_the_loop(iserver: Any, users: UserManager) -> None:
    """Make the asyncua server of ``iserver`` check passwords in a worker thread.

    asyncua handles an ActivateSession request synchronously on the event loop, and calls
    the user manager from there: a PBKDF2 check (0.1 s; a guesser's stream of them) held
    every other client's reads for as long. asyncua offers no asynchronous user manager, so
    the request handler of its message processor is wrapped (once per process; for the
    servers marked here only, every other server is left as it was): before an
    ActivateSession request carrying a user name is handled, its token is read from a copy of
    the message and :meth:`UserManager.precheck` awaited, so the synchronous handling that
    follows finds the verdict ready. Anything unexpected in that look-ahead is ignored: the
    request is then handled as before (checked on the loop), never refused for it.
    """
    from asyncua.server import uaprocessor

    setattr(iserver, _PRECHECK, users.precheck)
    cls = uaprocessor.UaProcessor
    if getattr(cls.process_message, _WRAPPED, False):
        return
    original = cls.process_message

    async def process_message(self: Any, seqhdr: Any, body: Any) -> Any:
        precheck = getattr(self.iserver, _PRECHECK, None)
        if precheck is not None and self.session is not None:
            try:
                await _look_ahead(self, body, precheck)
            except Exception:  # noqa: BLE001 - the request is handled as usual, its password checked there
                pass
        return await original(self, seqhdr, body)

    setattr(process_message, _WRAPPED, True)
    cls.process_message = process_message  # type: ignore[method-assign]


async def _look_ahead(processor: Any, body: Any, precheck: Any) -> None:
    """If ``body`` is an ActivateSession request with a user name token, await ``precheck``
    of its user and (decrypted) password. ``body`` is read through a copy: it is left as it was."""
    import asyncio

    from asyncua.ua.ua_binary import nodeid_from_binary, struct_from_binary

    buf = body.copy()
    if nodeid_from_binary(buf) != ua.NodeId(ua.Int32(ua.ObjectIds.ActivateSessionRequest_Encoding_DefaultBinary)):
        return
    struct_from_binary(ua.RequestHeader, buf)
    params = struct_from_binary(ua.ActivateSessionParameters, buf)
    token = params.UserIdentityToken
    if not isinstance(token, ua.UserNameIdentityToken):
        return
    # The RSA decryption is the same asyncua does next (a millisecond): off the loop too.
    username, password = await asyncio.to_thread(processor.iserver.decrypt_user_token, processor.session, token)
    await precheck(username, password)


class Rules(SimpleRoleRuleset):
    """Writers read, write and call; anonymous clients read (and write with ``anonymous_write``);
    no one changes the address space."""

    def __init__(self, anonymous_write: bool) -> None:
        super().__init__()
        user = set(self._permission_dict[UserRole.User])
        self._permission_dict[UserRole.Admin] = user
        self._permission_dict[UserRole.Anonymous] = user if anonymous_write else user - _WRITE


async def validator(trusted: Path) -> Any:
    """The client-certificate check: time range, application URI, key usage, and the
    certificate itself in ``trusted`` (BadCertificateUntrusted otherwise)."""
    from asyncua.crypto.truststore import TrustStore
    from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions

    store = TrustStore([trusted], [])
    await store.load()
    return CertificateValidator(CertificateValidatorOptions.TRUSTED_VALIDATION | CertificateValidatorOptions.PEER_CLIENT,
                                store)


def quiet_library_logs() -> None:
    """asyncua logs every refused request as an error with a traceback: the server reports
    refusals itself, in one line. Its loggers show only critical messages unless
    ``INSPECTOR_OPCUA_DEBUG`` is set."""
    import logging

    if os.environ.get("INSPECTOR_OPCUA_DEBUG"):
        logging.basicConfig(stream=sys.stderr, level=logging.DEBUG)
        return
    for name in ("asyncua", "asyncuagds"):  # asyncuagds: the trust store's "not trusted" traceback
        logging.getLogger(name).setLevel(logging.CRITICAL)
