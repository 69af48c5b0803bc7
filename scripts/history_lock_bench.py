"""Parts per minute of a cell while the plant database's ``inspections`` table is locked (issue 27).

Records parts through the ``history`` plugin's real hooks (``on_run_start``, ``on_result``,
``on_run_end``, a recipe with ``[plugins.history] url``) for ``--seconds`` with the plant
database free, then for ``--seconds`` while another session holds ``LOCK TABLE inspections``,
then free again, and prints the parts per minute of each phase, how many rows waited in the spool when the lock
was released, and whether every row reached the plant database once. Each part costs
``--inspect-s`` of simulated inspection (a sleep: what the line does besides recording) plus
the history's own work.

Usage::

    .venv/bin/python scripts/history_lock_bench.py --url postgresql://USER@HOST/DB [--seconds 60] [--inspect-s 0.5]
    .venv/bin/python scripts/history_lock_bench.py --seconds 60   # a throw-away local cluster (initdb on PATH)

The database is used as it is (tables made if missing); rows of the cell ``lock-bench-*`` are added.
"""

from __future__ import annotations

import argparse
import os
import pwd
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace


def _throwaway_cluster(root: Path) -> tuple[str, Callable[[], None]]:
    """initdb + pg_ctl start on a free loopback port (as ``nobody`` when run as root); the URL
    and a function that stops it."""
    initdb = shutil.which("initdb") or next(iter(sorted(Path("/usr/lib/postgresql").glob("*/bin/initdb"))), None)
    if initdb is None:
        sys.exit("history_lock_bench: no --url and no PostgreSQL server binaries (initdb)")
    bindir = Path(initdb).parent
    user = "nobody" if os.geteuid() == 0 else None
    root.mkdir(parents=True)
    if user:
        os.chown(root.parent, pwd.getpwnam(user).pw_uid, pwd.getpwnam(user).pw_gid)
        os.chown(root, pwd.getpwnam(user).pw_uid, pwd.getpwnam(user).pw_gid)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]

    def run(*args: str) -> None:
        cmd = [str(bindir / args[0]), *args[1:]]
        if user:
            cmd = ["runuser", "-u", user, "--", *cmd]
        subprocess.run(cmd, check=True, capture_output=True, timeout=120)

    run("initdb", "-D", str(root / "data"), "-U", "bench", "--auth=trust", "-E", "UTF8", "--locale=C", "--no-sync")
    run("pg_ctl", "-D", str(root / "data"), "-l", str(root / "log"), "-w", "-o",
        f"-c listen_addresses=127.0.0.1 -p {port} -k {root}", "start")
    return f"postgresql://bench@127.0.0.1:{port}/postgres", lambda: run("pg_ctl", "-D", str(root / "data"), "-m", "fast", "stop")


def _phase(pm, recipe, out: Path, cell: str, seconds: float, inspect_s: float, lock_url: str | None) -> tuple[int, float, int]:
    """Record parts for ``seconds`` (with the table locked when ``lock_url``); (parts, seconds, spooled at the end)."""
    import psycopg

    from inspector import history_store
    from inspector.model import InspectionResult

    locker = None
    if lock_url is not None:
        locker = psycopg.connect(lock_url)
        locker.execute("LOCK TABLE inspections IN ACCESS EXCLUSIVE MODE")
    pm.on_run_start(recipe, out, "captures")
    n, t0 = 0, time.monotonic()
    try:
        while time.monotonic() - t0 < seconds:
            time.sleep(inspect_s)
            result = InspectionResult(capture=f"{cell}-{n:05d}", recipe="bench", verdict="pass", error=None,
                                      timings_s={"total": inspect_s}, defects=(), metadata={"part_id": str(uuid.uuid4())})
            pm.on_result(result, out / result.capture)
            n += 1
        elapsed = time.monotonic() - t0
        waiting = history_store.spooled(out)
    finally:
        if locker is not None:
            locker.rollback()  # releases the lock
            locker.close()
    pm.on_run_end(recipe, out, SimpleNamespace())
    return n, elapsed, waiting


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--url", help="the plant database (default: a throw-away local cluster)")
    ap.add_argument("--seconds", type=float, default=60.0, help="length of each phase (s)")
    ap.add_argument("--inspect-s", type=float, default=0.5, help="simulated inspection time per part (s)")
    args = ap.parse_args()
    from inspector import history_store
    from inspector.manager import create_plugin_manager
    from inspector.recipe import parse_recipe
    from inspector_plugins import history

    root = Path(tempfile.mkdtemp(prefix="lock-bench-"))
    stop = None
    try:
        url = args.url
        if url is None:
            url, stop = _throwaway_cluster(root / "pg")
        cell = f"lock-bench-{uuid.uuid4().hex[:6]}"
        pm = create_plugin_manager()
        recipe = parse_recipe({"recipe": {"name": "bench"}, "stages": [{"use": "segment.threshold"}],
                               "plugins": {"history": {"url": url, "cell": cell, "flush_wait_s": 120.0}}}, pm)
        out = root / "out"
        out.mkdir()
        # free, locked, free again: a drift of the machine's load or of the file's size shows as
        # a difference between the two free phases, not as an effect of the lock
        phases = [("free", _phase(pm, recipe, out, cell + "-free", args.seconds, args.inspect_s, None)),
                  ("locked", _phase(pm, recipe, out, cell + "-locked", args.seconds, args.inspect_s, url)),
                  ("free", _phase(pm, recipe, out, cell + "-free2", args.seconds, args.inspect_s, None))]
        left = history.settle(out, 120.0)
        import psycopg

        with psycopg.connect(url) as con:
            got = con.execute("SELECT COUNT(*), COUNT(DISTINCT uid) FROM inspections WHERE cell = %s", (cell,)).fetchone()
        local = len(history_store.read_history(out))
        for name, (n, s, waiting) in phases:
            print(f"{name:7s} {n:6d} parts in {s:5.1f} s = {60 * n / s:7.1f} parts/min; {waiting} in the spool at the phase's end")
        print(f"after the lock: {left} left in the spool; plant rows {got[0]} ({got[1]} distinct uids) of {local} recorded "
              f"locally -> {'every row once' if got[0] == got[1] == local else 'MISMATCH'}")
        return 0 if got[0] == got[1] == local else 1
    finally:
        if stop is not None:
            stop()
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
