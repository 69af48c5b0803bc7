<?xml version="1.0" encoding="utf-8"?>
<!DOCTYPE TS>
<TS version="2.1" language="de_DE" sourcelanguage="en_US">
<context>
    <name>CameraDialog</name>
    <message>
        <source>Camera {name}</source>
        <translation>Kamera {name}</translation>
    </message>
    <message>
        <source>silhouette consistent with the other cameras</source>
        <translation>Silhouette stimmt mit den anderen Kameras überein</translation>
    </message>
    <message>
        <source>Fit (0)</source>
        <translation>Einpassen (0)</translation>
    </message>
    <message>
        <source>Close (Esc)</source>
        <translation>Schließen (Esc)</translation>
    </message>
</context>
<context>
    <name>CameraStrip</name>
    <message>
        <source>Camera images appear here after an inspection.</source>
        <translation>Die Kamerabilder erscheinen hier nach einer Prüfung.</translation>
    </message>
    <message>
        <source>No camera images: this result was opened from its folder.</source>
        <translation>Keine Kamerabilder: Dieses Ergebnis wurde aus seinem Ordner geöffnet.</translation>
    </message>
</context>
<context>
    <name>CameraTile</name>
    <message>
        <source>(double-click or Enter: open large)</source>
        <translation>(Doppelklick oder Eingabetaste: groß öffnen)</translation>
    </message>
    <message>
        <source>camera {name} flagged</source>
        <translation>Kamera {name} markiert</translation>
    </message>
    <message>
        <source>camera {name}</source>
        <translation>Kamera {name}</translation>
    </message>
</context>
<context>
    <name>CharacteristicsPanel</name>
    <message>
        <source>{id} {label}: last {n} parts</source>
        <translation>{id} {label}: letzte {n} Teile</translation>
    </message>
</context>
<context>
    <name>CharacteristicsTable</name>
    <message>
        <source>OK</source>
        <extracomment>Verdict of a characteristic -&gt; (word, glyph, colour); the word and glyph say it without colour.</extracomment>
        <translation>IO</translation>
    </message>
    <message>
        <source>NOK</source>
        <translation>NIO</translation>
    </message>
    <message>
        <source>not measurable</source>
        <translation>nicht messbar</translation>
    </message>
    <message>
        <source>characteristic</source>
        <extracomment>Column of the deviation bar.</extracomment>
        <translation>Merkmal</translation>
    </message>
    <message>
        <source>measured</source>
        <translation>Istwert</translation>
    </message>
    <message>
        <source>nominal</source>
        <translation>Nennmaß</translation>
    </message>
    <message>
        <source>deviation</source>
        <translation>Abweichung</translation>
    </message>
    <message>
        <source>U (k=2)</source>
        <translation>U (k=2)</translation>
    </message>
    <message>
        <source>verdict</source>
        <translation>Urteil</translation>
    </message>
    <message>
        <source>characteristics table</source>
        <translation>Merkmalstabelle</translation>
    </message>
</context>
<context>
    <name>DefectTable</name>
    <message>
        <source>kind</source>
        <translation>Art</translation>
    </message>
    <message>
        <source>region</source>
        <translation>Bereich</translation>
    </message>
    <message>
        <source>points</source>
        <translation>Punkte</translation>
    </message>
    <message>
        <source>worst mm</source>
        <translation>max. mm</translation>
    </message>
    <message>
        <source>extent mm</source>
        <translation>Ausdehnung mm</translation>
    </message>
    <message>
        <source>cameras</source>
        <translation>Kameras</translation>
    </message>
    <message>
        <source>defect table</source>
        <translation>Fehlstellentabelle</translation>
    </message>
    <message>
        <source>missing material</source>
        <translation>fehlendes Material</translation>
    </message>
    <message>
        <source>excess material</source>
        <translation>überschüssiges Material</translation>
    </message>
</context>
<context>
    <name>DeviationView</name>
    <message>
        <source>deviation</source>
        <extracomment>Points are drawn as flat squares of this many pixels. Names of the actors a defect selection adds (removed when a new result is shown).</extracomment>
        <translation>Abweichung</translation>
    </message>
    <message>
        <source>{verdict}  {capture}  ({n} points)</source>
        <translation>{verdict}  {capture}  ({n} Punkte)</translation>
    </message>
</context>
<context>
    <name>HistoryStrip</name>
    <message>
        <source>no inspection yet</source>
        <translation>noch keine Prüfung</translation>
    </message>
    <message>
        <source>last {n}: yield {share} · pass {p} · fail {f} · error {e}</source>
        <translation>letzte {n}: Ausbeute {share} · IO {p} · NIO {f} · Störungen {e}</translation>
    </message>
    <message>
        <source>error {e}</source>
        <translation>Störungen {e}</translation>
    </message>
    <message>
        <source>no part judged yet</source>
        <translation>noch kein Teil bewertet</translation>
    </message>
</context>
<context>
    <name>LoginDialog</name>
    <message>
        <source>Engineer login</source>
        <extracomment>The widget that edits one parameter (see :meth:`RecipeEditor._editor`).</extracomment>
        <translation>Anmeldung Einrichter</translation>
    </message>
    <message>
        <source>Name</source>
        <translation>Name</translation>
    </message>
    <message>
        <source>Password</source>
        <translation>Passwort</translation>
    </message>
</context>
<context>
    <name>MainWindow</name>
    <message>
        <source>Inspector: operator</source>
        <translation>Inspector: Bediener</translation>
    </message>
    <message>
        <source>INSPECT</source>
        <translation>PRÜFEN</translation>
    </message>
    <message>
        <source>Inspect the next part (Space or F5)</source>
        <translation>Das nächste Teil prüfen (Leertaste oder F5)</translation>
    </message>
    <message>
        <source>LIVE</source>
        <translation>DAUERBETRIEB</translation>
    </message>
    <message>
        <source>Inspect continuously until stopped (F6)</source>
        <translation>Fortlaufend prüfen, bis angehalten (F6)</translation>
    </message>
    <message>
        <source>CANCEL</source>
        <translation>ABBRECHEN</translation>
    </message>
    <message>
        <source>Abort the inspection in progress (Esc)</source>
        <translation>Die laufende Prüfung abbrechen (Esc)</translation>
    </message>
    <message>
        <source>&amp;File</source>
        <translation>&amp;Datei</translation>
    </message>
    <message>
        <source>Open capture folder…</source>
        <translation>Aufnahmeordner öffnen…</translation>
    </message>
    <message>
        <source>Open result folder…</source>
        <translation>Ergebnisordner öffnen…</translation>
    </message>
    <message>
        <source>Export report (PDF)</source>
        <translation>Bericht exportieren (PDF)</translation>
    </message>
    <message>
        <source>Quit</source>
        <translation>Beenden</translation>
    </message>
    <message>
        <source>&amp;Role</source>
        <translation>&amp;Rolle</translation>
    </message>
    <message>
        <source>Engineer login…</source>
        <translation>Als Einrichter anmelden…</translation>
    </message>
    <message>
        <source>Back to operator</source>
        <translation>Zurück zum Bediener</translation>
    </message>
    <message>
        <source>Re&amp;cipe</source>
        <translation>Prüf&amp;plan</translation>
    </message>
    <message>
        <source>Choose recipe…</source>
        <translation>Prüfplan wählen…</translation>
    </message>
    <message>
        <source>Edit recipe…</source>
        <translation>Prüfplan bearbeiten…</translation>
    </message>
    <message>
        <source>&amp;View</source>
        <translation>&amp;Ansicht</translation>
    </message>
    <message>
        <source>Reset 3D view</source>
        <translation>3D-Ansicht zurücksetzen</translation>
    </message>
    <message>
        <source>plugin {name} disabled: its panel raised {error}</source>
        <translation>Plugin {name} deaktiviert: sein Bereich meldete {error}</translation>
    </message>
    <message>
        <source>plugin {name} disabled: its panel must be (title, QWidget), got {type}</source>
        <translation>Plugin {name} deaktiviert: sein Bereich muss (Titel, QWidget) sein, erhalten: {type}</translation>
    </message>
    <message>
        <source>warning: {text}</source>
        <translation>Warnung: {text}</translation>
    </message>
    <message>
        <source>recipe {name}: INVALID: {error}</source>
        <translation>Prüfplan {name}: UNGÜLTIG: {error}</translation>
    </message>
    <message>
        <source>capture {path}</source>
        <translation>Aufnahme {path}</translation>
    </message>
    <message>
        <source>watch {path}</source>
        <translation>überwacht {path}</translation>
    </message>
    <message>
        <source>driver {name}</source>
        <translation>Treiber {name}</translation>
    </message>
    <message>
        <source>recipe {name} ({file}, sha256 {sha}) · {source} · results in {out}</source>
        <translation>Prüfplan {name} ({file}, sha256 {sha}) · {source} · Ergebnisse in {out}</translation>
    </message>
    <message>
        <source>this recipe may not run in the operator role</source>
        <translation>dieser Prüfplan darf in der Rolle Bediener nicht laufen</translation>
    </message>
    <message>
        <source>LIVE stopping after the part in progress…</source>
        <translation>Dauerbetrieb endet nach dem laufenden Teil…</translation>
    </message>
    <message>
        <source>cancelling before the next stage…</source>
        <translation>Abbruch vor dem nächsten Schritt…</translation>
    </message>
    <message>
        <source>{capture}: {step} done ({seconds} s)</source>
        <translation>{capture}: {step} fertig ({seconds} s)</translation>
    </message>
    <message>
        <source>the run could not go on</source>
        <translation>der Lauf konnte nicht fortgesetzt werden</translation>
    </message>
    <message>
        <source>error: {message}</source>
        <translation>Fehler: {message}</translation>
    </message>
    <message>
        <source>no capture arrived</source>
        <translation>keine Aufnahme eingetroffen</translation>
    </message>
    <message>
        <source>nothing to inspect</source>
        <translation>nichts zu prüfen</translation>
    </message>
    <message>
        <source>nothing was inspected</source>
        <translation>es wurde nichts geprüft</translation>
    </message>
    <message>
        <source>{capture}: {verdict} in {seconds} s</source>
        <translation>{capture}: {verdict} in {seconds} s</translation>
    </message>
    <message>
        <source>defect {n}: missing material {worst} mm, seen by {cameras}</source>
        <translation>Fehlstelle {n}: fehlendes Material {worst} mm, gesehen von {cameras}</translation>
    </message>
    <message>
        <source>defect {n}: excess material {worst} mm, seen by {cameras}</source>
        <translation>Fehlstelle {n}: überschüssiges Material {worst} mm, gesehen von {cameras}</translation>
    </message>
    <message>
        <source>no camera</source>
        <translation>keiner Kamera</translation>
    </message>
    <message>
        <source>Open capture folder</source>
        <translation>Aufnahmeordner öffnen</translation>
    </message>
    <message>
        <source>Open result folder</source>
        <translation>Ergebnisordner öffnen</translation>
    </message>
    <message>
        <source>cannot open {folder}</source>
        <translation>{folder} kann nicht geöffnet werden</translation>
    </message>
    <message>
        <source>no written result to export</source>
        <translation>kein geschriebenes Ergebnis zum Exportieren</translation>
    </message>
    <message>
        <source>export failed: {error}</source>
        <translation>Export fehlgeschlagen: {error}</translation>
    </message>
    <message>
        <source>report written: {path}</source>
        <translation>Bericht geschrieben: {path}</translation>
    </message>
    <message>
        <source>Engineer login</source>
        <translation>Anmeldung Einrichter</translation>
    </message>
    <message>
        <source>Wrong password, or no engineer password is set (`inspector roles set-password`).</source>
        <translation>Falsches Passwort, oder es ist kein Einrichter-Passwort gesetzt (`inspector roles set-password`).</translation>
    </message>
    <message>
        <source>engineer idle: back to operator</source>
        <translation>Einrichter inaktiv: zurück zum Bediener</translation>
    </message>
    <message>
        <source>ENGINEER {user}  (operator in {time})</source>
        <translation>EINRICHTER {user}  (Bediener in {time})</translation>
    </message>
    <message>
        <source>OPERATOR</source>
        <translation>BEDIENER</translation>
    </message>
    <message>
        <source>Choose recipe</source>
        <translation>Prüfplan wählen</translation>
    </message>
    <message>
        <source>Recipes (*.toml)</source>
        <translation>Prüfpläne (*.toml)</translation>
    </message>
    <message>
        <source>the recipe editor needs engineer mode (Ctrl+L)</source>
        <translation>der Prüfplan-Editor erfordert den Einrichter-Modus (Strg+L)</translation>
    </message>
    <message>
        <source>cannot edit: {error}</source>
        <translation>Bearbeiten nicht möglich: {error}</translation>
    </message>
    <message>
        <source>the kiosk stays open: closing needs engineer mode (Ctrl+L)</source>
        <translation>der Kiosk bleibt offen: Schließen erfordert den Einrichter-Modus (Strg+L)</translation>
    </message>
</context>
<context>
    <name>RecipeEditor</name>
    <message>
        <source>Recipe editor: {name} ({file})</source>
        <translation>Prüfplan-Editor: {name} ({file})</translation>
    </message>
    <message>
        <source>type {type}; default {default}</source>
        <translation>Typ {type}; Vorgabe {default}</translation>
    </message>
    <message>
        <source>; min {min}</source>
        <translation>; Min. {min}</translation>
    </message>
    <message>
        <source>; max {max}</source>
        <translation>; Max. {max}</translation>
    </message>
    <message>
        <source>Values marked ● are set by the recipe; the others are defaults.</source>
        <translation>Mit ● markierte Werte setzt der Prüfplan; die anderen sind Vorgaben.</translation>
    </message>
    <message>
        <source>Check</source>
        <translation>Prüfen</translation>
    </message>
    <message>
        <source>Save as new recipe</source>
        <translation>Als neuen Prüfplan speichern</translation>
    </message>
    <message>
        <source>Cancel</source>
        <translation>Abbrechen</translation>
    </message>
    <message>
        <source>New recipe name</source>
        <translation>Name des neuen Prüfplans</translation>
    </message>
    <message>
        <source>{key}: cannot read {error}</source>
        <translation>{key}: nicht lesbar {error}</translation>
    </message>
    <message>
        <source>Valid: `inspector recipe check` accepts it.</source>
        <translation>Gültig: `inspector recipe check` akzeptiert ihn.</translation>
    </message>
</context>
<context>
    <name>ResultTabs</name>
    <message>
        <source>Defects ({n})</source>
        <translation>Fehlstellen ({n})</translation>
    </message>
    <message>
        <source>Characteristics ({n}, {nok} NOK)</source>
        <translation>Merkmale ({n}, {nok} NIO)</translation>
    </message>
    <message>
        <source>Characteristics ({n})</source>
        <translation>Merkmale ({n})</translation>
    </message>
</context>
<context>
    <name>Shift</name>
    <message>
        <source>early</source>
        <extracomment>The default shift names (:class:`inspector.shift.ShiftSettings`), marked for translation: a cell&apos;s own names are shown as they are.</extracomment>
        <translation>Frühschicht</translation>
    </message>
    <message>
        <source>late</source>
        <translation>Spätschicht</translation>
    </message>
    <message>
        <source>night</source>
        <translation>Nachtschicht</translation>
    </message>
    <message>
        <source>no reason recorded</source>
        <extracomment>The history database in a run&apos;s OUTDIR (the ``history`` plugin&apos;s :data:`HISTORY_FILE`; the name is repeated here so that the core does not import a plugin).</extracomment>
        <translation>kein Grund erfasst</translation>
    </message>
    <message>
        <source>shift {name} {start} to {end}</source>
        <translation>Schicht {name} {start} bis {end}</translation>
    </message>
    <message>
        <source>{n} inspected: {p} pass, {f} fail, {e} error; yield {y}</source>
        <translation>{n} geprüft: {p} IO, {f} NIO, {e} Störungen; Ausbeute {y}</translation>
    </message>
    <message>
        <source>worst regions (parts with a defect there, defects, worst mm):</source>
        <translation>schlechteste Bereiche (Teile mit Fehlstelle dort, Fehlstellen, max. mm):</translation>
    </message>
    <message>
        <source>worst characteristics (parts, NOK, not measurable, most of the tolerance used):</source>
        <translation>schlechteste Merkmale (Teile, NIO, nicht messbar, größter Anteil der Toleranz):</translation>
    </message>
    <message>
        <source>errors by reason:</source>
        <translation>Störungen nach Grund:</translation>
    </message>
</context>
<context>
    <name>ShiftPanel</name>
    <message>
        <source>Shift</source>
        <translation>Schicht</translation>
    </message>
    <message>
        <source>no inspection in this shift yet</source>
        <translation>noch keine Prüfung in dieser Schicht</translation>
    </message>
    <message>
        <source>{name} shift, {date} {start} to {end}</source>
        <translation>{name}, {date} {start} bis {end}</translation>
    </message>
    <message>
        <source>yield {share}: {n} inspected · pass {p} · fail {f} · error {e}</source>
        <translation>Ausbeute {share}: {n} geprüft · IO {p} · NIO {f} · Störungen {e}</translation>
    </message>
    <message>
        <source>{region} {parts}× ({worst} mm)</source>
        <translation>{region} {parts}× ({worst} mm)</translation>
    </message>
    <message>
        <source>worst regions: {list}</source>
        <translation>schlechteste Bereiche: {list}</translation>
    </message>
    <message>
        <source>no defect in this shift</source>
        <translation>keine Fehlstelle in dieser Schicht</translation>
    </message>
    <message>
        <source>errors: {list}</source>
        <translation>Störungen: {list}</translation>
    </message>
    <message>
        <source>no error in this shift</source>
        <translation>keine Störung in dieser Schicht</translation>
    </message>
    <message>
        <source>{id} {n}× NOK</source>
        <translation>{id} {n}× NIO</translation>
    </message>
    <message>
        <source>{id} {n}× not measurable</source>
        <translation>{id} {n}× nicht messbar</translation>
    </message>
    <message>
        <source>{id} at most {share} of the tolerance</source>
        <translation>{id} höchstens {share} der Toleranz</translation>
    </message>
    <message>
        <source>worst characteristics: {list}</source>
        <translation>schlechteste Merkmale: {list}</translation>
    </message>
</context>
<context>
    <name>TrendChart</name>
    <message>
        <source>characteristic trend</source>
        <translation>Merkmalsverlauf</translation>
    </message>
    <message>
        <source>green: tolerance · dashed: control limits · ring: this part</source>
        <translation>grün: Toleranz · gestrichelt: Eingriffsgrenzen · Ring: dieses Teil</translation>
    </message>
    <message>
        <source>select a characteristic to see its trend</source>
        <translation>Merkmal wählen, um seinen Verlauf zu sehen</translation>
    </message>
    <message>
        <source>no recorded value yet</source>
        <translation>noch kein Wert aufgezeichnet</translation>
    </message>
</context>
<context>
    <name>Verdict</name>
    <message>
        <source>PASS</source>
        <extracomment>Keys of :attr:`ResultView.prepared` filled by :func:`~inspector_frontends.gui.prepare.prepare_view`. Verdict -&gt; (word, icon glyph, background). The word and the glyph say it without colour. The words are English sources: :func:`verdict_word` gives them in the GUI&apos;s language.</extracomment>
        <translation>IO</translation>
    </message>
    <message>
        <source>FAIL</source>
        <translation>NIO</translation>
    </message>
    <message>
        <source>ERROR</source>
        <translation>STÖRUNG</translation>
    </message>
    <message>
        <source>ABORTED</source>
        <translation>ABGEBROCHEN</translation>
    </message>
    <message>
        <source>INSPECTING</source>
        <translation>PRÜFUNG LÄUFT</translation>
    </message>
    <message>
        <source>READY</source>
        <translation>BEREIT</translation>
    </message>
    <message>
        <source>RECIPE INVALID</source>
        <translation>PRÜFPLAN UNGÜLTIG</translation>
    </message>
</context>
<context>
    <name>VerdictBanner</name>
    <message>
        <source>Press INSPECT (Space) to inspect the next part.</source>
        <translation>PRÜFEN (Leertaste) drücken, um das nächste Teil zu prüfen.</translation>
    </message>
    <message>
        <source>verdict {word}</source>
        <translation>Ergebnis {word}</translation>
    </message>
    <message>
        <source>part {id}</source>
        <translation>Teil {id}</translation>
    </message>
    <message>
        <source>capture {name}</source>
        <translation>Aufnahme {name}</translation>
    </message>
    <message>
        <source>cycle {s} s</source>
        <translation>Takt {s} s</translation>
    </message>
    <message>
        <source>deviation {lo} to {hi} mm (limits {lower} / {upper})</source>
        <translation>Abweichung {lo} bis {hi} mm (Grenzen {lower} / {upper})</translation>
    </message>
</context>
<context>
    <name>ViewModel</name>
    <message>
        <source>calibration: disagrees with the other cameras by {off} px (threshold {limit} px): check its mounting or recalibrate</source>
        <extracomment>The colour scale spans this many tolerance widths on each side. Key of :attr:`ResultView.prepared` holding the deviations in units of their limit. Thumbnails are at most this many pixels on their longer side. A camera is flagged when the share of its contour rays without a consistent BCPS point exceeds the cameras&apos; median share by this much (its silhouette disagrees with the others).</extracomment>
        <translation>Kalibrierung: weicht um {off} px von den anderen Kameras ab (Schwelle {limit} px): Befestigung prüfen oder neu kalibrieren</translation>
    </message>
    <message>
        <source>calibration: disagrees with the other cameras (threshold {limit} px): check its mounting or recalibrate</source>
        <translation>Kalibrierung: weicht von den anderen Kameras ab (Schwelle {limit} px): Befestigung prüfen oder neu kalibrieren</translation>
    </message>
    <message>
        <source> (+{n} NOK characteristics)</source>
        <translation> (+{n} NIO-Merkmale)</translation>
    </message>
    <message>
        <source>characteristic {id} ({label}): {value} {unit}, deviation {dev}, limits {lower} / {upper}</source>
        <translation>Merkmal {id} ({label}): {value} {unit}, Abweichung {dev}, Grenzen {lower} / {upper}</translation>
    </message>
    <message>
        <source> (+{n} more NOK)</source>
        <translation> (+{n} weitere NIO)</translation>
    </message>
    <message>
        <source>missing material in region &apos;{region}&apos;: {worst} mm, limit {limit} mm</source>
        <translation>fehlendes Material im Bereich &apos;{region}&apos;: {worst} mm, Grenze {limit} mm</translation>
    </message>
    <message>
        <source>excess material in region &apos;{region}&apos;: {worst} mm, limit {limit} mm</source>
        <translation>überschüssiges Material im Bereich &apos;{region}&apos;: {worst} mm, Grenze {limit} mm</translation>
    </message>
    <message>
        <source> (+1 more defect)</source>
        <translation> (+1 weitere Fehlstelle)</translation>
    </message>
    <message>
        <source> (+{n} more defects)</source>
        <translation> (+{n} weitere Fehlstellen)</translation>
    </message>
    <message>
        <source>silhouette touches the image border</source>
        <translation>Silhouette berührt den Bildrand</translation>
    </message>
    <message>
        <source>silhouette disagrees with the others: {share} % of its contour rays inconsistent (median {median} %)</source>
        <translation>Silhouette weicht von den anderen ab: {share} % ihrer Konturstrahlen widersprüchlich (Median {median} %)</translation>
    </message>
</context>
<context>
    <name>Widgets</name>
    <message>
        <source>yield {share}</source>
        <extracomment>History rows the strip reads (chips show the last ``HistoryStrip.CHIPS`` of them). matplotlib&apos;s figures are not meant to be drawn by two threads at once. The figure :func:`history_chart` draws on (under the lock), and its size.</extracomment>
        <translation>Ausbeute {share}</translation>
    </message>
    <message>
        <source>no part judged</source>
        <translation>kein Teil bewertet</translation>
    </message>
    <message>
        <source>{n} inspections · pass {p} · fail {f} · error {e} · {yld}</source>
        <translation>{n} Prüfungen · IO {p} · NIO {f} · Störungen {e} · {yld}</translation>
    </message>
    <message>
        <source>tolerance</source>
        <translation>Toleranz</translation>
    </message>
</context>
<context>
    <name>_Chips</name>
    <message>
        <source>history: last parts</source>
        <translation>Verlauf: letzte Teile</translation>
    </message>
    <message>
        <source>{capture}: {word}, worst {worst} mm</source>
        <translation>{capture}: {word}, max. {worst} mm</translation>
    </message>
</context>
</TS>
