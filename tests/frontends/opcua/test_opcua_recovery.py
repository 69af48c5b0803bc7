"""``inspector serve`` killed with SIGKILL at each moment of a cycle, then started again.

Issue 27 finding 4: a kill after the result folder and before its history row left an
orphan folder (the PLC's re-trigger wrote ``P-2``); a kill after the row left the verdict
unpublished (the re-trigger added a second row); ``.P.partial`` stayed. Here a real
``inspector serve`` process kills itself at a chosen point of one part's cycle: a plugin file
of this test (``inspector --plugin FILE serve``, the ordinary way to load a local plugin)
sends SIGKILL from the hook that runs at that moment, so nothing in the product knows about
the test. Its state after each restart is read with an asyncua client, as a PLC reads it.
No timing is asserted anywhere.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
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

from inspector.history_store import read_history, recorded
from inspector_frontends.opcua import model
from inspector_frontends.opcua.journal import JOURNAL_FILE

RECIPES = Path(__file__).resolve().parent / "opcua_recipes"
INSPECTOR = str(Path(sys.executable).parent / "inspector")
WAIT_S = 120.0

#: The test plugin: SIGKILL at the point $TEST_CRASH_AT of the part $TEST_CRASH_PART.
CRASHER = '''
import os, signal, time
from pathlib import Path
from inspector import hookimpl

AT, PART = os.environ.get("TEST_CRASH_AT", ""), os.environ.get("TEST_CRASH_PART", "")


def _mine(metadata):
    return bool(PART) and str((metadata or {}).get("part_id") or "") == PART


@hookimpl
def inspector_before_stage(context, stage, step):
    if AT == "inspecting" and _mine(context.capture.metadata):
        os.kill(os.getpid(), signal.SIGKILL)


@hookimpl(ORDER=True)
def inspector_on_result(result, outdir):
    if not _mine(result.metadata):
        return
    if AT == "after-row":  # called after the history plugin: wait for its row, then die
        from inspector.history_store import recorded
        end = time.monotonic() + 60
        while recorded(Path(outdir).parent, result.capture) is not True and time.monotonic() < end:
            time.sleep(0.01)
        os.kill(os.getpid(), signal.SIGKILL)
    if AT == "before-row":  # called before the history plugin: the result folder is written, no row
        os.kill(os.getpid(), signal.SIGKILL)
'''


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Cell:
    """A result folder served by one ``inspector serve`` process after another."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.out = root / "out"
        (root / "recipes").mkdir()
        self.recipe = root / "recipes" / "fast.toml"
        shutil.copy(RECIPES / "fast.toml", self.recipe)
        # Unsecured and writable by anonymous clients: the test is about recovery, not security.
        (root / "cell.toml").write_text('[server]\nsecurity = "none"\nanonymous_write = true\n')
        self.url = ""
        self.proc: subprocess.Popen[str] | None = None
        self.lines: list[str] = []

    def start(self, crash_at: str = "", part: str = "") -> list[str]:
        """Start a server (killing itself at ``crash_at`` of part ``part``); the lines it
        printed before it listened (the recovery's)."""
        order = "trylast" if crash_at == "after-row" else "tryfirst"
        plugin = self.root / f"crash_{order}.py"
        plugin.write_text(CRASHER.replace("ORDER", order))
        self.url = f"opc.tcp://127.0.0.1:{free_port()}"
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "TEST_CRASH_AT": crash_at, "TEST_CRASH_PART": part,
               # the watchdog's limits: a verdict must not depend on how busy the machine is
               "INSPECTOR_STAGE_LIMIT_S": "86400", "INSPECTOR_INSPECTION_LIMIT_S": "86400"}
        for k in ("INSPECTOR_OPCUA_USER", "INSPECTOR_OPCUA_PASSWORD"):
            env.pop(k, None)
        self.proc = subprocess.Popen([INSPECTOR, "--plugin", str(plugin), "serve", str(self.recipe), "--opcua", self.url,
                                      "--out", str(self.out), "--config", str(self.root / "cell.toml")],
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        watchdog = threading.Timer(300, self.proc.kill)  # a hung server fails the test, never the suite
        watchdog.daemon = True
        watchdog.start()
        before = []
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            if line.startswith("Inspector OPC UA server on"):
                break
            before.append(line.rstrip("\n"))
        else:
            raise AssertionError(f"the server did not start: {before}")
        # Keep reading (a full pipe would block the server).
        threading.Thread(target=lambda: self.lines.extend(self.proc.stdout), daemon=True).start()  # type: ignore[union-attr, arg-type]
        return before

    def killed(self) -> None:
        """Wait for the server to have killed itself (SIGKILL)."""
        assert self.proc is not None
        assert self.proc.wait(WAIT_S) == -signal.SIGKILL, self.lines

    def stop(self) -> None:
        assert self.proc is not None
        self.proc.send_signal(signal.SIGINT)
        assert self.proc.wait(WAIT_S) == 0, self.lines

    def rows(self, part_id: str) -> list[dict]:
        return [r for r in read_history(self.out) if r["part_id"] == part_id]


class Plc:
    def __init__(self, client: Client, idx: int) -> None:
        self.client, self.idx = client, idx

    def node(self, name: str):
        return self.client.get_node(ua.NodeId(model.node_id(name), self.idx))

    async def read(self, *names: str):
        values = await self.client.read_values([self.node(n) for n in names])
        return values[0] if len(names) == 1 else values

    async def result(self) -> dict:
        names = ("ResultCounter", "Verdict", "ResultPartId", "ErrorText", "LastResult", "Busy", "State")
        values = dict(zip(names, await self.read(*names)))
        values["LastResult"] = json.loads(values["LastResult"])
        return values

    async def trigger(self, part_id: str) -> None:
        obj = self.client.get_node(ua.NodeId(model.OBJECT, self.idx))
        await obj.call_method(ua.QualifiedName("StartSingleJob", self.idx), ua.Variant(part_id, ua.VariantType.String))

    async def result_after(self, before: int) -> dict:
        """The result published after counter ``before`` (polled: the state, not a signal)."""
        end = time.monotonic() + WAIT_S
        while True:
            res = await self.result()
            if res["ResultCounter"] != before and res["Busy"] is False:
                return res
            assert time.monotonic() < end, f"ResultCounter stayed {before}"
            await asyncio.sleep(0.02)


@contextlib.asynccontextmanager
async def plc(cell: Cell):
    client = Client(cell.url, timeout=WAIT_S)  # a loaded machine answers late, never wrongly
    await client.connect()
    try:
        yield Plc(client, await client.get_namespace_index(model.NAMESPACE))
    finally:
        with contextlib.suppress(Exception):
            await client.disconnect()


def run(coro):
    return asyncio.run(coro)


def test_a_server_killed_at_any_moment_of_a_cycle_is_reconciled_at_restart(tmp_path):
    cell = Cell(tmp_path)

    # 1. One part published, then a kill after A's result folder is written, before its row.
    cell.start(crash_at="before-row", part="A")

    async def first():
        async with plc(cell) as p:
            await p.trigger("P0")
            assert (await p.result_after(0))["ResultPartId"] == "P0"
            await p.trigger("A")

    run(first())
    cell.killed()
    assert (cell.out / "A" / "result.json").is_file() and recorded(cell.out, "A") is False
    assert json.loads((cell.out / JOURNAL_FILE).read_text())["pending"]["capture"] == "A"

    # 2. Restart: A gets its row and is published under the next counter; the PLC's
    #    re-trigger of A is recognised. Then a kill after B's row, before its publication.
    printed = cell.start(crash_at="after-row", part="B")
    assert any(line.startswith("recovered: A") and "history row added" in line for line in printed), printed

    async def second():
        async with plc(cell) as p:
            res = await p.result()
            assert (res["ResultCounter"], res["ResultPartId"], res["Verdict"], res["State"]) == (2, "A", "pass", "Ready")
            last = res["LastResult"]
            assert (last["counter"], last["capture"], last["result_dir"], last["recovered"]) == (2, "A", "A", True)
            await p.trigger("A")  # the PLC never saw A's verdict before the kill: it triggers A again
            again = await p.result_after(2)
            assert (again["ResultCounter"], again["ResultPartId"], again["Verdict"]) == (3, "A", "pass")
            assert again["LastResult"]["capture"] == "A" and again["LastResult"]["recovered"] is True
            await p.trigger("B")

    run(second())
    cell.killed()
    assert [r["capture"] for r in cell.rows("A")] == ["A"]  # one row, no A-2
    assert not (cell.out / "A-2").exists()
    assert [r["capture"] for r in cell.rows("B")] == ["B"]

    # 3. Restart: B (recorded, never published) is published under counter 4 and its
    #    re-trigger recognised. Then a kill during C's inspection, and what a kill inside
    #    the result's write leaves: its hidden partial folder.
    cell.start(crash_at="inspecting", part="C")

    async def third():
        async with plc(cell) as p:
            res = await p.result()
            assert (res["ResultCounter"], res["ResultPartId"], res["Verdict"]) == (4, "B", "pass")
            assert res["LastResult"]["counter"] == 4 and res["LastResult"]["recovered"] is True
            await p.trigger("B")
            assert (await p.result_after(4))["ResultPartId"] == "B"
            await p.trigger("C")

    run(third())
    cell.killed()
    assert [r["capture"] for r in cell.rows("B")] == ["B"] and not (cell.out / "B-2").exists()
    partial = cell.out / ".C.partial"
    partial.mkdir()
    (partial / "result.json.part").write_text("{")

    # 4. Restart: C was never written: published aborted, the partial folder removed; the
    #    re-trigger inspects C under its own name. A later trigger of A is a new inspection.
    printed = cell.start()
    assert any(line.startswith("recovered: C: aborted") for line in printed), printed

    async def fourth():
        async with plc(cell) as p:
            res = await p.result()
            assert (res["ResultCounter"], res["ResultPartId"], res["Verdict"]) == (6, "C", "aborted")
            assert "trigger it again" in res["ErrorText"] and res["LastResult"]["counter"] == 6
            await p.trigger("C")
            res = await p.result_after(6)
            assert (res["ResultCounter"], res["ResultPartId"], res["Verdict"]) == (7, "C", "pass")
            assert res["LastResult"]["capture"] == "C" and "recovered" not in res["LastResult"]
            await p.trigger("A")  # recognition is for the first trigger after a restart only
            res = await p.result_after(7)
            assert (res["ResultCounter"], res["LastResult"]["capture"]) == (8, "A-2")
            return res

    assert not partial.exists()
    last = run(fourth())
    # A second server on the same result folder is refused: one journal, one writer.
    other = subprocess.run([INSPECTOR, "serve", str(cell.recipe), "--opcua", f"opc.tcp://127.0.0.1:{free_port()}",
                            "--out", str(cell.out), "--config", str(tmp_path / "cell.toml")],
                           capture_output=True, text=True, timeout=WAIT_S)
    assert other.returncode == 2 and "another inspector serve uses this result folder" in other.stderr, other.stderr
    cell.stop()
    assert [r["capture"] for r in cell.rows("C")] == ["C"] and not (cell.out / "C-2").exists()
    assert [r["capture"] for r in cell.rows("A")] == ["A", "A-2"]

    # 5. After a clean stop the last result is published again under the same counter.
    cell.start()

    async def fifth():
        async with plc(cell) as p:
            return await p.result()

    res = run(fifth())
    cell.stop()
    assert (res["ResultCounter"], res["ResultPartId"], res["Verdict"]) == (8, "A", "pass")
    assert res["LastResult"] == last["LastResult"]
    assert [r["capture"] for r in read_history(cell.out)] == ["P0", "A", "B", "C", "A-2"]  # nothing doubled
