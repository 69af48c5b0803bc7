"""The ``history`` plugin's plant database (issue 17): a real PostgreSQL server, the spool.

The server is Debian's ``postgresql`` package (``make`` installs it when run as root): a
cluster made by ``initdb`` in a temporary folder, run by an unprivileged user (``nobody``
when the tests run as root), listening on a free loopback port, with a password (scram) so
that its masking is tested too. Without the binaries or psycopg the server tests skip and
say why; the tests above the server's need neither server nor folder.
"""

from __future__ import annotations

import json
import os
import pwd
import re
import shlex
import shutil
import socket
import sqlite3
import subprocess
import sys
import tempfile
import threading
from pathlib import Path
from types import SimpleNamespace
from urllib.parse import quote

import pytest

from inspector import history_store
from inspector.errors import RecipeError
from inspector.model import Defect, DeviationStats, EvaluationSummary, InspectionResult
from inspector_frontends.cli import main
from inspector_plugins import history

PASSWORD = "plant:p@ss/w0rd"  # a ':', an '@' and a '/' to mask, percent-encoded in the URL
ENCODED = quote(PASSWORD, safe="")


# --------------------------------------------------------------------------- results


def _result(i: int, cell: str) -> InspectionResult:
    """A real result; every third one fails with a defect (rows with and without defects)."""
    defects = (Defect("missing", (1.0, 2.0, 3.0 + i), (0.5, 0.5, 0.5), 12, -0.25 - i / 1000, "default"),) if i % 3 == 0 else ()
    dev = DeviationStats(mean=0.001 * i, std=0.01, min=-0.05 - (0.25 if defects else 0.0), max=0.05, p01=-0.04, p99=0.04,
                         mean_abs=0.02)
    return InspectionResult(
        capture=f"{cell}-part-{i:04d}", recipe="cube-30", verdict="fail" if defects else "pass", error=None,
        timings_s={"total": 0.8}, defects=defects, metadata={"part_id": f"P-{i:05d}", "timestamp": "2026-12-01T08:00:00+00:00"},
        summary=EvaluationSummary(n_points=1000 + i, deviation_mm=dev, tolerance_mm=(-0.1, 0.1), within_tolerance=0.99,
                                  out_of_tolerance_points=12 if defects else 0),
        extras={"line": "L1", "nan": float("nan")},
    )


class Cell:
    """One inspection cell: its own plugin manager, recipe and OUTDIR, recording through the
    real hooks (``[plugins.history]`` validated by the recipe loader, then the session's
    ``on_run_start`` / ``on_result`` / ``on_run_end`` calls)."""

    def __init__(self, outdir: Path, **history):
        from inspector.manager import create_plugin_manager
        from inspector.recipe import parse_recipe

        self.pm = create_plugin_manager()
        self.recipe = parse_recipe({"recipe": {"name": "cube-30"}, "stages": [{"use": "segment.threshold"}],
                                    "plugins": {"history": history}}, self.pm)
        self.name = history.get("cell", "")
        self.out = outdir
        outdir.mkdir(parents=True, exist_ok=True)

    def __enter__(self):
        self.pm.on_run_start(self.recipe, self.out, "captures")
        return self

    def __exit__(self, *exc):
        self.pm.on_run_end(self.recipe, self.out, SimpleNamespace())

    def inspect(self, i: int) -> None:
        result = _result(i, self.name)
        self.pm.on_result(result, self.out / result.capture)


def _spool(out: Path) -> int:
    con = sqlite3.connect(out / "history.sqlite")
    try:
        return con.execute("SELECT COUNT(*) FROM spool").fetchone()[0]
    finally:
        con.close()


def _warnings(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("inspector: warning:")]


# --------------------------------------------------------------------------- no server needed


def test_a_password_is_masked_in_every_form():
    from inspector_plugins.history_plant import mask_url, scrub

    assert mask_url(f"postgresql://inspector:{ENCODED}@db.plant:5432/plant") == "postgresql://inspector:***@db.plant:5432/plant"
    assert mask_url(f"postgresql://inspector:{PASSWORD}@db.plant/plant") == "postgresql://inspector:***@db.plant/plant"  # raw
    assert mask_url("postgres://db.plant/plant?user=i&password=s3cret&sslmode=require") == \
        "postgres://db.plant/plant?user=i&password=***&sslmode=require"
    assert mask_url("postgresql://inspector@db.plant/plant") == "postgresql://inspector@db.plant/plant"
    url = f"postgresql://inspector:{ENCODED}@db.plant/plant"
    assert scrub(f"failed for {PASSWORD} and {ENCODED}", url) == "failed for *** and ***"
    assert ENCODED not in repr(history.HistorySettings(url=url)) and "inspector:***@db.plant" in repr(history.HistorySettings(url=url))


def test_the_recipe_table_is_checked_when_the_recipe_loads(pm, tmp_path):
    from inspector.recipe import parse_recipe

    def load(history):
        return parse_recipe({"recipe": {"name": "t"}, "stages": [{"use": "segment.threshold"}],
                             "plugins": {"history": history}}, pm, path=tmp_path / "r.toml")

    assert load({}).plugins["history"].url == ""  # the defaults: the file only (or $INSPECTOR_HISTORY_URL)
    ok = load({"url": f"postgresql://inspector:{ENCODED}@db.plant:5432/plant", "cell": "cell-7", "retry_s": 0.0})
    assert ok.plugins["history"].cell == "cell-7"
    for table, key in (({"url": f"mysql://inspector:{ENCODED}@db/plant"}, "url: expected a PostgreSQL URL"),
                       ({"url": f"postgresql://inspector:{ENCODED}@db:port/plant"}, "url: not a valid port"),
                       ({"url": "postgresql://db/plant name"}, "url: a PostgreSQL URL has no spaces"),
                       ({"cell": "a\nb"}, "cell: at most 64 characters"),
                       ({"connect_timeout_s": 0}, "connect_timeout_s"),
                       ({"retry_s": float("nan")}, "retry_s"),
                       ({"uri": "x"}, "unknown parameter 'uri'")):
        with pytest.raises(RecipeError) as e:
            load(table)
        text = str(e.value)
        assert text.startswith("r.toml: plugins.history") and key in text and "\n" not in text, text
        assert PASSWORD not in text and ENCODED not in text


#: history.sqlite as the first version wrote it (no extras, cell, uid or spool).
OLD_SCHEMA = """
CREATE TABLE inspections (id INTEGER PRIMARY KEY, inspected_at TEXT NOT NULL, capture TEXT NOT NULL, part_id TEXT,
    triggered_at TEXT, recipe TEXT NOT NULL, verdict TEXT NOT NULL, error TEXT, n_points INTEGER, deviation_mean_mm REAL,
    deviation_min_mm REAL, deviation_max_mm REAL, n_defects INTEGER NOT NULL, worst_mm REAL, tolerance_lower_mm REAL,
    tolerance_upper_mm REAL, total_s REAL, result_dir TEXT, metadata TEXT);
CREATE TABLE defects (inspection_id INTEGER NOT NULL REFERENCES inspections (id), kind TEXT NOT NULL,
    n_points INTEGER NOT NULL, worst_mm REAL NOT NULL, x REAL, y REAL, z REAL, region TEXT);
PRAGMA user_version = 1;
"""


def test_an_older_file_gets_the_cell_and_uid_columns(tmp_path):
    con = sqlite3.connect(tmp_path / "history.sqlite")
    con.executescript(OLD_SCHEMA)
    con.execute("INSERT INTO inspections (inspected_at, capture, recipe, verdict, n_defects) VALUES ('t', 'old', 'r', 'pass', 0)")
    con.commit()
    con.close()
    history_store.record(_result(3, "cell-1"), tmp_path, cell="cell-1")
    rows = history_store.read_history(tmp_path)
    assert [(r["capture"], r["cell"]) for r in rows] == [("old", None), ("cell-1-part-0003", "cell-1")]
    assert rows[0]["uid"] is None and len(rows[1]["uid"]) == 36
    assert [r["capture"] for r in history_store.read_history(tmp_path, cell="cell-1")] == ["cell-1-part-0003"]
    assert history_store.spooled(tmp_path) == 0  # no plant database: nothing waits


def test_the_plugin_loads_no_database_driver():
    code = ("import sys\nfrom inspector.manager import create_plugin_manager\ncreate_plugin_manager()\n"
            "import inspector_plugins.history\nprint([m for m in sys.modules if m.split('.')[0] == 'psycopg'])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_a_database_that_does_not_answer_costs_one_warning_and_the_rows_wait(tmp_path, capfd):
    pytest.importorskip("psycopg", reason="psycopg is not installed (requirements.lock pins it)")
    with socket.socket() as s:  # a loopback port nobody listens on: refused at once
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    url = f"postgresql://inspector:{ENCODED}@127.0.0.1:{port}/plant"
    with Cell(tmp_path / "out", url=url, cell="cell-9", retry_s=0.0) as cell:
        for i in range(3):
            cell.inspect(i)
    err = capfd.readouterr().err
    warnings = _warnings(err)
    assert len(warnings) == 1, err
    assert warnings[0].startswith(f"inspector: warning: history: plant database postgresql://inspector:***@127.0.0.1:{port}/plant: ")
    # at the sender's first try (the first row or the first few: it sends off the inspection's path);
    # the others follow silently
    assert re.search(r"; [123] inspections? waits? in the spool of", warnings[0]), warnings[0]
    assert PASSWORD not in err and ENCODED not in err
    assert _spool(tmp_path / "out") == 3 and len(history_store.read_history(tmp_path / "out")) == 3
    assert main(["history", str(tmp_path / "out")]) == 0
    assert "3 of them wait in the spool" in capfd.readouterr().out
    assert main(["history", str(tmp_path / "out"), "--send", "--url", url]) == 3
    err = capfd.readouterr().err
    assert err.startswith(f"inspector: error: plant database postgresql://inspector:***@127.0.0.1:{port}/plant: ")
    assert err.strip().endswith("3 inspections stay in the spool") and PASSWORD not in err and ENCODED not in err


def test_reading_without_outdir_needs_a_valid_url(capfd, monkeypatch):
    monkeypatch.delenv("INSPECTOR_HISTORY_URL", raising=False)
    assert main(["history"]) == 2
    assert "give OUTDIR, or the plant database with --url URL or $INSPECTOR_HISTORY_URL" in capfd.readouterr().err
    monkeypatch.setenv("INSPECTOR_HISTORY_URL", f"mysql://inspector:{ENCODED}@db/plant")
    assert main(["history"]) == 2
    err = capfd.readouterr().err
    assert err.startswith("inspector: error: INSPECTOR_HISTORY_URL: expected a PostgreSQL URL") and ENCODED not in err


# --------------------------------------------------------------------------- a real server


def _pg_bindir() -> Path | None:
    found = shutil.which("initdb")
    if found:
        return Path(found).parent
    versions = [p for p in Path("/usr/lib/postgresql").glob("*/bin/initdb") if p.parts[-3].isdigit()]
    return max(versions, key=lambda p: int(p.parts[-3])).parent if versions else None


class PgServer:
    """A throw-away PostgreSQL cluster on 127.0.0.1:``port``, run as an unprivileged user."""

    def __init__(self, bindir: Path, root: Path, user: str | None):
        self.bindir, self.root, self.user = bindir, root, user
        self.data, self.log = root / "data", root / "server.log"
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]

    def _run(self, *args: str) -> None:
        cmd = [str(self.bindir / args[0]), *args[1:]]
        if self.user is not None:  # as root: postgres refuses to run as root
            runuser = shutil.which("runuser")
            cmd = [runuser, "-u", self.user, "--", *cmd] if runuser else ["su", "-s", "/bin/sh", self.user, "-c", shlex.join(cmd)]
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
        if done.returncode != 0:
            log = self.log.read_text(errors="replace")[-2000:] if self.log.exists() else ""
            raise RuntimeError(f"{shlex.join(cmd)}: {done.returncode}\n{done.stdout}\n{done.stderr}\n{log}")

    def init(self) -> None:
        pwfile = self.root / "pw"
        pwfile.write_text(PASSWORD + "\n")
        if self.user is not None:
            os.chown(pwfile, pwd.getpwnam(self.user).pw_uid, -1)
        self._run("initdb", "-D", str(self.data), "-U", "inspector", f"--pwfile={pwfile}", "--auth-local=trust",
                  "--auth-host=scram-sha-256", "-E", "UTF8", "--locale=C", "--no-sync")
        pwfile.unlink()

    def start(self) -> None:
        opts = f"-c listen_addresses=127.0.0.1 -p {self.port} -k {self.root} -c fsync=off -c full_page_writes=off"
        self._run("pg_ctl", "-D", str(self.data), "-l", str(self.log), "-w", "-t", "60", "-o", opts, "start")

    def stop(self, mode: str = "fast") -> None:
        self._run("pg_ctl", "-D", str(self.data), "-m", mode, "-w", "-t", "60", "stop")

    def url(self, database: str) -> str:
        return f"postgresql://inspector:{ENCODED}@127.0.0.1:{self.port}/{database}"


@pytest.fixture(scope="session")
def pg_server():
    pytest.importorskip("psycopg", reason="psycopg is not installed (requirements.lock pins it)")
    bindir = _pg_bindir()
    if bindir is None:
        pytest.skip("PostgreSQL server not found (initdb): install Debian's postgresql package (make does, as root)")
    user = None
    if os.geteuid() == 0:
        try:
            pwd.getpwnam("nobody")
        except KeyError:
            pytest.skip("running as root without a 'nobody' user to run PostgreSQL as")
        user = "nobody"
    root = Path(tempfile.mkdtemp(prefix="inspector-pg-"))  # in /tmp: reachable by 'nobody', unlike pytest's folders
    if user is not None:
        os.chown(root, pwd.getpwnam(user).pw_uid, pwd.getpwnam(user).pw_gid)
    server = PgServer(bindir, root, user)
    try:
        server.init()
        server.start()
        yield server
    finally:
        try:
            server.stop("immediate")
        except RuntimeError:
            pass  # not running
        shutil.rmtree(root, ignore_errors=True)


@pytest.fixture
def plant(pg_server, request):
    """A fresh database of the test server: (its URL, a query function)."""
    import psycopg

    name = "t_" + request.node.name.removeprefix("test_")[:40].lower()
    with psycopg.connect(pg_server.url("postgres"), autocommit=True) as con:
        con.execute(f'DROP DATABASE IF EXISTS "{name}"')
        con.execute(f'CREATE DATABASE "{name}"')
    url = pg_server.url(name)

    def query(sql: str, *params):
        with psycopg.connect(url) as con:
            return con.execute(sql, params).fetchall()

    return url, query


def test_two_cells_writing_at_once_lose_and_double_nothing(plant, tmp_path, capfd):
    url, query = plant
    n = 200
    errors: list[BaseException] = []

    def run(cell: Cell) -> None:  # a cell of its own: its plugin manager, OUTDIR, connection
        try:
            with cell:
                for i in range(n):
                    cell.inspect(i)
        except BaseException as e:  # noqa: BLE001 - reported by the test
            errors.append(e)

    cells = [Cell(tmp_path / name, url=url, cell=name, retry_s=0.0) for name in ("cell-a", "cell-b")]
    threads = [threading.Thread(target=run, args=(cell,)) for cell in cells]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert not errors
    err = capfd.readouterr().err
    assert "warning" not in err, err
    assert query("SELECT cell, COUNT(*), COUNT(DISTINCT capture) FROM inspections GROUP BY cell ORDER BY cell") == \
        [("cell-a", n, n), ("cell-b", n, n)]
    assert query("SELECT COUNT(DISTINCT uid) FROM inspections") == [(2 * n,)]
    n_defects = 2 * len([i for i in range(n) if i % 3 == 0])
    assert query("SELECT COUNT(*) FROM defects") == [(n_defects,)]
    assert query("SELECT COUNT(*) FROM defects d JOIN inspections i ON i.id = d.inspection_id"
                 " WHERE i.n_defects = 1 AND d.worst_mm = i.worst_mm") == [(n_defects,)]
    for name in ("cell-a", "cell-b"):
        local = history_store.read_history(tmp_path / name)
        assert _spool(tmp_path / name) == 0 and len(local) == n
        pg = query("SELECT inspected_at, capture, part_id, verdict, n_points, deviation_min_mm, worst_mm, metadata,"
                   " extras, uid FROM inspections WHERE cell = %s ORDER BY id", name)
        assert pg == [(r["inspected_at"], r["capture"], r["part_id"], r["verdict"], r["n_points"], r["deviation_min_mm"],
                       r["worst_mm"], r["metadata"], r["extras"], r["uid"]) for r in local]  # the same rows, in order
    # `inspector history` on the plant database: every cell's, or one cell's
    assert main(["history", "--url", url, "--cell", "cell-b", "--last", "3", "--json"]) == 0
    rows = json.loads(capfd.readouterr().out)
    assert [r["capture"] for r in rows] == [f"cell-b-part-{i:04d}" for i in range(n - 3, n)]
    assert set(rows[0]) == set(history_store.read_history(tmp_path / "cell-b")[0])
    assert main(["history", "--url", url]) == 0
    out = capfd.readouterr()
    assert out.out.strip().splitlines()[-1].startswith(f"{2 * n} inspections: ") and "cell-a" in out.out
    assert PASSWORD not in out.out + out.err and ENCODED not in out.out + out.err


def test_a_server_stopped_and_restarted_during_a_run_gets_every_row_once(pg_server, plant, tmp_path, capfd):
    from inspector_plugins.history import flush_spool
    from inspector_plugins.history_plant import PlantDatabase

    url, query = plant
    out = tmp_path / "cell-c"
    with Cell(out, url=url, cell="cell-c", retry_s=0.0) as cell:
        for i in range(10):
            cell.inspect(i)
        assert history.settle(out) == 0  # sent by the sender thread (the inspections did not wait for it)
        assert query("SELECT COUNT(*) FROM inspections") == [(10,)]
        pg_server.stop("fast")
        try:
            for i in range(10, 25):
                cell.inspect(i)
            assert history.settle(out) == 15 and _spool(out) == 15
            err = capfd.readouterr().err
            warnings = _warnings(err)
            assert len(warnings) == 1, err  # one line for the outage, not one per row
            assert f"plant database postgresql://inspector:***@127.0.0.1:{pg_server.port}/" in warnings[0]
            assert "inspections wait in the spool of" in warnings[0] or "inspection waits in the spool of" in warnings[0] and PASSWORD not in err and ENCODED not in err
        finally:
            pg_server.start()
        for i in range(25, 35):
            cell.inspect(i)
        assert history.settle(out) == 0
        err = capfd.readouterr().err
        # the first send after the restart takes the 15 spooled rows and those recorded meanwhile
        sent = re.findall(r"answers again; (\d+) spooled inspections sent", err)
        assert _warnings(err) == [] and len(sent) == 1 and 15 <= int(sent[0]) <= 25, err
        # a restart between two records: the stale connection is replaced, no warning, nothing spooled
        pg_server.stop("fast")
        pg_server.start()
        cell.inspect(35)
        assert history.settle(out) == 0
        assert _warnings(capfd.readouterr().err) == [] and _spool(out) == 0
    expected = [f"cell-c-part-{i:04d}" for i in range(36)]
    assert [c for (c,) in query("SELECT capture FROM inspections ORDER BY id")] == expected  # oldest first, once
    n_defects = len([i for i in range(36) if i % 3 == 0])
    assert query("SELECT COUNT(*), COUNT(DISTINCT uid) FROM inspections") == [(36, 36)]
    assert query("SELECT COUNT(*) FROM defects") == [(n_defects,)]
    # the spool flushed again (a crash after the server's commit, before the spool's delete): no row doubled
    con = sqlite3.connect(out / "history.sqlite")
    con.execute("INSERT INTO spool (inspection_id) SELECT id FROM inspections")
    con.commit()
    con.close()
    plant_db = PlantDatabase(url)
    try:
        assert flush_spool(out, plant_db) == 36
    finally:
        plant_db.close()
    assert _spool(out) == 0
    assert query("SELECT COUNT(*), COUNT(DISTINCT uid) FROM inspections") == [(36, 36)]
    assert query("SELECT COUNT(*) FROM defects") == [(n_defects,)]


def test_rows_spooled_by_an_earlier_run_are_sent_by_the_next_or_by_send(pg_server, plant, tmp_path, capfd, monkeypatch):
    url, query = plant
    out = tmp_path / "cell-d"
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        dead = f"postgresql://inspector:{ENCODED}@127.0.0.1:{s.getsockname()[1]}/plant"
    with Cell(out, url=dead, cell="cell-d", retry_s=0.0) as cell:
        for i in range(4):
            cell.inspect(i)
    assert _spool(out) == 4 and len(_warnings(capfd.readouterr().err)) == 1
    assert main(["history", str(out), "--send", "--url", url]) == 0
    assert capfd.readouterr().out.strip() == f"sent 4 spooled inspections to postgresql://inspector:***@127.0.0.1:{pg_server.port}/{url.rsplit('/', 1)[1]}"
    with Cell(out, url=dead, cell="cell-d", retry_s=0.0) as cell:
        cell.inspect(4)
    monkeypatch.setenv("INSPECTOR_HISTORY_URL", url)  # the recipe gives no URL: the environment's
    with Cell(out, cell="cell-d"):
        pass  # the run's start sends what waits
    assert _spool(out) == 0
    assert [c for (c,) in query("SELECT capture FROM inspections ORDER BY id")] == [f"cell-d-part-{i:04d}" for i in range(5)]


# --------------------------------------------------------------------------- calibration health (issue 24)


def _calibrated(i: int, cell: str, flagged: tuple[str, ...] = ()) -> InspectionResult:
    """:func:`_result` with the evaluate stage's calibration health in its stats."""
    import dataclasses

    cams = {f"cam{k:02d}": {"median_px": 0.02, "p90_px": 0.05, "signed_px": 0.0, "shift_px": 0.03, "off_px": 0.03,
                            "rays": 64} for k in range(4)}
    for name in flagged:
        cams[name] = {**cams[name], "shift_px": 1.9, "off_px": 1.9, "median_px": 0.9}
    cams["cam03"]["median_px"] = float("nan")  # not measured: null, never NaN in the JSON
    stats = {"calibration": {"cameras": cams, "flagged": list(flagged), "threshold_px": 0.3}}
    return dataclasses.replace(_result(i, cell), stats=stats)


def test_the_calibration_health_is_a_column_and_an_older_file_gets_it(tmp_path):
    # A file of the version before (extras, cell, uid and the spool, no calibration_json).
    con = sqlite3.connect(tmp_path / "history.sqlite")
    con.executescript(history_store.SCHEMA.replace(",\n    calibration_json TEXT", ""))
    con.execute("CREATE UNIQUE INDEX inspections_uid ON inspections (uid)")
    con.execute("INSERT INTO inspections (inspected_at, capture, recipe, verdict, n_defects) VALUES ('t', 'old', 'r', 'pass', 0)")
    con.commit()
    con.close()
    history_store.record(_calibrated(1, "cell-1", ("cam02",)), tmp_path, cell="cell-1")
    history_store.record(_result(2, "cell-1"), tmp_path, cell="cell-1")  # no calibration checked (an error, an older stage)
    rows = history_store.read_history(tmp_path)
    assert [r["calibration_json"] is None for r in rows] == [True, False, True]
    doc = json.loads(rows[1]["calibration_json"])
    assert doc["flagged"] == ["cam02"] and doc["threshold_px"] == 0.3
    assert doc["off_px"] == {"cam00": 0.03, "cam01": 0.03, "cam02": 1.9, "cam03": 0.03}
    assert doc["median_px"]["cam03"] is None


def test_the_camera_trend_marks_the_flagged_inspections(tmp_path):
    import cv2

    for i in range(6):
        history_store.record(_calibrated(i, "cell-1", ("cam01",) if i >= 4 else ()), tmp_path, cell="cell-1")
    history_store.record(_result(6, "cell-1"), tmp_path, cell="cell-1")  # a gap
    png = history.plot_cameras(history_store.read_history(tmp_path), tmp_path / "cameras.png")
    img = cv2.imread(str(png)).astype(int)
    red = (img[..., 2] > 170) & (img[..., 1] < 60) & (img[..., 0] < 60)  # threshold line, rings
    assert red.sum() > 300


def test_an_older_plant_database_gets_the_new_columns(plant, tmp_path):
    """A plant database made before the calibration column: a cell that connects adds it, and
    its rows (and the older ones) read back."""
    from inspector_plugins.history_plant import PG_ADDED, PG_SCHEMA

    url, query = plant
    old = PG_SCHEMA[0]
    for column, kind in PG_ADDED:
        old = old.replace(f",\n    {column} {kind}", "")
    assert "calibration_json" not in old
    import psycopg

    with psycopg.connect(url, autocommit=True) as con:
        for statement in (old, *PG_SCHEMA[1:]):
            con.execute(statement)
        con.execute("INSERT INTO inspections (inspected_at, capture, recipe, verdict, n_defects, cell, uid)"
                    " VALUES ('t', 'old', 'r', 'pass', 0, 'cell-0', 'u-0')")
    out = tmp_path / "cell-c"
    out.mkdir()
    history_store.record(_calibrated(1, "cell-c", ("cam02",)), out, cell="cell-c", spool=True)
    plant_db = history.PlantDatabase(url)
    try:
        assert history.flush_spool(out, plant_db) == 1
    finally:
        plant_db.close()
    got = query("SELECT capture, calibration_json FROM inspections ORDER BY id")
    assert got[0] == ("old", None) and json.loads(got[1][1])["flagged"] == ["cam02"]
    rows = history.read_plant(url)
    assert sorted(r["capture"] for r in rows) == ["cell-c-part-0001", "old"] and all("calibration_json" in r for r in rows)


# --------------------------------------------------------------------------- a slow plant database (issue 27)


def _waiting_on_inspections(query) -> int:
    """Sessions of the plant database waiting for a lock on ``inspections`` (read from the
    catalogue: it never waits itself)."""
    return query("SELECT COUNT(*) FROM pg_locks WHERE NOT granted AND relation = to_regclass('inspections')")[0][0]


def _until(predicate, what: str, limit: int = 600) -> None:
    """Poll ``predicate`` (state, not time: up to ``limit`` polls 0.05 s apart)."""
    import time

    for _ in range(limit):
        if predicate():
            return
        time.sleep(0.05)
    raise AssertionError(f"never: {what}")


def test_a_locked_table_never_holds_the_line_and_every_row_arrives_once(plant, tmp_path, capfd):
    """``LOCK TABLE inspections`` held by another session: the sender waits on the server, the
    inspections do not (all recorded while the lock is still held), the run's end waits only
    ``flush_wait_s``, and once the lock is released every row is in the plant database once."""
    import psycopg

    url, query = plant
    out = tmp_path / "cell-l"
    locker = None
    try:
        with Cell(out, url=url, cell="cell-l", lock_timeout_s=3600.0, statement_timeout_s=3600.0,
                  flush_wait_s=0.5) as cell:
            cell.inspect(0)
            assert history.settle(out) == 0  # the tables exist, the connection is open
            locker = psycopg.connect(url)
            locker.execute("LOCK TABLE inspections IN ACCESS EXCLUSIVE MODE")  # held until the transaction ends
            cell.inspect(1)
            _until(lambda: _waiting_on_inspections(query) == 1, "the sender waits for the lock")
            for i in range(2, 30):
                cell.inspect(i)  # the line goes on while the sender is stuck in the server
            assert len(history_store.read_history(out)) == 30 and _spool(out) == 29
            assert _waiting_on_inspections(query) == 1 and locker.info.transaction_status == psycopg.pq.TransactionStatus.INTRANS
        # the run ended (its bounded wait ran out) while the lock is still held: the rows wait in the spool
        assert locker.info.transaction_status == psycopg.pq.TransactionStatus.INTRANS and _spool(out) == 29
        warnings = _warnings(capfd.readouterr().err)
        assert len(warnings) == 1 and "not answered within 0.5 s at the run's end; 29 inspections wait in the spool" \
            in warnings[0], warnings
    finally:
        if locker is not None:
            locker.rollback()
            locker.close()
    assert history.settle(out) == 0  # the stuck send went through once the lock was released
    captures = [c for (c,) in query("SELECT capture FROM inspections ORDER BY id")]
    assert captures == [f"cell-l-part-{i:04d}" for i in range(30)]
    # each row's hash-chain value travels with it: the plant database holds a copy of the chain
    assert query("SELECT uid, chain FROM inspections ORDER BY id") == [(r["uid"], r["chain"]) for r in history_store.read_history(out)]
    assert history.verify_history(out).ok
    assert query("SELECT COUNT(DISTINCT uid), COUNT(*) FROM defects d JOIN inspections i ON i.id = d.inspection_id") == \
        [(10, 10)]


def test_a_lock_or_a_slow_statement_ends_the_send_in_its_timeout_with_one_warning(plant, tmp_path, capfd):
    import psycopg

    url, query = plant
    out = tmp_path / "cell-t"
    with Cell(out, url=url, cell="cell-t", retry_s=0.0, lock_timeout_s=0.2, statement_timeout_s=0.5) as cell:
        cell.inspect(0)
        assert history.settle(out) == 0
        with psycopg.connect(url) as locker:
            locker.execute("LOCK TABLE inspections IN ACCESS EXCLUSIVE MODE")
            for i in range(1, 8):
                cell.inspect(i)
                assert history.settle(out) == i  # each try ended by the lock timeout: the row waits
            err = capfd.readouterr().err
            warnings = _warnings(err)
            assert len(warnings) == 1 and "lock timeout" in warnings[0] and PASSWORD not in err and ENCODED not in err
            assert "1 inspection waits in the spool of" in warnings[0]
        cell.inspect(8)  # the lock is gone: the episode ends (at this row, or at the sender's retry just before)
        assert history.settle(out) == 0
        assert re.search(r"answers again; [78] spooled inspections sent", capfd.readouterr().err)
        # a slow server (a trigger sleeping 5 s in every insert): the statement timeout ends the send
        with psycopg.connect(url, autocommit=True) as admin:
            admin.execute("CREATE FUNCTION slow() RETURNS trigger LANGUAGE plpgsql AS "
                          "$$ BEGIN PERFORM pg_sleep(5); RETURN NEW; END $$")
            admin.execute("CREATE TRIGGER slow BEFORE INSERT ON inspections FOR EACH ROW EXECUTE FUNCTION slow()")
        cell.inspect(9)
        assert history.settle(out) == 1
        warnings = _warnings(capfd.readouterr().err)
        assert len(warnings) == 1 and "statement timeout" in warnings[0], warnings
        with psycopg.connect(url, autocommit=True) as admin:
            admin.execute("DROP TRIGGER slow ON inspections")
        cell.inspect(10)
        assert history.settle(out) == 0
    assert [c for (c,) in query("SELECT capture FROM inspections ORDER BY id")] == [f"cell-t-part-{i:04d}" for i in range(11)]


def test_send_takes_the_url_from_the_recipe_after_url_and_before_the_environment(pg_server, plant, tmp_path, capfd,
                                                                                  monkeypatch):
    """Point 10 of issue 27: ``--send`` with ``--recipe`` sends where the run would have."""
    url, query = plant
    out = tmp_path / "cell-r"
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        dead = f"postgresql://inspector:{ENCODED}@127.0.0.1:{s.getsockname()[1]}/plant"
    with Cell(out, url=dead, cell="cell-r", retry_s=0.0) as cell:
        for i in range(3):
            cell.inspect(i)
    assert _spool(out) == 3
    recipe = tmp_path / "line.toml"
    recipe.write_text(f'[recipe]\nname = "line"\n\n[[stages]]\nuse = "segment.threshold"\n\n'
                      f'[plugins.history]\nurl = "{url}"\ncell = "cell-r"\n')
    capfd.readouterr()
    assert main(["history", str(out), "--send", "--recipe", str(recipe), "--url", dead]) == 3  # --url comes first
    assert _spool(out) == 3
    monkeypatch.setenv("INSPECTOR_HISTORY_URL", dead)  # the recipe's URL comes before the environment's
    assert main(["history", str(out), "--send", "--recipe", str(recipe)]) == 0
    assert capfd.readouterr().out.strip().startswith("sent 3 spooled inspections to postgresql://inspector:***@")
    assert _spool(out) == 0 and query("SELECT COUNT(*) FROM inspections") == [(3,)]
    bad = tmp_path / "bad.toml"
    bad.write_text('[recipe]\nname = "bad"\n\n[[stages]]\nuse = "segment.threshold"\n\n[plugins.history]\nurl = "mysql://x/y"\n')
    assert main(["history", str(out), "--send", "--recipe", str(bad)]) == 2
    err = capfd.readouterr().err
    assert err.startswith("inspector: error: ") and "bad.toml" in err and len(err.strip().splitlines()) == 1
