"""``inspector serve``: the OPC UA server a PLC talks to.

    inspector serve RECIPE --opcua opc.tcp://HOST:PORT [--out OUTDIR] [--config CELL.toml]
                    [--pki DIR] [--security sign-encrypt|both|none] [--recipes DIR]
    inspector serve --make-cert DIR [--host NAME ...]   # server + PLC certificates, DIR/trusted/
    inspector serve --hash-password                      # a password_hash for the [server] table

Results go to ``--out`` (default ``out/serve``) as ``inspector run`` writes them: a result
folder per part, named after its PartId, and a row of ``OUTDIR/history.sqlite``
(``inspector history OUTDIR``). The server runs until Ctrl-C (the part in progress is
aborted). Exit status: 0 stopped, 2 invalid command, recipe or settings, 3 the server could
not start (the port is taken).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from inspector.errors import RecipeError

__all__ = ["add_parser", "run"]


def add_parser(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "serve", help="an OPC UA server a PLC triggers: PartId, Trigger -> Verdict, ResultCounter (see docs/opcua.md)",
        description="Serve RECIPE over OPC UA: each trigger from the PLC acquires and inspects one part with the "
                    "recipe's driver; results and history rows go to OUTDIR as with `inspector run`.")
    p.add_argument("recipe", nargs="?", metavar="RECIPE", help="the recipe served first")
    p.add_argument("--opcua", metavar="URL", help="endpoint to listen on, opc.tcp://HOST:PORT (or endpoint in --config)")
    p.add_argument("--out", default="out/serve", metavar="OUTDIR", help="result folder (default out/serve)")
    p.add_argument("--config", metavar="TOML", help="server settings: a [server] table (endpoint, security, pki, user, "
                                                      "password_hash, anonymous_write, recipes)")
    p.add_argument("--pki", metavar="DIR", help="certificates made by --make-cert (server certificate, key, trusted/)")
    p.add_argument("--security", choices=("sign-encrypt", "both", "none"),
                   help="endpoints: Basic256Sha256 sign-and-encrypt (default), that and an unsecured one, or only an "
                        "unsecured one (no password then: read-only unless anonymous_write)")
    p.add_argument("--recipes", metavar="DIR", help="folder of the recipes RecipeName may name (default: RECIPE's folder)")
    p.add_argument("--make-cert", metavar="DIR", help="write a self-signed server certificate and key, a PLC client "
                                                      "certificate and key, and DIR/trusted/ (the clients accepted); "
                                                      "then exit")
    p.add_argument("--host", action="append", default=[], metavar="NAME",
                   help="with --make-cert: a host name or IP address the server certificate is for (repeatable)")
    p.add_argument("--hash-password", action="store_true",
                   help="read a password (twice from a terminal, or one line of standard input) and print its "
                        "password_hash; then exit")
    p.add_argument("-q", "--quiet", action="store_true", help="no line per result")


def _make_cert(args: argparse.Namespace) -> int:
    try:
        from inspector_frontends.opcua.security import make_pki
    except ImportError as e:
        raise RecipeError(_missing(e)) from None
    files = make_pki(args.make_cert, tuple(args.host))
    for f in files:
        print(f"wrote {f}")
    print(f"serve with --pki {args.make_cert}; a client uses {files[2].name} and {files[3].name} "
          f"(copy another client's certificate into {files[4].parent} to trust it)")
    return 0


def _hash_password() -> int:
    import getpass

    from inspector_frontends.opcua.config import hash_password

    if sys.stdin.isatty():
        pw = getpass.getpass("password: ")
        if getpass.getpass("again: ") != pw:
            raise RecipeError("the two passwords differ")
    else:
        pw = sys.stdin.readline().rstrip("\r\n")
    if len(pw) < 8:
        raise RecipeError("a password needs at least 8 characters")
    print(hash_password(pw))
    return 0


def _missing(e: ImportError) -> str:
    return (f"inspector serve needs asyncua ({e}): pip install 'inspector-bcps[opcua]' "
            "(make installs it from requirements.lock)")


def run(args: argparse.Namespace) -> int:
    """``inspector serve``; see the module docstring."""
    if args.make_cert:
        return _make_cert(args)
    if args.hash_password:
        return _hash_password()
    if not args.recipe:
        raise RecipeError("serve: give a RECIPE (or --make-cert DIR, or --hash-password)")
    from inspector_frontends.opcua.config import load_settings, with_options

    settings = with_options(load_settings(args.config), endpoint=args.opcua, pki=args.pki, security=args.security,
                            recipes=args.recipes)
    try:
        import asyncio

        from inspector_frontends.opcua.server import InspectorServer
    except ImportError as e:
        raise RecipeError(_missing(e)) from None
    say = (lambda line: None) if args.quiet else (lambda line: print(line, flush=True))

    def log(line: str) -> None:  # refusals and problems on stderr, even with -q; results on stdout
        if line.startswith(("refused", "login refused", "error", "warning")):
            print(f"inspector: {line}", file=sys.stderr, flush=True)
        else:
            say(line)

    out = Path(args.out)
    server = InspectorServer(args.recipe, out, settings, pm=getattr(args, "plugin_manager", None), log=log)

    async def main() -> None:
        import signal

        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                loop.add_signal_handler(sig, stop.set)
            except (NotImplementedError, RuntimeError):  # not the main thread, or not POSIX
                pass
        await server.start()
        writer = server.writer
        who = f"user {writer!r}" if writer else "nobody"
        if settings.anonymous_write:
            who += " and anonymous clients"
        say(f"Inspector OPC UA server on {settings.endpoint} (namespace {server.namespace_index}: "
            f"urn:inspector-bcps:opcua), security {settings.security}; writes: {who}")
        if server.warm_up_s is not None:
            say(f"warmed up: one simulated inspection in {server.warm_up_s:.1f} s (the kernels are loaded)")
        say(f"recipe {server.recipe_name} ({', '.join(server.recipe_names())} in {server.recipes_dir}); "
            f"results in {out.resolve()} (inspector history {out}); Ctrl-C stops")
        try:
            await stop.wait()
        finally:
            await server.stop()

    asyncio.run(main())
    say(f"stopped after {server.counter} results")
    return 0
