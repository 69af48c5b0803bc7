"""``inspector run --scheduler ADDRESS`` (issue 17): an archive of captures inspected on a real
Dask cluster (a ``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1, started
here) gives the results and history of a local run; a worker killed mid-run costs a retry of
its capture only, and every capture ends with exactly one result and one history row.

Kept small (the group's budget is about a minute on a 2-core machine): the archive holds 20
byte-identical copies of 4 small simulated captures (8 cameras, 256 px), so the local run
that the cluster's must equal inspects those 4 (the pipeline is deterministic: a copy's
result is its source's under another name); the cluster is started once for the module.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from inspector_frontends.cli import main

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
RECIPE = str(ROOT / "tests" / "drivers" / "small_sim.toml")
N_CAPTURES = 20
#: Columns of a history row that differ between two runs: its row id and uid, when it was
#: written, how long the inspection took, and its hash-chain value (which hashes those).
VARYING = {"id", "uid", "inspected_at", "total_s", "chain"}


def _simulate(folder: Path, **params) -> Path:
    from inspector_tools.testing import simulate_capture

    return simulate_capture(folder, **params)


#: The distinct captures: 2 good cubes and 2 with a notch (seed, notched).
DISTINCT = {"g1": (31, False), "n1": (32, True), "g2": (33, False), "n2": (34, True)}


def _source(name: str) -> str:
    """The distinct capture that archive capture ``name`` (``partNN``) is a copy of."""
    return list(DISTINCT)[int(name[4:]) % len(DISTINCT)]


@pytest.fixture(scope="module")
def archive(tmp_path_factory) -> Path:
    """20 capture folders ``part00`` ... ``part19`` (copies of the 4 distinct ones, in turn) in
    one archive folder; the distinct ones are in ``../src``."""
    root = tmp_path_factory.mktemp("archive")
    notch = ({"at": [15.0, 15.0, 0.0], "radius_mm": 3.0, "kind": "remove"},)
    for name, (seed, notched) in DISTINCT.items():
        _simulate(root / "src" / name, seed=seed, bumps=notch if notched else ())
    arch = root / "archive"
    for i in range(N_CAPTURES):
        shutil.copytree(root / "src" / _source(f"part{i:02d}"), arch / f"part{i:02d}")
    return arch


def _inspector(*args: str, **kw) -> subprocess.Popen:
    return subprocess.Popen([str(BIN / "inspector"), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


@pytest.fixture(scope="module")
def local_run(archive, tmp_path_factory):
    """``inspector run`` without a cluster (here, in the test's process): the reference the
    cluster's run must equal."""
    import contextlib
    import io

    out = tmp_path_factory.mktemp("local") / "out"
    with contextlib.redirect_stdout(io.StringIO()):
        code = main(["run", RECIPE, "--capture", str(archive.parent / "src"), "--out", str(out)])
    assert code in (0, 1)
    return code, out


class Cluster:
    """A ``dask scheduler`` and two ``dask worker`` processes (no nanny: a killed worker stays dead)."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.procs: dict[str, subprocess.Popen] = {}
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        sched_file = folder / "scheduler.json"
        self.procs["scheduler"] = subprocess.Popen(
            [str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
             "--scheduler-file", str(sched_file)],
            cwd=folder, env=env, stdout=subprocess.DEVNULL, stderr=open(folder / "scheduler.log", "w"))
        deadline = time.monotonic() + 60
        while not sched_file.is_file() or not sched_file.read_text().strip():
            assert self.procs["scheduler"].poll() is None, (folder / "scheduler.log").read_text()
            assert time.monotonic() < deadline, "the scheduler did not start"
            time.sleep(0.1)
        self.address = json.loads(sched_file.read_text())["address"]
        assert self.address.startswith("tcp://127.0.0.1:")
        for name in ("w1", "w2"):
            self.procs[name] = subprocess.Popen(
                [str(BIN / "dask"), "worker", self.address, "--nthreads", "1", "--nworkers", "1", "--no-nanny",
                 "--name", name, "--local-directory", str(folder / name), "--no-dashboard"],
                cwd=folder, env=env, stdout=subprocess.DEVNULL, stderr=open(folder / f"{name}.log", "w"))
        from distributed import Client

        self.client = Client(self.address, timeout="30s")
        self.client.wait_for_workers(2, timeout=120)

    def workers(self) -> dict[str, str]:
        """Worker name -> address, as the scheduler knows them."""
        return {str(w["name"]): addr for addr, w in self.client.scheduler_info()["workers"].items()}

    def close(self) -> None:
        self.client.close()
        for p in self.procs.values():  # throwaway processes: no graceful shutdown to wait for
            if p.poll() is None:
                p.kill()
            p.wait(timeout=30)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    c = Cluster(tmp_path_factory.mktemp("dask"))
    try:
        yield c
    finally:
        c.close()


def _results(out: Path) -> dict[str, dict]:
    return {p.parent.name: json.loads(p.read_text()) for p in sorted(out.glob("*/result.json"))}


def _history(out: Path) -> list[dict]:
    from inspector.history_store import read_history

    return read_history(out)


def _check_exactly_once(out: Path) -> None:
    names = {f"part{i:02d}" for i in range(N_CAPTURES)}
    assert {p.name for p in out.iterdir() if p.is_dir()} == names  # no hidden .partial / .old folder left
    for name in names:
        assert {"result.json", "bcps_points.ply", "reconstruction.ply"} <= {f.name for f in (out / name).iterdir()}
    rows = _history(out)
    assert sorted(r["capture"] for r in rows) == sorted(names)  # one row each, none twice


def _stable(doc: dict) -> dict:
    """``result.json`` less what depends on the moment: a stage or hook over its time budget
    (a loaded machine) is a warning in ``stats.warnings``."""
    stats = dict(doc["stats"])
    warnings = [w for w in stats.pop("warnings", ()) if "budget" not in w]
    if warnings:
        stats["warnings"] = warnings
    return {**doc, "stats": stats}


def _same_as_local(out: Path, local_out: Path) -> None:
    """Every result and history row of ``out`` is its source's in the local run, but for the
    capture's name (and the columns that differ between any two runs)."""
    mine, ref = _results(out), _results(local_out)
    assert len(mine) == N_CAPTURES and set(ref) == set(DISTINCT)
    for name, doc in mine.items():
        local = _stable(ref[_source(name)])
        doc = _stable(doc)
        assert doc["capture"] == name and local["capture"] == _source(name)
        for key in ("recipe", "verdict", "error", "stats", "defects", "pose", "metadata", "recipe_path",
                    "recipe_sha256", "points", "extras"):
            assert doc[key] == local[key], (name, key, str(doc[key])[:800], str(local[key])[:800])
        assert set(doc["timings_s"]) == set(local["timings_s"])
    local_rows = {r["capture"]: r for r in _history(local_out)}
    for row in _history(out):
        want = {**local_rows[_source(row["capture"])], "capture": row["capture"], "result_dir": row["capture"]}
        assert {k: v for k, v in row.items() if k not in VARYING} == {k: v for k, v in want.items() if k not in VARYING}


def test_an_archive_on_the_cluster_gives_the_local_run_s_results(archive, local_run, cluster, tmp_path, capsys):
    local_code, local_out = local_run
    verdicts = {name: d["verdict"] for name, d in _results(local_out).items()}
    assert verdicts == {"g1": "pass", "n1": "fail", "g2": "pass", "n2": "fail"} and local_code == 1
    out = tmp_path / "out"
    code = main(["run", RECIPE, "--capture", str(archive), "--out", str(out), "--scheduler", cluster.address])
    stdout, stderr = capsys.readouterr()
    assert code == local_code, stderr
    assert "Traceback" not in stderr
    lines = [line for line in stdout.splitlines() if line.startswith("[")]
    assert len(lines) == N_CAPTURES and all(f"/{N_CAPTURES}] part" in line for line in lines)
    assert stdout.splitlines()[-1].startswith(f"{N_CAPTURES} inspected: ")
    _check_exactly_once(out)
    _same_as_local(out, local_out)
    # The inspections ran on both workers (each loaded the recipe once), not in the client.
    loaded = cluster.client.run(lambda: len(__import__("inspector_frontends.distributed").distributed._LOADED))
    assert sorted(loaded.values()) == [1, 1]


def test_a_worker_killed_mid_run_costs_a_retry_of_its_capture_only(archive, local_run, cluster, tmp_path):
    local_code, local_out = local_run
    out = tmp_path / "out"
    p = _inspector("run", RECIPE, "--capture", str(archive), "--out", str(out), "--scheduler", cluster.address)
    assert p.stdout is not None
    first = p.stdout.readline()  # the first result is written: both workers are busy now
    assert first.startswith(f"[1/{N_CAPTURES}]"), first + p.stderr.read()
    by_addr = {addr: name for name, addr in cluster.workers().items()}
    processing = {by_addr[a]: keys for a, keys in cluster.client.processing().items() if keys}
    victim = "w2" if processing.get("w2") else "w1"
    keys = processing[victim]
    assert keys, processing
    cluster.procs[victim].send_signal(signal.SIGKILL)
    cluster.procs[victim].wait(timeout=10)
    stdout, stderr = p.communicate(timeout=300)
    stdout = first + stdout
    assert p.returncode == local_code, stderr
    assert "Traceback" not in stderr
    assert len([line for line in stdout.splitlines() if line.startswith("[")]) == N_CAPTURES
    _check_exactly_once(out)
    _same_as_local(out, local_out)
    # The capture the killed worker was inspecting was inspected again, once, elsewhere.
    key_of = {f"inspector-{hashlib.sha1(str(archive / n).encode()).hexdigest()[:16]}": n for n in _results(out)}
    killed = [key_of[k.rsplit("-", 1)[0]] for k in keys]
    rows = _history(out)
    for name in killed:
        assert _results(out)[name]["verdict"] in ("pass", "fail")
        assert sum(r["capture"] == name for r in rows) == 1


def test_workers_n_runs_a_local_cluster(archive, local_run, tmp_path, capsys):
    """``--workers N``: a LocalCluster of N processes, started and closed by the run."""
    _, local_out = local_run
    out = tmp_path / "out"
    code = main(["run", RECIPE, "--capture", str(archive / "part01"), "--out", str(out), "--workers", "1"])
    stdout = capsys.readouterr().out
    assert code == 1 and "[1/1] part01: FAIL" in stdout  # part01 is a copy of n1, notched
    assert _stable(_results(out)["part01"])["stats"] == _stable(_results(local_out)["n1"])["stats"]
    assert [r["capture"] for r in _history(out)] == ["part01"]


# -- bad input: one line, exit 2, nothing inspected ---------------------------------------
@pytest.mark.parametrize("extra, needle", [
    (["--workers", "0"], "--workers: expected a number >= 1, got 0"),
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "--scheduler and --workers: give one"),
    (["--scheduler", " "], "--scheduler: expected an address"),
])
def test_bad_cluster_options_are_one_line_and_exit_2(extra, needle, tmp_path, capsys):
    code = main(["run", RECIPE, "--capture", str(tmp_path), "--out", str(tmp_path / "out"), *extra])
    err = capsys.readouterr().err
    assert code == 2
    assert err.strip().splitlines() == [f"inspector: error: {err.split('inspector: error: ', 1)[1].strip()}"]
    assert needle in err and not (tmp_path / "out").exists()


def test_cluster_options_need_capture_folders(tmp_path, capsys):
    code = main(["run", RECIPE, "--watch", str(tmp_path), "--out", str(tmp_path / "out"), "--workers", "2"])
    assert code == 2
    assert "--workers: only with --capture" in capsys.readouterr().err


def test_an_unreachable_scheduler_is_one_line_and_exit_2(archive, tmp_path, capsys):
    import dask

    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        code = main(["run", RECIPE, "--capture", str(archive), "--out", str(tmp_path / "out"),
                     "--scheduler", "tcp://127.0.0.1:9"])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "--scheduler tcp://127.0.0.1:9: cannot connect to a Dask scheduler" in err
    assert not (tmp_path / "out").exists()  # nothing inspected, nothing written
