"""Compile the Numba kernels into their on-disk cache once, with a progress line per kernel.

The first inspection after an install compiles every kernel (issue 15 measured 280-580 s
and about 3 GB with nothing printed). ``make setup`` runs ``python -m inspector_tools.precompile``
so that this happens during the install, visibly, and the first inspection only loads the
cached machine code (seconds).

How: two small simulated captures (8 cameras of 256x256 at 0.4 mm/px; a good and a notched
cube) are inspected with the built-in recipes. Numba specialises a kernel on the argument
types (dtype, dimensions, layout), never on the array sizes, so a small capture compiles
exactly the machine code a full-size one uses; rendering it takes a second. Numba's compile
events name each kernel as it is compiled. A kernel that a later recipe reaches and this
run did not is compiled on its first use, as before.

Both cores: the kernels a run compiles, with their argument types, are listed in
``inspector/kernels/signatures.json`` (``python -m inspector_tools.precompile --record``, a test
checks the list is current). The install step compiles them explicitly in two processes at
once, each its share by the recorded compile times, then runs the small captures, which load
them (and compile whatever the list missed). Compiling is single-threaded in Numba: one
process left a core idle for the 80 s the kernels take.

Importing this module never imports Numba (the kernels are compiled when first called), so
``--record`` still sets ``NUMBA_CACHE_DIR`` before Numba is imported.
"""

from __future__ import annotations

import argparse
import functools
import os
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

import inspector
from inspector.capture_folder import read_capture, save_capture
from inspector.kernels import fits
from inspector.params import build_params
from inspector.parts import load_reference
from inspector.registry import Acquisition
from inspector.resources import recipe_path
from inspector.runner import run_batch
from inspector.session import Session
from inspector_drivers.sim.simulate import SimParams, simulate

__all__ = ["precompile", "first_run", "cold_start", "main"]

#: The built-in recipes whose pipelines are compiled (package data, see inspector.resources).
RECIPES = ("demo.toml", "default.toml")
#: The small capture: the kernels' argument types are those of any capture.
_SMALL = {"part": "cube30", "cameras": 8, "width": 256, "height": 256, "mm_per_px": 0.4}


class _Progress:
    """A Numba compile-event listener that reports the project's kernels, outermost only."""

    def __init__(self, say: Callable[[str], None]) -> None:
        from numba.core import event

        class Listener(event.Listener):
            def on_start(inner, ev: Any) -> None:
                self._start(ev)

            def on_end(inner, ev: Any) -> None:
                self._end(ev)

        self.say = say
        self.depth = 0
        self.t0 = 0.0
        self.kernels: list[tuple[str, float]] = []
        #: Outermost compiles: {"module", "name", "args" (repr of the argument types), "seconds"}.
        self.compiled: list[dict[str, Any]] = []
        self._args = ""
        self.listener = Listener()

    @staticmethod
    def _name(ev: Any) -> str | None:
        fn = getattr(ev.data.get("dispatcher"), "py_func", None)
        mod = getattr(fn, "__module__", "") or ""
        return f"{mod.rsplit('.', 1)[-1]}.{fn.__name__}" if fn is not None and mod.startswith("inspector") else None

    def _start(self, ev: Any) -> None:
        name = self._name(ev)
        if name is None:
            return
        if self.depth == 0:
            self.t0 = time.perf_counter()
            self._args = repr(ev.data.get("args"))
            self.say(f"  compiling {name} ...")
        self.depth += 1

    def _end(self, ev: Any) -> None:
        name = self._name(ev)
        if name is None:
            return
        self.depth -= 1
        if self.depth == 0:
            dt = time.perf_counter() - self.t0
            self.kernels.append((name, dt))
            fn = ev.data["dispatcher"].py_func
            self.compiled.append({"module": fn.__module__, "name": fn.__name__, "args": self._args,
                                  "seconds": round(dt, 1)})
            self.say(f"  compiled  {name} in {dt:.1f} s")

    def __enter__(self) -> _Progress:
        from numba.core import event

        event.register("numba:compile", self.listener)
        return self

    def __exit__(self, *exc: object) -> None:
        from numba.core import event

        event.unregister("numba:compile", self.listener)


def precompile(work: Path, say: Callable[[str], None] = print, parallel: int = 2) -> dict[str, Any]:
    """Inspect two small simulated captures with :data:`RECIPES`, compiling every kernel
    they use into Numba's on-disk cache (loading it where it is already there), then the
    characteristics' kernels, which those recipes do not reach.

    Parameters
    ----------
    work : Path
        A scratch folder for the captures and results (left for the caller to remove).
    say : callable
        Where the progress lines go.
    parallel : int
        Child processes compiling the recorded kernels first (:data:`SIGNATURES`); 0: none,
        the run compiles every kernel it reaches, in this process.

    Returns
    -------
    dict
        ``seconds`` (wall time), ``ahead`` (kernels compiled by the child processes),
        ``kernels`` (``[(module.name, seconds)]`` compiled by the run, in order; empty when
        all were cached), ``compiled`` (those, as :data:`SIGNATURES` lists them) and
        ``verdicts`` (recipe -> capture -> verdict).
    """
    t0 = time.perf_counter()
    ahead = _compile_in_parallel(say, parallel) if parallel > 0 else 0
    notch = {"at": [15.0, 15.0, 0.0], "radius_mm": 1.5, "kind": "remove"}
    folders = []
    for name, extra in (("good", {}), ("notched", {"bumps": (notch,)})):
        params = build_params(SimParams, {**_SMALL, "seed": 5, **extra}, "precompile")
        folders.append(save_capture(simulate(params, 0, name=name), work / "captures" / name, overwrite=True))
    verdicts: dict[str, dict[str, str]] = {}
    with _Progress(say) as progress:
        for rname in RECIPES:
            session = Session.open(str(recipe_path(rname)), ".", reference="builtin:cube30")
            acqs = [Acquisition(f.name, functools.partial(read_capture, f)) for f in folders]
            out = work / "results" / Path(rname).stem
            verdicts[rname] = {o.result.capture: o.result.verdict
                               for o in run_batch(session.recipe, acqs, session.pm, reference=session.reference, outdir=out)}
        _characteristics_kernels()
        _display_mesh_kernels(folders[0])
    return {"seconds": time.perf_counter() - t0, "ahead": ahead, "kernels": progress.kernels,
            "compiled": progress.compiled, "verdicts": verdicts}


def _characteristics_kernels() -> None:
    """The characteristics stage's own kernels: a cylinder fit (its compiled loop,
    :mod:`inspector.kernels.fits_jit`) and the one-thread closest-point query
    (:func:`inspector.kernels.meshdist.closest_query_serial`). The built-in recipes measure
    no characteristics, so without this a recipe's first part would compile them (10-15 s)."""
    from inspector.kernels.meshdist import MeshDistance  # lazy: Numba (see the module docstring)

    t = np.linspace(0.0, 2.0 * np.pi, 40, endpoint=False)
    P = np.column_stack([5.0 * np.cos(t), 5.0 * np.sin(t), np.linspace(0.0, 10.0, 40)])
    fits.fit_cylinder(P, axis=np.array([0.0, 0.0, 1.0]), point=np.zeros(3), radius=5.0)
    box = load_reference("builtin:cube30")
    MeshDistance(np.asarray(box.vertices, float), np.asarray(box.faces)).closest(P, parallel=False)


def _display_mesh_kernels(folder: Path) -> None:
    """The carving's display-mesh kernels: ``carve.hull`` makes the mesh only with ``mesh =
    true``, which no built-in recipe sets, so without this such a recipe's first part would
    compile them."""
    from inspector.kernels.carving import carve  # lazy: Numba (see the module docstring)

    cap = read_capture(folder)
    carve(cap.rig.cameras, [np.asarray(cap.images[c.name]) < 128 for c in cap.rig.cameras], voxel_mm=1.0, mesh=True)


#: The recorded kernels (``--record``): what :func:`compile_listed` compiles ahead of the run.
SIGNATURES = Path(inspector.__file__).resolve().parent / "kernels" / "signatures.json"


def _dispatcher(module: str, name: str) -> Any:
    """The Numba dispatcher of kernel ``module.name``: the module attribute, or for a kernel
    jitted on first use, what the module's ``_compiled<name>()`` returns (None: not found)."""
    import importlib

    from numba.core.dispatcher import Dispatcher

    mod = importlib.import_module(module)
    obj = getattr(mod, name, None)
    if isinstance(obj, Dispatcher):
        return obj
    make = getattr(mod, f"_compiled{name}", None)
    return make() if callable(make) else None


def _argument_types(args: str) -> tuple[Any, ...]:
    """The argument types from their recorded ``repr`` (numba.core.types names)."""
    from numba.core import types

    names = {k: v for k, v in vars(types).items() if not k.startswith("_")}
    names["bool"] = types.boolean
    value = eval(args, {"__builtins__": {}}, names)
    return tuple(value)


def compile_listed(entries: Sequence[dict[str, Any]], say: Callable[[str], None] = print) -> list[str]:
    """Compile each recorded kernel for its recorded argument types (into the on-disk cache);
    returns the problems, one line each (a kernel left to the run)."""
    problems = []
    for e in entries:
        t0 = time.perf_counter()
        try:
            disp = _dispatcher(e["module"], e["name"])
            if disp is None:
                raise LookupError("no such kernel")
            disp.compile(_argument_types(e["args"]))
        except Exception as exc:  # noqa: BLE001 - the run compiles it then
            problems.append(f"{e['module']}.{e['name']}: {type(exc).__name__}: {exc}")
            continue
        say(f"  compiled  {e['module'].rsplit('.', 1)[-1]}.{e['name']} in {time.perf_counter() - t0:.1f} s")
    return problems


def split(entries: Sequence[dict[str, Any]], parts: int) -> list[list[dict[str, Any]]]:
    """``entries`` in ``parts`` groups of about equal recorded compile time (longest first)."""
    groups: list[list[dict[str, Any]]] = [[] for _ in range(parts)]
    load = [0.0] * parts
    for e in sorted(entries, key=lambda e: -float(e.get("seconds", 0.0))):
        i = load.index(min(load))
        groups[i].append(e)
        load[i] += float(e.get("seconds", 0.0))
    return [g for g in groups if g]


def _compile_in_parallel(say: Callable[[str], None], parts: int) -> int:
    """:func:`compile_listed` over :data:`SIGNATURES` in ``parts`` child processes at once,
    their lines relayed to ``say``; returns how many kernels they compiled."""
    import json
    import threading

    try:
        entries = json.loads(SIGNATURES.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return 0  # no list (a wheel without it): the run compiles everything
    code = ("import json, sys; from inspector_tools.precompile import compile_listed; "
            "[print('inspector: warning: precompile: ' + p, file=sys.stderr) "
            "for p in compile_listed(json.loads(sys.argv[1]), lambda s: print(s, flush=True))]")
    done = [0]
    lock = threading.Lock()

    def relay(proc: subprocess.Popen[str]) -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            with lock:
                done[0] += line.startswith("  compiled ")
                say(line.rstrip("\n"))

    procs, threads = [], []
    for group in split(entries, parts):
        say(f"  compiling {', '.join(e['module'].rsplit('.', 1)[-1] + '.' + e['name'] for e in group)} ...")
        proc = subprocess.Popen([sys.executable, "-c", code, json.dumps(group)], stdout=subprocess.PIPE, text=True)
        procs.append(proc)
        threads.append(threading.Thread(target=relay, args=(proc,), daemon=True))
        threads[-1].start()
    for proc, t in zip(procs, threads):
        proc.wait()
        t.join()
    return done[0]


def first_run(work: Path) -> dict[str, Any]:
    """What a fresh install pays: :func:`precompile` in a child process whose Numba cache
    (``NUMBA_CACHE_DIR``) is the empty folder ``work/numba-cache``, the installed cache
    untouched.

    Returns ``{"seconds": wall time of the child, "exit": its status, "kernels": number of
    kernels it compiled}``.
    """
    env = {**os.environ, "NUMBA_CACHE_DIR": str(work / "numba-cache")}
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "inspector_tools.precompile"], env=env, capture_output=True, text=True,
                          check=False)
    seconds = time.perf_counter() - t0
    kernels = sum(1 for line in proc.stdout.splitlines() if line.startswith("  compiled "))
    return {"seconds": seconds, "exit": proc.returncode, "kernels": kernels}


_VERDICT_LINE = re.compile(r"^\[\d+/\d+\] \S+: (PASS|FAIL|ERROR|ABORTED)\b")


def cold_start(recipe: str | Path, capture: Path, outdir: Path, reference: str | None = None) -> dict[str, Any]:
    """A new ``inspector run RECIPE --capture CAPTURE`` process, timed from its start to
    the verdict line on its standard output (interpreter start, imports, cached kernels
    loaded, one inspection) and to its exit.

    Returns ``{"verdict_s", "exit_s", "exit", "verdict"}`` (``verdict_s`` None when no
    verdict line came).
    """
    cmd = [sys.executable, "-c", "import sys; from inspector_frontends.cli import main; sys.exit(main(sys.argv[1:]))", "run",
           str(recipe), "--capture", str(capture), "--out", str(outdir)]
    if reference is not None:
        cmd += ["--reference", reference]
    t0 = time.perf_counter()
    verdict_s, verdict = None, None
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True) as proc:
        assert proc.stdout is not None
        for line in proc.stdout:
            m = _VERDICT_LINE.match(line)
            if m and verdict_s is None:
                verdict_s, verdict = time.perf_counter() - t0, m.group(1).lower()
        code = proc.wait()
    return {"verdict_s": verdict_s, "exit_s": time.perf_counter() - t0, "exit": code, "verdict": verdict}


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m inspector_tools.precompile``: exit 0 (a failure is one warning line: the
    kernels then compile on their first use, as without this step)."""
    ap = argparse.ArgumentParser(prog="python -m inspector_tools.precompile", description=__doc__.split("\n\n")[0])
    ap.add_argument("-q", "--quiet", action="store_true", help="only the summary line")
    ap.add_argument("-j", "--jobs", type=int, default=2, metavar="N",
                    help="processes compiling the listed kernels at once (default 2; 0: all in the run)")
    ap.add_argument("--record", action="store_true",
                    help=f"compile everything in one process into an empty cache and write the list ({SIGNATURES.name})")
    args = ap.parse_args(argv)
    say = (lambda s: None) if args.quiet else (lambda s: print(s, flush=True))
    if args.record:
        return _record(say)
    print("Compiling the inspection kernels into Numba's cache (once per install; about a minute) ...", flush=True)
    try:
        with tempfile.TemporaryDirectory(prefix="inspector-precompile-") as tmp:
            doc = precompile(Path(tmp), say, parallel=max(0, args.jobs))
    except Exception as e:  # noqa: BLE001 - the install goes on; the kernels compile on first use
        print(f"inspector: warning: precompile: {type(e).__name__}: {e} (the kernels will compile on the first inspection)",
              file=sys.stderr)
        return 0
    n = doc["ahead"] + len(doc["kernels"])
    what = f"{n} kernel(s) compiled" if n else "all kernels already cached"
    seen = sorted({f"{cap} {verdict}" for caps in doc["verdicts"].values() for cap, verdict in caps.items()})
    print(f"Kernels ready in {doc['seconds']:.1f} s ({what}; the small captures: {', '.join(seen)}).", flush=True)
    return 0


def _record(say: Callable[[str], None]) -> int:
    """``--record``: every kernel the run compiles, from an empty cache, into :data:`SIGNATURES`."""
    import json

    with tempfile.TemporaryDirectory(prefix="inspector-record-") as tmp:
        os.environ["NUMBA_CACHE_DIR"] = str(Path(tmp) / "numba-cache")  # before numba is imported
        doc = precompile(Path(tmp), say, parallel=0)
    entries = sorted((e for e in doc["compiled"] if "Literal" not in e["args"]), key=lambda e: (e["module"], e["name"]))
    SIGNATURES.write_text(json.dumps(entries, indent=1) + "\n", encoding="utf-8")
    print(f"{len(entries)} kernels written to {SIGNATURES}", flush=True)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
