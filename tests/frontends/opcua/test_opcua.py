"""``inspector serve``: a real OPC UA server and real asyncua clients over loopback.

One server (module scope) serves ``opcua_recipes/fast.toml`` (a tiny simulated rig, segment +
carve: the server is under test, not the pipeline) on ``opc.tcp://127.0.0.1:<free port>``
with Basic256Sha256 sign-and-encrypt, a PKI made by ``make_pki`` and a user ``plc``. A test
plugin on its plugin manager (:class:`Gate`) can hold an inspection inside its first stage,
so "busy" is a state the tests choose, not a race. No timing is asserted anywhere.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("asyncua", reason="asyncua is not installed (make installs it from requirements.lock)")

from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

from inspector import hookimpl
from inspector.errors import RecipeError
from inspector.history_store import read_history
from inspector_frontends.opcua import model
from inspector_frontends.opcua.config import ServerSettings, credentials, load_settings, parse_endpoint
from inspector_frontends.opcua.security import CLIENT_URI, make_certificate, make_pki
from inspector_frontends.opcua.server import InspectorServer, ServerThread, part_id_problem

ROOT = Path(__file__).resolve().parents[3]
RECIPES = Path(__file__).resolve().parent / "opcua_recipes"
BIN = Path(sys.executable).parent
USER, PASSWORD = "plc", "correct horse battery"
WAIT_S = 120.0  # generous: the first cycle of a process loads the compiled kernels


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Gate:
    """Holds every stage (``inspector_before_stage``) while armed, until opened."""

    def __init__(self) -> None:
        self.armed = False
        self.entered = threading.Event()
        self.released = threading.Event()

    @hookimpl
    def inspector_before_stage(self, context, stage, step):
        if self.armed:
            self.entered.set()
            self.released.wait(WAIT_S)

    def arm(self) -> None:
        self.entered.clear()
        self.released.clear()
        self.armed = True

    def open(self) -> None:
        self.armed = False
        self.released.set()


#: The stage watchdog's limits while these tests run: a verdict must not depend on how busy the
#: machine is (the watchdog itself: tests/core/test_watchdog.py).
NO_DEADLINE = {"INSPECTOR_STAGE_LIMIT_S": "86400", "INSPECTOR_INSPECTION_LIMIT_S": "86400"}


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    from inspector.manager import create_plugin_manager

    with pytest.MonkeyPatch.context() as env:  # read whenever a recipe is loaded: for the module's life
        for name, value in NO_DEADLINE.items():
            env.setenv(name, value)
        yield from _cell(tmp_path_factory, create_plugin_manager)


def _cell(tmp_path_factory, create_plugin_manager):
    root = tmp_path_factory.mktemp("opcua")
    make_pki(root / "pki")
    gate = Gate()
    pm = create_plugin_manager()
    pm.register(gate, "opcua_test_gate")
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    settings = ServerSettings(endpoint=url, pki=root / "pki", recipes=RECIPES)
    lines: list[str] = []
    server = InspectorServer(RECIPES / "fast.toml", root / "out", settings, pm=pm, log=lines.append,
                             env={"INSPECTOR_OPCUA_USER": USER, "INSPECTOR_OPCUA_PASSWORD": PASSWORD})
    with ServerThread(server):
        yield type("Cell", (), {"url": url, "root": root, "pki": root / "pki", "out": root / "out", "server": server,
                                "gate": gate, "lines": lines})()
    gate.open()


class Plc:
    """A connected client and the Inspector nodes."""

    def __init__(self, client: Client, idx: int) -> None:
        self.client, self.idx = client, idx
        self.obj = client.get_node(ua.NodeId(model.OBJECT, idx))

    def node(self, name: str):
        return self.client.get_node(ua.NodeId(model.node_id(name), self.idx))

    async def read(self, *names: str):
        values = await self.client.read_values([self.node(n) for n in names])
        return values[0] if len(names) == 1 else values

    async def call(self, method: str, *args):
        return await self.obj.call_method(ua.QualifiedName(method, self.idx), *[ua.Variant(a, ua.VariantType.String)
                                                                                for a in args])

    async def trigger(self, part_id: str, via: str = "method") -> None:
        if via == "method":
            await self.call("StartSingleJob", part_id)
        else:
            await self.client.write_values([self.node("PartId"), self.node("Trigger")], [part_id, True])

    async def wait(self, name: str, ok, timeout: float = WAIT_S):
        end = time.monotonic() + timeout
        while True:
            value = await self.read(name)
            if ok(value):
                return value
            assert time.monotonic() < end, f"{name} stayed {value!r}"
            await asyncio.sleep(0.005)

    async def counter_after(self, before: int, timeout: float = WAIT_S) -> int:
        """Wait for ResultCounter to change: woken by a subscription (publishing interval 0),
        as a PLC would subscribe, so no polling loads the machine while a part is inspected;
        decided by a read, so a late notification cannot fool it."""
        if not hasattr(self, "_changed"):
            self._changed = asyncio.Event()
            changed = self._changed

            class Handler:
                def datachange_notification(self, node, val, data):
                    changed.set()

            sub = await self.client.create_subscription(0, Handler())
            await sub.subscribe_data_change(self.node("ResultCounter"))
        end = time.monotonic() + timeout
        while True:
            self._changed.clear()
            value = await self.read("ResultCounter")
            if value != before:
                return value
            remaining = end - time.monotonic()
            assert remaining > 0, f"ResultCounter stayed {before}"
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(self._changed.wait(), min(remaining, 0.5))

    async def result_after(self, before: int) -> dict:
        counter = await self.counter_after(before)
        names = ("Verdict", "VerdictCode", "ResultPartId", "DefectCount", "WorstDeviation", "CycleTime", "ErrorText",
                 "LastResult", "ResultCounter")
        values = dict(zip(names, await self.read(*names)))
        assert values["ResultCounter"] == counter  # nothing else published in between
        return values


@contextlib.asynccontextmanager
async def plc(cell, *, user: str | None = USER, password: str = PASSWORD, cert: Path | None = None,
              key: Path | None = None, secure: bool = True):
    # A request may legitimately take long under load (a RecipeName write answers once the
    # recipe is loaded: 12 s for the full recipe's first load at load average 24); waiting on
    # it with a 20 s request timeout made the recipe test fail on a busy machine.
    client = Client(cell.url, timeout=WAIT_S)
    client.application_uri = CLIENT_URI
    if secure:
        await client.set_security(SecurityPolicyBasic256Sha256, str(cert or cell.pki / "plc-cert.der"),
                                  str(key or cell.pki / "plc-key.pem"), mode=ua.MessageSecurityMode.SignAndEncrypt)
    if user:
        client.set_user(user)
        client.set_password(password)
    await client.connect()
    try:
        yield Plc(client, await client.get_namespace_index(model.NAMESPACE))
    finally:
        with contextlib.suppress(Exception):
            await client.disconnect()


def history(cell) -> list[dict]:
    return read_history(cell.out)


def run(coro):
    return asyncio.run(coro)


# --------------------------------------------------------------------------- the handshake
def test_a_hundred_parts_in_a_row_each_part_id_with_its_verdict_and_history_row(cell):
    seen: list[dict] = []

    async def main():
        async with plc(cell) as p:
            assert await p.read("State") == "Ready" and await p.read("Ready") is True
            for i in range(100):
                part_id = f"RUN-{i:03d}"
                before = await p.read("ResultCounter")
                await p.trigger(part_id, "method" if i % 2 else "variable")
                assert await p.read("Busy") is True or await p.read("ResultCounter") == before + 1
                res = await p.result_after(before)
                assert res["ResultCounter"] == before + 1  # exactly one increment per trigger
                assert res["ResultPartId"] == part_id
                assert await p.read("Trigger") is False
                seen.append(res)
            await p.wait("Ready", bool)

    run(main())
    rows = {r["capture"]: r for r in history(cell) if r["capture"].startswith("RUN-")}
    assert len(rows) == 100
    for i, res in enumerate(seen):
        part_id = f"RUN-{i:03d}"
        row = rows[part_id]
        last = json.loads(res["LastResult"])
        assert row["part_id"] == part_id and last["part_id"] == part_id and last["capture"] == part_id
        assert row["verdict"] == res["Verdict"] == last["verdict"] == "pass"
        assert res["VerdictCode"] == 1 and res["ErrorText"] == ""
        assert last["counter"] == res["ResultCounter"] and last["result_dir"] == part_id  # no server path
        assert (cell.out / last["result_dir"] / "result.json").is_file()
        assert row["triggered_at"] == last["triggered_at"]
        assert json.loads((cell.out / part_id / "result.json").read_text())["metadata"]["part_id"] == part_id
        assert math.isnan(res["WorstDeviation"])  # the fast recipe measures nothing


def test_trigger_while_busy_is_refused_and_a_reconnecting_client_sees_a_consistent_state(cell):
    async def main():
        cell.gate.arm()
        try:
            async with plc(cell) as a:
                before = await a.read("ResultCounter")
                await a.trigger("BUSY-1", "variable")
                assert cell.gate.entered.wait(WAIT_S)
                assert await a.read("Busy", "Ready", "State", "Trigger") == [True, False, "SingleExecution", True]
                with pytest.raises(ua.uaerrors.BadInvalidState):
                    await a.trigger("BUSY-2", "method")
                with pytest.raises(ua.uaerrors.BadInvalidState):
                    await a.trigger("BUSY-3", "variable")
                assert "busy with part 'BUSY-1'" in await a.read("ErrorText")
                await a.node("Trigger").write_value(False)  # the PLC drops its bit: accepted, the cycle goes on
                with pytest.raises(ua.uaerrors.BadInvalidState):
                    await a.node("Trigger").write_value(True)  # a new rising edge while Busy: refused too
                assert await a.read("PartId") == "BUSY-1"  # the refused writes changed nothing
            # The PLC's connection drops mid-cycle; it reconnects and reads the same state.
            async with plc(cell) as b:
                assert await b.read("Busy", "Ready", "State", "ResultCounter") == [True, False, "SingleExecution", before]
                cell.gate.open()
                res = await b.result_after(before)
                assert res["ResultCounter"] == before + 1  # the refused triggers counted nothing
                assert (res["ResultPartId"], res["Verdict"]) == ("BUSY-1", "pass")
                await b.wait("Busy", lambda v: v is False)
                assert await b.read("Ready", "State", "Trigger") == [True, "Ready", False]
        finally:
            cell.gate.open()

    run(main())
    rows = [r for r in history(cell) if r["part_id"] and r["part_id"].startswith("BUSY-")]
    assert [(r["capture"], r["verdict"]) for r in rows] == [("BUSY-1", "pass")]


def test_abort_publishes_an_aborted_result_and_writes_nothing(cell):
    async def main():
        cell.gate.arm()
        try:
            async with plc(cell) as p:
                before = await p.read("ResultCounter")
                await p.trigger("ABORT-1")
                assert cell.gate.entered.wait(WAIT_S)
                await p.call("Abort")
                cell.gate.open()
                res = await p.result_after(before)
                assert (res["Verdict"], res["VerdictCode"], res["ResultPartId"]) == ("aborted", 4, "ABORT-1")
                assert res["ErrorText"]
                await p.wait("Ready", bool)
                before = await p.read("ResultCounter")
                await p.trigger("ABORT-2")  # the next part runs as usual
                assert (await p.result_after(before))["Verdict"] == "pass"
        finally:
            cell.gate.open()

    run(main())
    assert not (cell.out / "ABORT-1").exists()
    assert [r["capture"] for r in history(cell) if r["capture"].startswith("ABORT-")] == ["ABORT-2"]


def test_part_ids_that_cannot_name_a_folder_are_refused_and_a_repeated_one_gets_a_suffix(cell):
    async def main():
        async with plc(cell) as p:
            before = await p.read("ResultCounter")
            await p.node("PartId").write_value("GOOD")
            for bad in ("a/b", "history.sqlite", "x" * 300, "..", "tab\there", ".hidden"):
                with pytest.raises(ua.uaerrors.BadInvalidArgument):
                    await p.node("PartId").write_value(bad)
                with pytest.raises(ua.uaerrors.BadInvalidArgument):
                    await p.trigger(bad)
                with pytest.raises(ua.uaerrors.BadInvalidArgument):
                    await p.trigger(bad, "variable")  # PartId and Trigger in one write: neither is applied
                text = await p.read("ErrorText")
                assert text.startswith("PartId ") and "\n" not in text
            assert await p.read("PartId") == "GOOD" and await p.read("ResultCounter") == before
            with pytest.raises(ua.uaerrors.BadTypeMismatch):
                await p.node("Trigger").write_value("yes")
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await p.node("Verdict").write_value("pass")  # outputs are read-only, for every user
            for _ in range(2):
                before = await p.read("ResultCounter")
                await p.trigger("DUP")
                await p.result_after(before)
                await p.wait("Ready", bool)

    run(main())
    rows = [(r["capture"], r["part_id"]) for r in history(cell) if r["part_id"] == "DUP"]
    assert rows == [("DUP", "DUP"), ("DUP-2", "DUP")]


def test_recipes_switch_by_name_and_a_bad_one_is_refused(cell):
    async def main():
        async with plc(cell) as p:
            assert await p.read("Recipes") == ["broken", "fast", "full"]
            for bad, why in (("broken", "unknown stage 'segment.nothing'"), ("nope", "no recipe nope.toml"),
                             ("../fast", "no recipe")):
                with pytest.raises(ua.uaerrors.BadInvalidArgument):
                    await p.node("RecipeName").write_value(bad)
                text = await p.read("ErrorText")
                assert why in text and "\n" not in text and "Traceback" not in text
                assert await p.read("RecipeName", "State", "Ready") == ["fast", "Ready", True]
            await p.node("RecipeName").write_value("full")
            assert await p.read("RecipeName", "State", "Ready", "ErrorText") == ["full", "Ready", True, ""]
            results = []
            for i in range(5):
                before = await p.read("ResultCounter")
                await p.trigger(f"FULL-{i}")
                results.append(await p.result_after(before))
                await p.wait("Ready", bool)
            await p.node("RecipeName").write_value("fast")
            return results

    results = run(main())
    rows = {r["capture"]: r for r in history(cell) if r["capture"].startswith("FULL-")}
    for i, res in enumerate(results):
        row = rows[f"FULL-{i}"]
        assert row["recipe"] == "opcua-full" and row["verdict"] == res["Verdict"] in ("pass", "fail")
        assert res["DefectCount"] == row["n_defects"]
        worst = max(row["deviation_min_mm"], row["deviation_max_mm"], key=abs)
        assert res["WorstDeviation"] == pytest.approx(worst)
        assert res["VerdictCode"] == {"pass": 1, "fail": 2}[res["Verdict"]]
    assert cell.server.recipe_name == "fast"


def test_the_calibration_state_is_published_with_the_result(cell):
    """A result whose calibration health flags a camera sets CalibrationOk false and names it,
    before ResultCounter; one that did not check it (an error) leaves the state as it was."""
    from inspector.model import InspectionResult
    from inspector_frontends.opcua.records import record

    def published(flagged: list[str] | None) -> dict:
        stats = {} if flagged is None else {"calibration": {
            "cameras": {n: {"off_px": 1.9 if n in flagged else 0.03} for n in ("cam00", "cam01", "cam02")},
            "flagged": flagged, "threshold_px": 0.3}}
        res = InspectionResult(capture="CAL", recipe="opcua-fast", verdict="pass" if flagged is not None else "error",
                               error=None if flagged is not None else "segment: broken", timings_s={"total": 0.1},
                               stats=stats)
        rec = record(res, None)
        asyncio.run_coroutine_threadsafe(cell.server._publish(rec), cell.server._loop).result(WAIT_S)
        return rec

    async def main():
        async with plc(cell) as p:
            assert model.variable("CalibrationOk").initial is True
            out = []
            for flagged in (["cam01"], None, []):
                before = await p.read("ResultCounter")
                rec = published(flagged)
                res = await p.result_after(before)
                out.append((await p.read("CalibrationOk", "CalibrationFlagged"), json.loads(res["LastResult"]), rec))
            return out

    (ok1, last1, _), (ok2, last2, _), (ok3, _, _) = run(main())
    assert ok1 == [False, "cam01"] and last1["calibration"] == {"flagged": ["cam01"],
                                                                "off_px": {"cam00": 0.03, "cam01": 1.9, "cam02": 0.03}}
    assert ok2 == [False, "cam01"] and last2["calibration"] is None  # not checked: the state stays
    assert ok3 == [True, ""]


def test_the_characteristics_are_published_with_the_result(cell):
    """A result with measured characteristics (issue 28): their values and the NOK ids, before
    ResultCounter; a result without any publishes an empty list."""
    from inspector.model import InspectionResult
    from inspector_frontends.opcua.records import record

    rows = [{"id": "1", "kind": "diameter", "nominal": 36.0, "measured": 35.982, "deviation": -0.018, "lower": -0.05,
             "upper": 0.05, "u": 0.0015, "U": 0.003, "verdict": "ok", "points": 812, "reason": None},
            {"id": "7", "kind": "distance", "nominal": 6.0, "measured": 6.071, "deviation": 0.071, "lower": -0.05,
             "upper": 0.05, "u": 0.001, "U": 0.002, "verdict": "nok", "points": 403, "reason": None},
            {"id": "9", "kind": "flatness", "nominal": 0.0, "measured": None, "deviation": None, "lower": 0.0,
             "upper": 0.01, "u": None, "U": None, "verdict": "not_measurable", "points": 3, "reason": "3 points"}]

    def published(chars: list | None) -> None:
        res = InspectionResult(capture="CHR", recipe="opcua-fast", verdict="fail" if chars else "pass", error=None,
                               timings_s={"total": 0.1}, extras={} if chars is None else {"characteristics": chars})
        asyncio.run_coroutine_threadsafe(cell.server._publish(record(res, None)), cell.server._loop).result(WAIT_S)

    async def main():
        async with plc(cell) as p:
            out = []
            for chars in (rows, None):
                before = await p.read("ResultCounter")
                published(chars)
                res = await p.result_after(before)
                out.append((await p.read("CharacteristicsNok", "Characteristics"), json.loads(res["LastResult"])))
            return out

    ((nok, text), last), ((nok2, text2), last2) = run(main())
    assert nok == "7"
    assert json.loads(text) == last["characteristics"] == [
        {"id": "1", "kind": "diameter", "measured": 35.982, "deviation": -0.018, "lower": -0.05, "upper": 0.05,
         "U": 0.003, "verdict": "ok"},
        {"id": "7", "kind": "distance", "measured": 6.071, "deviation": 0.071, "lower": -0.05, "upper": 0.05,
         "U": 0.002, "verdict": "nok"},
        {"id": "9", "kind": "flatness", "measured": None, "deviation": None, "lower": 0.0, "upper": 0.01, "U": None,
         "verdict": "not_measurable"}]
    assert (nok2, json.loads(text2), last2["characteristics"]) == ("", [], [])


def test_an_anonymous_reader_sees_no_server_path(cell):
    """Issue 27 finding 10: LastResult showed the result folder's absolute path (and an error
    its files') to every reader. Now result_dir is the folder's name in --out, and the out
    folder's path is taken out of the published error."""
    root = str(cell.out.resolve())
    text = f"capture 'X': result not written: {root}/X/result.json: No space left on device"

    async def main():
        async with plc(cell, user=None) as anonymous:
            before = await anonymous.read("ResultCounter")
            asyncio.run_coroutine_threadsafe(cell.server._publish(cell.server._error_record(None, text)),
                                             cell.server._loop).result(WAIT_S)
            await anonymous.counter_after(before)
            return await anonymous.read("ErrorText", "LastResult")

    error, last = run(main())
    assert error == "capture 'X': result not written: X/result.json: No space left on device"
    assert root not in last and json.loads(last)["error"] == error


def test_continuous_execution_until_stop(cell):
    async def main():
        async with plc(cell) as p:
            before = await p.read("ResultCounter")
            await p.call("StartContinuous")
            assert await p.read("State") == "ContinuousExecution"
            with pytest.raises(ua.uaerrors.BadInvalidState):
                await p.trigger("NOT-NOW")
            await p.wait("ResultCounter", lambda c: c >= before + 3)
            await p.call("Stop")
            await p.wait("State", lambda s: s == "Ready")
            assert await p.read("Busy", "Ready") == [False, True]
            after = await p.read("ResultCounter")
            await asyncio.sleep(0.2)
            assert await p.read("ResultCounter") == after  # stopped: nothing more comes
            return after - before

    n = run(main())
    assert n >= 3


# --------------------------------------------------------------------------- security
def test_wrong_password_unknown_user_and_an_untrusted_certificate_are_refused(cell, tmp_path):
    make_certificate(tmp_path / "c.der", tmp_path / "k.pem", uri=CLIENT_URI, name="stranger", server=False)

    async def main():
        for user, password in ((USER, "wrong password"), ("mallory", PASSWORD)):
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                async with plc(cell, user=user, password=password):
                    pass
        with pytest.raises(ua.uaerrors.BadCertificateUntrusted):
            async with plc(cell, cert=tmp_path / "c.der", key=tmp_path / "k.pem"):
                pass
        with pytest.raises(ua.UaError, match="No matching endpoints"):  # no unsecured endpoint is offered
            async with plc(cell, secure=False):
                pass
        async with plc(cell, user=None) as anonymous:  # a trusted certificate, no user: reads only
            assert await anonymous.read("State") == "Ready"
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await anonymous.node("PartId").write_value("ANON")
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await anonymous.trigger("ANON")

    run(main())
    assert not any(r["capture"] == "ANON" for r in history(cell))
    assert any("login refused: user 'mallory'" in line for line in cell.lines)
    assert not any(PASSWORD in line or "wrong password" in line for line in cell.lines)  # never printed


def test_settings_are_checked_before_the_server_starts(tmp_path):
    cfg = tmp_path / "cell.toml"
    cfg.write_text('[server]\nendpoint = "opc.tcp://127.0.0.1:4840"\nsecurity = "open"\n')
    with pytest.raises(RecipeError, match=r"cell\.toml: server.*security"):
        load_settings(cfg)
    cfg.write_text('[server]\nport = 4840\n')
    with pytest.raises(RecipeError, match=r"cell\.toml: server.*'port'"):
        load_settings(cfg)
    cfg.write_text('[recipe]\nname = "x"\n')
    with pytest.raises(RecipeError, match="unknown table 'recipe'"):
        load_settings(cfg)
    cfg.write_text('[server]\npki = "pki"\nanonymous_write = true\n')
    s = load_settings(cfg)
    assert s.pki == tmp_path / "pki" and s.anonymous_write and s.security == "sign-encrypt"
    for url in ("http://x:1", "opc.tcp://host", "opc.tcp://h:99999", ""):
        with pytest.raises(RecipeError):
            parse_endpoint(url)
    with pytest.raises(RecipeError, match="has no password"):
        credentials(ServerSettings(user="plc"), env={})
    with pytest.raises(RecipeError, match="no user"):
        credentials(ServerSettings(), env={"INSPECTOR_OPCUA_PASSWORD": "x"})
    with pytest.raises(RecipeError, match="password_hash"):
        credentials(ServerSettings(user="plc", password_hash="plain"), env={})
    assert "secret" not in repr(credentials(ServerSettings(), env={"INSPECTOR_OPCUA_USER": "u",
                                                                   "INSPECTOR_OPCUA_PASSWORD": "secret"}))
    url = "opc.tcp://127.0.0.1:4840"
    with pytest.raises(RecipeError, match="--make-cert"):  # sign-encrypt without a certificate
        InspectorServer(RECIPES / "fast.toml", tmp_path / "out", ServerSettings(endpoint=url), env={})
    with pytest.raises(RecipeError, match="plain text"):
        InspectorServer(RECIPES / "fast.toml", tmp_path / "out", ServerSettings(endpoint=url, security="none"),
                        env={"INSPECTOR_OPCUA_USER": "u", "INSPECTOR_OPCUA_PASSWORD": "p"})
    assert part_id_problem("") is None and part_id_problem("A-0001_x.y") is None
    assert part_id_problem("recipes") and part_id_problem("a\\b") and part_id_problem("é" * 101)


# --------------------------------------------------------------------------- the README's walk-through
def test_inspector_serve_and_the_example_client_as_the_readme_shows(tmp_path, capsys, monkeypatch):
    import io

    from inspector_frontends.cli import main

    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("INSPECTOR_OPCUA_USER", None)
    env.pop("INSPECTOR_OPCUA_PASSWORD", None)
    inspector = str(BIN / "inspector")
    assert main(["serve", "--make-cert", str(tmp_path / "pki")]) == 0
    assert (tmp_path / "pki" / "trusted" / "plc-cert.der").is_file()
    assert main(["serve", "--make-cert", str(tmp_path / "pki")]) == 2  # a certificate is never replaced
    assert "exists already" in capsys.readouterr().err
    monkeypatch.setattr(sys, "stdin", io.StringIO(PASSWORD + "\n"))
    assert main(["serve", "--hash-password"]) == 0
    hashed = capsys.readouterr().out.strip()
    assert hashed.startswith("pbkdf2_sha256$") and PASSWORD not in hashed
    (tmp_path / "cell.toml").write_text(f'[server]\npki = "pki"\nuser = "{USER}"\npassword_hash = "{hashed}"\n')
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    out = tmp_path / "out"
    recipe = tmp_path / "recipes" / "fast.toml"
    recipe.parent.mkdir()
    shutil.copy(RECIPES / "fast.toml", recipe)
    server = subprocess.Popen([inspector, "serve", str(recipe), "--opcua", url, "--out", str(out),
                               "--config", str(tmp_path / "cell.toml")],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    watchdog = threading.Timer(300, server.kill)  # a hung server fails the test, never the suite
    watchdog.start()
    try:
        first = server.stdout.readline()
        assert first.startswith(f"Inspector OPC UA server on {url}"), first + server.stderr.read()
        client = subprocess.run([sys.executable, str(ROOT / "examples" / "plc_client.py"), "--url", url,
                                 "--pki", str(tmp_path / "pki"), "--user", USER, "--parts", "3", "--prefix", "EX-",
                                 "--json"], capture_output=True, text=True, timeout=300,
                                env={**env, "INSPECTOR_OPCUA_PASSWORD": PASSWORD})
        assert client.returncode == 0, client.stdout + client.stderr
        parts = [json.loads(line) for line in client.stdout.splitlines()]
        assert [(p["part_id"], p["result_part_id"], p["verdict"]) for p in parts] == [
            (f"EX-{i:04d}", f"EX-{i:04d}", "pass") for i in (1, 2, 3)]
        assert [p["counter"] for p in parts] == [1, 2, 3]
    finally:
        server.send_signal(signal.SIGINT)
        stdout, stderr = server.communicate(timeout=120)
        watchdog.cancel()
    assert server.returncode == 0, stderr
    assert "EX-0003: PASS" in stdout and "stopped after 3 results" in stdout
    capsys.readouterr()
    assert main(["history", str(out), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [(r["capture"], r["part_id"], r["verdict"]) for r in rows] == [(f"EX-{i:04d}", f"EX-{i:04d}", "pass")
                                                                            for i in (1, 2, 3)]


# --------------------------------------------------------------------------- light and documented
def test_the_plugin_loads_without_asyncua_and_the_manual_documents_the_model():
    code = ("import sys, inspector\nfrom inspector.manager import create_plugin_manager\n"
            "pm = create_plugin_manager(); assert 'serve' in pm.commands.names()\n"
            "print([m for m in ('asyncua', 'cryptography', 'inspector_frontends.opcua.server') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
    page = (ROOT / "docs" / "opcua.md").read_text()
    assert model.markdown_table() in page  # the manual's table is the model's, node for node
    assert "examples/plc_client.py" in page and "inspector serve" in page


def test_failed_logins_are_slowed_per_user_and_for_everyone():
    """Issue 27 finding 9: 48 password guesses in 6.4 s, each a PBKDF2 check on the event loop."""
    from inspector_frontends.opcua.config import Credentials
    from inspector_frontends.opcua.security import LoginThrottle, UserManager

    now = [0.0]
    checks = []

    class Counting(Credentials):
        def check(self, user, password):
            checks.append(user)
            return super().check(user, password)

    lines = []
    users = UserManager(Counting(USER, PASSWORD), lines.append, LoginThrottle(clock=lambda: now[0]))
    for _ in range(48):  # one guesser, as fast as it can: the clock barely moves
        assert users.get_user(None, USER, "guess") is None
        now[0] += 0.13
    assert len(checks) <= 3 + 3  # three free, then one per back-off (1, 2, 4 ... s)
    assert any("too many failed logins" in line for line in lines)
    assert users.get_user(None, USER, PASSWORD) is None  # locked: even the right password waits
    now[0] += 61.0
    assert users.get_user(None, USER, PASSWORD) is not None  # after the back-off, and the record is cleared
    assert users.get_user(None, USER, "guess") is None and users.get_user(None, USER, PASSWORD) is not None
    # Many names: the shared record slows them all.
    before = len(checks)
    for i in range(40):
        users.get_user(None, f"name{i}", "guess")
        now[0] += 0.1
    assert len(checks) - before <= 10 + 4


def test_a_password_check_runs_off_the_event_loop_and_reads_go_on(tmp_path):
    """Issue 27 finding 9: each PBKDF2 check ran on the server's event loop (reads delayed up
    to 677 ms). A check is held in progress here until another client's read has been
    served: on the loop, that read would wait behind it, and the order below would differ."""
    from types import SimpleNamespace

    from inspector_frontends.opcua.config import Credentials

    order: list[str] = []
    entered, release = threading.Event(), threading.Event()

    class Held(Credentials):
        def check(self, user, password):
            order.append("check started")
            entered.set()
            release.wait(30)  # the read below releases it (or 30 s pass: the test then fails on the order)
            order.append("check ended")
            return super().check(user, password)

    make_pki(tmp_path / "pki")
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    server = InspectorServer(RECIPES / "fast.toml", tmp_path / "out", ServerSettings(endpoint=url, pki=tmp_path / "pki"),
                             env={"INSPECTOR_OPCUA_USER": USER, "INSPECTOR_OPCUA_PASSWORD": PASSWORD}, warm_up=False)
    server._creds = Held(USER, _plain=PASSWORD)  # the server's one user, its check held
    where = SimpleNamespace(url=url, pki=tmp_path / "pki")

    async def login():
        async with plc(where) as writer:
            return await writer.read("State")

    async def main():
        async with plc(where, user=None) as reader:
            logging_in = asyncio.create_task(login())
            assert await asyncio.to_thread(entered.wait, WAIT_S)
            assert await reader.read("State") == "Ready"  # served while the password is being checked
            order.append("read served")
            release.set()
            assert await logging_in == "Ready"  # and the login goes through

    with ServerThread(server):
        try:
            run(main())
        finally:
            release.set()
    assert order == ["check started", "read served", "check ended"]
