"""Compile the Numba kernels into their on-disk cache once, with a progress line per kernel.

The first inspection after an install compiles every kernel (issue 15 measured 280-580 s
and about 3 GB with nothing printed). ``make setup`` runs ``python -m inspector.precompile``
so that this happens during the install, visibly, and the first inspection only loads the
cached machine code (seconds).

How: two small simulated captures (8 cameras of 256x256 at 0.4 mm/px; a good and a notched
cube) are inspected with the built-in recipes. Numba specialises a kernel on the argument
types (dtype, dimensions, layout), never on the array sizes, so a small capture compiles
exactly the machine code a full-size one uses; rendering it takes a second. Numba's compile
events name each kernel as it is compiled. A kernel that a later recipe reaches and this
run did not is compiled on its first use, as before.

Importing this module is cheap; the pipeline is imported by :func:`precompile`.
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
            self.say(f"  compiled  {name} in {dt:.1f} s")

    def __enter__(self) -> _Progress:
        from numba.core import event

        event.register("numba:compile", self.listener)
        return self

    def __exit__(self, *exc: object) -> None:
        from numba.core import event

        event.unregister("numba:compile", self.listener)


def precompile(work: Path, say: Callable[[str], None] = print) -> dict[str, Any]:
    """Inspect two small simulated captures with :data:`RECIPES`, compiling every kernel
    they use into Numba's on-disk cache (loading it where it is already there).

    Parameters
    ----------
    work : Path
        A scratch folder for the captures and results (left for the caller to remove).
    say : callable
        Where the progress lines go.

    Returns
    -------
    dict
        ``seconds`` (wall time), ``kernels`` (``[(module.name, seconds)]`` compiled, in
        order; empty when all were cached) and ``verdicts`` (recipe -> capture -> verdict).
    """
    from inspector.params import build_params
    from inspector.resources import recipe_path
    from inspector.runner import run_batch
    from inspector.session import Session
    from inspector_drivers.replay.folder import read_capture, save_capture
    from inspector_drivers.sim.simulate import SimParams, simulate

    from inspector.registry import Acquisition

    t0 = time.perf_counter()
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
    return {"seconds": time.perf_counter() - t0, "kernels": progress.kernels, "verdicts": verdicts}


def first_run(work: Path) -> dict[str, Any]:
    """What a fresh install pays: :func:`precompile` in a child process whose Numba cache
    (``NUMBA_CACHE_DIR``) is the empty folder ``work/numba-cache``, the installed cache
    untouched.

    Returns ``{"seconds": wall time of the child, "exit": its status, "kernels": number of
    kernels it compiled}``.
    """
    env = {**os.environ, "NUMBA_CACHE_DIR": str(work / "numba-cache")}
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "inspector.precompile"], env=env, capture_output=True, text=True,
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
    cmd = [sys.executable, "-c", "import sys; from inspector.cli import main; sys.exit(main(sys.argv[1:]))", "run",
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
    """``python -m inspector.precompile``: exit 0 (a failure is one warning line: the
    kernels then compile on their first use, as without this step)."""
    ap = argparse.ArgumentParser(prog="python -m inspector.precompile", description=__doc__.split("\n\n")[0])
    ap.add_argument("-q", "--quiet", action="store_true", help="only the summary line")
    args = ap.parse_args(argv)
    say = (lambda s: None) if args.quiet else (lambda s: print(s, flush=True))
    print("Compiling the inspection kernels into Numba's cache (once per install; about a minute) ...", flush=True)
    try:
        with tempfile.TemporaryDirectory(prefix="inspector-precompile-") as tmp:
            doc = precompile(Path(tmp), say)
    except Exception as e:  # noqa: BLE001 - the install goes on; the kernels compile on first use
        print(f"inspector: warning: precompile: {type(e).__name__}: {e} (the kernels will compile on the first inspection)",
              file=sys.stderr)
        return 0
    n = len(doc["kernels"])
    what = f"{n} kernel(s) compiled" if n else "all kernels already cached"
    seen = sorted({f"{cap} {verdict}" for caps in doc["verdicts"].values() for cap, verdict in caps.items()})
    print(f"Kernels ready in {doc['seconds']:.1f} s ({what}; the small captures: {', '.join(seen)}).", flush=True)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
