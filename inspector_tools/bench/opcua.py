"""``inspector bench --opcua``: what the OPC UA server adds to a cycle, seen from the PLC's side.

Target: the median trigger-to-verdict latency seen by an OPC UA client within
:data:`LATENCY_TARGET_S` (50 ms) of the median headless cycle of the same parts.

How it is measured (``--recipe``, default ``recipes/demo.toml``: the simulated 16-camera rig
at 1024x1024; ``--opcua-parts N``, default 100, each side with one warm-up part first):

1. **Headless**: a :class:`inspector.session.Session` of the recipe runs
   ``Session.run(Source(limit=1))`` on the recipe's driver, in this process, no server: per part
   the wall time of the run (acquisition, inspection, result folder, history row).
2. **Served**: the same recipe behind :class:`~inspector_frontends.opcua.server.InspectorServer`
   on ``opc.tcp://127.0.0.1:<free port>``, configured as on a line (Basic256Sha256
   sign-and-encrypt, a fresh PKI, a user with a password), its event loop in a thread of this
   process. A client (asyncua, its own thread and event loop) subscribes to ``ResultCounter``
   (publishing interval 0: the server sends a change at once), then per part: clock, call
   ``StartSingleJob(PartId)``, wait for the counter's change, read ``Verdict``,
   ``ResultPartId`` and ``CycleTime``, clock. That interval is the latency; the part's verdict
   must belong to its PartId. The server's own ``CycleTime`` (trigger accepted to result
   published) is reported beside it, and per part the latency minus it (the protocol's share).

The two alternate part by part (a headless part, then a served one, from the client's thread
while the server is idle), so a change of the machine's load touches both alike. The same driver parameters give the same parts on both sides (a simulated rig starts from its
seed). Exit 0 target met, 1 not met, 3 an inspection failed or a result was wrong.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import socket
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from inspector.errors import RecipeError
from inspector.resources import recipe_path
from inspector.session import Inspected, Session, Source
from inspector_frontends.opcua import model
from inspector_frontends.opcua.config import ServerSettings
from inspector_tools.bench.common import recipes_dir, write_figures

try:  # asyncua is optional: run_opcua_bench says so when it is missing
    from inspector_frontends.opcua.security import CLIENT_URI, make_pki
    from inspector_frontends.opcua.server import InspectorServer, ServerThread
except ImportError as _e:
    _OPCUA_MISSING: ImportError | None = _e
else:
    _OPCUA_MISSING = None

__all__ = ["LATENCY_TARGET_S", "run_opcua_bench"]

#: Median client-side trigger-to-verdict minus median headless cycle, seconds.
LATENCY_TARGET_S = 0.050


def _p(values: list[float], q: float) -> float:
    """Nearest-rank percentile ``q`` (0-100) of ``values``."""
    v = sorted(values)
    return v[max(0, math.ceil(q / 100 * len(v)) - 1)]


def _summary(values: list[float]) -> dict[str, float]:
    return {"median": statistics.median(values), "p99": _p(values, 99), "min": min(values), "max": max(values),
            "n": len(values)}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _recipe(args: argparse.Namespace) -> str:
    if args.recipe == str(recipes_dir() / "default.toml"):
        return str(recipe_path("demo.toml"))
    return str(args.recipe)


class Headless:
    """The recipe through a plain Session: :meth:`part` runs one capture, returns its record."""

    def __init__(self, recipe: str, out: Path) -> None:
        self.session = Session.open(recipe, out)
        self._got: list[Any] = []
        self.session.subscribe(lambda e: self._got.append(e.outcome.result) if isinstance(e, Inspected) else None)

    def part(self) -> dict[str, Any]:
        self._got.clear()
        t0 = time.perf_counter()
        self.session.run(Source(limit=1))
        wall = time.perf_counter() - t0
        res = self._got[-1] if self._got else None
        self._got.clear()
        return {"wall_s": wall, "verdict": res.verdict if res else None,
                "inspection_s": res.timings_s.get("total") if res else None, "error": res.error if res else "no result"}


async def _client(url: str, pki: Path, user: str, password: str, parts: int, head: Headless, say: Any,
                  ) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    from asyncua import Client, ua
    from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

    client = Client(url, timeout=30)
    client.application_uri = CLIENT_URI
    await client.set_security(SecurityPolicyBasic256Sha256, str(pki / "plc-cert.der"), str(pki / "plc-key.pem"),
                              mode=ua.MessageSecurityMode.SignAndEncrypt)
    client.set_user(user)
    client.set_password(password)
    await client.connect()
    records: list[dict[str, Any]] = []
    heads: list[dict[str, Any]] = []
    try:
        idx = await client.get_namespace_index(model.NAMESPACE)
        node = {n: client.get_node(ua.NodeId(ua.String(model.node_id(n)), ua.Int16(idx)))
                for n in ("ResultCounter", "Verdict", "ResultPartId", "CycleTime", "LastResult", "Ready")}
        obj = client.get_node(ua.NodeId(ua.String(model.OBJECT), ua.Int16(idx)))
        changed = asyncio.Event()
        latest = {"counter": await node["ResultCounter"].read_value()}

        class Handler:
            def datachange_notification(self, n: Any, val: Any, data: Any) -> None:
                latest["counter"] = val
                changed.set()

        sub = await client.create_subscription(0, Handler())
        await sub.subscribe_data_change(node["ResultCounter"])
        await asyncio.sleep(0.1)  # the initial notification
        method = ua.QualifiedName("StartSingleJob", idx)
        for i in range(parts + 1):
            heads.append(head.part())  # the server is idle meanwhile
            part_id = f"BENCH-{i:04d}"
            while not await node["Ready"].read_value():  # Busy falls right after the counter
                await asyncio.sleep(0.001)
            before = latest["counter"]
            changed.clear()
            t0 = time.perf_counter()
            await obj.call_method(method, ua.Variant(part_id, ua.VariantType.String))
            while latest["counter"] == before:
                await asyncio.wait_for(changed.wait(), 600)
                changed.clear()
            verdict, got, cycle = await client.read_values([node["Verdict"], node["ResultPartId"], node["CycleTime"]])
            latency = time.perf_counter() - t0
            last = json.loads(await node["LastResult"].read_value())
            records.append({"part_id": part_id, "latency_s": latency, "verdict": verdict, "result_part_id": got,
                            "cycle_s": cycle, "run_s": last.get("run_s"), "inspection_s": last.get("inspection_s"),
                            "error": last.get("error")})
            if i == 0 or (i % 20 == 0):
                say(f"  {'warm-up' if i == 0 else f'{i}/{parts}'}: headless {heads[-1]['verdict']} in "
                    f"{heads[-1]['wall_s']:.3f} s; served {verdict} for {got}, seen after {latency:.3f} s "
                    f"(server cycle {cycle:.3f} s)")
    finally:
        await client.disconnect()
    return heads, records


def measure(recipe: str, work: Path, parts: int, say: Any) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """``1 + parts`` parts each way, alternating: (headless records, served records)."""
    import secrets

    if _OPCUA_MISSING is not None:
        raise _OPCUA_MISSING
    make_pki(work / "pki")
    user, password = "bench", secrets.token_urlsafe(16)
    url = f"opc.tcp://127.0.0.1:{_free_port()}"
    server = InspectorServer(recipe, work / "served", ServerSettings(endpoint=url, pki=work / "pki"),
                             env={"INSPECTOR_OPCUA_USER": user, "INSPECTOR_OPCUA_PASSWORD": password})
    head = Headless(recipe, work / "headless")
    out: dict[str, Any] = {}

    def client_thread() -> None:
        try:
            out["records"] = asyncio.run(_client(url, work / "pki", user, password, parts, head, say))
        except BaseException as e:  # noqa: BLE001 - handed to the caller
            out["error"] = e

    try:
        with ServerThread(server):
            t = threading.Thread(target=client_thread, name="opcua-bench-client")
            t.start()
            t.join()
    finally:
        head.session.close()
    if "error" in out:
        raise out["error"]
    heads, records = out["records"]
    return heads, records


def run_opcua_bench(args: argparse.Namespace) -> int:
    """``inspector bench --opcua``; see the module docstring."""
    parts = int(args.opcua_parts)
    if parts < 1:
        raise RecipeError("bench --opcua-parts: expected a number >= 1")
    try:
        import asyncua  # noqa: F401
    except ImportError as e:
        raise RecipeError(f"bench --opcua needs asyncua ({e}): pip install 'inspector-bcps[opcua]'") from None
    say = (lambda s: None) if args.quiet else (lambda s: print(s, flush=True))
    recipe = _recipe(args)
    with tempfile.TemporaryDirectory(prefix="inspector-bench-opcua-") as tmp:
        work = Path(args.keep) if args.keep else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        say(f"{parts} parts (+1 warm-up) of {recipe}, alternately through a Session (headless) and through the "
            "OPC UA server (sign-and-encrypt; a client subscribed to ResultCounter) ...")
        load = _load()
        head, srv = measure(recipe, work, parts, say)
    bad = [r for r in head + srv if r["verdict"] in (None, "error")]
    wrong = [r for r in srv if r["result_part_id"] != r["part_id"]]
    h, s = head[1:], srv[1:]
    lat = [r["latency_s"] for r in s]
    wall = [r["wall_s"] for r in h]
    cycle = [r["cycle_s"] for r in s]
    protocol = [r["latency_s"] - r["cycle_s"] for r in s]
    handoff = [r["cycle_s"] - r["run_s"] for r in s if r.get("run_s") is not None]
    runs = [r["run_s"] for r in s if r.get("run_s") is not None]
    over = statistics.median(lat) - statistics.median(wall)
    doc: dict[str, Any] = {
        "config": {"recipe": recipe, "parts": parts, "warmup_parts": 1, "security": "Basic256Sha256 SignAndEncrypt",
                   "client": "asyncua, subscription to ResultCounter (publishing interval 0), same process"},
        "machine": {"cpus": os.cpu_count(), "load_before": load, "python": sys.version.split()[0]},
        "latency_s": _summary(lat),
        "headless_cycle_s": _summary(wall),
        "server_cycle_s": _summary(cycle),
        "latency_minus_server_cycle_s": _summary(protocol),
        "server_run_s": _summary(runs) if runs else None,
        "server_cycle_minus_run_s": _summary(handoff) if handoff else None,
        "median_latency_minus_median_headless_s": over,
        "target": {"what": f"median latency - median headless cycle <= {LATENCY_TARGET_S * 1000:.0f} ms",
                   "met": over <= LATENCY_TARGET_S},
        "verdicts": {"headless": _count(h), "served": _count(s)},
        "errors": [r.get("error") for r in bad][:5],
        "wrong_part": len(wrong),
    }
    doc["machine"]["load_after"] = _load()
    if not args.quiet:
        ms = lambda x: f"{x * 1000:.1f} ms"  # noqa: E731
        print(f"\n  OPC UA trigger -> verdict, {parts} parts of {Path(recipe).name} ({doc['config']['security']}):")
        print(f"    client latency:          median {ms(doc['latency_s']['median'])}, p99 {ms(doc['latency_s']['p99'])}")
        print(f"    headless cycle:          median {ms(doc['headless_cycle_s']['median'])}, "
              f"p99 {ms(doc['headless_cycle_s']['p99'])}")
        print(f"    server cycle (CycleTime): median {ms(doc['server_cycle_s']['median'])}, "
              f"p99 {ms(doc['server_cycle_s']['p99'])}")
        print(f"    latency - server cycle:  median {ms(doc['latency_minus_server_cycle_s']['median'])}, "
              f"p99 {ms(doc['latency_minus_server_cycle_s']['p99'])} (the protocol: call, notification, read)")
        if handoff:
            print(f"    server cycle - its Session.run: median {ms(doc['server_cycle_minus_run_s']['median'])}, "
                  f"p99 {ms(doc['server_cycle_minus_run_s']['p99'])} (hand-offs between the event loop and the "
                  f"worker); Session.run median {ms(doc['server_run_s']['median'])}")
        print(f"    median latency - median headless: {ms(over)} (target <= {ms(LATENCY_TARGET_S)}): "
              f"{'MET' if doc['target']['met'] else 'NOT MET'}")
        print(f"    load average {doc['machine']['load_before']} -> {doc['machine']['load_after']}")
    if args.json:
        say(f"\n  figures written to {write_figures(args.json, {'opcua': doc, 'served': srv, 'headless': head})}")
    if bad or wrong:
        print(f"inspector: error: bench --opcua: {len(bad)} inspections failed, {len(wrong)} results for another "
              f"part{': ' + str(doc['errors'][0]) if doc['errors'] else ''}", file=sys.stderr)
        return 3
    return 0 if doc["target"]["met"] else 1


def _count(records: list[dict[str, Any]]) -> dict[str, int]:
    out: dict[str, int] = {}
    for r in records:
        out[str(r["verdict"])] = out.get(str(r["verdict"]), 0) + 1
    return out


def _load() -> list[float] | None:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None
