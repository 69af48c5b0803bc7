<?xml version="1.0" encoding="utf-8"?>
<!DOCTYPE TS>
<TS version="2.1" language="es_ES" sourcelanguage="en_US">
<context>
    <name>CameraDialog</name>
    <message>
        <source>Camera {name}</source>
        <translation>Cámara {name}</translation>
    </message>
    <message>
        <source>silhouette consistent with the other cameras</source>
        <translation>silueta coherente con las demás cámaras</translation>
    </message>
    <message>
        <source>Fit (0)</source>
        <translation>Ajustar (0)</translation>
    </message>
    <message>
        <source>Close (Esc)</source>
        <translation>Cerrar (Esc)</translation>
    </message>
</context>
<context>
    <name>CameraStrip</name>
    <message>
        <source>Camera images appear here after an inspection.</source>
        <translation>Las imágenes de las cámaras aparecen aquí tras una inspección.</translation>
    </message>
    <message>
        <source>No camera images: this result was opened from its folder.</source>
        <translation>Sin imágenes de cámara: este resultado se abrió desde su carpeta.</translation>
    </message>
</context>
<context>
    <name>CameraTile</name>
    <message>
        <source>(double-click or Enter: open large)</source>
        <translation>(doble clic o Intro: abrir en grande)</translation>
    </message>
    <message>
        <source>camera {name} flagged</source>
        <translation>cámara {name} señalada</translation>
    </message>
    <message>
        <source>camera {name}</source>
        <translation>cámara {name}</translation>
    </message>
</context>
<context>
    <name>CharacteristicsPanel</name>
    <message>
        <source>{id} {label}: last {n} parts</source>
        <translation>{id} {label}: últimas {n} piezas</translation>
    </message>
</context>
<context>
    <name>CharacteristicsTable</name>
    <message>
        <source>OK</source>
        <extracomment>Verdict of a characteristic -&gt; (word, glyph, colour); the word and glyph say it without colour.</extracomment>
        <translation>OK</translation>
    </message>
    <message>
        <source>NOK</source>
        <translation>NOK</translation>
    </message>
    <message>
        <source>not measurable</source>
        <translation>no medible</translation>
    </message>
    <message>
        <source>characteristic</source>
        <extracomment>Column of the deviation bar.</extracomment>
        <translation>característica</translation>
    </message>
    <message>
        <source>measured</source>
        <translation>medido</translation>
    </message>
    <message>
        <source>nominal</source>
        <translation>nominal</translation>
    </message>
    <message>
        <source>deviation</source>
        <translation>desviación</translation>
    </message>
    <message>
        <source>U (k=2)</source>
        <translation>U (k=2)</translation>
    </message>
    <message>
        <source>verdict</source>
        <translation>veredicto</translation>
    </message>
    <message>
        <source>characteristics table</source>
        <translation>tabla de características</translation>
    </message>
</context>
<context>
    <name>DefectTable</name>
    <message>
        <source>kind</source>
        <translation>tipo</translation>
    </message>
    <message>
        <source>region</source>
        <translation>zona</translation>
    </message>
    <message>
        <source>points</source>
        <translation>puntos</translation>
    </message>
    <message>
        <source>worst mm</source>
        <translation>peor mm</translation>
    </message>
    <message>
        <source>extent mm</source>
        <translation>extensión mm</translation>
    </message>
    <message>
        <source>cameras</source>
        <translation>cámaras</translation>
    </message>
    <message>
        <source>defect table</source>
        <translation>tabla de defectos</translation>
    </message>
    <message>
        <source>missing material</source>
        <translation>falta material</translation>
    </message>
    <message>
        <source>excess material</source>
        <translation>exceso de material</translation>
    </message>
</context>
<context>
    <name>DeviationView</name>
    <message>
        <source>deviation</source>
        <extracomment>Points are drawn as flat squares of this many pixels. Names of the actors a defect selection adds (removed when a new result is shown).</extracomment>
        <translation>desviación</translation>
    </message>
    <message>
        <source>{verdict}  {capture}  ({n} points)</source>
        <translation>{verdict}  {capture}  ({n} puntos)</translation>
    </message>
</context>
<context>
    <name>HistoryStrip</name>
    <message>
        <source>no inspection yet</source>
        <translation>aún ninguna inspección</translation>
    </message>
    <message>
        <source>last {n}: yield {share} · pass {p} · fail {f} · error {e}</source>
        <translation>últimas {n}: rendimiento {share} · conformes {p} · rechazadas {f} · errores {e}</translation>
    </message>
    <message>
        <source>error {e}</source>
        <translation>errores {e}</translation>
    </message>
    <message>
        <source>no part judged yet</source>
        <translation>aún ninguna pieza evaluada</translation>
    </message>
</context>
<context>
    <name>LoginDialog</name>
    <message>
        <source>Engineer login</source>
        <extracomment>The widget that edits one parameter (see :meth:`RecipeEditor._editor`).</extracomment>
        <translation>Acceso de ingeniero</translation>
    </message>
    <message>
        <source>Name</source>
        <translation>Nombre</translation>
    </message>
    <message>
        <source>Password</source>
        <translation>Contraseña</translation>
    </message>
</context>
<context>
    <name>MainWindow</name>
    <message>
        <source>Inspector: operator</source>
        <translation>Inspector: operario</translation>
    </message>
    <message>
        <source>INSPECT</source>
        <translation>INSPECCIONAR</translation>
    </message>
    <message>
        <source>Inspect the next part (Space or F5)</source>
        <translation>Inspeccionar la siguiente pieza (Espacio o F5)</translation>
    </message>
    <message>
        <source>LIVE</source>
        <translation>CONTINUO</translation>
    </message>
    <message>
        <source>Inspect continuously until stopped (F6)</source>
        <translation>Inspeccionar sin parar hasta detener (F6)</translation>
    </message>
    <message>
        <source>CANCEL</source>
        <translation>CANCELAR</translation>
    </message>
    <message>
        <source>Abort the inspection in progress (Esc)</source>
        <translation>Interrumpir la inspección en curso (Esc)</translation>
    </message>
    <message>
        <source>&amp;File</source>
        <translation>&amp;Archivo</translation>
    </message>
    <message>
        <source>Open capture folder…</source>
        <translation>Abrir carpeta de captura…</translation>
    </message>
    <message>
        <source>Open result folder…</source>
        <translation>Abrir carpeta de resultado…</translation>
    </message>
    <message>
        <source>Export report (PDF)</source>
        <translation>Exportar informe (PDF)</translation>
    </message>
    <message>
        <source>Quit</source>
        <translation>Salir</translation>
    </message>
    <message>
        <source>&amp;Role</source>
        <translation>&amp;Rol</translation>
    </message>
    <message>
        <source>Engineer login…</source>
        <translation>Acceso de ingeniero…</translation>
    </message>
    <message>
        <source>Back to operator</source>
        <translation>Volver a operario</translation>
    </message>
    <message>
        <source>Re&amp;cipe</source>
        <translation>Re&amp;ceta</translation>
    </message>
    <message>
        <source>Choose recipe…</source>
        <translation>Elegir receta…</translation>
    </message>
    <message>
        <source>Edit recipe…</source>
        <translation>Editar receta…</translation>
    </message>
    <message>
        <source>&amp;View</source>
        <translation>&amp;Ver</translation>
    </message>
    <message>
        <source>Reset 3D view</source>
        <translation>Restablecer vista 3D</translation>
    </message>
    <message>
        <source>plugin {name} disabled: its panel raised {error}</source>
        <translation>complemento {name} desactivado: su panel produjo {error}</translation>
    </message>
    <message>
        <source>plugin {name} disabled: its panel must be (title, QWidget), got {type}</source>
        <translation>complemento {name} desactivado: su panel debe ser (título, QWidget), se recibió {type}</translation>
    </message>
    <message>
        <source>warning: {text}</source>
        <translation>aviso: {text}</translation>
    </message>
    <message>
        <source>recipe {name}: INVALID: {error}</source>
        <translation>receta {name}: NO VÁLIDA: {error}</translation>
    </message>
    <message>
        <source>capture {path}</source>
        <translation>captura {path}</translation>
    </message>
    <message>
        <source>watch {path}</source>
        <translation>vigila {path}</translation>
    </message>
    <message>
        <source>driver {name}</source>
        <translation>controlador {name}</translation>
    </message>
    <message>
        <source>recipe {name} ({file}, sha256 {sha}) · {source} · results in {out}</source>
        <translation>receta {name} ({file}, sha256 {sha}) · {source} · resultados en {out}</translation>
    </message>
    <message>
        <source>this recipe may not run in the operator role</source>
        <translation>esta receta no puede ejecutarse en el rol de operador</translation>
    </message>
    <message>
        <source>LIVE stopping after the part in progress…</source>
        <translation>el modo continuo se detiene tras la pieza en curso…</translation>
    </message>
    <message>
        <source>cancelling before the next stage…</source>
        <translation>cancelando antes de la siguiente etapa…</translation>
    </message>
    <message>
        <source>{capture}: {step} done ({seconds} s)</source>
        <translation>{capture}: {step} terminado ({seconds} s)</translation>
    </message>
    <message>
        <source>the run could not go on</source>
        <translation>la ejecución no pudo continuar</translation>
    </message>
    <message>
        <source>error: {message}</source>
        <translation>error: {message}</translation>
    </message>
    <message>
        <source>no capture arrived</source>
        <translation>no llegó ninguna captura</translation>
    </message>
    <message>
        <source>nothing to inspect</source>
        <translation>nada que inspeccionar</translation>
    </message>
    <message>
        <source>nothing was inspected</source>
        <translation>no se inspeccionó nada</translation>
    </message>
    <message>
        <source>{capture}: {verdict} in {seconds} s</source>
        <translation>{capture}: {verdict} en {seconds} s</translation>
    </message>
    <message>
        <source>defect {n}: missing material {worst} mm, seen by {cameras}</source>
        <translation>defecto {n}: falta material {worst} mm, visto por {cameras}</translation>
    </message>
    <message>
        <source>defect {n}: excess material {worst} mm, seen by {cameras}</source>
        <translation>defecto {n}: exceso de material {worst} mm, visto por {cameras}</translation>
    </message>
    <message>
        <source>no camera</source>
        <translation>ninguna cámara</translation>
    </message>
    <message>
        <source>Open capture folder</source>
        <translation>Abrir carpeta de captura</translation>
    </message>
    <message>
        <source>Open result folder</source>
        <translation>Abrir carpeta de resultado</translation>
    </message>
    <message>
        <source>cannot open {folder}</source>
        <translation>no se puede abrir {folder}</translation>
    </message>
    <message>
        <source>no written result to export</source>
        <translation>ningún resultado escrito que exportar</translation>
    </message>
    <message>
        <source>export failed: {error}</source>
        <translation>la exportación falló: {error}</translation>
    </message>
    <message>
        <source>report written: {path}</source>
        <translation>informe escrito: {path}</translation>
    </message>
    <message>
        <source>Engineer login</source>
        <translation>Acceso de ingeniero</translation>
    </message>
    <message>
        <source>Wrong password, or no engineer password is set (`inspector roles set-password`).</source>
        <translation>Contraseña incorrecta, o no hay contraseña de ingeniero (`inspector roles set-password`).</translation>
    </message>
    <message>
        <source>engineer idle: back to operator</source>
        <translation>ingeniero inactivo: vuelta a operario</translation>
    </message>
    <message>
        <source>ENGINEER {user}  (operator in {time})</source>
        <translation>INGENIERO {user}  (operario en {time})</translation>
    </message>
    <message>
        <source>OPERATOR</source>
        <translation>OPERARIO</translation>
    </message>
    <message>
        <source>Choose recipe</source>
        <translation>Elegir receta</translation>
    </message>
    <message>
        <source>Recipes (*.toml)</source>
        <translation>Recetas (*.toml)</translation>
    </message>
    <message>
        <source>the recipe editor needs engineer mode (Ctrl+L)</source>
        <translation>el editor de recetas requiere el modo ingeniero (Ctrl+L)</translation>
    </message>
    <message>
        <source>cannot edit: {error}</source>
        <translation>no se puede editar: {error}</translation>
    </message>
    <message>
        <source>the kiosk stays open: closing needs engineer mode (Ctrl+L)</source>
        <translation>el quiosco sigue abierto: cerrar requiere el modo ingeniero (Ctrl+L)</translation>
    </message>
</context>
<context>
    <name>RecipeEditor</name>
    <message>
        <source>Recipe editor: {name} ({file})</source>
        <translation>Editor de recetas: {name} ({file})</translation>
    </message>
    <message>
        <source>type {type}; default {default}</source>
        <translation>tipo {type}; por defecto {default}</translation>
    </message>
    <message>
        <source>; min {min}</source>
        <translation>; mín. {min}</translation>
    </message>
    <message>
        <source>; max {max}</source>
        <translation>; máx. {max}</translation>
    </message>
    <message>
        <source>Values marked ● are set by the recipe; the others are defaults.</source>
        <translation>Los valores marcados con ● los fija la receta; los demás son los valores por defecto.</translation>
    </message>
    <message>
        <source>Check</source>
        <translation>Comprobar</translation>
    </message>
    <message>
        <source>Save as new recipe</source>
        <translation>Guardar como receta nueva</translation>
    </message>
    <message>
        <source>Cancel</source>
        <translation>Cancelar</translation>
    </message>
    <message>
        <source>New recipe name</source>
        <translation>Nombre de la receta nueva</translation>
    </message>
    <message>
        <source>{key}: cannot read {error}</source>
        <translation>{key}: no se puede leer {error}</translation>
    </message>
    <message>
        <source>Valid: `inspector recipe check` accepts it.</source>
        <translation>Válida: `inspector recipe check` la acepta.</translation>
    </message>
</context>
<context>
    <name>ResultTabs</name>
    <message>
        <source>Defects ({n})</source>
        <translation>Defectos ({n})</translation>
    </message>
    <message>
        <source>Characteristics ({n}, {nok} NOK)</source>
        <translation>Características ({n}, {nok} NOK)</translation>
    </message>
    <message>
        <source>Characteristics ({n})</source>
        <translation>Características ({n})</translation>
    </message>
</context>
<context>
    <name>Shift</name>
    <message>
        <source>early</source>
        <extracomment>The default shift names (:class:`inspector.shift.ShiftSettings`), marked for translation: a cell&apos;s own names are shown as they are.</extracomment>
        <translation>mañana</translation>
    </message>
    <message>
        <source>late</source>
        <translation>tarde</translation>
    </message>
    <message>
        <source>night</source>
        <translation>noche</translation>
    </message>
    <message>
        <source>no reason recorded</source>
        <extracomment>The history database in a run&apos;s OUTDIR (the ``history`` plugin&apos;s :data:`HISTORY_FILE`; the name is repeated here so that the core does not import a plugin).</extracomment>
        <translation>sin motivo registrado</translation>
    </message>
    <message>
        <source>shift {name} {start} to {end}</source>
        <translation>turno {name} {start} a {end}</translation>
    </message>
    <message>
        <source>{n} inspected: {p} pass, {f} fail, {e} error; yield {y}</source>
        <translation>{n} inspeccionadas: {p} conformes, {f} rechazadas, {e} errores; rendimiento {y}</translation>
    </message>
    <message>
        <source>worst regions (parts with a defect there, defects, worst mm):</source>
        <translation>peores zonas (piezas con un defecto allí, defectos, peor mm):</translation>
    </message>
    <message>
        <source>worst characteristics (parts, NOK, not measurable, most of the tolerance used):</source>
        <translation>peores características (piezas, NOK, no medibles, mayor parte de la tolerancia usada):</translation>
    </message>
    <message>
        <source>errors by reason:</source>
        <translation>errores por motivo:</translation>
    </message>
</context>
<context>
    <name>ShiftPanel</name>
    <message>
        <source>Shift</source>
        <translation>Turno</translation>
    </message>
    <message>
        <source>no inspection in this shift yet</source>
        <translation>aún ninguna inspección en este turno</translation>
    </message>
    <message>
        <source>{name} shift, {date} {start} to {end}</source>
        <translation>Turno de {name}, {date} {start} a {end}</translation>
    </message>
    <message>
        <source>yield {share}: {n} inspected · pass {p} · fail {f} · error {e}</source>
        <translation>rendimiento {share}: {n} inspeccionadas · conformes {p} · rechazadas {f} · errores {e}</translation>
    </message>
    <message>
        <source>{region} {parts}× ({worst} mm)</source>
        <translation>{region} {parts}× ({worst} mm)</translation>
    </message>
    <message>
        <source>worst regions: {list}</source>
        <translation>peores zonas: {list}</translation>
    </message>
    <message>
        <source>no defect in this shift</source>
        <translation>ningún defecto en este turno</translation>
    </message>
    <message>
        <source>errors: {list}</source>
        <translation>errores: {list}</translation>
    </message>
    <message>
        <source>no error in this shift</source>
        <translation>ningún error en este turno</translation>
    </message>
    <message>
        <source>{id} {n}× NOK</source>
        <translation>{id} {n}× NOK</translation>
    </message>
    <message>
        <source>{id} {n}× not measurable</source>
        <translation>{id} {n}× no medible</translation>
    </message>
    <message>
        <source>{id} at most {share} of the tolerance</source>
        <translation>{id} como máximo {share} de la tolerancia</translation>
    </message>
    <message>
        <source>worst characteristics: {list}</source>
        <translation>peores características: {list}</translation>
    </message>
</context>
<context>
    <name>TrendChart</name>
    <message>
        <source>characteristic trend</source>
        <translation>tendencia de la característica</translation>
    </message>
    <message>
        <source>green: tolerance · dashed: control limits · ring: this part</source>
        <translation>verde: tolerancia · discontinuo: límites de control · anillo: esta pieza</translation>
    </message>
    <message>
        <source>select a characteristic to see its trend</source>
        <translation>seleccione una característica para ver su tendencia</translation>
    </message>
    <message>
        <source>no recorded value yet</source>
        <translation>aún no hay valores registrados</translation>
    </message>
</context>
<context>
    <name>Verdict</name>
    <message>
        <source>PASS</source>
        <extracomment>Keys of :attr:`ResultView.prepared` filled by :func:`~inspector_frontends.gui.prepare.prepare_view`. Verdict -&gt; (word, icon glyph, background). The word and the glyph say it without colour. The words are English sources: :func:`verdict_word` gives them in the GUI&apos;s language.</extracomment>
        <translation>CONFORME</translation>
    </message>
    <message>
        <source>FAIL</source>
        <translation>RECHAZADA</translation>
    </message>
    <message>
        <source>ERROR</source>
        <translation>ERROR</translation>
    </message>
    <message>
        <source>ABORTED</source>
        <translation>INTERRUMPIDA</translation>
    </message>
    <message>
        <source>INSPECTING</source>
        <translation>INSPECCIONANDO</translation>
    </message>
    <message>
        <source>READY</source>
        <translation>LISTO</translation>
    </message>
    <message>
        <source>RECIPE INVALID</source>
        <translation>RECETA NO VÁLIDA</translation>
    </message>
</context>
<context>
    <name>VerdictBanner</name>
    <message>
        <source>Press INSPECT (Space) to inspect the next part.</source>
        <translation>Pulse INSPECCIONAR (Espacio) para inspeccionar la siguiente pieza.</translation>
    </message>
    <message>
        <source>verdict {word}</source>
        <translation>veredicto {word}</translation>
    </message>
    <message>
        <source>part {id}</source>
        <translation>pieza {id}</translation>
    </message>
    <message>
        <source>capture {name}</source>
        <translation>captura {name}</translation>
    </message>
    <message>
        <source>cycle {s} s</source>
        <translation>ciclo {s} s</translation>
    </message>
    <message>
        <source>deviation {lo} to {hi} mm (limits {lower} / {upper})</source>
        <translation>desviación {lo} a {hi} mm (límites {lower} / {upper})</translation>
    </message>
</context>
<context>
    <name>ViewModel</name>
    <message>
        <source>calibration: disagrees with the other cameras by {off} px (threshold {limit} px): check its mounting or recalibrate</source>
        <extracomment>The colour scale spans this many tolerance widths on each side. Key of :attr:`ResultView.prepared` holding the deviations in units of their limit. Thumbnails are at most this many pixels on their longer side. A camera is flagged when the share of its contour rays without a consistent BCPS point exceeds the cameras&apos; median share by this much (its silhouette disagrees with the others).</extracomment>
        <translation>calibración: discrepa de las demás cámaras en {off} px (umbral {limit} px): revise su montaje o recalibre</translation>
    </message>
    <message>
        <source>calibration: disagrees with the other cameras (threshold {limit} px): check its mounting or recalibrate</source>
        <translation>calibración: discrepa de las demás cámaras (umbral {limit} px): revise su montaje o recalibre</translation>
    </message>
    <message>
        <source> (+{n} NOK characteristics)</source>
        <translation> (+{n} características NOK)</translation>
    </message>
    <message>
        <source>characteristic {id} ({label}): {value} {unit}, deviation {dev}, limits {lower} / {upper}</source>
        <translation>característica {id} ({label}): {value} {unit}, desviación {dev}, límites {lower} / {upper}</translation>
    </message>
    <message>
        <source> (+{n} more NOK)</source>
        <translation> (+{n} NOK más)</translation>
    </message>
    <message>
        <source>missing material in region &apos;{region}&apos;: {worst} mm, limit {limit} mm</source>
        <translation>falta material en la zona &apos;{region}&apos;: {worst} mm, límite {limit} mm</translation>
    </message>
    <message>
        <source>excess material in region &apos;{region}&apos;: {worst} mm, limit {limit} mm</source>
        <translation>exceso de material en la zona &apos;{region}&apos;: {worst} mm, límite {limit} mm</translation>
    </message>
    <message>
        <source> (+1 more defect)</source>
        <translation> (+1 defecto más)</translation>
    </message>
    <message>
        <source> (+{n} more defects)</source>
        <translation> (+{n} defectos más)</translation>
    </message>
    <message>
        <source>silhouette touches the image border</source>
        <translation>la silueta toca el borde de la imagen</translation>
    </message>
    <message>
        <source>silhouette disagrees with the others: {share} % of its contour rays inconsistent (median {median} %)</source>
        <translation>la silueta discrepa de las demás: {share} % de sus rayos de contorno incoherentes (mediana {median} %)</translation>
    </message>
</context>
<context>
    <name>Widgets</name>
    <message>
        <source>yield {share}</source>
        <extracomment>History rows the strip reads (chips show the last ``HistoryStrip.CHIPS`` of them). matplotlib&apos;s figures are not meant to be drawn by two threads at once. The figure :func:`history_chart` draws on (under the lock), and its size.</extracomment>
        <translation>rendimiento {share}</translation>
    </message>
    <message>
        <source>no part judged</source>
        <translation>ninguna pieza evaluada</translation>
    </message>
    <message>
        <source>{n} inspections · pass {p} · fail {f} · error {e} · {yld}</source>
        <translation>{n} inspecciones · conformes {p} · rechazadas {f} · errores {e} · {yld}</translation>
    </message>
    <message>
        <source>tolerance</source>
        <translation>tolerancia</translation>
    </message>
</context>
<context>
    <name>_Chips</name>
    <message>
        <source>history: last parts</source>
        <translation>historial: últimas piezas</translation>
    </message>
    <message>
        <source>{capture}: {word}, worst {worst} mm</source>
        <translation>{capture}: {word}, peor {worst} mm</translation>
    </message>
</context>
</TS>
