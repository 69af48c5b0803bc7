"""The quality-data formats plants require: Q-DAS AQDEF (DFQ) and QIF 3.0 Results.

**DFQ** (:func:`write_dfq`): the AQDEF ASCII transfer format, description and values in one
file. The header holds ``K0100`` (number of characteristics), the part (``K1001`` number,
``K1002`` description) and per characteristic ``i`` the ``K2xxx/i`` fields: ``K2001``
number (the balloon id), ``K2002`` description, ``K2004`` type (0: variable), ``K2005``
class (from the criticality), ``K2101`` nominal, ``K2110``/``K2111`` lower and upper
specification limits (absolute: nominal + lower/upper), ``K2112``/``K2113`` the same as
allowances, ``K2142`` unit, ``K2022`` decimal places. Then one value line per part: per
characteristic the fields value, attribute, date/time (``dd.mm.yyyy/HH:MM:SS``), events,
batch (the part id), separated by ``0x14`` (DC4), characteristics separated by ``0x0F``
(SI). A characteristic not measurable on a part gets an empty value and attribute 255
(the value is not to be used). Numbers use the decimal point; the file is ISO 8859-1
(CR LF line ends), as Q-DAS tools expect.

**QIF** (:func:`write_qif`): a QIF 3.0 document (ISO 23952) with the header, the file
units, the measurement resource (the cell), the product, the features the characteristics
apply to (definitions, nominals, items), the characteristics (definitions with their
tolerances, nominals, items with balloon id and criticality) and the results: one
``MeasurementResults`` per part with each characteristic's actual value and status
(``PASS``/``FAIL``, ``INDETERMINATE`` when not measurable), the part id as the actual
component's serial number; the expanded uncertainty ``U`` (k = 2) rides along as a
user attribute (QIF has no field for it in a characteristic's actual).
"""

from __future__ import annotations

import json
import math
import os
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any
from xml.sax.saxutils import escape, quoteattr

from inspector import __version__
from inspector.characteristics.definitions import features_for, rows_of
from inspector.characteristics.measure import Characteristic, CharacteristicResult, unit_of
from inspector.errors import InputError, RecipeError

__all__ = ["DFQ_FIELD", "DFQ_CHARACTERISTIC", "PartRecord", "RunRecords", "HistoryRecords", "write_dfq", "write_qif",
           "history_records", "output_file", "part_number_of"]

#: AQDEF separators of a value line: between the fields of one value, between characteristics.
DFQ_FIELD = "\x14"
DFQ_CHARACTERISTIC = "\x0f"
#: AQDEF attribute of a value that must not be used (the characteristic was not measurable).
DFQ_INVALID = 255
#: K2005 characteristic class per criticality (0 unimportant ... 4 critical).
DFQ_CLASS = {"minor": 2, "major": 3, "critical": 4, "key": 4}


@dataclass(frozen=True)
class PartRecord:
    """The characteristics measured on one part.

    Attributes
    ----------
    part_id : str
        The part's identification (serial number, capture name).
    time : datetime
        When it was inspected.
    results : sequence
        :class:`~inspector.characteristics.measure.CharacteristicResult` or their
        ``to_json()`` dicts (as ``result.json`` and the history hold them).
    """

    part_id: str
    time: datetime
    results: Sequence[CharacteristicResult | Mapping[str, Any]] = field(default_factory=tuple)

    def by_id(self) -> dict[str, CharacteristicResult]:
        out = {}
        for r in self.results:
            res = r if isinstance(r, CharacteristicResult) else CharacteristicResult.from_json(r)
            out[res.id] = res
        return out


def _number(v: float, places: int = 6) -> str:
    s = f"{v:.{places}f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def _dfq_text(s: str) -> str:
    """A K-field text: one line, no separators, ISO 8859-1."""
    s = " ".join(str(s).replace(DFQ_FIELD, " ").replace(DFQ_CHARACTERISTIC, " ").split())
    return s.encode("latin-1", "replace").decode("latin-1")


def _nominals(characteristics: Sequence[Characteristic], parts: Sequence[PartRecord]) -> dict[str, float]:
    out: dict[str, float] = {}
    for c in characteristics:
        if c.nominal is not None:
            out[c.id] = float(c.nominal)
    for p in parts:
        for cid, r in p.by_id().items():
            out.setdefault(cid, float(r.nominal))
    for c in characteristics:
        if c.id not in out:
            if c.kind in ("flatness", "roundness", "cylindricity", "position"):
                out[c.id] = 0.0
            else:
                raise ValueError(f"characteristic {c.id!r}: no nominal (give one, or a measured part)")
    return out


def write_dfq(path: str | os.PathLike[str], characteristics: Sequence[Characteristic], parts: Sequence[PartRecord], *,
              part_number: str = "", part_description: str = "", places: int = 4) -> Path:
    """Write a DFQ file (AQDEF ASCII transfer format): header, then one value line per part.

    Parameters
    ----------
    path : path
        The file to write (replaced whole: a temporary file, then a rename).
    characteristics : sequence of Characteristic
        In the order of the file's characteristic numbers 1..K.
    parts : sequence of PartRecord
        One value line each, in order; a characteristic missing from a part's results, or not
        measurable on it, is written empty with attribute 255.
    part_number, part_description : str
        K1001 and K1002 (e.g. the reference and the recipe).
    places : int
        Decimal places of the values (K2022).

    Returns
    -------
    Path
    """
    nom = _nominals(characteristics, parts)
    lines = [f"K0100 {len(characteristics)}", f"K1001 {_dfq_text(part_number or 'part')}"]
    if part_description:
        lines.append(f"K1002 {_dfq_text(part_description)}")
    for i, c in enumerate(characteristics, start=1):
        n = nom[c.id]
        lines += [
            f"K2001/{i} {_dfq_text(c.id)}",
            f"K2002/{i} {_dfq_text(c.label)}",
            f"K2004/{i} 0",
            f"K2005/{i} {DFQ_CLASS[c.criticality]}",
            f"K2022/{i} {places}",
            f"K2101/{i} {_number(n)}",
            f"K2110/{i} {_number(n + c.lower)}",
            f"K2111/{i} {_number(n + c.upper)}",
            f"K2112/{i} {_number(c.lower)}",
            f"K2113/{i} {_number(c.upper)}",
            f"K2142/{i} {unit_of(c.kind)}",
        ]
    for p in parts:
        res = p.by_id()
        when = p.time.strftime("%d.%m.%Y/%H:%M:%S")
        cells = []
        for c in characteristics:
            r = res.get(c.id)
            if r is None or r.measured is None or not math.isfinite(r.measured):
                value, attr = "", DFQ_INVALID
            else:
                value, attr = f"{r.measured:.{places}f}", 0
            cells.append(DFQ_FIELD.join([value, str(attr), when, "", _dfq_text(p.part_id)]))
        lines.append(DFQ_CHARACTERISTIC.join(cells))
    return _write(path, ("\r\n".join(lines) + "\r\n").encode("latin-1", "replace"))


def _write(path: str | os.PathLike[str], data: bytes) -> Path:
    p = Path(path)
    tmp = p.with_name(f".{p.name}.partial")
    tmp.write_bytes(data)
    os.replace(tmp, p)
    return p


# --------------------------------------------------------------------------- QIF

_QIF_NS = "http://qifstandards.org/xsd/qif3"
#: QIF element stem of each characteristic kind.
_QIF_KIND = {"diameter": "Diameter", "radius": "Radius", "distance": "DistanceBetween", "angle": "AngleBetween",
             "position": "Position", "flatness": "Flatness", "roundness": "Circularity", "cylindricity": "Cylindricity"}
#: Kinds whose QIF definition holds a single tolerance value (a zone), not limits.
_QIF_ZONE = ("position", "flatness", "roundness", "cylindricity")
_QIF_FEATURE = {"plane": "Plane", "cylinder": "Cylinder", "cone": "Cone", "sphere": "Sphere", "torus": "Torus"}


class _Ids:
    def __init__(self) -> None:
        self.n = 0

    def __call__(self) -> int:
        self.n += 1
        return self.n


def status_of(verdicts: set[str]) -> str:
    """A part's QIF inspection status from its characteristics' verdicts."""
    return "FAIL" if "nok" in verdicts else "UNKNOWN" if "not_measurable" in verdicts else "PASS"


def _v3(v: Any) -> str:
    return " ".join(repr(float(x)) for x in v)


def write_qif(path: str | os.PathLike[str], characteristics: Sequence[Characteristic], features: Sequence[Any],
              parts: Sequence[PartRecord], *, part_number: str = "", part_description: str = "",
              device: str = "Inspector silhouette cell (BCPS)", application: str = "Inspector") -> Path:
    """Write a QIF 3.0 Results document.

    Parameters
    ----------
    path : path
        The file to write (replaced whole).
    characteristics : sequence of Characteristic
    features : sequence of Feature
        The reference's features (those the characteristics name are written).
    parts : sequence of PartRecord
        One ``MeasurementResults`` each.
    part_number, part_description : str
        The product's part (model number and name).
    device, application : str
        The measurement device's and the writing application's names.

    Returns
    -------
    Path
    """
    nom = _nominals(characteristics, parts)
    by_fid = {f.id: f for f in features}
    for c in characteristics:
        c.validate(by_fid)
    ids = _Ids()
    out: list[str] = []
    w = out.append
    w('<?xml version="1.0" encoding="UTF-8"?>')
    body: list[str] = []
    b = body.append
    b(f"<QPId>{uuid.uuid4()}</QPId>")
    b(f"<Version><TimeCreated>{datetime.now().replace(microsecond=0).isoformat()}</TimeCreated></Version>")
    b(f"<Header><Application><Name>{escape(application)}</Name><Organization>Inspector {escape(__version__)}"
      "</Organization></Application></Header>")
    std = ids()
    b(f'<StandardsDefinitions n="1"><Standard id="{std}"><Organization><StandardsOrganizationEnum>ISO'
      "</StandardsOrganizationEnum></Organization><Designator>1101</Designator><Year>2017</Year></Standard>"
      "</StandardsDefinitions>")
    b("<FileUnits><PrimaryUnits>"
      "<AngularUnit><SIUnitName>radian</SIUnitName><UnitName>degree</UnitName>"
      "<UnitConversion><Factor>0.0174532925199433</Factor></UnitConversion></AngularUnit>"
      "<LinearUnit><SIUnitName>meter</SIUnitName><UnitName>mm</UnitName>"
      "<UnitConversion><Factor>0.001</Factor></UnitConversion></LinearUnit>"
      "</PrimaryUnits></FileUnits>")
    dev = ids()
    b(f'<MeasurementResources><MeasurementDevices n="1"><MeasurementDevice id="{dev}"><Name>{escape(device)}</Name>'
      "</MeasurementDevice></MeasurementDevices></MeasurementResources>")
    part_id = ids()
    desc = (f'<Attributes n="1"><AttributeStr name="description" value={quoteattr(part_description)}/></Attributes>'
            if part_description else "")
    b(f'<Product><PartSet n="1"><Part id="{part_id}">{desc}<ModelNumber>{escape(part_number or "part")}</ModelNumber>'
      "</Part></PartSet></Product>")
    # features
    used = []
    for c in characteristics:
        for fid in c.features:
            if fid not in used:
                used.append(fid)
    features_xml, item_of = _qif_features(used, by_fid, ids)
    b(features_xml)
    characteristics_xml, citem_of = _qif_characteristics(characteristics, nom, item_of, std, dev, ids)
    b(characteristics_xml)
    b(_qif_results(characteristics, parts, citem_of, ids))
    w(f'<QIFDocument xmlns="{_QIF_NS}" versionQIF="3.0.0" idMax="{ids.n}">')
    out += body
    w("</QIFDocument>")
    return _write(path, ("\n".join(out) + "\n").encode("utf-8"))


def _qif_features(used: list[str], by_fid: dict[str, Any], ids: _Ids) -> tuple[str, dict[str, int]]:
    """The ``Features`` element of :func:`write_qif`: the definition, nominal and item of each
    feature ``used``, in that order.

    Parameters
    ----------
    used : list of str
        The ids of the features the characteristics name, first named first.
    by_fid : dict
        The reference's features by id.
    ids : _Ids
        The document's id counter (ids are drawn in document order).

    Returns
    -------
    xml : str
        The element.
    item_of : dict
        Each feature's ``FeatureItem`` id.
    """
    fdef, fnom, fitem = [], [], []
    item_of: dict[str, int] = {}
    for fid in used:
        f = by_fid[fid]
        stem = _QIF_FEATURE[f.kind]
        d, n_, it = ids(), ids(), ids()
        item_of[fid] = it
        nm = f.nominal
        ie = "EXTERNAL" if nm.get("convex", True) else "INTERNAL"
        if f.kind == "plane":
            fdef.append(f'<PlaneFeatureDefinition id="{d}"/>')
            geo = f"<Location>{_v3(nm['point'])}</Location><Normal>{_v3(nm['normal'])}</Normal>"
        elif f.kind == "cylinder":
            fdef.append(f'<CylinderFeatureDefinition id="{d}"><InternalExternal>{ie}</InternalExternal>'
                        f"<Diameter>{2.0 * float(nm['radius'])!r}</Diameter><Length>{float(nm['length'])!r}</Length>"
                        "</CylinderFeatureDefinition>")
            geo = f"<Axis><AxisPoint>{_v3(nm['point'])}</AxisPoint><Direction>{_v3(nm['direction'])}</Direction></Axis>"
        elif f.kind == "sphere":
            fdef.append(f'<SphereFeatureDefinition id="{d}"><InternalExternal>{ie}</InternalExternal>'
                        f"<Diameter>{2.0 * float(nm['radius'])!r}</Diameter></SphereFeatureDefinition>")
            geo = f"<Location>{_v3(nm['centre'])}</Location>"
        elif f.kind == "torus":
            fdef.append(f'<TorusFeatureDefinition id="{d}"><InternalExternal>{ie}</InternalExternal>'
                        f"<MinorDiameter>{2.0 * float(nm['minor_radius'])!r}</MinorDiameter>"
                        f"<MajorDiameter>{2.0 * float(nm['major_radius'])!r}</MajorDiameter></TorusFeatureDefinition>")
            geo = f"<Location>{_v3(nm['centre'])}</Location><AxisVector>{_v3(nm['axis'])}</AxisVector>"
        else:  # cone
            fdef.append(f'<ConeFeatureDefinition id="{d}"><InternalExternal>{ie}</InternalExternal>'
                        f"<Angle>{2.0 * float(nm['half_angle_deg'])!r}</Angle></ConeFeatureDefinition>")
            geo = f"<Axis><AxisPoint>{_v3(nm['apex'])}</AxisPoint><Direction>{_v3(nm['axis'])}</Direction></Axis>"
        fnom.append(f'<{stem}FeatureNominal id="{n_}"><FeatureDefinitionId>{d}</FeatureDefinitionId>{geo}'
                    f"</{stem}FeatureNominal>")
        fitem.append(f'<{stem}FeatureItem id="{it}"><FeatureNominalId>{n_}</FeatureNominalId>'
                     f"<FeatureName>{escape(fid)}</FeatureName><DeterminationMode><Checked><CheckDetails><Measured/>"
                     f"</CheckDetails></Checked></DeterminationMode></{stem}FeatureItem>")
    k = len(used)
    return (f'<Features><FeatureDefinitions n="{k}">{"".join(fdef)}</FeatureDefinitions>'
            f'<FeatureNominals n="{k}">{"".join(fnom)}</FeatureNominals>'
            f'<FeatureItems n="{k}">{"".join(fitem)}</FeatureItems></Features>'), item_of


def _qif_characteristics(characteristics: Sequence[Characteristic], nom: dict[str, float], item_of: dict[str, int],
                         std: int, dev: int, ids: _Ids) -> tuple[str, dict[str, int]]:
    """The ``Characteristics`` element of :func:`write_qif`: each characteristic's definition
    (its tolerance), nominal and item.

    Parameters
    ----------
    characteristics : sequence of Characteristic
    nom : dict
        Each characteristic's nominal value (:func:`_nominals`).
    item_of : dict
        Each feature's ``FeatureItem`` id (:func:`_qif_features`).
    std, dev : int
        The ids of the standard (ISO 1101) and of the measurement device.
    ids : _Ids
        The document's id counter.

    Returns
    -------
    xml : str
        The element.
    citem_of : dict
        Each characteristic's ``CharacteristicItem`` id.
    """
    cdef, cnom, citem = [], [], []
    citem_of: dict[str, int] = {}
    for c in characteristics:
        stem = _QIF_KIND[c.kind]
        d, n_, it = ids(), ids(), ids()
        citem_of[c.id] = it
        if c.kind in _QIF_ZONE:
            tol = f"<ToleranceValue>{float(c.upper)!r}</ToleranceValue>"
            if c.kind == "position":
                tol += "<MaterialCondition>REGARDLESS</MaterialCondition><ZoneShape><DiametricalZone/></ZoneShape>"
        else:
            tol = (f"<Tolerance><MaxValue>{float(c.upper)!r}</MaxValue><MinValue>{float(c.lower)!r}</MinValue>"
                   "<DefinedAsLimit>false</DefinedAsLimit></Tolerance>")
        cdef.append(f'<{stem}CharacteristicDefinition id="{d}">{tol}</{stem}CharacteristicDefinition>')
        target = "" if c.kind in _QIF_ZONE else f"<TargetValue>{nom[c.id]!r}</TargetValue>"
        if c.kind in ("distance", "angle"):
            target += "<AnalysisMode>THREEDIMENSIONAL</AnalysisMode>"
        cnom.append(f'<{stem}CharacteristicNominal id="{n_}"><CharacteristicDefinitionId>{d}</CharacteristicDefinitionId>'
                    f"{target}</{stem}CharacteristicNominal>")
        fitems = "".join(f"<Id>{item_of[fid]}</Id>" for fid in c.features)
        desc = f"<Description>{escape(c.description)}</Description>" if c.description else ""
        citem.append(f'<{stem}CharacteristicItem id="{it}">{desc}<Name>{escape(c.id)}</Name>'
                     f"<CharacteristicDesignator><Designator>{escape(c.id)}</Designator><Criticality>"
                     f"<LevelEnum>{c.criticality.upper()}</LevelEnum></Criticality></CharacteristicDesignator>"
                     f'<FeatureItemIds n="{len(c.features)}">{fitems}</FeatureItemIds>'
                     f'<MeasurementDeviceIds n="1"><Id>{dev}</Id></MeasurementDeviceIds>'
                     f"<CharacteristicNominalId>{n_}</CharacteristicNominalId></{stem}CharacteristicItem>")
    m = len(characteristics)
    return (f'<Characteristics><FormalStandardId>{std}</FormalStandardId><CharacteristicDefinitions n="{m}">{"".join(cdef)}</CharacteristicDefinitions>'
            f'<CharacteristicNominals n="{m}">{"".join(cnom)}</CharacteristicNominals>'
            f'<CharacteristicItems n="{m}">{"".join(citem)}</CharacteristicItems></Characteristics>'), citem_of


def _qif_results(characteristics: Sequence[Characteristic], parts: Sequence[PartRecord], citem_of: dict[str, int],
                 ids: _Ids) -> str:
    """The ``Results`` element of :func:`write_qif`: one ``MeasurementResults`` and one
    ``ActualComponent`` per part.

    Parameters
    ----------
    characteristics : sequence of Characteristic
    parts : sequence of PartRecord
    citem_of : dict
        Each characteristic's ``CharacteristicItem`` id (:func:`_qif_characteristics`).
    ids : _Ids
        The document's id counter.

    Returns
    -------
    str
        The element.
    """
    sets, actuals = [], []
    for p in parts:
        res = p.by_id()
        mr, comp = ids(), ids()
        meas = []
        verdicts = set()
        for c in characteristics:
            r = res.get(c.id)
            verdicts.add(r.verdict if r is not None else "not_measurable")
            stem = _QIF_KIND[c.kind]
            if r is None or r.verdict == "not_measurable" or r.measured is None:
                status, value = "INDETERMINATE", ""
                why = (r.reason if r is not None else "not measured") or "not measurable"
                attrs = f'<Attributes n="1"><AttributeStr name="reason" value={quoteattr(why)}/></Attributes>'
            else:
                status = "PASS" if r.verdict == "ok" else "FAIL"
                value = f"<Value>{float(r.measured)!r}</Value>"
                uu = float(r.U) if r.U is not None else float("nan")
                attrs = (f'<Attributes n="2"><AttributeD1 name="U" value="{uu!r}"/>'
                         f'<AttributeD1 name="deviation" value="{float(r.deviation or 0.0)!r}"/></Attributes>'
                         if math.isfinite(uu) else "")
            meas.append(f'<{stem}CharacteristicMeasurement id="{ids()}">{attrs}<Status><CharacteristicStatusEnum>{status}'
                        f"</CharacteristicStatusEnum></Status><CharacteristicItemId>{citem_of[c.id]}</CharacteristicItemId>"
                        f"<TimeStamp>{p.time.replace(microsecond=0).isoformat()}</TimeStamp>"
                        f"<ActualComponentId>{comp}</ActualComponentId>{value}</{stem}CharacteristicMeasurement>")
        sets.append(f'<MeasurementResults id="{mr}"><ThisResultsInstanceQPId>{uuid.uuid4()}</ThisResultsInstanceQPId>'
                    f'<MeasuredCharacteristics><CharacteristicMeasurements n="{len(meas)}">{"".join(meas)}'
                    f"</CharacteristicMeasurements></MeasuredCharacteristics><InspectionStatus><InspectionStatusEnum>"
                    f"{status_of(verdicts)}"
                    f'</InspectionStatusEnum></InspectionStatus><ActualComponentIds n="1"><Id>{comp}</Id>'
                    "</ActualComponentIds></MeasurementResults>")
        actuals.append(f'<ActualComponent id="{comp}"><SerialNumber>{escape(p.part_id)}</SerialNumber>'
                       f"<Status><InspectionStatusEnum>{status_of(verdicts)}</InspectionStatusEnum></Status>"
                       "</ActualComponent>")
    return (f'<Results><MeasurementResultsSet n="{len(sets)}">{"".join(sets)}</MeasurementResultsSet>'
            f'<ActualComponentSets n="1"><ActualComponentSet n="{len(actuals)}">{"".join(actuals)}</ActualComponentSet>'
            "</ActualComponentSets></Results>")


# --------------------------------------------------------------------------- a run's files


def _when(metadata: Mapping[str, Any]) -> datetime:
    """The part's capture time (``capture.json`` ``timestamp``, ISO 8601), else now."""
    ts = metadata.get("timestamp") if isinstance(metadata, Mapping) else None
    if isinstance(ts, str):
        try:
            return datetime.fromisoformat(ts.replace("Z", "+00:00"))
        except ValueError:
            pass
    return datetime.now().astimezone()


def output_file(path: str, option: str) -> Path:
    """``path`` as a file to write: RecipeError (one line naming ``option`` and ``path``) when it
    is a folder or its folder does not exist."""
    p = Path(path).expanduser()
    if p.is_dir():
        raise RecipeError(f"{option} {path}: is a folder, not a file")
    if not p.parent.is_dir():
        raise RecipeError(f"{option} {path}: no such folder {p.parent}")
    return p


@dataclass
class RunRecords:
    """The characteristics of a run's parts, collected as they are inspected and written to
    ``--dfq`` / ``--qif`` files at its end (``inspector run``).

    Only the rows are kept (``result.extras["characteristics"]``: a few hundred bytes a
    part), never the points. A part with no rows (an error before the characteristics
    stage) has no value line.
    """

    characteristics: tuple[Characteristic, ...]
    features: Sequence[Any]
    dfq: Path | None
    qif: Path | None
    part_number: str = ""
    part_description: str = ""
    parts: list[PartRecord] = field(default_factory=list)

    @classmethod
    def open(cls, recipe: Any, reference: Any, *, dfq: str | None = None, qif: str | None = None) -> RunRecords:
        """Check the options against ``recipe`` (a :class:`~inspector.recipe.Recipe`) before the
        run; RecipeError (one line) when it defines no characteristics or a file's folder is
        missing."""
        option = "--dfq" if dfq is not None else "--qif"
        chars = tuple(getattr(recipe, "characteristics", ()))
        if not chars:
            raise RecipeError(f"{option}: the recipe {recipe.name!r} defines no [[characteristics]] to write")
        if reference is None:
            raise RecipeError(f"{option}: the recipe {recipe.name!r} has no reference mesh")
        return cls(chars, features_for(reference.vertices, reference.faces),
                   output_file(dfq, "--dfq") if dfq is not None else None,
                   output_file(qif, "--qif") if qif is not None else None,
                   part_number=part_number_of(str(reference.name)), part_description=str(recipe.name))

    def add(self, result: Any) -> None:
        """Keep one result's characteristics (an :class:`~inspector.model.InspectionResult`)."""
        rows = (getattr(result, "extras", None) or {}).get("characteristics")
        if not isinstance(rows, list) or not rows:
            return
        self.parts.append(PartRecord(str(result.capture), _when(getattr(result, "metadata", {}) or {}), tuple(rows)))

    def write(self) -> list[Path]:
        """Write the files asked for (also with no part: the header alone); their paths."""
        out = []
        if self.dfq is not None:
            out.append(write_dfq(self.dfq, self.characteristics, self.parts, part_number=self.part_number,
                                 part_description=self.part_description))
        if self.qif is not None:
            out.append(write_qif(self.qif, self.characteristics, self.features, self.parts,
                                 part_number=self.part_number, part_description=self.part_description))
        return out


def part_number_of(reference: str) -> str:
    """A part's number (the DFQ's K1001) from its reference: the mesh file's stem, or
    ``builtin:NAME`` as it is."""
    return reference if reference.startswith("builtin:") else Path(reference).stem


def _recorded_time(row: Mapping[str, Any]) -> datetime:
    """When a recorded part was inspected, as :class:`RunRecords` dates it: capture.json's
    ``timestamp`` (the ``triggered_at`` column), else the row's ``inspected_at`` (UTC) in
    local time, as the run's clock would have read it."""
    for key in ("triggered_at", "inspected_at"):
        v = row.get(key)
        t: datetime | None = v if isinstance(v, datetime) else None
        if t is None:
            try:
                t = datetime.fromisoformat(str(v).replace("Z", "+00:00")) if v else None
            except ValueError:
                t = None
        if t is not None:
            if key == "triggered_at":
                return t
            return (t if t.tzinfo is not None else t.replace(tzinfo=UTC)).astimezone()
    raise ValueError("no inspected_at")


@dataclass(frozen=True)
class HistoryRecords:
    """What :func:`history_records` takes from recorded inspections for :func:`write_dfq`."""

    characteristics: tuple[Characteristic, ...]
    parts: list[PartRecord]
    recipes: list[str]


def history_records(rows: Sequence[Mapping[str, Any]]) -> HistoryRecords:
    """The characteristics of recorded inspections (``read_history`` or the plant database's
    rows, oldest first), as :class:`RunRecords` collects them in a run: one
    :class:`PartRecord` per inspection with characteristics rows (its ``extras`` column),
    the capture as the part id, dated by :func:`_recorded_time`; each characteristic's
    definition (kind, features, limits, nominal, criticality, description) from its first
    recorded row, in first-recorded order (as ``inspector history --characteristics``
    takes them); the recipes' names in first-recorded order. Inspections without
    characteristics (an error, an older recipe) are left out.

    Raises InputError (one line naming the inspection) for a row that cannot be read.
    """
    chars: dict[str, Characteristic] = {}
    parts: list[PartRecord] = []
    recipes: dict[str, None] = {}
    keys = ("id", "kind", "features", "lower", "upper", "nominal", "criticality", "description")
    for row in rows:
        where = f"history: the inspection of {row.get('capture')!r} at {row.get('inspected_at')}"
        try:
            raw = row.get("extras")
            found = rows_of({"extras": (json.loads(raw) if isinstance(raw, str) else raw) or {}})
            if not found:
                continue
            results = tuple(CharacteristicResult.from_json(r) for r in found)
            for r in found:
                if str(r["id"]) not in chars:
                    chars[str(r["id"])] = Characteristic.from_dict(
                        {k: r[k] for k in keys if r.get(k) is not None}, where=f"characteristic {r['id']!r}")
            when = _recorded_time(row)
        except (KeyError, TypeError, ValueError, RecipeError) as e:
            raise InputError(f"{where}: its characteristics cannot be read ({type(e).__name__}: {e})") from None
        parts.append(PartRecord(str(row.get("capture")), when, results))
        recipes.setdefault(str(row.get("recipe")), None)
    return HistoryRecords(tuple(chars.values()), parts, list(recipes))
