#!/usr/bin/env python3
"""Play the PLC against ``inspector serve``: set PartId, trigger, wait for the counter, read the verdict.

    python examples/plc_client.py --url opc.tcp://127.0.0.1:4840 --pki pki --user plc --parts 5

Each part is the handshake a PLC program does, step by step:

1. wait until ``Ready`` is true (a trigger now would be accepted);
2. remember ``ResultCounter``;
3. trigger part ``PREFIX0001``: either call ``StartSingleJob(PartId)`` (``--trigger method``,
   the default) or write ``PartId`` and ``Trigger = true`` in one write (``--trigger variable``,
   a rising edge; the server sets ``Trigger`` back to false when the result is out);
4. poll ``ResultCounter`` every ``--poll-ms`` until it changes: the server writes it after
   the result's other variables, so what is read next belongs to this part;
5. read ``Verdict``, ``ResultPartId``, ``DefectCount``, ``WorstDeviation``, ``CycleTime`` and
   ``ErrorText``, and check that ``ResultPartId`` is the part just triggered.

Security: with ``--pki DIR`` (made by ``inspector serve --make-cert DIR``) the client uses the
PLC certificate there (``plc-cert.der``, ``plc-key.pem``) and the Basic256Sha256
sign-and-encrypt endpoint; ``--user`` logs in (password from ``$INSPECTOR_OPCUA_PASSWORD``,
else asked), without it the client is anonymous (read-only unless the server allows
anonymous writes). Exit status: 0 every part passed, 1 a part failed, 3 a part's verdict was
error or aborted, 2 the server could not be reached or refused a request.

Needs only asyncua (``pip install asyncua``); it does not import Inspector.
"""

from __future__ import annotations

import argparse
import asyncio
import getpass
import json
import math
import os
import sys
import time
from pathlib import Path

from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

NAMESPACE = "urn:inspector-bcps:opcua"  # the Inspector nodes: ns=<its index>;s=Inspector.<Name>
CLIENT_URI = "urn:inspector-bcps:opcua:plc"  # the application URI in plc-cert.der


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--url", default="opc.tcp://127.0.0.1:4840", help="the server's endpoint")
    p.add_argument("--parts", type=int, default=3, help="parts to trigger (default 3)")
    p.add_argument("--prefix", default="PART-", help="PartId prefix; the parts are PREFIX0001, PREFIX0002 ...")
    p.add_argument("--start", type=int, default=1, help="number of the first part (default 1)")
    p.add_argument("--trigger", choices=("method", "variable"), default="method",
                   help="StartSingleJob(PartId), or PartId + Trigger = true in one write")
    p.add_argument("--pki", metavar="DIR", help="use DIR/plc-cert.der and DIR/plc-key.pem, Basic256Sha256 sign-and-encrypt")
    p.add_argument("--user", default=os.environ.get("INSPECTOR_OPCUA_USER"), help="log in as this user "
                   "(password: $INSPECTOR_OPCUA_PASSWORD, else asked); default $INSPECTOR_OPCUA_USER, else anonymous")
    p.add_argument("--poll-ms", type=float, default=10.0, help="how often ResultCounter is read while waiting (default 10)")
    p.add_argument("--timeout", type=float, default=60.0, help="seconds to wait for Ready and for each result (default 60)")
    p.add_argument("--json", action="store_true", help="one JSON object per part instead of a line of text")
    return p.parse_args(argv)


async def connect(args: argparse.Namespace) -> Client:
    client = Client(args.url, timeout=30)
    client.application_uri = CLIENT_URI
    if args.pki:
        pki = Path(args.pki)
        await client.set_security(SecurityPolicyBasic256Sha256, str(pki / "plc-cert.der"), str(pki / "plc-key.pem"),
                                  mode=ua.MessageSecurityMode.SignAndEncrypt)
    if args.user:
        password = os.environ.get("INSPECTOR_OPCUA_PASSWORD")
        if password is None:
            password = getpass.getpass(f"password of {args.user}: ")
        client.set_user(args.user)
        client.set_password(password)
    await client.connect()
    return client


async def wait_until(read, ok, timeout: float, poll_s: float, what: str):
    """Poll ``read()`` until ``ok(value)``; TimeoutError naming ``what``."""
    end = time.monotonic() + timeout
    while True:
        value = await read()
        if ok(value):
            return value
        if time.monotonic() > end:
            raise TimeoutError(f"no {what} after {timeout:g} s")
        await asyncio.sleep(poll_s)


async def play(args: argparse.Namespace) -> int:
    client = await connect(args)
    try:
        idx = await client.get_namespace_index(NAMESPACE)
        obj = client.get_node(ua.NodeId("Inspector", idx))

        def node(name: str):
            return client.get_node(ua.NodeId(f"Inspector.{name}", idx))

        poll = args.poll_ms / 1000.0
        worst_exit = 0
        for i in range(args.start, args.start + args.parts):
            part_id = f"{args.prefix}{i:04d}"
            await wait_until(node("Ready").read_value, bool, args.timeout, poll, "Ready")          # 1
            before = await node("ResultCounter").read_value()                                       # 2
            t0 = time.perf_counter()
            if args.trigger == "method":                                                            # 3
                await obj.call_method(ua.QualifiedName("StartSingleJob", idx), ua.Variant(part_id, ua.VariantType.String))
            else:
                await client.write_values([node("PartId"), node("Trigger")], [part_id, True])
            counter = await wait_until(node("ResultCounter").read_value, lambda c, before=before: c != before,   # 4
                                       args.timeout, poll, f"result for {part_id}")
            seen_s = time.perf_counter() - t0
            names = ("Verdict", "ResultPartId", "DefectCount", "WorstDeviation", "CycleTime", "ErrorText")  # 5
            verdict, got_id, defects, worst, cycle, error = await client.read_values([node(n) for n in names])
            if got_id != part_id:
                print(f"plc_client: result {counter} is for {got_id!r}, not {part_id!r}", file=sys.stderr)
                worst_exit = max(worst_exit, 3)
            worst_exit = max(worst_exit, {"pass": 0, "fail": 1}.get(verdict, 3))
            if args.json:
                print(json.dumps({"part_id": part_id, "counter": counter, "verdict": verdict, "result_part_id": got_id,
                                  "defects": defects, "worst_deviation_mm": None if math.isnan(worst) else worst,
                                  "cycle_s": cycle, "seen_s": seen_s, "error": error}), flush=True)
            else:
                dev = "" if math.isnan(worst) else f", worst {worst:+.3f} mm"
                why = f": {error}" if error else ""
                print(f"{part_id}: {verdict.upper()}{why} ({defects} defects{dev}; counter {counter}, "
                      f"cycle {cycle:.3f} s, seen after {seen_s:.3f} s)", flush=True)
        return worst_exit
    finally:
        await client.disconnect()


def main(argv: list[str] | None = None) -> int:
    import logging

    logging.getLogger("asyncua").setLevel(logging.ERROR)  # its notices (revised timeouts ...) are not ours
    args = parse_args(argv)
    try:
        return asyncio.run(play(args))
    except ua.UaStatusCodeError as e:
        print(f"plc_client: refused: {type(e).__name__} ({e})", file=sys.stderr)
        return 2
    except (OSError, TimeoutError) as e:
        print(f"plc_client: {args.url}: {e or type(e).__name__}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
