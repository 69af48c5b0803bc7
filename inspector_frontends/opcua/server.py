"""The OPC UA server of ``inspector serve``: a PLC triggers, Inspector answers.

:class:`InspectorServer` holds a :class:`inspector.session.Session` of the served recipe and
an asyncua server exposing the information model of :mod:`inspector_frontends.opcua.model`.
One accepted trigger (a rising edge of ``Trigger``, or ``StartSingleJob(PartId)``) is one
``Session.run(Source(limit=1))`` on the recipe's driver (kept open between triggers): one
acquisition, one inspection, its result folder in ``--out`` and its history row, exactly as
``inspector run`` writes them, the capture named after the PartId.

The inspection runs in a worker thread; the server's event loop stays free to answer reads,
subscriptions and refusals while ``Busy``. The handshake:

* a trigger while ``Busy`` (or in ``Error``, or while a recipe loads) is refused with
  ``BadInvalidState``, never queued; a PartId that cannot name a result folder with
  ``BadInvalidArgument``; ``ErrorText`` says why, in one line;
* an accepted trigger sets ``Busy`` and clears ``Ready`` before the call returns;
* its result is published in one turn of the event loop, in this order: ``Verdict``,
  ``VerdictCode``, ``ResultPartId``, ``CycleTime``, ``WorstDeviation``, ``DefectCount``,
  ``CalibrationOk`` and ``CalibrationFlagged`` (when the part checked the calibration), ``CharacteristicsNok``
  and ``Characteristics`` (the measured characteristics),
  ``ErrorText``, ``LastResult``, then ``ResultCounter`` (+1, exactly once per accepted
  trigger, whatever the verdict: pass, fail, error or aborted), then ``Trigger`` back to
  false, ``Busy`` false, ``Ready`` and ``State``. A PLC that sees the counter change reads
  the new verdict; a PLC that sees ``Busy`` fall may trigger again at once.

A client that disconnects changes nothing: the cycle goes on and its result is published;
a client that reconnects reads the same state as every other.

Crash recovery (:mod:`inspector_frontends.opcua.journal`): every cycle is journaled in the
result folder, and a server started again after a kill reconciles what the kill left before
it listens: a written result gets the history row it lacked and is published; a part killed
before its result was written is published ``aborted`` (its hidden ``.NAME.partial`` folder
removed), so the PLC triggers it again; otherwise the last result is published again.
``ResultCounter`` goes on from the journal's. The first trigger after such a restart with the
PartId of the recovered result is recognised as the PLC's re-trigger of that part: its
result is published again (``LastResult`` ``recovered``: true), not a second inspection, so
no ``PartId-2`` folder and no second history row.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import os
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from asyncua import Server, ua
from asyncua.common.callback import CallbackType

from inspector import outputs
from inspector.approval import approval_problem
from inspector.errors import CaptureError, InspectorError, RecipeError
from inspector.history_store import recorded
from inspector.manager import PluginManager, create_plugin_manager
from inspector.names import name_problem, printable
from inspector.runner import inspect_capture
from inspector.session import Inspected, RunSummary, Session, Source, Warned
from inspector.tracebacks import save_traceback
from inspector_drivers.sim.simulate import SimParams, simulate
from inspector_frontends.opcua import model
from inspector_frontends.opcua.address_space import add_model, data_value, secured_server
from inspector_frontends.opcua.config import ServerSettings, credentials, parse_endpoint, pki_files
from inspector_frontends.opcua.journal import Journal, lock_outdir, result_from_json
from inspector_frontends.opcua.records import log_line, record
from inspector_frontends.opcua.security import quiet_library_logs
from inspector_frontends.opcua.triggers import Job, PartIdDriver, now, part_id_problem

__all__ = ["InspectorServer", "ServerThread", "part_id_problem"]


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


class InspectorServer:
    """The served recipe, its session and the OPC UA server.

    Parameters
    ----------
    recipe : path
        The recipe served first (validated now: RecipeError).
    outdir : path
        Where results and ``history.sqlite`` go (``--out``).
    settings : ServerSettings
        Endpoint, security, users, recipes folder (:mod:`inspector_frontends.opcua.config`).
    pm : PluginManager, optional
        The plugin manager of every session (a test may register plugins on it).
    log : callable, optional
        Receives one line per result, refusal and recipe change (the CLI prints them).
    env : mapping, optional
        The environment the user and password are read from (default ``os.environ``).
    warm_up : bool
        Before listening, inspect one small simulated capture of the reference part (nothing
        written; its stage hooks run): the compiled kernels are loaded then, so the first
        PLC trigger has an ordinary cycle and no client waits behind a cold start.
    """

    def __init__(self, recipe: str | os.PathLike[str], outdir: str | os.PathLike[str], settings: ServerSettings, *,
                 pm: PluginManager | None = None, log: Callable[[str], None] | None = None,
                 env: dict[str, str] | None = None, warm_up: bool = True) -> None:
        self.settings = settings
        self.endpoint = settings.endpoint
        parse_endpoint(self.endpoint)
        self._creds = credentials(settings, env)
        self._pki = pki_files(settings.pki) if settings.pki is not None else None
        if settings.security != "none" and self._pki is None:
            raise RecipeError(f"security {settings.security!r} needs a server certificate: make one with "
                              "`inspector serve --make-cert DIR` and give --pki DIR (or security none, read-only)")
        if settings.security == "none" and self._creds is not None:
            raise RecipeError("security 'none': a password would cross the network in plain text; use sign-encrypt "
                              "or both (with --pki), or no user")
        self.outdir = Path(outdir)
        try:
            self.outdir.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise RecipeError(f"--out {outdir}: cannot create the result folder ({e.strerror or e})") from None
        if not os.access(self.outdir, os.W_OK | os.X_OK):
            raise RecipeError(f"--out {outdir}: the result folder is not writable")
        self.log = log or (lambda line: None)
        self.pm = pm if pm is not None else create_plugin_manager()
        recipe = Path(recipe)
        self.recipes_dir = Path(settings.recipes) if settings.recipes is not None else recipe.resolve().parent
        if not self.recipes_dir.is_dir():
            raise RecipeError(f"recipes folder {self.recipes_dir}: not a folder")
        self._session = self._open_session(recipe)
        self.recipe_name = recipe.stem
        self._job: Job | None = None
        self._part_id = ""  # the PartId variable's value (what a Trigger edge inspects)
        self._records: list[dict[str, Any]] = []
        self._continuous = False
        self._busy = False
        self._state = "Ready"
        self._counter = 0
        self._journal = Journal(self.outdir)
        self._lock_file: Any = None
        #: (PartId, record) of a result a restart recovered: its re-trigger is recognised.
        self._recovered: tuple[str, dict[str, Any]] | None = None
        self._task: asyncio.Task[None] | None = None
        self._executor = ThreadPoolExecutor(1, thread_name_prefix="inspector-opcua")
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: Server | None = None
        self._nodes: dict[str, Any] = {}
        self._inputs: dict[Any, str] = {}
        self.namespace_index = 0
        self._warm_up = warm_up
        self.warm_up_s: float | None = None

    # -- sessions ---------------------------------------------------------------------------
    def _open_session(self, path: Path) -> Session:
        """A session of ``path`` whose driver names captures after the PartIds."""
        session = Session.open(path, self.outdir, pm=self.pm)
        # A PLC has no login: the server runs as the operator, so on a production station only
        # a recipe an engineer approved (file and reference unchanged since) may run (issue 27).
        problem = approval_problem(session.recipe)
        if problem is not None:
            session.close()
            raise RecipeError(problem)
        spec = session.recipe.driver.spec

        def opened(params: Any, _open: Callable[[Any], Any] = spec.open) -> Any:
            driver = _open(params)
            if hasattr(driver, "taken"):  # a hot folder names captures after its folders
                return driver
            return PartIdDriver(driver, lambda: self._job, self._journal_named)

        driver = dataclasses.replace(session.recipe.driver, spec=dataclasses.replace(spec, open=opened))
        session.recipe = dataclasses.replace(session.recipe, driver=driver)
        session.subscribe(self._on_event)
        return session

    def recipe_names(self) -> list[str]:
        """The recipes ``RecipeName`` may name: the ``*.toml`` of the recipes folder."""
        try:
            return sorted(p.stem for p in self.recipes_dir.glob("*.toml") if p.is_file() and name_problem(p.stem) is None)
        except OSError:
            return []

    @property
    def writer(self) -> str | None:
        """The user allowed to write and call (None: nobody but, with ``anonymous_write``,
        anonymous clients)."""
        return self._creds.user if self._creds is not None else None

    @property
    def counter(self) -> int:
        return self._counter

    @property
    def state(self) -> str:
        return self._state

    # -- the OPC UA server -----------------------------------------------------------------
    async def start(self) -> None:
        """Build the address space and listen (InspectorError when the port cannot be bound)."""
        quiet_library_logs()
        self._loop = asyncio.get_running_loop()
        self._lock_file = lock_outdir(self.outdir)  # one server per result folder: one journal
        server = await secured_server(self.settings, self._creds, self._pki, self.log)
        handlers = {"StartSingleJob": self._m_start_single, "StartContinuous": self._m_start_continuous,
                    "Stop": self._m_stop, "Abort": self._m_abort, "Reset": self._m_reset}
        self.namespace_index, self._nodes, self._inputs = await add_model(server, self.recipe_name, self.recipe_names(),
                                                                          handlers)
        server.subscribe_server_callback(CallbackType.PreWrite, self._pre_write)
        if self._warm_up:
            self.warm_up_s = await self._loop.run_in_executor(self._executor, self._warm)
        self._server = server  # for _set: the recovered result is published before anyone connects
        counter, rec = await self._loop.run_in_executor(self._executor, self._recover)
        if rec is not None:
            await self._publish(rec, counter=counter)
        try:
            await server.start()
        except OSError as e:
            self._server = None
            raise InspectorError(f"cannot listen on {self.endpoint}: {e.strerror or e}") from None

    async def stop(self) -> None:
        """Cancel the cycle in progress (verdict aborted), stop listening, close the driver."""
        if self._busy:
            self._session.cancel()
        if self._task is not None:
            try:
                await asyncio.wait_for(asyncio.shield(self._task), 60)
            except (TimeoutError, Exception):  # noqa: BLE001 - stopping anyway
                pass
        if self._server is not None:
            await self._server.stop()
            self._server = None
        loop = asyncio.get_running_loop()
        await loop.run_in_executor(self._executor, self._session.close)
        self._executor.shutdown(wait=False)
        if self._lock_file is not None:
            self._lock_file.close()
            self._lock_file = None

    async def _set(self, name: str, value: Any) -> None:
        """Write variable ``name`` (server side: no permission check, subscribers notified)."""
        assert self._server is not None
        await self._server.write_attribute_value(self._nodes[name].nodeid, data_value(name, value))

    async def _set_state(self, state: str, *, busy: bool) -> None:
        self._state = state
        await self._set("Busy", busy)
        await self._set("Ready", state == "Ready" and not busy)
        await self._set("State", state)

    async def _refuse(self, code: int, text: str) -> ua.StatusCode:
        """``ErrorText`` = ``text``, a log line, and the status to answer with."""
        self.log(f"refused: {text}")
        if self._server is not None:
            await self._set("ErrorText", text)
        return ua.StatusCode(ua.UInt32(code))

    # -- inputs: writes ---------------------------------------------------------------------
    async def _pre_write(self, event: Any, _dispatcher: Any) -> None:
        """Every client write, before it is applied: the inputs are checked in order and acted
        on (a trigger starts, a recipe is loaded); a refused one raises its status, and then
        nothing of the request is written."""
        if not event.is_external:
            return
        part_id: str | None = None
        actions: list[tuple[str, Any]] = []
        for wv in event.request_params.NodesToWrite:
            name = self._inputs.get(wv.NodeId)
            if name is None or wv.AttributeId != ua.AttributeIds.Value:
                continue
            variant = wv.Value.Value if wv.Value is not None else None
            want = ua.VariantType.Boolean if name == "Trigger" else ua.VariantType.String
            if variant is None or variant.VariantType != want or variant.Value is None:
                raise ua.UaStatusCodeError(ua.StatusCodes.BadTypeMismatch)
            value = variant.Value
            if name == "PartId":
                why = part_id_problem(value)
                if why is not None:
                    refused = await self._refuse(ua.StatusCodes.BadInvalidArgument, f"PartId '{printable(value)}' {why}")
                    raise ua.UaStatusCodeError(refused.value)
                part_id = value
            elif name == "Trigger" and value:
                actions.append(("trigger", None))
            elif name == "RecipeName":
                actions.append(("recipe", value))
        for kind, arg in actions:  # checked before anything happens
            status = await (self._can_trigger("Trigger") if kind == "trigger" else self._can_switch(arg))
            if status is not None:
                raise ua.UaStatusCodeError(status.value)
        if part_id is not None:
            self._part_id = part_id
        for kind, arg in actions:
            if kind == "trigger":
                await self._trigger(self._part_id, via="Trigger")
            else:
                status = await self._switch_recipe(arg)
                if status is not None:
                    raise ua.UaStatusCodeError(status.value)

    async def _can_trigger(self, what: str) -> ua.StatusCode | None:
        if self._state == "Error":
            return await self._refuse(ua.StatusCodes.BadInvalidState, f"{what} refused: in Error state (call Reset)")
        if self._busy:
            doing = {"Preoperational": "a recipe is loading", "ContinuousExecution": "in continuous execution"}.get(
                self._state, f"busy with part '{printable(self._job.part_id if self._job else '')}'")
            return await self._refuse(ua.StatusCodes.BadInvalidState, f"{what} refused: {doing}")
        return None

    async def _trigger(self, part_id: str, *, via: str) -> None:
        """Start one cycle for ``part_id`` (checked by the caller: not busy, a valid id)."""
        self._busy = True
        job = Job(part_id, now(), time.perf_counter())
        self._job = job
        await self._journaled(self._journal.accepted, part_id, job.triggered_at)  # before the PLC hears Good
        await self._set("ErrorText", "")
        if via == "StartSingleJob":
            await self._set("PartId", part_id)
            self._part_id = part_id
        else:
            await self._set("Trigger", True)
        await self._set_state("SingleExecution", busy=True)
        assert self._loop is not None
        self._task = self._loop.create_task(self._single(job))

    async def _single(self, job: Job) -> None:
        assert self._loop is not None
        recovered, self._recovered = self._recovered, None  # only the first trigger after a restart
        try:
            if recovered is not None and job.part_id and job.part_id == recovered[0]:
                rec, failed = await self._republish(job, recovered[1]), False
            else:
                rec, failed = await self._loop.run_in_executor(self._executor, self._run_single, job)
        except BaseException as e:  # noqa: BLE001 - a result is published whatever happens
            rec, failed = self._error_record(job, f"internal error {type(e).__name__}: {_one_line(e)}"), True
        rec["cycle_s"] = time.perf_counter() - job.t0
        await self._publish(rec)
        await self._set("Trigger", False)
        await self._set_state("Error" if failed else "Ready", busy=False)
        self._job = None
        self._busy = False  # last: until here a trigger is refused, never mixed into this end

    async def _republish(self, job: Job, rec: dict[str, Any]) -> dict[str, Any]:
        """The PLC's re-trigger of the part a restart recovered: that result again, not a
        second inspection (no ``PartId-2``, no second history row)."""
        capture = rec.get("capture") or ""
        await self._journaled(self._journal.named, capture, job.part_id, job.triggered_at)
        self.log(f"{printable(job.part_id)}: the re-trigger of the part inspected before the restart: its result "
                 f"({rec.get('verdict')}, {printable(capture)}) published again, not inspected twice")
        return {k: v for k, v in rec.items() if k not in ("counter", "cycle_s")} | {"recovered": True}

    def _public(self, text: str | None) -> str | None:
        """``text`` (an error) with the result folder's path on the server made relative to it:
        ``ErrorText`` and ``LastResult`` are read by anonymous clients too, and show no server path."""
        if not text:
            return text
        for root in sorted({str(self.outdir.resolve()), str(self.outdir.absolute())}, key=len, reverse=True):
            text = text.replace(root + os.sep, "").replace(root, ".")
        return text

    # -- the journal ----------------------------------------------------------------------------
    async def _journaled(self, write: Callable[..., None], *args: Any) -> None:
        """A journal write, in a helper thread (the loop stays free); a failure (a full disk)
        is one warning: the cycle goes on, only its recovery after a crash is at stake."""
        try:
            await asyncio.to_thread(write, *args)
        except OSError as e:
            self.log(f"warning: {self._journal.path}: not written ({e.strerror or e}); a crash now would not be "
                     "reconciled at the next start")

    def _journal_named(self, capture: str, part_id: str, at: str) -> None:
        """The driver named the capture (worker thread)."""
        try:
            self._journal.named(capture, part_id, at)
        except OSError as e:
            self.log(f"warning: {self._journal.path}: not written ({e.strerror or e})")

    def _recover(self) -> tuple[int, dict[str, Any] | None]:
        """Reconcile what the last server on this result folder left (worker thread, before
        listening): the counter to publish under and the record to publish (None: a first start)."""
        warning = self._journal.load()
        if warning is not None:
            self.log(f"warning: {warning}")
        j = self._journal
        self._counter = j.counter
        if j.pending is None:
            return j.counter, j.last  # a clean stop, or a kill after the publication: the same again
        pending = j.pending
        name = pending.get("capture")
        rec = self._reconcile(name, pending) if name else None
        if rec is not None:
            self._recovered = (pending["part_id"], rec)
        else:
            what = f"part '{printable(pending['part_id'])}'" if pending["part_id"] else "the part"
            rec = {**self._error_record(None, f"the server stopped during the inspection of {what} (killed or "
                                              "powered off): nothing written; trigger it again", verdict="aborted"),
                   "part_id": pending["part_id"], "triggered_at": pending.get("triggered_at"), "recovered": True}
            self.log(f"recovered: {printable(pending['part_id'] or name or '-')}: aborted (the server stopped during "
                     "its inspection; nothing written)")
        return (j.counter + 1) % 2**32, rec

    def _reconcile(self, name: str, pending: dict[str, Any]) -> dict[str, Any] | None:
        """Capture ``name``'s result as the kill left it: its record (the history row added
        when it lacks one), or None when no result was written (what a write in progress left
        is removed)."""
        try:
            folder = outputs.result_folder(self.outdir, name)
            outputs.clear_leftovers(folder)  # a kill inside write_result: its .NAME.partial (and .old) folder
        except (CaptureError, OSError) as e:
            self.log(f"warning: recovering {printable(name)}: {_one_line(e)}")
            return None
        if not outputs.result_written(self.outdir, name):
            return None
        try:
            result = result_from_json(json.loads((folder / outputs.RESULT_JSON).read_text(encoding="utf-8")))
        except (OSError, ValueError, KeyError, TypeError) as e:
            self.log(f"warning: recovering {printable(name)}: {folder / outputs.RESULT_JSON} cannot be read ({e})")
            return None
        if "history" in self.pm.plugin_names():
            if recorded(self.outdir, name) is False:  # killed before its row: the hooks that record it, now
                recipe = self._session.recipe
                self.pm.on_run_start(recipe, self.outdir, "serve recovery")
                self.pm.on_result(result, folder)
                self.pm.on_run_end(recipe, self.outdir, RunSummary({result.verdict: 1}, "done", self.outdir))
                self.log(f"recovered: {printable(name)}: its history row added")
        rec = record(result, folder)
        rec["part_id"] = rec["part_id"] or pending["part_id"]
        rec["triggered_at"] = rec["triggered_at"] or pending.get("triggered_at")
        rec["recovered"] = True
        self.log(f"recovered: {log_line(result)}")
        return rec

    # -- the worker thread ------------------------------------------------------------------
    def _warm(self) -> float | None:
        """One inspection of a small simulated capture, nothing written (worker thread); its
        seconds, or None when it could not run (best effort: the first part then pays)."""
        t0 = time.perf_counter()
        recipe, ref = self._session.recipe, self._session.reference
        part = recipe.reference.removeprefix("builtin:") if recipe.reference else "cube30"
        # The kernels are compiled for argument types, not sizes: 6 small images will do, with
        # the part filling about two thirds of them.
        across = float(np.linalg.norm(np.ptp(ref.vertices, axis=0))) if ref is not None else 52.0
        mm_per_px = min(max(1.5 * across / 128, 0.01), 100.0)
        try:
            capture = simulate(SimParams(part=part, cameras=6, width=128, height=128, mm_per_px=mm_per_px, supersample=2),
                               0, name="warm-up")
            inspect_capture(capture, recipe, ref, self.pm)
        except Exception as e:  # noqa: BLE001 - a warm-up never stops the server
            self.log(f"warning: warm-up inspection failed ({type(e).__name__}: {_one_line(e)}); the first part loads "
                     "the kernels")
            return None
        return time.perf_counter() - t0

    def _run_single(self, job: Job) -> tuple[dict[str, Any], bool]:
        """One ``Session.run`` of one capture (worker thread): (its record, driver failed)."""
        self._records = []
        t0 = time.perf_counter()
        try:
            summary = self._session.run(Source(limit=1))
        except InspectorError as e:
            return self._error_record(job, str(e)), True
        except Exception as e:  # noqa: BLE001 - a bug: one line, the traceback in a file
            where = save_traceback()
            what = f"internal error {type(e).__name__}: {_one_line(e)}"
            self.log(f"error: {what} (traceback in {where})")  # the path for the server's log, not for every reader
            return self._error_record(job, f"{what} (traceback in the server's log)"), True
        if self._records:
            rec = self._records[-1]
            rec["run_s"] = time.perf_counter() - t0  # Session.run alone: the cycle less the hand-offs
            rec["part_id"] = rec["part_id"] or job.part_id  # a capture that did not load has no metadata
            rec["triggered_at"] = rec["triggered_at"] or job.triggered_at
            return rec, False
        if summary.ended in ("cancelled", "stopped"):
            return self._error_record(job, "aborted before a capture was acquired", verdict="aborted"), False
        return self._error_record(job, "the driver delivered no capture"), True

    def _error_record(self, job: Job | None, text: str, verdict: str = "error") -> dict[str, Any]:
        return {"part_id": job.part_id if job else "", "capture": None, "verdict": verdict, "error": _one_line(text),
                "recipe": self._session.recipe.name, "inspection_s": None, "worst_deviation_mm": None,
                "defect_count": 0, "defects": [], "result_dir": None,
                "triggered_at": job.triggered_at if job else None}

    def _on_event(self, event: Any) -> None:
        """The session's events (worker thread): each result becomes a record; in continuous
        execution it is published at once."""
        if isinstance(event, Warned):
            self.log(f"warning: {printable(event.capture)}: {event.text}")
            return
        if not isinstance(event, Inspected):
            return
        result, folder = event.outcome.result, event.folder
        rec = record(result, folder)
        self.log(log_line(result))
        if self._continuous and self._loop is not None:
            rec["cycle_s"] = result.timings_s.get("total")
            asyncio.run_coroutine_threadsafe(self._publish(rec), self._loop).result()
        else:
            self._records.append(rec)

    # -- results ------------------------------------------------------------------------------
    async def _publish(self, rec: dict[str, Any], *, counter: int | None = None) -> None:
        """One result under the next counter (``counter``: this one, a restart's): journaled,
        then its variables, then ResultCounter."""
        self._counter = (self._counter + 1) % 2**32 if counter is None else counter
        rec = {"counter": self._counter, **{k: v for k, v in rec.items() if k != "counter"}}
        rec["error"] = self._public(rec.get("error"))
        await self._journaled(self._journal.published, self._counter, rec)
        verdict = rec["verdict"]
        worst = rec.get("worst_deviation_mm")
        await self._set("Verdict", verdict)
        await self._set("VerdictCode", model.VERDICT_CODES.get(verdict, 3))
        await self._set("ResultPartId", rec.get("part_id") or "")
        await self._set("CycleTime", float(rec.get("cycle_s") or 0.0))
        await self._set("WorstDeviation", float("nan") if worst is None else float(worst))
        await self._set("DefectCount", int(rec.get("defect_count") or 0))
        cal = rec.get("calibration")
        if cal is not None:  # checked: the calibration state is this part's; else it stays
            await self._set("CalibrationOk", not cal["flagged"])
            await self._set("CalibrationFlagged", ",".join(cal["flagged"]))
        chars = rec.get("characteristics") or []
        await self._set("CharacteristicsNok", ",".join(str(c["id"]) for c in chars if c.get("verdict") == "nok"))
        await self._set("Characteristics", json.dumps(chars, separators=(",", ":"), allow_nan=False))
        await self._set("ErrorText", rec.get("error") or "")
        await self._set("LastResult", json.dumps(rec, separators=(",", ":"), default=str, allow_nan=False))
        await self._set("ResultCounter", self._counter)

    # -- recipes ------------------------------------------------------------------------------
    async def _can_switch(self, name: str) -> ua.StatusCode | None:
        if self._busy:
            return await self._refuse(ua.StatusCodes.BadInvalidState, f"RecipeName refused: busy ({self._state})")
        names = self.recipe_names()
        if name not in names or name_problem(name) is not None:
            return await self._refuse(ua.StatusCodes.BadInvalidArgument,
                                      f"RecipeName '{printable(name)}': no recipe {printable(name)}.toml in the "
                                      f"recipes folder (recipes: {', '.join(names) or 'none'})")
        return None

    async def _switch_recipe(self, name: str) -> ua.StatusCode | None:
        """Load and validate ``name`` (a worker thread); the current recipe stays on failure."""
        if name == self.recipe_name and self._state != "Error":
            return None
        assert self._loop is not None
        before = self._state
        self._busy = True
        await self._set_state("Preoperational", busy=True)
        try:
            new = await self._loop.run_in_executor(self._executor, self._open_session, self.recipes_dir / f"{name}.toml")
        except InspectorError as e:
            await self._set("Recipes", self.recipe_names())
            await self._set_state(before, busy=False)
            self._busy = False
            return await self._refuse(ua.StatusCodes.BadInvalidArgument, f"RecipeName '{name}': {_one_line(e)}")
        old, self._session = self._session, new
        await self._loop.run_in_executor(self._executor, old.close)
        self.log(f"recipe: {self.recipe_name} -> {name}")
        self.recipe_name = name
        await self._set("ErrorText", "")
        await self._set("Recipes", self.recipe_names())
        await self._set_state("Ready", busy=False)
        self._busy = False
        return None

    # -- methods ------------------------------------------------------------------------------
    async def _m_start_single(self, parent: Any, *args: Any) -> Any:
        if len(args) != 1 or not isinstance(args[0], ua.Variant) or args[0].VariantType != ua.VariantType.String:
            return ua.StatusCode(ua.UInt32(ua.StatusCodes.BadTypeMismatch))
        part_id = args[0].Value or ""
        why = part_id_problem(part_id)
        if why is not None:
            return await self._refuse(ua.StatusCodes.BadInvalidArgument, f"PartId '{printable(part_id)}' {why}")
        status = await self._can_trigger("StartSingleJob")
        if status is not None:
            return status
        await self._trigger(part_id, via="StartSingleJob")
        return []

    async def _m_start_continuous(self, parent: Any, *args: Any) -> Any:
        status = await self._can_trigger("StartContinuous")
        if status is not None:
            return status
        self._busy = True
        self._continuous = True
        self._job = None
        self._recovered = None  # a re-trigger is recognised only as the first trigger after a restart
        await self._set("ErrorText", "")
        await self._set_state("ContinuousExecution", busy=True)
        assert self._loop is not None
        self._task = self._loop.create_task(self._continuous_run())
        return []

    async def _continuous_run(self) -> None:
        assert self._loop is not None
        failed = None
        try:
            await self._loop.run_in_executor(self._executor, self._session.run, Source())
        except InspectorError as e:
            failed = _one_line(e)
        except Exception as e:  # noqa: BLE001
            failed = f"internal error {type(e).__name__}: {_one_line(e)}"
        self._continuous = False
        if failed:
            self.log(f"error: {failed}")
            await self._set("ErrorText", failed)
        await self._set_state("Error" if failed else "Ready", busy=False)
        self._busy = False

    async def _m_stop(self, parent: Any, *args: Any) -> Any:
        if self._continuous:
            self._session.stop()
        return []

    async def _m_abort(self, parent: Any, *args: Any) -> Any:
        if self._busy and self._state in ("SingleExecution", "ContinuousExecution"):
            self.log("abort")
            self._session.cancel()
        return []

    async def _m_reset(self, parent: Any, *args: Any) -> Any:
        if self._state == "Error" and not self._busy:
            assert self._loop is not None
            await self._loop.run_in_executor(self._executor, self._session.close)
            await self._set("ErrorText", "")
            await self._set_state("Ready", busy=False)
        return []

    # -- the command --------------------------------------------------------------------------
    async def serve(self, stop: asyncio.Event) -> None:
        """Start, run until ``stop`` is set, stop."""
        await self.start()
        try:
            await stop.wait()
        finally:
            await self.stop()


class ServerThread:
    """An :class:`InspectorServer` on an event loop of its own, in a background thread (the
    tests and ``inspector bench --opcua``)::

        with ServerThread(InspectorServer(recipe, out, settings)) as st:
            ...  # clients connect to st.server.endpoint
    """

    def __init__(self, server: InspectorServer) -> None:
        self.server = server
        self.loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None

    def __enter__(self) -> ServerThread:
        self._thread = threading.Thread(target=self._main, name="inspector-opcua-server", daemon=True)
        self._thread.start()
        self._ready.wait()
        if self._error is not None:
            raise self._error
        return self

    def __exit__(self, *exc: object) -> None:
        if self.loop is not None and self._thread is not None and self._thread.is_alive():
            self.loop.call_soon_threadsafe(self.loop.stop)
            self._thread.join(120)

    def call(self, coro: Any, timeout: float = 60) -> Any:
        """Run ``coro`` on the server's loop and wait for its result."""
        assert self.loop is not None
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def _main(self) -> None:
        loop = asyncio.new_event_loop()
        self.loop = loop
        try:
            loop.run_until_complete(self.server.start())
        except BaseException as e:  # noqa: BLE001 - handed to the caller
            self._error = e
            self._ready.set()
            loop.close()
            return
        self._ready.set()
        try:
            loop.run_forever()
        finally:
            try:
                loop.run_until_complete(self.server.stop())
            except Exception as e:  # noqa: BLE001
                print(f"inspector: warning: stopping the OPC UA server: {type(e).__name__}: {_one_line(e)}",
                      file=sys.stderr)
            loop.close()
