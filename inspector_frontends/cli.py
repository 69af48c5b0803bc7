"""The ``inspector`` command line.

Exit status of ``inspector run`` (CONTRACT): 0 every part passed; 1 at least one part
failed its tolerances; 2 the command or the recipe is invalid (nothing inspected); 3 at
least one capture could not be inspected. Errors are one line on stderr, never a traceback.

The core commands are defined here (``run``, ``plugins``, ``plugin new``, ``recipe check``,
``report``, ``roles``); every other one is registered by a plugin through
``inspector_register_commands`` (as datasette's ``register_commands``), the built-in ones
included: ``simulate`` and ``demo`` (plugin ``sim``), ``capture``, ``import``, ``history``,
``bench``, ``experiment``, ``gui``. So this module imports no driver, no built-in plugin
and no GUI. Global options, before the command: ``--block NAME`` (as
``INSPECTOR_BLOCK_PLUGINS``) and ``--plugin FILE.py`` (a local module loaded as a plugin, for
development; recipes can never load code).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

from inspector import API_VERSION, __version__, report, roles
from inspector.approval import add_approve_parser, require_approved, run_approve
from inspector.errors import InspectorError, PluginError, RecipeError
from inspector.locale import _, choose, using
from inspector.manager import BLOCK_ENV, create_plugin_manager
from inspector.params import describe_params

if TYPE_CHECKING:
    from inspector.manager import PluginManager
    from inspector.recipe import Recipe
    from inspector.reference import Reference

__all__ = ["main", "build_parser", "run_recipe", "CORE_COMMANDS", "EXIT_OK", "EXIT_FAIL", "EXIT_INVALID", "EXIT_ERROR"]

EXIT_OK, EXIT_FAIL, EXIT_INVALID, EXIT_ERROR = 0, 1, 2, 3


def err(msg: str) -> None:
    """Print one error line on stderr: ``inspector: error: MSG``."""
    print(f"inspector: error: {msg}", file=sys.stderr)


_err = err


# -- run -------------------------------------------------------------------------------
def _load(recipe_path: str, reference: str | None,
          pm: PluginManager | None = None) -> tuple[PluginManager, Recipe, Reference | None]:
    """Plugin manager, validated recipe and loaded reference (RecipeError on any problem)."""
    from inspector.session import Session

    s = Session.open(recipe_path, ".", reference=reference, pm=pm)  # the same loading as every run
    return s.pm, s.recipe, s.reference


def _watch_params(args: argparse.Namespace) -> dict[str, Any] | None:
    """The hot-folder driver's parameters from ``--watch``, ``--count``, ``--idle-exit``."""
    if args.watch is None:
        for flag, value in (("--count", args.count), ("--idle-exit", args.idle_exit)):
            if value is not None:
                raise RecipeError(f"{flag}: only with --watch")
        return None
    if args.count is not None and args.count < 1:
        raise RecipeError(f"--count: expected a number >= 1, got {args.count}")
    if args.idle_exit is not None and not args.idle_exit > 0:
        raise RecipeError(f"--idle-exit: expected seconds > 0, got {args.idle_exit}")
    return {"folder": args.watch, "count": args.count or 0, "idle_exit_s": args.idle_exit or 0.0}


def run_recipe(recipe_path: str, captures: Sequence[str] | None, out: str, reference: str | None, quiet: bool,
               watch: dict[str, Any] | None = None, csv: bool = False, pm: PluginManager | None = None,
               cluster: dict[str, Any] | None = None, unapproved: bool = False, dfq: str | None = None,
               qif: str | None = None) -> int:
    """``inspector run``: a :class:`~inspector.session.Session` whose events are printed;
    returns the exit status (CONTRACT). ``pm``: the plugin manager (default: a new one).
    ``cluster``: ``{"scheduler": ADDRESS}`` or ``{"workers": N}``: the captures are inspected on
    a Dask cluster (:mod:`inspector_frontends.distributed`), with the same results and output.
    ``unapproved``: on a production station, run a recipe no engineer approved anyway
    (:func:`inspector.approval.require_approved`: a warning and an audit row)."""
    from inspector.outputs import one_line
    from inspector.session import Inspected, RunStarted, Session, Source, Warned

    session = Session.open(recipe_path, out, reference=reference, csv=csv, pm=pm)
    quality = _quality_files(session, dfq, qif)  # --dfq / --qif (issue 28)

    def show(event: object) -> None:
        if quality is not None and isinstance(event, Inspected):
            quality.add(event.outcome.result)
        # Only the verdicts are kept (the summary counts them): a live driver or a long batch
        # must not hold every result's points in memory (5 MB a capture).
        if isinstance(event, RunStarted) and event.inbox is not None and not quiet:
            print(_("watching {inbox} for capture folders (Ctrl-C to stop); results in {outdir}").format(
                inbox=event.inbox, outdir=event.outdir), flush=True)
        elif isinstance(event, Inspected):
            result = event.outcome.result
            if not quiet:
                of = f"/{event.total}" if event.total else ""
                print(f"[{event.index}{of}] {one_line(result)}", flush=True)
            elif result.verdict == "error":  # no progress lines, but no silent error
                err(f"{result.capture}: {result.error}")
        elif isinstance(event, Warned):
            print(f"inspector: warning: {event.capture}: {event.text}", file=sys.stderr, flush=True)

    session.subscribe(show)
    try:
        require_approved(session.recipe, outdir=out, unapproved=unapproved)  # the operator role: RecipeError, exit 2
        if cluster is None:
            summary = session.run(Source(captures=tuple(captures or ()), watch=watch))
        else:
            from inspector_frontends.distributed import run_on_cluster

            summary = run_on_cluster(session, captures or (), progress=not quiet, **cluster)
    finally:
        session.close()
        if quality is not None:
            for path in quality.write():
                if not quiet:
                    print(f"wrote {path}", flush=True)
    if summary.inbox is not None and summary.ended == "interrupted" and not quiet:
        print(_("watch stopped"), flush=True)
    if not summary.inspected and summary.inbox is not None:
        if not quiet:
            print(_("no capture arrived in {inbox}").format(inbox=summary.inbox))
        return EXIT_OK
    if not summary.inspected:
        raise RecipeError("no capture to inspect")
    if not quiet:
        n = summary.counts
        print(_("{n} inspected: {p} pass, {f} fail, {e} error. Results in {outdir}").format(
            n=summary.inspected, p=n["pass"], f=n["fail"], e=n["error"], outdir=summary.outdir.resolve()))
    return summary.exit_status


def _quality_files(session: Any, dfq: str | None, qif: str | None) -> Any:
    """``--dfq`` / ``--qif``: the collector of the run's characteristics (None without either
    option); RecipeError (one line) when the recipe defines none or a file cannot be placed."""
    if dfq is None and qif is None:
        return None
    from inspector.characteristics.formats import RunRecords

    return RunRecords.open(session.recipe, session.reference, dfq=dfq, qif=qif)


def _add_run(sub: argparse._SubParsersAction[Any]) -> None:
    r = sub.add_parser("run", help="inspect captures with a recipe (batch: in this process, or on a Dask cluster)")
    r.add_argument("recipe", help="recipe TOML file")
    src = r.add_mutually_exclusive_group()
    src.add_argument("--capture", nargs="+", metavar="DIR", help="capture folders, or folders of capture folders (default: the recipe's driver)")
    src.add_argument("--watch", metavar="INBOX", help="hot folder: inspect capture folders as they land in INBOX, then move them to INBOX/done/")
    r.add_argument("--count", type=int, metavar="N", help="with --watch: stop after N captures")
    r.add_argument("--idle-exit", type=float, metavar="S", help="with --watch: stop after S seconds without a new capture")
    r.add_argument("--out", required=True, metavar="OUTDIR", help="result folder (one sub-folder per capture)")
    r.add_argument("--reference", metavar="MESH", help="reference mesh (STL/PLY/OBJ in mm, or builtin:NAME); replaces the recipe's")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress lines (capture errors are still printed, on stderr)")
    r.add_argument("--csv", action="store_true",
                   help="also write bcps_points.csv (per-point deviations) and regions.csv (per-region summary) "
                        "in each result folder (as the recipe's [outputs] csv = true)")
    r.add_argument("--scheduler", metavar="ADDRESS",
                   help="with --capture: inspect on the workers of this Dask scheduler (e.g. tcp://host:8786); "
                        "they must see the capture folders by the same paths. Results are written here, as a local run's")
    r.add_argument("--workers", type=int, metavar="N",
                   help="with --capture: inspect on a local Dask cluster of N worker processes")
    r.add_argument("--dfq", metavar="FILE", help="also write the run's characteristics as Q-DAS AQDEF (DFQ): one value "
                                                 "line per part (the recipe's [[characteristics]])")
    r.add_argument("--qif", metavar="FILE", help="also write the run's characteristics as a QIF 3.0 Results document")
    r.add_argument("--lang", metavar="LANG",
                   help="language of the progress and summary lines: en, de or es (default: $INSPECTOR_LANG, else en; "
                        "never the system locale: plant scripts parse these lines)")
    r.add_argument("--unapproved", action="store_true",
                   help="in production mode (inspector roles production on), run a recipe no engineer approved, or "
                        "changed since, anyway: a warning, and an unapproved-run row in OUTDIR's audit")


def _cluster_params(args: argparse.Namespace) -> dict[str, Any] | None:
    """Where ``--scheduler`` or ``--workers`` send the inspections (None: this process)."""
    if args.scheduler is None and args.workers is None:
        return None
    if args.scheduler is not None and args.workers is not None:
        raise RecipeError("--scheduler and --workers: give one, a running cluster or a local one of N workers")
    flag = "--scheduler" if args.scheduler is not None else "--workers"
    if not args.capture:
        raise RecipeError(f"{flag}: only with --capture (a batch of capture folders)")
    if args.workers is not None and args.workers < 1:
        raise RecipeError(f"--workers: expected a number >= 1, got {args.workers}")
    if args.scheduler is not None and not args.scheduler.strip():
        raise RecipeError("--scheduler: expected an address such as tcp://host:8786")
    return {"scheduler": args.scheduler} if args.scheduler is not None else {"workers": args.workers}


def _run_command(args: argparse.Namespace) -> int:
    try:
        lang = choose(getattr(args, "lang", None))  # --lang, else $INSPECTOR_LANG, else English
    except ValueError as e:
        raise RecipeError(f"--lang: {e}") from None
    with using(lang):
        return run_recipe(args.recipe, args.capture, args.out, args.reference, args.quiet,
                          watch=_watch_params(args), csv=args.csv, pm=args.plugin_manager, cluster=_cluster_params(args),
                          unapproved=args.unapproved, dfq=args.dfq, qif=args.qif)


# -- plugins / recipe check ---------------------------------------------------
def _add_plugins(sub: argparse._SubParsersAction[Any]) -> None:
    pl = sub.add_parser("plugins", help="the plugins (distribution, version, what each provides, blocked or not), "
                                        "stages and drivers with their parameters")
    pl.add_argument("--json", action="store_true", help="machine-readable output")
    pl.add_argument("--parts", action="store_true", help="also list the built-in parts")



def _plugins(args: argparse.Namespace) -> int:
    pm: PluginManager = args.plugin_manager
    doc: dict[str, Any] = {"inspector": __version__, "api_version": API_VERSION,
                           "plugins": pm.plugin_names(), "plugin_info": pm.plugins(), "blocked": list(pm.blocked),
                           "stages": {}, "drivers": {}, "commands": {}, "settings": {},
                           "problems": [p.message() for p in pm.problems]}  # also warned on stderr
    for kind, reg in (("stages", pm.stages), ("drivers", pm.drivers), ("settings", pm.settings)):
        for name in reg.names():
            spec = reg[name]
            doc[kind][name] = {"doc": spec.doc, "plugin": reg.owner(name), "params": describe_params(spec.params)}
            if kind == "stages":
                doc[kind][name]["requires"] = list(spec.requires)
    for name in pm.commands.names():
        doc["commands"][name] = {"doc": pm.command(name).doc, "plugin": pm.commands.owner(name)}
    if args.json:
        print(json.dumps(doc, indent=2, default=repr))
        return EXIT_OK
    print(f"inspector {__version__}, plugin API {API_VERSION}")
    print("\nPLUGINS")
    for row in doc["plugin_info"]:
        where = f"file {row['file']}" if row["file"] else f"{row['dist'] or 'from code'} {row['version'] or ''}".strip()
        state = "" if row["status"] == "loaded" else f"  [{row['status'].upper()}]"
        builtin = ", built-in" if row["builtin"] else ""
        what = "; ".join(f"{kind}{'s' if len(names) > 1 and kind != 'settings' else ''} {', '.join(names)}"
                         for kind, names in row["provides"].items() if names)
        print(f"  {row['name']} ({where}{builtin}){state}: {what or 'nothing'}")
        for problem in row["problems"]:
            print(f"      ! {problem}")
    for kind in ("stages", "drivers"):
        print(f"\n{kind.upper()}")
        for name, d in doc[kind].items():
            req = f"  (after: {', '.join(d['requires'])})" if d.get("requires") else ""
            print(f"  {name}: {d['doc']}{req}")
            for prm in d["params"]:
                print(f"      {prm['name']} ({prm['type']}, default {prm['default']!r}): {prm['doc']}")
    if doc["settings"]:
        print("\nPLUGIN SETTINGS (a recipe's [plugins.NAME] table)")
        for name, d in doc["settings"].items():
            print(f"  [plugins.{name}]: {d['doc']}")
            for prm in d["params"]:
                print(f"      {prm['name']} ({prm['type']}, default {prm['default']!r}): {prm['doc']}")
    print("\nCOMMANDS (from plugins)")
    for name, d in doc["commands"].items():
        print(f"  inspector {name}: {d['doc']}  (plugin {d['plugin']})")
    if args.parts:
        from inspector.parts import BUILTIN_PARTS

        print("\nBUILT-IN PARTS (reference = \"builtin:NAME\")")
        for name, desc in BUILTIN_PARTS.items():
            print(f"  {name}: {desc}")
    return EXIT_OK


def _add_recipe(sub: argparse._SubParsersAction[Any]) -> None:
    rc = sub.add_parser("recipe", help="recipe tools")
    rsub = rc.add_subparsers(dest="recipe_command", required=True, parser_class=_Parser)
    chk = rsub.add_parser("check", help="validate a recipe without running it")
    chk.add_argument("recipe")
    chk.add_argument("--reference", metavar="MESH")
    chk.add_argument("--rig", metavar="RIG.json", help="the rig the recipe will run on (a capture folder's rig.json): "
                                                       "refused when no part could ever be rejected with it")
    add_approve_parser(rsub)


def _recipe_command(args: argparse.Namespace) -> int:
    if args.recipe_command == "approve":
        return run_approve(args)
    return _recipe_check(args)


def _recipe_check(args: argparse.Namespace) -> int:
    _pm, recipe, _ref = _load(args.recipe, args.reference, args.plugin_manager)
    on = ""
    if getattr(args, "rig", None):  # issue 27: values in range that make a rejection impossible on this rig
        from inspector import api
        from inspector.recipe import rig_problems

        try:
            rig = api.read_rig(args.rig)
        except InspectorError as e:  # a command's input: exit 2 like the recipe's own problems
            raise RecipeError(f"--rig {args.rig}: {e}") from None
        problems = rig_problems(recipe, rig)
        if problems:
            raise RecipeError(f"{args.recipe}: {problems[0]} (rig {args.rig})")
        on = f"; rig {args.rig} ({len(rig)} cameras): a part can be rejected"
    steps = " -> ".join(f"{s.name} ({s.spec.name})" for s in recipe.steps)
    print(f"{args.recipe}: OK: recipe {recipe.name!r}, driver {recipe.driver.spec.name}, stages {steps}; reference {recipe.reference or 'none'}{on}")
    return EXIT_OK


def _add_report(sub: argparse._SubParsersAction[Any]) -> None:
    report.add_parser(sub)


def _report(args: argparse.Namespace) -> int:
    return report.run(args)


def _add_roles(sub: argparse._SubParsersAction[Any]) -> None:
    roles.add_parser(sub)


def _roles(args: argparse.Namespace) -> int:
    return roles.run(args)


#: The core's own commands: name -> (add_parser, run). Every other command comes from a
#: plugin (``inspector_register_commands``); a plugin cannot take one of these names.
CORE_COMMANDS: dict[str, tuple[Callable[[argparse._SubParsersAction[Any]], None], Callable[[argparse.Namespace], int]]] = {
    # run functions looked up when called (a test may replace one)
    "run": (_add_run, lambda args: _run_command(args)),
    "plugins": (_add_plugins, lambda args: _plugins(args)),
    "recipe": (_add_recipe, lambda args: _recipe_command(args)),
    "report": (_add_report, lambda args: _report(args)),
    "roles": (_add_roles, lambda args: _roles(args)),
}


# -- entry point -----------------------------------------------------------------------
class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]  # one line, exit 2 (CONTRACT)
        self.print_usage(sys.stderr)
        err(message)
        raise SystemExit(EXIT_INVALID)


def _global_options(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    """``--block`` names (comma-separated, repeatable) and ``--plugin`` files given before the
    command, read before the plugin manager that builds the parser exists."""
    block: list[str] = []
    files: list[str] = []
    i = 0
    while i < len(argv):
        tok = argv[i]
        if not tok.startswith("-"):
            break  # the command: what follows is its own
        for flag, into in (("--block", block), ("--plugin", files)):
            if tok == flag and i + 1 < len(argv):
                into.append(argv[i + 1])
                i += 1
            elif tok.startswith(flag + "="):
                into.append(tok.split("=", 1)[1])
        i += 1
    names = [n.strip() for b in block for n in b.split(",") if n.strip()]
    return names, files


def plugin_manager_for(argv: Sequence[str]) -> PluginManager:
    """The plugin manager a command line asks for: every installed plugin, less the
    ``--block`` ones and ``$INSPECTOR_BLOCK_PLUGINS``, plus the ``--plugin`` files.

    Raises
    ------
    PluginError
        A ``--plugin`` file that is missing or broken (one line naming it).
    """
    block, files = _global_options(argv)
    env = [b.strip() for b in os.environ.get(BLOCK_ENV, "").split(",") if b.strip()]
    return create_plugin_manager(block=[*env, *block], files=files)


def build_parser(pm: PluginManager | None = None) -> argparse.ArgumentParser:
    """The whole command line: the core commands, then each plugin's (``pm``: default a
    new plugin manager). A plugin command that takes a core command's name, or whose
    ``add_parser`` raises or adds no sub-parser of its name, is left out with one warning
    naming the plugin."""
    if pm is None:
        pm = create_plugin_manager()
    ap = _Parser(prog="inspector", description="3D quality inspection from the silhouettes of a multi-camera rig (BCPS).")
    ap.add_argument("--version", action="version", version=f"inspector {__version__} (plugin API {API_VERSION})")
    ap.add_argument("--block", action="append", default=[], metavar="NAME",
                    help="do not load plugin NAME (an entry-point name; comma-separated or repeated), "
                         "as INSPECTOR_BLOCK_PLUGINS=NAME")
    ap.add_argument("--plugin", action="append", default=[], metavar="FILE.py",
                    help="also load this local module as a plugin (development; repeatable)")
    sub = ap.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for add, _run in CORE_COMMANDS.values():
        add(sub)
    for name in pm.commands.names():
        owner = pm.commands.owner(name) or "?"
        who = pm.info(owner).label()
        if name in CORE_COMMANDS:
            print(f"inspector: warning: {who}: command {name!r} is a core command; its own is not added; "
                  f"rename it, or block it with --block {owner}", file=sys.stderr)
            continue
        try:
            pm.command(name).add_parser(sub)
        except Exception as e:  # noqa: BLE001 - one plugin's parser must not stop the command line
            sub.choices.pop(name, None)
            # Private: argparse offers no public way to take a sub-parser's help entry back out.
            sub._choices_actions[:] = [a for a in sub._choices_actions if a.dest != name]  # noqa: SLF001 - argparse keeps its help list here, no API removes one
            print(f"inspector: warning: {who}: command {name!r} not added: add_parser raised "
                  f"{type(e).__name__}: {' '.join(str(e).split())}; block it with --block {owner}", file=sys.stderr)
            continue
        if name not in sub.choices:
            print(f"inspector: warning: {who}: command {name!r} not added: add_parser added no sub-parser named "
                  f"{name!r}", file=sys.stderr)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    from inspector.startup import defer_open3d_plotly

    defer_open3d_plotly()  # a new process reaches its first verdict sooner (see inspector.startup)

    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        pm = plugin_manager_for(argv)
    except PluginError as e:
        err(str(e))
        return EXIT_INVALID
    args = build_parser(pm).parse_args(argv)
    args.plugin_manager = pm
    # Code that builds its own plugin manager (the GUI window, Dask workers) honours --block too.
    old_block = os.environ.get(BLOCK_ENV)
    if args.block:
        os.environ[BLOCK_ENV] = ",".join([*filter(None, (old_block or "").split(",")), *args.block])
    try:
        if args.command in CORE_COMMANDS:
            return CORE_COMMANDS[args.command][1](args)
        return pm.command(args.command).run(args)
    except RecipeError as e:
        err(str(e))
        return EXIT_INVALID
    except InspectorError as e:
        err(str(e))
        return EXIT_ERROR
    except BrokenPipeError:  # output piped to a pager or head that closed early
        return EXIT_OK
    except KeyboardInterrupt:
        err("interrupted; results written so far are kept")
        return 130
    except OSError as e:
        err(f"{e.filename or ''}: {e.strerror or e}".strip(": "))
        return EXIT_ERROR
    except Exception as e:  # noqa: BLE001 - a bug: one line for the user, the traceback kept for us
        err(f"internal error {type(e).__name__}: {' '.join(str(e).split())} (traceback in {_save_traceback()})")
        return EXIT_ERROR
    finally:
        if args.block:
            if old_block is None:
                os.environ.pop(BLOCK_ENV, None)
            else:
                os.environ[BLOCK_ENV] = old_block


def _save_traceback() -> str:
    """Write the current exception's traceback to a new private file; its path."""
    from inspector.tracebacks import save_traceback

    return save_traceback()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
