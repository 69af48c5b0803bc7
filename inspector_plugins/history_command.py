"""``inspector history``: the inspections recorded in ``OUTDIR/history.sqlite`` or in the plant
database, the yield, their charts (:mod:`inspector_plugins.history_charts`), the shift report,
the characteristics' capability, ``--send`` (the spool now) and ``--verify`` (the hash chain).
Registered by the ``history`` plugin (:mod:`inspector_plugins.history`)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any

from inspector.errors import InputError
from inspector.history_store import HISTORY_FILE, read_history, spooled
from inspector.locale import choose, using
from inspector.shift import print_shifts
from inspector_plugins.history import URL_ENV, HistorySettings, flush_spool, read_plant, verify_history
from inspector_plugins.history_charts import plot_cameras, plot_history, tally
from inspector_plugins.history_plant import PlantDatabase, PlantUnavailable, check_url

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("history", help="list the inspections recorded in OUTDIR/history.sqlite or in the plant "
                                              "database, and the yield")
    p.add_argument("outdir", metavar="OUTDIR", nargs="?",
                   help="an inspector run --out folder (none: the plant database, --url or $" + URL_ENV + ")")
    p.add_argument("--url", metavar="URL", help="the plant database, postgresql://USER@HOST[:PORT]/DATABASE (default: "
                                                "--recipe's [plugins.history] url, else $" + URL_ENV
                                                + "; a password is better in $PGPASSWORD or ~/.pgpass)")
    p.add_argument("--recipe", metavar="RECIPE", help="take the plant database from this recipe's [plugins.history] url "
                                                      "(as the run did) when --url is not given")
    p.add_argument("--cell", metavar="NAME", help="only the inspections of this cell")
    p.add_argument("--send", action="store_true", help="send OUTDIR's spooled inspections to the plant database now")
    p.add_argument("--verify", action="store_true", help="check OUTDIR's hash chain: name the first inspection changed "
                                                         "or removed since it was recorded (exit 1), else exit 0")
    p.add_argument("--last", type=int, metavar="N", help="only the last N inspections")
    p.add_argument("--json", action="store_true", help="the rows as JSON")
    p.add_argument("--plot", metavar="PNG", help="also draw the trend: each part's deviation range against its tolerance")
    p.add_argument("--cameras", metavar="PNG", help="also draw the calibration health: how far each camera was off (px) "
                                                    "in each inspection, against the flagging threshold")
    p.add_argument("--characteristics", nargs="?", const="", metavar="PNG",
                   help="each characteristic over the parts: n, mean, s, Cp, Cpk, out of tolerance, Cg, Cgk; with PNG "
                        "also its individuals control chart with the tolerance band")
    p.add_argument("--dfq", metavar="FILE", help="write the recorded characteristics as Q-DAS AQDEF (DFQ), one value line "
                                                 "per part, as inspector run --dfq does (K1001: --recipe's reference, "
                                                 "else the recorded recipe)")
    p.add_argument("--shift", nargs="?", type=int, const=1, metavar="N",
                   help="the current shift's counters (and the N-1 before it): yield, worst regions, errors by reason")
    p.add_argument("--config", metavar="TOML", help="the cell's settings for --shift ([shifts]; default cell.toml in "
                                                    "$INSPECTOR_CONFIG_DIR or ~/.config/inspector when present)")
    p.add_argument("--pdf", metavar="FILE", help="with --shift: also the shift report as a PDF, one A4 page per shift")
    p.add_argument("--lang", metavar="LANG", help="with --shift: the language of its lines and PDF: en, de or es "
                                                  "(default: $INSPECTOR_LANG, else en; never the system locale)")


def _fmt(x: Any, spec: str) -> str:
    return "-" if x is None else format(x, spec)


def _url_of(args) -> tuple[str | None, str]:
    """(the plant database's URL, where it came from) of ``inspector history``'s arguments, in
    this order: ``--url``; the ``--recipe``'s ``[plugins.history] url`` (what the run used);
    ``$INSPECTOR_HISTORY_URL``. Raises RecipeError (one line naming the recipe) for a recipe
    that cannot be read."""
    if args.url:
        return args.url, "--url"
    if getattr(args, "recipe", None):
        from inspector.recipe import load_recipe

        recipe = args.loaded_recipe = load_recipe(args.recipe, args.plugin_manager)  # --dfq takes its reference
        settings = recipe.plugins.get("history")
        if isinstance(settings, HistorySettings) and settings.url:
            return settings.url, f"{args.recipe}: plugins.history.url"
    return os.environ.get(URL_ENV, "").strip() or None, URL_ENV


def _verify_cmd(outdir: Path) -> int:
    """``inspector history OUTDIR --verify``: 0 intact, 1 broken, 3 unreadable."""
    path = outdir / HISTORY_FILE
    if not path.is_file():
        print(f"inspector: error: {path}: no history", file=sys.stderr)
        return 3
    try:
        report = verify_history(outdir)
    except InputError as e:
        print(f"inspector: error: {e}", file=sys.stderr)
        return 3
    if not report.ok:
        print(f"inspector: error: {path}: {report.summary()}", file=sys.stderr)
        return 1
    print(f"{path}: {report.summary()}")
    return 0


def _send_now(outdir: Path, url: str) -> int:
    """``inspector history OUTDIR --send``."""
    plant = PlantDatabase(url, connect_timeout_s=10, application_name="inspector history --send")
    try:
        sent = flush_spool(outdir, plant)
    except PlantUnavailable as e:
        print(f"inspector: error: {e}; {spooled(outdir)} inspections stay in the spool", file=sys.stderr)
        return 3
    finally:
        plant.close()
    print(f"sent {sent} spooled inspection{'s' if sent != 1 else ''} to {plant.label}")
    return 0


def run(args) -> int:
    if args.last is not None and args.last < 1:
        print(f"inspector: error: --last: expected a number >= 1, got {args.last}", file=sys.stderr)
        return 2
    if args.shift is not None:
        if args.outdir is None:
            print("inspector: error: --shift: give OUTDIR (its history.sqlite)", file=sys.stderr)
            return 2
        try:
            lang = choose(args.lang)
        except ValueError as e:
            print(f"inspector: error: --lang: {e}", file=sys.stderr)
            return 2
        with using(lang):
            return print_shifts(args.outdir, shifts=args.shift, config=args.config, pdf=args.pdf)
    if args.pdf is not None:
        print("inspector: error: --pdf: the shift report; give --shift too", file=sys.stderr)
        return 2
    if args.dfq is not None:
        from inspector.characteristics.formats import output_file

        output_file(args.dfq, "--dfq")  # a folder, or one that does not exist: RecipeError, one line, exit 2
    if args.verify:
        if args.outdir is None or args.send or args.url:
            print("inspector: error: --verify: give OUTDIR only (its history.sqlite is checked)", file=sys.stderr)
            return 2
        return _verify_cmd(Path(args.outdir))
    url, source = _url_of(args)
    if url is not None and (args.send or args.outdir is None):
        try:
            check_url(url)
        except ValueError as e:
            print(f"inspector: error: {source}: {str(e).removeprefix('url: ')}", file=sys.stderr)
            return 2
    if args.send:
        if args.outdir is None or url is None:
            print(f"inspector: error: --send: give OUTDIR and the plant database (--url URL, --recipe RECIPE with "
                  f"[plugins.history] url, or ${URL_ENV})", file=sys.stderr)
            return 2
        if not (Path(args.outdir) / HISTORY_FILE).is_file():
            print(f"inspector: error: {Path(args.outdir) / HISTORY_FILE}: no history", file=sys.stderr)
            return 3
        return _send_now(Path(args.outdir), url)
    if args.outdir is not None and args.url:
        print("inspector: error: give OUTDIR (its history.sqlite) or --url (the plant database), not both", file=sys.stderr)
        return 2
    plant = args.outdir is None
    if plant and url is None:
        print(f"inspector: error: history: give OUTDIR, or the plant database with --url URL or ${URL_ENV}", file=sys.stderr)
        return 2
    try:
        if plant:
            assert url is not None
            rows = read_plant(url, last=args.last, cell=args.cell)
        else:
            rows = read_history(Path(args.outdir), last=args.last, cell=args.cell)
    except InputError as e:
        print(f"inspector: error: {e}", file=sys.stderr)
        return 3
    if args.dfq is not None:
        rc = _dfq_cmd(rows, args)
        if rc or args.characteristics is None:
            return rc
    if args.characteristics is not None:
        return _characteristics_cmd(rows, args.characteristics)
    for picture, draw in ((args.plot, plot_history), (args.cameras, plot_cameras)):
        if picture:
            try:
                draw(rows, Path(picture))
            except OSError as e:
                print(f"inspector: error: {picture}: cannot write ({e.strerror or e})", file=sys.stderr)
                return 3
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    cell_head = f"{'cell':14s} " if plant else ""
    print(f"{'inspected at (UTC)':24s} {cell_head}{'capture':24s} {'part id':14s} {'verdict':7s} {'defects':>7s} "
          f"{'worst mm':>9s} {'s':>6s}")
    for r in rows:
        cell = f"{(r['cell'] or '-')[:14]:14s} " if plant else ""
        print(f"{r['inspected_at'][:23]:24s} {cell}{r['capture'][:24]:24s} {(r['part_id'] or '-')[:14]:14s} "
              f"{r['verdict'].upper():7s} {r['n_defects']:7d} {_fmt(r['worst_mm'], '+9.3f'):>9s} {_fmt(r['total_s'], '6.2f'):>6s}")
    n, share = tally(rows)
    yld = f"yield {share:.1%} of the parts judged" if share is not None else "no part judged"
    span = f", {rows[0]['inspected_at'][:19]} to {rows[-1]['inspected_at'][:19]}" if rows else ""
    print(f"{len(rows)} inspections: {n['pass']} pass, {n['fail']} fail, {n['error']} error; {yld}{span}")
    waiting = 0 if plant else spooled(Path(args.outdir))
    if waiting:
        print(f"{waiting} of them wait in the spool for the plant database (sent at the next record, or with --send)")
    for picture in (args.plot, args.cameras):
        if picture:
            print(f"wrote {picture}")
    return 0


def _characteristics_cmd(rows: list[dict[str, Any]], picture: str) -> int:
    """``--characteristics [PNG]``: the capability table, and the control charts."""
    from inspector.characteristics.charts import capability_text, parts_rows, plot_charts

    parts = parts_rows(rows)
    if not parts:
        print(f"inspector: error: none of the {len(rows)} inspections measured characteristics (a recipe's "
              "[[characteristics]] and its evaluate.characteristics stage)", file=sys.stderr)
        return 3
    for line in capability_text(parts):
        print(line)
    print(f"{len(parts)} parts with characteristics of {len(rows)} inspections")
    if picture:
        try:
            plot_charts(parts, Path(picture))
        except OSError as e:
            print(f"inspector: error: {picture}: cannot write ({e.strerror or e})", file=sys.stderr)
            return 3
        print(f"wrote {picture}")
    return 0


def _dfq_cmd(rows: list[dict[str, Any]], args) -> int:
    """``--dfq FILE``: the recorded characteristics as Q-DAS AQDEF, by :func:`write_dfq` as
    ``inspector run --dfq`` writes them. The history holds each part's rows (definition,
    nominal, limits, value), its capture and its time, and the recipe's name, not the
    reference: K1001 is ``--recipe``'s reference (as the run's), else the recorded recipe."""
    from inspector.characteristics.formats import history_records, part_number_of, write_dfq
    from inspector.recipe import load_recipe

    rec = history_records(rows)  # InputError naming an unreadable row: exit 3
    if not rec.parts:
        print(f"inspector: error: none of the {len(rows)} inspections measured characteristics (a recipe's "
              "[[characteristics]] and its evaluate.characteristics stage)", file=sys.stderr)
        return 3
    described = ", ".join(rec.recipes)
    number = described
    if getattr(args, "recipe", None):
        recipe = getattr(args, "loaded_recipe", None) or load_recipe(args.recipe, args.plugin_manager)
        if recipe.name not in rec.recipes:
            print(f"inspector: error: --recipe {args.recipe}: recipe {recipe.name!r}, but the parts were inspected "
                  f"with {described}", file=sys.stderr)
            return 2
        number = part_number_of(str(recipe.reference)) if recipe.reference else recipe.name
    try:
        path = write_dfq(args.dfq, rec.characteristics, rec.parts, part_number=number, part_description=described)
    except OSError as e:
        print(f"inspector: error: --dfq {args.dfq}: cannot write ({e.strerror or e})", file=sys.stderr)
        return 3
    print(f"wrote {path}: {len(rec.characteristics)} characteristics, {len(rec.parts)} parts of {len(rows)} inspections")
    return 0
