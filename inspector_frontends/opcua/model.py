"""The OPC UA information model of ``inspector serve``: what a PLC reads, writes and calls.

Plain data (no asyncua import): the server builds its address space from these tables, the
docs/opcua.md's table is checked against them (``tests/frontends/opcua/test_opcua.py``), and a client can
import them for the node names.

Every node is a child of one object, ``Objects/Inspector``, in the namespace :data:`NAMESPACE`
(index 2 on this server; a client should look the index up by the URI). Node ids are strings,
stable across versions: ``ns=2;s=Inspector.PartId``, ``ns=2;s=Inspector.StartSingleJob``.

The model follows the concepts of OPC 40100-1 (machine vision), kept as small as a PLC needs:

* the vision system's state machine: :data:`STATES` (``Ready``, ``SingleExecution``,
  ``ContinuousExecution``, ``Error``; ``Preoperational`` while a recipe is being loaded) in
  ``State``, with the handshake bits ``Ready`` and ``Busy``, and the methods
  ``StartSingleJob``, ``StartContinuous``, ``Stop``, ``Abort`` and ``Reset``;
* recipe management: ``RecipeName`` (write a name of ``Recipes`` to switch) and ``Recipes``;
* result management: one result at a time, ``Verdict`` ... ``LastResult``, then
  ``ResultCounter`` (always written last); with it the calibration state, ``CalibrationOk`` and
  ``CalibrationFlagged`` (the evaluate stage's check of every camera on every part).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

__all__ = ["NAMESPACE", "OBJECT", "STATES", "VERDICT_CODES", "Variable", "Method", "VARIABLES", "METHODS", "node_id",
           "variable", "markdown_table"]

#: The namespace URI of the Inspector nodes.
NAMESPACE = "urn:inspector-bcps:opcua"
#: The browse name of the object holding every node (under ``Objects``).
OBJECT = "Inspector"

#: The values of ``State`` (OPC 40100-1's vision state machine names).
STATES = ("Preoperational", "Ready", "SingleExecution", "ContinuousExecution", "Error")

#: ``VerdictCode`` of each ``Verdict`` (0: no result yet).
VERDICT_CODES = {"": 0, "pass": 1, "fail": 2, "error": 3, "aborted": 4}


@dataclass(frozen=True)
class Variable:
    """One variable node.

    Attributes
    ----------
    name : str
        Browse name (and the last part of the string node id).
    type : str
        OPC UA built-in type: ``String``, ``Boolean``, ``UInt32``, ``Int32``, ``Double``;
        ``String[]`` for an array of strings.
    access : str
        ``"rw"``: the PLC writes it (an input); ``"r"``: only the server does.
    group : str
        ``input``, ``state``, ``result`` or ``recipe`` (the manual's grouping).
    doc : str
        What it means, one sentence or two (also the node's Description).
    initial : object
        Its value when the server starts.
    """

    name: str
    type: str
    access: str
    group: str
    doc: str
    initial: Any


@dataclass(frozen=True)
class Method:
    """One method node: ``inputs`` are ``(name, type, doc)``; none has outputs (the result
    is the call's status code)."""

    name: str
    inputs: tuple[tuple[str, str, str], ...]
    doc: str


NAN = float("nan")

VARIABLES: tuple[Variable, ...] = (
    # -- inputs (the PLC writes these) ------------------------------------------------------
    Variable("PartId", "String", "rw", "input",
             "The next part's id: the capture, its result folder and its history row are named after it "
             "(PartId-2, -3 ... when taken). Refused (BadInvalidArgument) when it cannot name a folder. "
             "Empty: the driver names the capture.", ""),
    Variable("Trigger", "Boolean", "rw", "input",
             "Rising edge (false -> true) starts one acquisition and inspection of PartId. Refused "
             "(BadInvalidState) while Busy or in Error, never queued. The server writes it back to false "
             "when the result is out.", False),
    Variable("RecipeName", "String", "rw", "input",
             "The recipe in use (a file name of the recipes folder, without .toml). Write another name of "
             "Recipes to switch: it is loaded and validated first; a bad one is refused (BadInvalidArgument, "
             "ErrorText says why) and the current recipe stays.", ""),
    # -- state -------------------------------------------------------------------------------
    Variable("State", "String", "r", "state",
             "Preoperational (loading a recipe), Ready, SingleExecution, ContinuousExecution or Error.", "Ready"),
    Variable("Ready", "Boolean", "r", "state", "A trigger would be accepted now.", True),
    Variable("Busy", "Boolean", "r", "state",
             "From an accepted trigger until its result is out (ResultCounter written).", False),
    # -- the last result (written in this order, ResultCounter last) --------------------------
    Variable("Verdict", "String", "r", "result", "pass, fail, error or aborted; empty before the first result.", ""),
    Variable("VerdictCode", "Int32", "r", "result", "The verdict as a number: 1 pass, 2 fail, 3 error, 4 aborted "
             "(0: no result yet).", 0),
    Variable("ResultPartId", "String", "r", "result", "The PartId the result belongs to.", ""),
    Variable("CycleTime", "Double", "r", "result", "Seconds from the accepted trigger to the result.", 0.0),
    Variable("WorstDeviation", "Double", "r", "result",
             "The signed deviation of largest magnitude over the measured points, mm (negative: missing "
             "material); NaN when the part was not measured (error, aborted, no evaluate stage).", NAN),
    Variable("DefectCount", "UInt32", "r", "result", "Defect clusters that reject the part.", 0),
    Variable("CalibrationOk", "Boolean", "r", "result",
             "False when the last inspection that checked the calibration found a camera disagreeing with the "
             "others (evaluate's health_px): check its mounting or recalibrate; true otherwise. An inspection that "
             "could not check it (error before evaluate, aborted) leaves it as it was.", True),
    Variable("CalibrationFlagged", "String", "r", "result",
             "The cameras that disagree, comma-separated (e.g. cam07), as of the last inspection that checked the "
             "calibration; empty when none.", ""),
    Variable("CharacteristicsNok", "String", "r", "result",
             "The ids of the last part's characteristics out of tolerance (the recipe's [[characteristics]]), "
             "comma-separated; empty when none (or none measured).", ""),
    Variable("Characteristics", "String", "r", "result",
             "The last part's characteristics as JSON: a list of {id, kind, measured, deviation, lower, upper, U, "
             "verdict (ok, nok, not_measurable)}, in mm or degrees; [] when the recipe measures none.", "[]"),
    Variable("ErrorText", "String", "r", "result",
             "One line: why the verdict is error or aborted, or why the last write or call was refused; "
             "empty when all went well.", ""),
    Variable("LastResult", "String", "r", "result",
             "The result as JSON (counter, part_id, capture, verdict, error, recipe, cycle_s, run_s (Session.run), "
             "inspection_s (the stages), worst_deviation_mm, defect_count, defects (at most 10), result_dir (the "
             "result folder's name, relative to the server's --out folder: no server path is shown to any reader), "
             "triggered_at, calibration: {flagged, off_px per camera} or null; characteristics: as Characteristics; recovered: true when a restart "
             "published it again).", "{}"),
    Variable("ResultCounter", "UInt32", "r", "result",
             "+1 for every accepted trigger, written after the result's other variables (so a PLC polling it "
             "never reads a stale verdict); wraps at 2^32. Kept across restarts (the result folder's journal): a "
             "restart publishes the last result again under its counter, or, when a part was in progress, that "
             "part's result (aborted if none was written) under the next.", 0),
    # -- recipes ------------------------------------------------------------------------------
    Variable("Recipes", "String[]", "r", "recipe", "The recipe names RecipeName may take.", []),
)

METHODS: tuple[Method, ...] = (
    Method("StartSingleJob", (("PartId", "String", "the part's id (empty: the driver names it)"),),
           "The trigger as a method (OPC 40100's name): sets PartId and starts one cycle, as a rising edge of "
           "Trigger does. Good when accepted; BadInvalidState while Busy or in Error; BadInvalidArgument for "
           "a PartId that cannot name a folder."),
    Method("StartContinuous", (),
           "Inspect every capture the recipe's driver delivers until Stop (ContinuousExecution); each result "
           "counts like a triggered one. BadInvalidState unless Ready."),
    Method("Stop", (), "End continuous execution after the part in progress (a no-op otherwise)."),
    Method("Abort", (), "End the cycle in progress before its next stage: verdict aborted, nothing written, "
           "no history row, ResultCounter +1 (a no-op when idle)."),
    Method("Reset", (), "Leave the Error state (the driver is opened again on the next trigger); a no-op "
           "otherwise."),
)


def node_id(name: str) -> str:
    """The string identifier of node ``name`` (in :data:`NAMESPACE`): ``Inspector.NAME``."""
    return f"{OBJECT}.{name}"


def variable(name: str) -> Variable:
    """The :class:`Variable` called ``name`` (KeyError otherwise)."""
    for v in VARIABLES:
        if v.name == name:
            return v
    raise KeyError(name)


def markdown_table() -> str:
    """The information model as the manual's Markdown table (docs/opcua.md) (one row per node)."""
    rows = ["| node | type | access | meaning |", "|---|---|---|---|"]
    for v in VARIABLES:
        rows.append(f"| `{v.name}` | {v.type} | {'read/write' if v.access == 'rw' else 'read'} | {v.doc} |")
    for m in METHODS:
        args = ", ".join(f"{n}: {t}" for n, t, _ in m.inputs)
        rows.append(f"| `{m.name}({args})` | method | call | {m.doc} |")
    return "\n".join(rows)
