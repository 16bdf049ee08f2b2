/* nscatter web page: edit a scene, render it through POST /v1/renders, compare renders.
 *
 * The JSON text in the editor is the source of truth. The quick controls read it and
 * rewrite the parts they own; when the text is not valid JSON they are disabled rather
 * than guessing. The server is the only validator: the page sends the text exactly as
 * typed, so what the server says (RFC 9457 problem+json) is what the user sees.
 *
 * Plain ES2020, no build step, no external resources: the page is embedded in the binary
 * and must work offline. */
'use strict';

/* ------------------------------------------------------------------------------------
 * Constants
 * ---------------------------------------------------------------------------------- */

/* The layout (camera, materials, objects, lights) is kept identical to scenes/default.json:
 * tests/browser_page.mjs compares the editor's initial text with that file, so edit both
 * together. Only "render" differs: the page starts with the full solution (every component,
 * the paper's method) at one sample per pixel, as a preview: 4,000 light paths, one gathered
 * segment per 4x4 pixels and 16 single-scattering samples look the same here as the
 * server's defaults (10,000, 2x2, 100) and render about 5x faster on lavapipe. Emptying
 * those fields brings the defaults back. */
const DEFAULT_SCENE = {
  version: 1,
  camera: { position: [0, 1.6, 6], look_at: [0, -0.1, 0], up: [0, 1, 0], fov: 40, width: 256, height: 256 },
  materials: {
    floor: { type: 'diffuse', reflectance: [0.6, 0.6, 0.6] },
    clay: { type: 'diffuse', reflectance: [0.7, 0.25, 0.15] },
    wax: { type: 'medium', preset: 'candle', ior: 1.45 },
  },
  objects: [
    { shape: 'plane', point: [0, -1, 0], normal: [0, 1, 0], material: 'floor' },
    { shape: 'sphere', center: [-0.6, 0, 0], radius: 1, material: 'wax' },
    { shape: 'box', min: [1.0, -1, -0.6], max: [2.0, 0.2, 0.4], material: 'clay' },
  ],
  lights: [
    { type: 'directional', direction: [-0.4, -1, -0.6], irradiance: [2.5, 2.4, 2.2] },
    { type: 'sphere', center: [2.5, 3.5, 2.5], radius: 0.3, radiance: [20, 20, 20] },
    { type: 'environment', radiance: [0.25, 0.3, 0.4] },
  ],
  render: {
    method: 'nn', components: ['surface', 'single', 'double', 'multiple'], spp: 1, seed: 1, max_depth: 8, exposure: 0,
    vrls: 4000, gather_tile: 4, single_samples: 16,
  },
};

/* The paper's Table 1 (Ge et al. 2021): albedo and mean free path per RGB channel, g, ior.
 * Used only to show a preset's values on the sliders and to expand a preset into explicit
 * fields when the user switches to "custom"; the server resolves presets itself. */
const PRESETS = {
  bumpy_sphere: { albedo: [0.955, 0.677, 0.457], mfp: [4.55, 3.23, 2.17], g: 0.9, ior: 1.5 },
  candle: { albedo: [0.98, 0.962, 0.75], mfp: [0.65, 0.63, 0.59], g: 0.8, ior: 1.45 },
  dragon: { albedo: [0.882, 0.938, 0.98], mfp: [0.29, 0.18, 0.33], g: 0.5, ior: 1.5 },
  milk: { albedo: [0.999, 0.999, 0.999], mfp: [0.84, 0.75, 0.68], g: 0.7, ior: 1.3 },
  oil: { albedo: [0.398, 0.453, 0.032], mfp: [9.71, 11.63, 2.74], g: 0.9, ior: 1.5 },
  lucy: { albedo: [0.936, 0.939, 0.941], mfp: [0.21, 0.2, 0.19], g: 0.0, ior: 1.5 },
  cloud: { albedo: [0.909, 0.909, 0.909], mfp: [0.909, 0.909, 0.909], g: 0.0, ior: 1.0 },
};

const COMPONENT_ORDER = ['surface', 'single', 'double', 'multiple'];

/* render.method: what each one is, for the selector. Which components each can render
 * comes from GET /v1/info "methods" (this build may not have them all yet). */
const METHOD_SUMMARIES = {
  nn: 'network tables',
  table: 'Monte Carlo tables',
  vrl: 'brute-force VRLs',
  dipole: 'Jensen dipole',
  pt: 'path tracer',
};
const DEFAULT_METHOD = 'nn';

/* The scattering settings without a control of their own kind: JSON key under "render",
 * whether it is an integer, and the input's id. An empty input means the key is absent
 * (the server's default, shown as the placeholder). */
const SCATTER_NUMBERS = [
  { key: 'light_samples', id: 'light-samples', integer: true },
  { key: 'adaptive_spp', id: 'adaptive-spp', integer: false },
  { key: 'vrls', id: 'vrls', integer: true },
  { key: 'gather_tile', id: 'gather-tile', integer: true },
  { key: 'gather_levels', id: 'gather-levels', integer: true },
  { key: 'gather_tolerance', id: 'gather-tolerance', integer: false },
  { key: 'gather_camera_samples', id: 'gather-camera-samples', integer: true },
  { key: 'single_samples', id: 'single-samples', integer: true },
  { key: 'single_levels', id: 'single-levels', integer: true },
  { key: 'single_tolerance', id: 'single-tolerance', integer: false },
  { key: 'cull_solid_angle', id: 'cull-solid-angle', integer: false },
];
/* The scattering choices: a select per render key, with the server's default for a method.
 * The boundary correction is on by default where it applies (nn, table). */
const TABLE_METHODS = ['nn', 'table'];
const SCATTER_CHOICES = [
  { key: 'accumulation', id: 'accumulation', fallback: () => 'exact' },
  { key: 'tables', id: 'tables', fallback: () => 'auto' },
  { key: 'vrl_beams', id: 'vrl-beams', fallback: () => 'endless' },
  { key: 'boundary', id: 'boundary', fallback: (method) => (TABLE_METHODS.includes(method) ? 'walks' : 'off') },
];

/* X-Nscatter-Stats keys shown under the timings, in this order. */
const COUNT_ROWS = [
  { key: 'vrl_count', label: 'VRLs' },
  { key: 'vrl_paths', label: 'light paths traced' },
  { key: 'boundary_sources', label: 'boundary sources' },
  { key: 'camera_segments', label: 'camera segments in media' },
  { key: 'gather_segments', label: 'segments gathered' },
  { key: 'tiles_interpolated', label: 'tiles interpolated' },
  { key: 'single_interpolated', label: 'single scattering: pixels interpolated' },
  { key: 'corrections_interpolated', label: 'corrections interpolated' },
  { key: 'interactions', label: 'VRL–segment interactions' },
  { key: 'cells_culled', label: 'grid cells culled' },
  { key: 'cells_represented', label: 'grid cells by representative' },
  { key: 'tables_blended', label: 'tables blended from albedo nodes' },
  { key: 'adaptive_samples', label: 'camera samples added where pixels spread' },
  { key: 'table_bytes', label: 'table memory', bytes: true },
  { key: 'weights_bytes', label: 'network weights', bytes: true },
];
const MEDIUM_FIELDS = ['albedo', 'mfp', 'sigma_s', 'sigma_a', 'g', 'ior', 'scale', 'preset'];

/* The albedo and mean-free-path sliders (one per channel). An albedo slider's position is
 * t = -log10(1 - albedo), 0 (albedo 0) ... 5 (albedo 0.99999): equal slider distances are
 * equal ratios of 1 - albedo, so the travel is spent where the look changes (near 1). An
 * mfp slider's position is log10(mfp), 0.001 ... 100 scene units. "Move together" shifts
 * the other two channels by the same distance, which keeps the ratios of their
 * 1 - albedo (or of their mfp). Written values keep 3 significant digits of 1 - albedo
 * (0.962, 0.9985) and of the mfp. */
const CHANNEL_FIELDS = {
  albedo: {
    toSlider: (a) => (a >= 1 ? Infinity : -Math.log10(1 - Math.max(0, a))),
    fromSlider: (t) => (t <= 0 ? 0 : Number((1 - Number((10 ** -t).toPrecision(3))).toPrecision(12))),
    display: (a) => (a >= 1 ? '1' : a.toFixed(Math.min(6, Math.max(3, Math.ceil(-Math.log10(1 - a)) + 2)))),
  },
  mfp: {
    toSlider: (m) => Math.log10(m),
    fromSlider: (t) => Number((10 ** t).toPrecision(3)),
    display: (m) => String(Number(m.toPrecision(3))),
  },
};
const HISTORY_LIMIT = 24;
const STORAGE_KEY = 'nscatter.scene.v1';

/* ------------------------------------------------------------------------------------
 * Small helpers
 * ---------------------------------------------------------------------------------- */

const $ = (id) => document.getElementById(id);

function el(tag, props = {}, ...children) {
  const node = document.createElement(tag);
  for (const [key, value] of Object.entries(props)) {
    if (key === 'class') node.className = value;
    else if (key.startsWith('on')) node.addEventListener(key.slice(2), value);
    else if (key in node) node[key] = value;
    else node.setAttribute(key, value);
  }
  for (const child of children) node.append(child);
  return node;
}

const formatMs = (ms) => (ms >= 100 ? ms.toFixed(0) : ms >= 10 ? ms.toFixed(1) : ms.toFixed(2));
function inlineJson(value) {
  if (Array.isArray(value)) return '[' + value.map(inlineJson).join(', ') + ']';
  if (value !== null && typeof value === 'object') {
    return '{' + Object.keys(value).map((k) => JSON.stringify(k) + ': ' + inlineJson(value[k])).join(', ') + '}';
  }
  return JSON.stringify(value);
}

/* JSON as a person would write it: containers without objects inside stay on one line
 * when short ([0, 2, 6] rather than five lines), everything else is indented by two. */
function formatJson(value, indent = '') {
  const inline = inlineJson(value);
  const isContainer = value !== null && typeof value === 'object';
  const holdsObject = isContainer && Object.values(value).some((v) => v !== null && typeof v === 'object' && !Array.isArray(v));
  if (!isContainer || (!holdsObject && indent.length + inline.length <= 72)) return inline;
  const inner = indent + '  ';
  if (Array.isArray(value)) {
    if (value.length === 0) return '[]';
    return '[\n' + value.map((v) => inner + formatJson(v, inner)).join(',\n') + '\n' + indent + ']';
  }
  const keys = Object.keys(value);
  if (keys.length === 0) return '{}';
  return '{\n' + keys.map((k) => inner + JSON.stringify(k) + ': ' + formatJson(value[k], inner)).join(',\n') + '\n' + indent + '}';
}
const sceneText = (scene) => formatJson(scene) + '\n';

function storageGet() {
  try { return window.localStorage.getItem(STORAGE_KEY); } catch { return null; }
}
/* Only an edited scene is remembered: an untouched default is not pinned, so a newer
 * build's default scene shows up after an upgrade. */
function storageSet(text) {
  try {
    if (text === sceneText(DEFAULT_SCENE)) window.localStorage.removeItem(STORAGE_KEY);
    else window.localStorage.setItem(STORAGE_KEY, text);
  } catch { /* storage disabled (private mode): nothing is remembered */ }
}

/* ------------------------------------------------------------------------------------
 * JSON source positions: maps each JSON pointer (RFC 6901) to the character range of its
 * value in the text, so an error's pointer can select the offending value in the editor.
 * A small recursive-descent scanner; it gives up (returns null) on invalid JSON.
 * ---------------------------------------------------------------------------------- */

function escapePointerToken(token) {
  return String(token).replace(/~/g, '~0').replace(/\//g, '~1');
}

function locateJsonValues(text) {
  const ranges = new Map();
  let i = 0;
  const fail = () => { throw new SyntaxError('invalid JSON at ' + i); };
  const skipSpace = () => { while (i < text.length && ' \t\r\n'.includes(text[i])) i++; };

  function readString() {
    if (text[i] !== '"') fail();
    const start = i++;
    while (i < text.length && text[i] !== '"') i += text[i] === '\\' ? 2 : 1;
    if (i >= text.length) fail();
    i++;
    return JSON.parse(text.slice(start, i));
  }

  function readValue(pointer) {
    skipSpace();
    const start = i;
    const c = text[i];
    if (c === '{') {
      i++;
      skipSpace();
      if (text[i] === '}') i++;
      else {
        for (;;) {
          skipSpace();
          const key = readString();
          skipSpace();
          if (text[i++] !== ':') fail();
          readValue(pointer + '/' + escapePointerToken(key));
          skipSpace();
          if (text[i] === ',') { i++; continue; }
          if (text[i++] !== '}') fail();
          break;
        }
      }
    } else if (c === '[') {
      i++;
      skipSpace();
      if (text[i] === ']') i++;
      else {
        for (let index = 0; ; index++) {
          readValue(pointer + '/' + index);
          skipSpace();
          if (text[i] === ',') { i++; continue; }
          if (text[i++] !== ']') fail();
          break;
        }
      }
    } else if (c === '"') {
      readString();
    } else {
      const match = /^(-?\d+(\.\d+)?([eE][+-]?\d+)?|true|false|null)/.exec(text.slice(i, i + 64));
      if (!match) fail();
      i += match[0].length;
    }
    ranges.set(pointer, { start, end: i });
  }

  try {
    readValue('');
    return ranges;
  } catch {
    return null;
  }
}

/* The range for a pointer, or for its nearest existing ancestor (a missing required
 * field is reported at a pointer that is not in the text). */
function rangeForPointer(text, pointer) {
  const ranges = locateJsonValues(text);
  if (!ranges) return null;
  let p = pointer;
  for (;;) {
    if (ranges.has(p)) return ranges.get(p);
    if (p === '') return null;
    p = p.slice(0, p.lastIndexOf('/'));
  }
}

/* ------------------------------------------------------------------------------------
 * Server-Timing parsing: `name;dur=12.5;desc="text", other;dur=3` (one metric per stage).
 * ---------------------------------------------------------------------------------- */

function splitOutsideQuotes(value, separator) {
  const parts = [];
  let current = '';
  let quoted = false;
  for (let k = 0; k < value.length; k++) {
    const ch = value[k];
    if (ch === '"' && value[k - 1] !== '\\') quoted = !quoted;
    if (ch === separator && !quoted) { parts.push(current); current = ''; } else current += ch;
  }
  parts.push(current);
  return parts.map((s) => s.trim()).filter((s) => s.length > 0);
}

function parseServerTiming(header) {
  if (!header) return [];
  return splitOutsideQuotes(header, ',').map((metric) => {
    const [name, ...params] = splitOutsideQuotes(metric, ';');
    const entry = { name, dur: null, desc: '' };
    for (const param of params) {
      const eq = param.indexOf('=');
      const key = (eq < 0 ? param : param.slice(0, eq)).trim().toLowerCase();
      let value = eq < 0 ? '' : param.slice(eq + 1).trim();
      if (value.startsWith('"') && value.endsWith('"')) value = value.slice(1, -1).replace(/\\(.)/g, '$1');
      if (key === 'dur') entry.dur = Number.parseFloat(value);
      else if (key === 'desc') entry.desc = value;
    }
    return entry;
  });
}

/* ------------------------------------------------------------------------------------
 * Editor: cursor position, selecting a range, line/column to offset
 * ---------------------------------------------------------------------------------- */

const editor = $('editor');

function lineColumnAt(text, offset) {
  const before = text.slice(0, offset);
  const line = before.split('\n').length;
  const column = offset - before.lastIndexOf('\n');
  return { line, column };
}

function offsetOfLineColumn(text, line, column) {
  let offset = 0;
  for (let l = 1; l < line; l++) {
    const next = text.indexOf('\n', offset);
    if (next < 0) return text.length;
    offset = next + 1;
  }
  const lineEnd = text.indexOf('\n', offset);
  const limit = lineEnd < 0 ? text.length : lineEnd;
  return Math.min(offset + Math.max(column - 1, 0), limit);
}

function selectInEditor(start, end) {
  editor.focus();
  editor.setSelectionRange(start, Math.max(end, start + 1));
  /* Scroll so the selection sits a few lines from the top: textareas do not reliably
   * scroll a programmatic selection into view. */
  const lineHeight = Number.parseFloat(getComputedStyle(editor).lineHeight) || 18;
  const { line } = lineColumnAt(editor.value, start);
  editor.scrollTop = Math.max(0, (line - 4) * lineHeight);
  updateCursorPosition();
}

function updateCursorPosition() {
  const { line, column } = lineColumnAt(editor.value, editor.selectionStart);
  $('cursor-pos').textContent = `line ${line}, column ${column}`;
}

/* ------------------------------------------------------------------------------------
 * Quick controls: read from and write to the JSON text
 * ---------------------------------------------------------------------------------- */

const controls = {
  fieldset: $('controls'),
  note: $('controls-note'),
  material: $('material'),
  preset: $('preset'),
  g: $('g'),
  ior: $('ior'),
  scale: $('scale'),
  channels: {
    albedo: { sliders: ['albedo-r', 'albedo-g', 'albedo-b'].map($), lock: $('albedo-lock'), base: null },
    mfp: { sliders: ['mfp-r', 'mfp-g', 'mfp-b'].map($), lock: $('mfp-lock'), base: null },
  },
  swatch: $('albedo-swatch'),
  width: $('width'),
  height: $('height'),
  spp: $('spp'),
  exposure: $('exposure'),
  components: Array.from(document.querySelectorAll('input[name=component]')),
  method: $('method'),
  methodNote: $('method-note'),
  scatterChoices: SCATTER_CHOICES.map((choice) => ({ ...choice, select: $(choice.id) })),
  scatterNumbers: SCATTER_NUMBERS.map((field) => ({ ...field, input: $(field.id) })),
};

/* GET /v1/info "methods": [{name, components, unavailable_components}], or null until it
 * has answered (then every method is offered without a component note). */
let serverMethods = null;

function parseEditor() {
  try {
    const scene = JSON.parse(editor.value);
    return scene && typeof scene === 'object' && !Array.isArray(scene) ? scene : null;
  } catch {
    return null;
  }
}

function mediumNames(scene) {
  const materials = scene.materials && typeof scene.materials === 'object' ? scene.materials : {};
  return Object.keys(materials).filter((name) => materials[name] && materials[name].type === 'medium');
}

function setSlider(input, value, display) {
  input.value = String(value);
  const out = $(input.id + '-out');
  out.textContent = display;
  input.setAttribute('aria-valuetext', display);
}

const scaleFromSlider = (v) => Number((10 ** Number(v)).toPrecision(3));

/* Fills every control from the text; disables them (with a reason) when the text is not a
 * JSON object, so a half-typed edit is never overwritten. */
function readControls() {
  const scene = parseEditor();
  controls.fieldset.disabled = scene === null;
  controls.note.hidden = scene !== null;
  editor.setAttribute('aria-invalid', scene === null ? 'true' : 'false');
  if (scene === null) {
    controls.note.textContent = 'The text is not valid JSON; fix it (or render to see where) to use these controls.';
    return;
  }

  const names = mediumNames(scene);
  const previous = controls.material.value;
  controls.material.replaceChildren(...names.map((name) => el('option', { value: name, textContent: name })));
  if (names.length === 0) controls.material.append(el('option', { value: '', textContent: '(no medium material)' }));
  controls.material.value = names.includes(previous) ? previous : names[0] || '';
  readMaterialControls(scene);

  for (const input of [controls.width, controls.height, controls.spp]) input.removeAttribute('aria-invalid');
  const camera = scene.camera || {};
  controls.width.value = Number.isFinite(camera.width) ? camera.width : '';
  controls.height.value = Number.isFinite(camera.height) ? camera.height : '';
  const render = scene.render || {};
  controls.spp.value = Number.isFinite(render.spp) ? render.spp : '';
  const exposure = Number.isFinite(render.exposure) ? render.exposure : 0;
  setSlider(controls.exposure, exposure, exposure.toFixed(1));
  const components = Array.isArray(render.components) ? render.components : [];
  for (const box of controls.components) box.checked = components.includes(box.value);
  readRenderSettings(render);
}

/* Method, the scattering choices and numbers. A value the page does not know (a typo
 * the server will reject with its pointer) is shown as it is rather than replaced. */
function readRenderSettings(render) {
  const method = render.method === undefined ? DEFAULT_METHOD : String(render.method);
  setSelectValue(controls.method, method);
  showMethodComponents(method);
  showScatterChoices(render, method);
  for (const field of controls.scatterNumbers) {
    const value = render[field.key];
    const isNumber = typeof value === 'number' && Number.isFinite(value);
    field.input.value = isNumber ? String(value) : '';
    /* A non-number in the text cannot be shown in a number field: mark it instead of
     * letting the empty field pass for the default. */
    if (value !== undefined && !isNumber) field.input.setAttribute('aria-invalid', 'true');
    else field.input.removeAttribute('aria-invalid');
  }
}

/* Each choice as the text has it, or the method's default where the key is absent. */
function showScatterChoices(render, method) {
  for (const choice of controls.scatterChoices) {
    setSelectValue(choice.select, render[choice.key] === undefined ? choice.fallback(method) : String(render[choice.key]));
  }
}

/* Selects value, adding a marked option for a value outside the list so the control never
 * shows something other than what the text says. */
function setSelectValue(select, value) {
  for (const option of Array.from(select.options)) if (option.dataset.unknown) option.remove();
  if (!Array.from(select.options).some((o) => o.value === value)) {
    select.append(el('option', { value, textContent: `${value} (unknown)`, 'data-unknown': 'true' }));
  }
  select.value = value;
}

/* Marks the components the chosen method cannot render in this build (from /v1/info). */
function showMethodComponents(method) {
  const entry = serverMethods && serverMethods.find((m) => m.name === method);
  const missing = entry && Array.isArray(entry.unavailable_components) ? entry.unavailable_components : [];
  for (const box of controls.components) box.parentElement.classList.toggle('unavailable', missing.includes(box.value));
  const summary = METHOD_SUMMARIES[method] || '';
  if (!entry) {
    controls.methodNote.textContent = serverMethods ? `${method} is not a method of this server` : summary;
    return;
  }
  const renders = Array.isArray(entry.components) && entry.components.length ? entry.components.join(', ') : 'nothing';
  controls.methodNote.textContent = `renders ${renders}` + (missing.length ? `; not yet ${missing.join(', ')}` : '');
}

/* Rebuilds the method options from /v1/info, keeping the one the text names. */
function applyMethods(methods) {
  if (!Array.isArray(methods)) return;
  serverMethods = methods.filter((m) => m && typeof m.name === 'string');
  if (serverMethods.length === 0) { serverMethods = null; return; }
  controls.method.replaceChildren(...serverMethods.map((m) => el('option', {
    value: m.name,
    textContent: METHOD_SUMMARIES[m.name] ? `${m.name} — ${METHOD_SUMMARIES[m.name]}` : m.name,
  })));
  readControls();
}

/* A colour field as the server reads it: [r, g, b] or one number meaning grey. */
function asColor(value) {
  if (typeof value === 'number' && Number.isFinite(value)) return [value, value, value];
  if (Array.isArray(value) && value.length === 3 && value.every((v) => typeof v === 'number' && Number.isFinite(v))) return value.slice();
  return null;
}
/* Three equal channels are written as one number (grey), as a person would. */
const compactColor = (c) => (c[0] === c[1] && c[1] === c[2] ? c[0] : c);

/* The material's albedo and mfp per channel as the server resolves them (docs/scene.md):
 * the coefficient form (sigma_s + sigma_a) converted, else its own albedo / mfp, else the
 * preset's. null where the text gives neither (the server will say what is missing). */
function materialOptics(material) {
  const preset = PRESETS[material.preset] || null;
  const sigmaS = asColor(material.sigma_s);
  const sigmaA = asColor(material.sigma_a);
  if (sigmaS && sigmaA) {
    const sigmaT = sigmaS.map((s, c) => s + sigmaA[c]);
    return {
      form: 'coefficients',
      albedo: sigmaT.map((t, c) => (t > 0 ? sigmaS[c] / t : 1)),
      mfp: sigmaT.map((t) => (t > 0 ? 1 / t : 100)),
    };
  }
  return {
    form: 'table',
    albedo: asColor(material.albedo) || (preset ? preset.albedo.slice() : null),
    mfp: asColor(material.mfp) || (preset ? preset.mfp.slice() : null),
  };
}

/* Shows a channel field's values (or dashes when the text has none) and remembers them as
 * the base that "move together" shifts from. */
function readChannelControls(field, values) {
  const set = controls.channels[field];
  const spec = CHANNEL_FIELDS[field];
  set.base = values;
  set.sliders.forEach((slider, c) => {
    if (!values) {
      $(slider.id + '-out').textContent = '—';
      slider.setAttribute('aria-valuetext', 'not set');
      return;
    }
    setSlider(slider, spec.toSlider(values[c]), spec.display(values[c]));
  });
}

/* The diffusion approximation's total diffuse reflectance R_d (Jensen et al. 2001, with
 * the reduced albedo and the boundary's A from the ior) per channel, as an sRGB swatch: a
 * hint of the colour the albedo gives a thick slab, since the single-scattering albedo is
 * not itself the colour one sees. */
function diffuseReflectance(albedo, g, ior) {
  const eta = Math.max(1, ior);
  const fdr = -1.44 / (eta * eta) + 0.71 / eta + 0.668 + 0.0636 * eta;
  const A = (1 + fdr) / (1 - fdr);
  return albedo.map((a) => {
    const reduced = (a * (1 - g)) / (1 - a * g);
    const s = Math.sqrt(3 * Math.max(0, 1 - reduced));
    return (reduced / 2) * (1 + Math.exp((-4 / 3) * A * s)) * Math.exp(-s);
  });
}
const linearToSrgb8 = (v) => {
  if (!(v > 0)) return 0;
  if (v >= 1) return 255;
  const srgb = v <= 0.0031308 ? 12.92 * v : 1.055 * v ** (1 / 2.4) - 0.055;
  return Math.min(255, Math.max(0, Math.floor(srgb * 255 + 0.5)));
};

function showSwatch(albedo, g, ior) {
  if (!albedo) {
    controls.swatch.style.background = 'none';
    controls.swatch.setAttribute('aria-label', 'Approximate colour: no albedo');
    return;
  }
  const rd = diffuseReflectance(albedo, g, ior);
  const [r, gg, b] = rd.map(linearToSrgb8);
  controls.swatch.style.background = `rgb(${r}, ${gg}, ${b})`;
  controls.swatch.setAttribute('aria-label', `Approximate colour (diffuse reflectance R_d ${rd.map((v) => v.toFixed(3)).join(', ')})`);
}

function readMaterialControls(scene) {
  const name = controls.material.value;
  const material = name ? scene.materials[name] : null;
  const channelSliders = [...controls.channels.albedo.sliders, ...controls.channels.mfp.sliders];
  for (const input of [controls.preset, controls.g, controls.ior, controls.scale, ...channelSliders]) input.disabled = !material;
  if (!material) {
    controls.preset.value = '';
    for (const input of [controls.g, controls.ior, controls.scale]) $(input.id + '-out').textContent = '—';
    readChannelControls('albedo', null);
    readChannelControls('mfp', null);
    showSwatch(null);
    return;
  }
  const preset = PRESETS[material.preset] || null;
  controls.preset.value = preset ? material.preset : '';
  const g = Number.isFinite(material.g) ? material.g : preset ? preset.g : 0;
  const ior = Number.isFinite(material.ior) ? material.ior : preset ? preset.ior : 1;
  const scale = Number.isFinite(material.scale) && material.scale > 0 ? material.scale : 1;
  setSlider(controls.g, g, g.toFixed(2));
  setSlider(controls.ior, ior, ior.toFixed(2));
  setSlider(controls.scale, Math.log10(scale), String(Number(scale.toPrecision(3))));
  const optics = materialOptics(material);
  readChannelControls('albedo', optics.albedo);
  readChannelControls('mfp', optics.mfp);
  showSwatch(optics.albedo, g, ior);
}

/* Applies `change` to the parsed scene and writes it back formatted; every quick control
 * goes through here, so a change re-renders by itself (when "Render on change" is on). */
function editScene(change) {
  const scene = parseEditor();
  if (scene === null) return;
  change(scene);
  setEditorText(sceneText(scene), { keepControls: false });
  scheduleAutoRender();
}

function selectedMaterial(scene) {
  const name = controls.material.value;
  return name && scene.materials && scene.materials[name] ? scene.materials[name] : null;
}

function onPresetChange() {
  const name = controls.preset.value;
  editScene((scene) => {
    const material = selectedMaterial(scene);
    if (!material) return;
    const previous = PRESETS[material.preset] || PRESETS.candle;
    const own = { ...material };
    for (const field of MEDIUM_FIELDS) delete material[field];
    if (name) {
      /* A preset is a fresh start: the server fills albedo, mfp, g and ior from Table 1. */
      material.preset = name;
      return;
    }
    /* "custom": spell the preset out, keeping the material's own overrides, so the look
     * stays the same and every field becomes editable in the text. */
    Object.assign(material, structuredClone(previous));
    if (own.sigma_s !== undefined || own.sigma_a !== undefined) {
      delete material.albedo;
      delete material.mfp;
    }
    for (const field of MEDIUM_FIELDS) {
      if (field !== 'preset' && own[field] !== undefined) material[field] = own[field];
    }
  });
}

/* The values a channel slider's release writes: the moved channel from its position, the
 * others kept, or (moving together) shifted by the same slider distance. */
function channelValues(field, moved) {
  const set = controls.channels[field];
  const spec = CHANNEL_FIELDS[field];
  const min = Number(set.sliders[0].min);
  const max = Number(set.sliders[0].max);
  const position = Number(set.sliders[moved].value);
  const base = set.base;
  if (!base) return [0, 1, 2].map((c) => spec.fromSlider(c === moved ? position : Number(set.sliders[c].value)));
  const delta = position - Math.min(max, Math.max(min, spec.toSlider(base[moved])));
  return base.map((value, c) => {
    if (c === moved) return spec.fromSlider(position);
    if (!set.lock.checked) return value;
    return spec.fromSlider(Math.min(max, Math.max(min, spec.toSlider(value) + delta)));
  });
}

function onChannelInput(event) {
  const input = event.target;
  const field = input.dataset.field;
  const moved = Number(input.dataset.channel);
  const set = controls.channels[field];
  const spec = CHANNEL_FIELDS[field];
  const values = channelValues(field, moved);
  set.sliders.forEach((slider, c) => {
    if (c === moved) setSlider(slider, slider.value, spec.display(values[c]));
    else setSlider(slider, Math.min(Number(slider.max), Math.max(Number(slider.min), spec.toSlider(values[c]))), spec.display(values[c]));
  });
}

/* Writes materials/NAME/albedo or /mfp. A preset keeps supplying the other one (an
 * override, docs/scene.md); a material in the coefficient form (sigma_s, sigma_a) is first
 * converted to albedo + mfp, since the two forms cannot be mixed. */
function onChannelChange(event) {
  const input = event.target;
  const field = input.dataset.field;
  const values = channelValues(field, Number(input.dataset.channel));
  editScene((scene) => {
    const material = selectedMaterial(scene);
    if (!material) return;
    toTableForm(material);
    material[field] = compactColor(values);
  });
}

/* sigma_s + sigma_a -> albedo + mfp (same coefficients, rounded as the sliders write). */
function toTableForm(material) {
  const optics = materialOptics(material);
  if (optics.form !== 'coefficients') return;
  delete material.sigma_s;
  delete material.sigma_a;
  const round = (field, values) => values.map((v) => CHANNEL_FIELDS[field].fromSlider(CHANNEL_FIELDS[field].toSlider(v)));
  material.albedo = compactColor(round('albedo', optics.albedo));
  material.mfp = compactColor(round('mfp', optics.mfp));
}

function onSliderInput(event) {
  const input = event.target;
  const v = Number(input.value);
  const display = input === controls.scale ? String(scaleFromSlider(v)) : v.toFixed(input === controls.exposure ? 1 : 2);
  setSlider(input, input.value, display);
}

function onSliderChange(event) {
  const input = event.target;
  const key = input.id;
  const value = key === 'scale' ? scaleFromSlider(input.value) : Number(Number(input.value).toFixed(2));
  editScene((scene) => {
    const material = selectedMaterial(scene);
    if (material) material[key] = value;
  });
}

function onExposureChange() {
  const value = Number(Number(controls.exposure.value).toFixed(1));
  editScene((scene) => {
    scene.render = scene.render && typeof scene.render === 'object' ? scene.render : {};
    scene.render.exposure = value;
  });
}

function onIntegerChange(event, write) {
  const input = event.target;
  const value = Number(input.value);
  if (!Number.isInteger(value) || value < 1 || !input.checkValidity()) {
    input.setAttribute('aria-invalid', 'true');
    return; /* leave the text alone; the field shows it is invalid */
  }
  input.removeAttribute('aria-invalid');
  editScene((scene) => write(scene, value));
}

function onComponentsChange() {
  const chosen = COMPONENT_ORDER.filter((c) => controls.components.some((b) => b.checked && b.value === c));
  editScene((scene) => {
    scene.render = scene.render && typeof scene.render === 'object' ? scene.render : {};
    scene.render.components = chosen;
  });
}

const renderSettings = (scene) => (scene.render = scene.render && typeof scene.render === 'object' ? scene.render : {});

function onMethodChange() {
  const method = controls.method.value;
  showMethodComponents(method);
  editScene((scene) => { renderSettings(scene).method = method; });
}

function onScatterChoiceChange(choice) {
  const value = choice.select.value;
  editScene((scene) => { renderSettings(scene)[choice.key] = value; });
}

/* A scattering number: empty removes the key (the server's default applies); a value
 * outside the input's range or of the wrong kind marks the field and leaves the text alone. */
function onScatterNumberChange(field) {
  const input = field.input;
  const raw = input.value.trim();
  if (raw === '' && !input.validity.badInput) {
    input.removeAttribute('aria-invalid');
    editScene((scene) => { delete renderSettings(scene)[field.key]; });
    return;
  }
  const value = Number(raw);
  const kindOk = field.integer ? Number.isInteger(value) : Number.isFinite(value);
  if (!kindOk || !input.checkValidity()) {
    input.setAttribute('aria-invalid', 'true');
    return;
  }
  input.removeAttribute('aria-invalid');
  editScene((scene) => { renderSettings(scene)[field.key] = value; });
}

function setEditorText(text, { keepControls = false } = {}) {
  editor.value = text;
  storageSet(text);
  if (!keepControls) readControls();
  updateCursorPosition();
}

/* ------------------------------------------------------------------------------------
 * Status line and problem panel
 * ---------------------------------------------------------------------------------- */

let retryTimer = null;

function setStatus(text, kind = '') {
  const status = $('status');
  status.textContent = text;
  status.className = 'status' + (kind ? ' ' + kind : '');
}

function clearProblem() {
  $('problem').hidden = true;
  $('problem-errors').replaceChildren();
  if (retryTimer) { clearInterval(retryTimer); retryTimer = null; }
}

/* A button that selects the pointer's value in the editor, for text the editor holds. */
function pointerButton(pointer, sourceText) {
  return el('button', {
    type: 'button',
    class: 'pointer',
    textContent: pointer || '(document)',
    title: 'Select this field in the editor',
    onclick: () => {
      if (editor.value !== sourceText) {
        setStatus('The editor text changed since this render; the field is looked up in the current text.');
      }
      const range = rangeForPointer(editor.value, pointer);
      if (range) selectInEditor(range.start, range.end);
    },
  });
}

/* "line 5, column 12" (any punctuation between) in a syntax-error detail, if present. */
function findLineColumn(problem) {
  if (Number.isInteger(problem.line) && Number.isInteger(problem.column)) {
    return { line: problem.line, column: problem.column };
  }
  const texts = [problem.detail, ...(problem.errors || []).map((e) => e && e.detail)];
  for (const text of texts) {
    const match = /line\D{0,3}(\d+)\D{1,12}column\D{0,3}(\d+)/i.exec(String(text || ''));
    if (match) return { line: Number(match[1]), column: Number(match[2]) };
  }
  return null;
}

function showProblem(problem, httpStatus, sourceText) {
  clearProblem();
  const title = problem.title || `HTTP ${httpStatus}`;
  $('problem-title').textContent = `${title} (${httpStatus}${problem.code ? ', ' + problem.code : ''})`;
  $('problem-detail').textContent = problem.detail || '';
  const list = $('problem-errors');
  const errors = Array.isArray(problem.errors) ? problem.errors : [];
  for (const error of errors) {
    if (!error || typeof error !== 'object') continue;
    const pointer = typeof error.pointer === 'string' ? error.pointer : '';
    const item = el('li');
    if (pointer) item.append(pointerButton(pointer, sourceText), ': ');
    item.append(String(error.detail || ''));
    list.append(item);
  }
  const position = findLineColumn(problem);
  if (position) {
    const jump = el('button', {
      type: 'button',
      class: 'pointer',
      textContent: `go to line ${position.line}, column ${position.column}`,
      onclick: () => {
        const offset = offsetOfLineColumn(editor.value, position.line, position.column);
        selectInEditor(offset, offset + 1);
      },
    });
    list.append(el('li', {}, jump));
  }
  $('problem').hidden = false;
  $('viewer').classList.add('stale'); /* the image shown is not of the text that failed */
}

function showBusy(problem, retryAfterSeconds) {
  showProblem(problem, 503, editor.value);
  let remaining = retryAfterSeconds;
  const render = () => {
    $('problem-detail').textContent = remaining > 0
      ? `The server is busy, retry in ${remaining} s.`
      : 'The server was busy; you can retry now.';
  };
  render();
  retryTimer = setInterval(() => {
    remaining -= 1;
    render();
    if (remaining <= 0) { clearInterval(retryTimer); retryTimer = null; }
  }, 1000);
  setStatus(`Server busy, retry in ${retryAfterSeconds} s.`, 'error');
}

async function readProblem(response) {
  const type = response.headers.get('Content-Type') || '';
  const body = await response.text();
  if (type.includes('json')) {
    try { return JSON.parse(body); } catch { /* fall through to the text */ }
  }
  return { title: response.statusText || 'Request failed', detail: body.slice(0, 2000) };
}

/* ------------------------------------------------------------------------------------
 * Rendering and history
 * ---------------------------------------------------------------------------------- */

const renders = []; /* newest first */
let shownEntry = null;
let nextId = 1;

/* A render runs as a background job (Prefer: respond-async, progress from its events)
 * rather than as a direct answer when "Run as" says so, or on "auto" when it is long: the
 * path tracer, or at least this many pixel samples (width x height x spp: 1024 x 1024 at
 * 1 spp, 256 x 256 at 16). */
const JOB_PIXEL_SAMPLES = 1 << 20;
/* The preview: 1/4 of the width and height, 1/16 of the spp, 1/4 of the VRLs and single
 * samples; images smaller than this on both sides get none. */
const PREVIEW_DIVISOR = 4;
const PREVIEW_MIN_SIDE = 64;
/* A busy answer (503) to a render that follows a cancelled one (whose slot the server may
 * still be freeing), to an automatic re-render or to a background request is retried, at
 * most this long; an explicit render with nothing cancelled shows the busy message. */
const BUSY_RETRY_LIMIT_MS = 120_000;
const RECENT_CANCEL_MS = 10_000;
/* Changes within this pause make one automatic re-render. */
const AUTO_RENDER_DELAY_MS = 150;

function postScene(text, accept, { signal, async = false, query = '' } = {}) {
  const headers = { 'Content-Type': 'application/json', Accept: accept };
  if (async) headers.Prefer = 'respond-async';
  return fetch('/v1/renders' + query, { method: 'POST', headers, body: text, signal });
}

const messageOf = (error) => String(error && error.message ? error.message : error);
const isAbort = (error) => error && error.name === 'AbortError';

function sleep(ms, signal) {
  return new Promise((resolve, reject) => {
    if (signal && signal.aborted) { reject(new DOMException('Aborted', 'AbortError')); return; }
    const timer = setTimeout(() => { if (signal) signal.removeEventListener('abort', onAbort); resolve(); }, ms);
    const onAbort = () => { clearTimeout(timer); reject(new DOMException('Aborted', 'AbortError')); };
    if (signal) signal.addEventListener('abort', onAbort, { once: true });
  });
}

function retryAfterSeconds(response) {
  const retry = Number.parseInt(response.headers.get('Retry-After') || '', 10);
  return Number.isFinite(retry) && retry >= 0 ? retry : 1;
}

let lastCancelAt = -Infinity;

/* Sends a request; while the answer is 503 and retrying is allowed, waits (the server's
 * Retry-After, between 0.25 and 1 s: the slot is often our own cancelled render's) and
 * sends it again. */
async function sendWithRetry(send, { retry, signal, onWait }) {
  const started = performance.now();
  for (;;) {
    const response = await send();
    if (response.status !== 503 || !retry || performance.now() - started > BUSY_RETRY_LIMIT_MS) return response;
    const seconds = retryAfterSeconds(response);
    await response.text().catch(() => '');
    if (onWait) onWait(seconds);
    await sleep(Math.min(1000, Math.max(250, seconds * 1000)), signal);
  }
}

function describeScene(text) {
  const parts = [];
  try {
    const scene = JSON.parse(text);
    const name = mediumNames(scene)[0];
    if (name) {
      const m = scene.materials[name];
      const preset = PRESETS[m.preset];
      parts.push(m.preset ? `${name}=${m.preset}` : name);
      const g = Number.isFinite(m.g) ? m.g : preset && preset.g;
      const ior = Number.isFinite(m.ior) ? m.ior : preset && preset.ior;
      if (Number.isFinite(g)) parts.push(`g ${g}`);
      if (Number.isFinite(ior)) parts.push(`ior ${ior}`);
      if (Number.isFinite(m.scale)) parts.push(`×${m.scale}`);
    }
    const render = scene.render || {};
    if (typeof render.method === 'string') parts.push(render.method);
    if (Number.isFinite(render.spp)) parts.push(`${render.spp} spp`);
  } catch { /* the caption just stays short */ }
  return parts.join(' · ');
}

function parseSceneText(text) {
  try {
    const scene = JSON.parse(text);
    return scene && typeof scene === 'object' && !Array.isArray(scene) ? scene : null;
  } catch {
    return null;
  }
}

/* Job or direct answer (see JOB_PIXEL_SAMPLES). Text that is not a scene object goes
 * direct, so the server's error comes back at once. */
function runsAsJob(scene) {
  const mode = $('run-mode').value;
  if (!scene || mode === 'sync') return false;
  if (mode === 'job') return true;
  const render = scene.render && typeof scene.render === 'object' ? scene.render : {};
  if (render.method === 'pt') return true;
  const camera = scene.camera && typeof scene.camera === 'object' ? scene.camera : {};
  const spp = Number.isFinite(render.spp) ? render.spp : 1;
  return Number.isFinite(camera.width) && Number.isFinite(camera.height) && camera.width * camera.height * spp >= JOB_PIXEL_SAMPLES;
}

/* The same scene, smaller and cheaper (see PREVIEW_DIVISOR); null when the image is
 * already small or its size is not a pair of numbers. Only numbers are scaled: a field the
 * server would reject is left as it is (the full render then reports it). */
function previewScene(scene) {
  const camera = scene.camera;
  if (!camera || !Number.isInteger(camera.width) || !Number.isInteger(camera.height)) return null;
  if (Math.max(camera.width, camera.height) < PREVIEW_MIN_SIDE) return null;
  const copy = structuredClone(scene);
  copy.camera.width = Math.max(1, Math.round(camera.width / PREVIEW_DIVISOR));
  copy.camera.height = Math.max(1, Math.round(camera.height / PREVIEW_DIVISOR));
  const render = copy.render && typeof copy.render === 'object' ? copy.render : (copy.render = {});
  const cut = (key, fallback, divisor) => {
    const value = render[key] === undefined ? fallback : render[key];
    if (Number.isInteger(value) && value >= 1) render[key] = Math.max(1, Math.round(value / divisor));
  };
  cut('spp', 1, PREVIEW_DIVISOR * PREVIEW_DIVISOR);
  cut('vrls', 10000, PREVIEW_DIVISOR);
  cut('single_samples', 64, PREVIEW_DIVISOR);
  cut('light_samples', 2, PREVIEW_DIVISOR);
  // Added samples scale with the samples, as spp does (the server's default 2 included,
  // which pt does not take); at one sample per pixel there is no spread to place them by
  // (the server refuses them there), so the key goes.
  const adaptive = render.adaptive_spp === undefined && render.method !== 'pt' ? 2 : render.adaptive_spp;
  if (!(Number.isInteger(render.spp) && render.spp >= 2)) delete render.adaptive_spp;
  else if (typeof adaptive === 'number') render.adaptive_spp = adaptive / (PREVIEW_DIVISOR * PREVIEW_DIVISOR);
  return copy;
}

async function entryFromResponse(response, text, started, extra = {}) {
  const blob = await response.blob();
  return {
    id: extra.preview ? 0 : nextId++,
    sceneText: text,
    blob,
    url: URL.createObjectURL(blob),
    timings: parseServerTiming(response.headers.get('Server-Timing')),
    device: response.headers.get('X-Nscatter-Device') || '(not reported)',
    counts: parseCounts(response.headers.get('X-Nscatter-Stats')),
    roundTripMs: performance.now() - started,
    caption: describeScene(text),
    when: new Date(),
    preview: extra.preview || null, /* {width, height} of the full image it stands for */
    job: extra.job || null, /* {self, image, events}: the image can be fetched again (EXR) */
    exr: null, /* the float EXR, once fetched (Reference, Download EXR) */
  };
}

/* ------------------------------------------------------------------------------------
 * Background jobs: a progress bar and its stage, fed by the job's Server-Sent Events
 * ---------------------------------------------------------------------------------- */

/* The box, its <progress> and its label (id prefix: "job", "ref", "sweep"). */
function jobView(prefix) {
  const box = $(prefix === 'job' ? 'job' : `${prefix}-job`);
  const bar = $(`${prefix}-progress`);
  const label = $(`${prefix}-label`);
  let value = 0;
  let stage = null;
  const setValue = (p) => {
    if (typeof p !== 'number' || !Number.isFinite(p)) return;
    value = Math.max(value, Math.min(1, Math.max(0, p))); /* never goes back */
    bar.value = value;
  };
  const percent = () => `${Math.floor(value * 100)}%`;
  return {
    start(text) {
      value = 0;
      stage = null;
      bar.value = 0;
      label.textContent = text || 'submitted';
      box.hidden = false;
    },
    /* One event of the stream (name, parsed data); returns nothing. */
    event(name, data, prefix = '') {
      if (name === 'state') {
        if (data.state === 'queued') {
          const ahead = data.queue_position;
          label.textContent = prefix + (Number.isInteger(ahead) ? (ahead === 0 ? 'queued, next' : `queued, ${ahead} ahead`) : 'queued');
        } else label.textContent = prefix + (data.cancel_requested ? 'cancelling…' : String(data.state || ''));
        return;
      }
      if (typeof data.stage === 'string') stage = data.stage;
      setValue(data.progress);
      label.textContent = `${prefix}${stage || 'running'} · ${percent()}`;
    },
    text(text) { label.textContent = text; },
    finish(p) { setValue(p); },
    hide() { box.hidden = true; },
    get value() { return value; },
  };
}

const mainJob = jobView('job');

/* Follows a job's event stream until its final event: resolves {event, job} with event
 * done, failed or cancelled and the job JSON. The browser reconnects a dropped stream by
 * itself (with Last-Event-ID); when the stream cannot be opened at all, the job itself is
 * asked. `onEvent(name, data)` sees every other event. The signal closes the stream. */
function followJob(urls, onEvent, signal) {
  return new Promise((resolve, reject) => {
    const source = new EventSource(urls.events);
    let settled = false;
    const onAbort = () => settle(() => reject(new DOMException('Aborted', 'AbortError')));
    function settle(then) {
      if (settled) return;
      settled = true;
      source.close();
      signal.removeEventListener('abort', onAbort);
      then();
    }
    if (signal.aborted) { onAbort(); return; }
    signal.addEventListener('abort', onAbort);
    const parse = (event) => {
      try { return JSON.parse(event.data) || {}; } catch { return {}; }
    };
    for (const name of ['state', 'stage_start', 'progress', 'stage_end', 'variant_start', 'variant_end']) {
      source.addEventListener(name, (event) => { if (!settled) onEvent(name, parse(event)); });
    }
    for (const name of ['done', 'failed', 'cancelled']) {
      source.addEventListener(name, (event) => settle(() => resolve({ event: name, job: parse(event) })));
    }
    source.onerror = () => {
      if (source.readyState !== EventSource.CLOSED) return; /* reconnecting by itself */
      settle(async () => {
        try {
          const response = await fetch(urls.self, { headers: { Accept: 'application/json' }, signal });
          if (!response.ok) {
            const problem = await readProblem(response);
            reject(Object.assign(new Error(problem.detail || problem.title || `HTTP ${response.status}`), { problem, status: response.status }));
            return;
          }
          const job = await response.json();
          if (['done', 'failed', 'cancelled'].includes(job.state)) resolve({ event: job.state, job });
          else reject(new Error(`the job's event stream closed while it is ${job.state}`));
        } catch (error) {
          reject(error);
        }
      });
    };
  });
}

function jobUrls(response, job, collection = '/v1/renders') {
  const links = job && job.links && typeof job.links === 'object' ? job.links : {};
  const self = response.headers.get('Location') || links.self || `${collection}/${job.id}`;
  return { id: job.id, self, events: links.events || `${self}/events`, image: links.image || `${self}/image`, sheet: links.sheet || `${self}/sheet.png` };
}

function deleteJob(url) {
  return fetch(url, { method: 'DELETE' }).then((r) => r.status, () => 0);
}

/* ------------------------------------------------------------------------------------
 * Render runs. One at a time: a newer run (a change of a control, Render, Ctrl+Enter)
 * cancels the one in flight: its requests are aborted (the server cancels a direct render
 * whose client went away) and its job is deleted.
 * ---------------------------------------------------------------------------------- */

let currentRun = null;
let autoTimer = null;

function setRunBusy(busy) {
  const button = $('render');
  if (busy) button.setAttribute('aria-busy', 'true');
  else button.removeAttribute('aria-busy');
  $('cancel').disabled = !busy;
}

/* Ends the run in flight without a word (a newer one takes over the status line). */
function supersedeRun() {
  const run = currentRun;
  if (!run) return false;
  currentRun = null;
  lastCancelAt = performance.now();
  run.controller.abort();
  if (run.job && run.phase !== 'image') deleteJob(run.job.self);
  setRunBusy(false);
  mainJob.hide();
  return true;
}

/* The Cancel button: a direct render is aborted at once; a job is deleted and followed
 * until it says it stopped (a running job stops at its next dispatch boundary). */
async function cancelRender() {
  const run = currentRun;
  if (!run) return;
  if (!run.job || run.phase === 'image') {
    supersedeRun();
    setStatus('Cancelled.');
    return;
  }
  $('cancel').disabled = true;
  lastCancelAt = performance.now();
  run.cancelRequested = true;
  mainJob.text('cancelling…');
  setStatus('Cancelling the job…', 'busy');
  const status = await deleteJob(run.job.self);
  if (currentRun !== run) return;
  if (status === 202) setStatus('Cancelling: the job stops at its next dispatch boundary…', 'busy');
  else if (status === 200) setStatus('Cancelling: the job left the queue…', 'busy');
}

/* A control changed the text: re-render by itself (when "Render on change" is on). The
 * render in flight is stale at once, so it is cancelled now, not after the pause. */
function scheduleAutoRender() {
  if (!$('auto-render').checked) return;
  supersedeRun();
  clearTimeout(autoTimer);
  autoTimer = setTimeout(() => startRender('auto'), AUTO_RENDER_DELAY_MS);
}

async function startRender(trigger) {
  clearTimeout(autoTimer);
  readControls(); /* the controls may still be waiting for the typing pause */
  const superseded = supersedeRun();
  const run = {
    trigger,
    text: editor.value,
    controller: new AbortController(),
    started: performance.now(),
    /* 503 is retried after a cancel (our own render may still hold the slot) and for
     * automatic renders; an explicit render otherwise shows the busy message. */
    retryBusy: trigger === 'auto' || superseded || performance.now() - lastCancelAt < RECENT_CANCEL_MS,
    job: null,
    phase: 'post',
  };
  currentRun = run;
  setRunBusy(true);
  try {
    await executeRun(run);
  } catch (error) {
    if (run.controller.signal.aborted || isAbort(error)) return; /* a newer run owns the page */
    showProblem({ title: 'Cannot reach the server', detail: messageOf(error) }, 0, run.text);
    setStatus('Render failed: the server did not answer.', 'error');
  } finally {
    if (currentRun === run) {
      currentRun = null;
      setRunBusy(false);
      mainJob.hide();
    }
  }
}

const live = (run) => currentRun === run && !run.controller.signal.aborted;

async function executeRun(run) {
  const scene = parseSceneText(run.text);
  const asJob = runsAsJob(scene);
  const preview = scene && $('preview-first').checked ? previewScene(scene) : null;
  const onWait = (seconds) => { if (live(run)) setStatus(`Server busy (retry after ${seconds} s); waiting…`, 'busy'); };
  const send = (text, options = {}) => sendWithRetry(
    () => postScene(text, 'image/png', { signal: run.controller.signal, ...options }),
    { retry: run.retryBusy, signal: run.controller.signal, onWait });

  if (preview) {
    setStatus('Rendering a preview (¼ size)…', 'busy');
    run.started = performance.now();
    const response = await send(JSON.stringify(preview));
    if (response.status === 503) { await finishWithResponse(run, response); return; }
    if (response.ok) {
      const entry = await entryFromResponse(response, run.text, run.started, {
        preview: { width: scene.camera.width, height: scene.camera.height },
      });
      if (!live(run)) { URL.revokeObjectURL(entry.url); return; }
      await showEntry(entry);
      setStatus(asJob ? 'Preview shown; the full image runs as a job…' : 'Preview shown; rendering the full image…', 'busy');
    } else {
      /* The full render reports the problem, against the exact text. */
      await response.body?.cancel().catch(() => {});
    }
  } else setStatus(asJob ? 'Submitting a job…' : 'Rendering…', 'busy');

  /* The round trip shown is the full image's own: from its request (or the job's
   * submission) to its arrival. */
  run.started = performance.now();
  if (!asJob) {
    await finishWithResponse(run, await send(run.text));
    return;
  }
  const response = await send(run.text, { async: true });
  if (response.status !== 202) {
    /* A 200 here is a server without jobs answering directly (Prefer is only a wish). */
    await finishWithResponse(run, response);
    return;
  }
  const job = await response.json();
  if (!live(run)) return;
  run.job = jobUrls(response, job);
  mainJob.start('queued');
  mainJob.event('state', job);
  if (!run.cancelRequested) setStatus('Rendering as a background job…', 'busy');
  const final = await followJob(run.job, (name, data) => mainJob.event(name, data), run.controller.signal);
  if (!live(run)) return;
  if (final.event === 'done') {
    mainJob.finish(1);
    run.phase = 'image';
    const image = await fetch(run.job.image, { headers: { Accept: 'image/png' }, signal: run.controller.signal });
    await finishWithResponse(run, image, { job: run.job },
      run.cancelRequested ? 'The job finished before the cancel reached it' : 'Rendered as a job');
  } else if (final.event === 'failed') {
    const problem = final.job.error && typeof final.job.error === 'object' ? final.job.error : { title: 'The job failed' };
    showProblem(problem, problem.status || 500, run.text);
    setStatus(`Render failed: ${problem.title || 'the job failed'}.`, 'error');
  } else {
    const spent = final.job && final.job.finished && final.job.started ? Date.parse(final.job.finished) - Date.parse(final.job.started) : NaN;
    setStatus(Number.isFinite(spent) ? `Cancelled: the job stopped after ${formatMs(spent)} ms of rendering.` : 'Cancelled: the job stopped.');
  }
}

/* Shows an answer: the image (history, viewer) or the problem. */
async function finishWithResponse(run, response, extra = {}, how = 'Rendered') {
  if (!response.ok) {
    const problem = await readProblem(response);
    if (!live(run)) return;
    if (response.status === 503) showBusy(problem, retryAfterSeconds(response));
    else {
      showProblem(problem, response.status, run.text);
      setStatus(`Render failed: ${problem.title || response.status}.`, 'error');
    }
    return;
  }
  const entry = await entryFromResponse(response, run.text, run.started, extra);
  if (!live(run)) { URL.revokeObjectURL(entry.url); return; }
  clearProblem();
  addToHistory(entry);
  await showEntry(entry);
  setStatus(`${how} in ${formatMs(entry.roundTripMs)} ms (round trip).`, 'ok');
}

function addToHistory(entry) {
  renders.unshift(entry);
  while (renders.length > HISTORY_LIMIT) URL.revokeObjectURL(renders.pop().url);
  renderHistory();
}

function renderHistory() {
  const list = $('history');
  list.replaceChildren(...renders.map((entry) => {
    const total = entry.timings.reduce((sum, t) => sum + (Number.isFinite(t.dur) && t.name !== 'total' ? t.dur : 0), 0);
    const button = el('button', {
      type: 'button',
      title: `Render #${entry.id} at ${entry.when.toLocaleTimeString()}`,
      onclick: () => showEntry(entry),
    },
    el('img', { src: entry.url, alt: `Render #${entry.id}: ${entry.caption}` }),
    el('span', { class: 'caption', textContent: `#${entry.id} ${entry.caption} · ${formatMs(total || entry.roundTripMs)} ms` }));
    button.setAttribute('aria-current', entry === shownEntry ? 'true' : 'false');
    return el('li', {}, button);
  }));
}

async function showEntry(entry) {
  const previous = shownEntry;
  shownEntry = entry;
  const preview = entry.preview;
  $('viewer').classList.remove('stale');
  $('viewer').classList.toggle('preview', Boolean(preview));
  const image = $('image');
  image.alt = preview
    ? `Preview at ¼ size of ${preview.width}×${preview.height}: ${entry.caption}`
    : `Render #${entry.id}: ${entry.caption}`;
  const loaded = new Promise((resolve) => {
    image.onload = resolve;
    image.onerror = resolve;
  });
  image.src = entry.url;
  image.dataset.kind = preview ? 'preview' : 'full';
  image.hidden = false;
  $('placeholder').hidden = true;
  await loaded;
  /* A preview is not kept: its picture goes once something else is shown. */
  if (previous && previous.preview && previous !== entry) URL.revokeObjectURL(previous.url);
  $('image-meta').textContent = preview
    ? `${image.naturalWidth}×${image.naturalHeight} shown at ${preview.width}×${preview.height} · ${entry.caption}`
    : `#${entry.id} · ${image.naturalWidth}×${image.naturalHeight} · ${entry.caption}`;
  applyZoom();
  showTimings(entry);
  showCounts(entry);
  $('device').textContent = entry.device;
  for (const id of ['download-png', 'download-exr', 'load-scene', 'reference']) $(id).disabled = Boolean(preview);
  renderHistory();
}

function showTimings(entry) {
  const body = document.querySelector('#timings tbody');
  const foot = document.querySelector('#timings tfoot');
  const stages = entry.timings.filter((t) => t.name !== 'total');
  const longest = Math.max(1e-9, ...stages.map((t) => (Number.isFinite(t.dur) ? t.dur : 0)));
  body.replaceChildren(...stages.map((t) => {
    const width = Number.isFinite(t.dur) ? (100 * t.dur) / longest : 0;
    const bar = el('div', { class: 'meter' });
    bar.style.width = `${width.toFixed(1)}%`;
    return el('tr', {},
      el('th', { scope: 'row', textContent: t.desc ? `${t.name} (${t.desc})` : t.name }),
      el('td', { class: 'num', textContent: Number.isFinite(t.dur) ? formatMs(t.dur) : '—' }),
      el('td', {}, bar));
  }));
  const reported = entry.timings.find((t) => t.name === 'total');
  const serverTotal = reported && Number.isFinite(reported.dur)
    ? reported.dur
    : stages.reduce((sum, t) => sum + (Number.isFinite(t.dur) ? t.dur : 0), 0);
  foot.replaceChildren(
    el('tr', {}, el('td', { textContent: 'server total' }), el('td', { class: 'num', textContent: formatMs(serverTotal) }), el('td')),
    el('tr', {}, el('td', { textContent: 'round trip' }), el('td', { class: 'num', textContent: formatMs(entry.roundTripMs) }), el('td')));
}

/* X-Nscatter-Stats: one compact JSON object of counts; anything else is ignored. */
function parseCounts(header) {
  if (!header) return null;
  try {
    const counts = JSON.parse(header);
    return counts && typeof counts === 'object' && !Array.isArray(counts) ? counts : null;
  } catch {
    return null;
  }
}

const formatCount = (n) => Math.round(n).toLocaleString('en-US');
const formatMegabytes = (bytes) => `${(bytes / 1e6).toFixed(bytes >= 1e8 ? 0 : 2)} MB`;
function formatRate(perSecond) {
  const units = [[1e9, 'G'], [1e6, 'M'], [1e3, 'k']];
  for (const [scale, prefix] of units) if (perSecond >= scale) return `${(perSecond / scale).toPrecision(3)} ${prefix}/s`;
  return `${perSecond.toPrecision(3)} /s`;
}

/* The counts of the shown render, and the gather's rate: interactions evaluated per second
 * of its Server-Timing stage (the paper's figure of merit for Algorithm 1). */
function showCounts(entry) {
  const body = document.querySelector('#counts tbody');
  const note = $('counts-note');
  const counts = entry.counts;
  if (!counts) {
    body.replaceChildren();
    note.textContent = 'This render reported no counts.';
    note.hidden = false;
    return;
  }
  const row = (key, label, text, value) => {
    const tr = el('tr', {}, el('th', { scope: 'row', textContent: label }), el('td', { class: 'num', textContent: text }));
    tr.dataset.key = key;
    tr.dataset.value = String(value);
    return tr;
  };
  const rows = [];
  for (const { key, label, bytes } of COUNT_ROWS) {
    const value = counts[key];
    if (typeof value !== 'number' || !Number.isFinite(value)) continue;
    rows.push(row(key, label, bytes ? formatMegabytes(value) : formatCount(value), value));
  }
  const gather = entry.timings.find((t) => t.name === 'gather');
  if (gather && Number.isFinite(gather.dur) && gather.dur > 0 && counts.interactions > 0) {
    const rate = counts.interactions / (gather.dur / 1000);
    rows.push(row('interactions_per_second', 'gather interactions per second', formatRate(rate), rate));
  }
  body.replaceChildren(...rows);
  note.hidden = rows.length > 0;
  note.textContent = rows.length ? '' : 'This render reported no counts.';
}

function applyZoom() {
  const wrap = $('image-wrap');
  const image = $('image');
  const zoom = $('zoom').value;
  wrap.classList.toggle('fit', zoom === 'fit');
  wrap.classList.toggle('zoomed', zoom !== 'fit');
  /* A preview is drawn at the size of the image it stands for. */
  const width = shownEntry && shownEntry.preview ? shownEntry.preview.width : image.naturalWidth;
  if (!image.naturalWidth) image.style.width = '';
  else if (zoom === 'fit') image.style.width = shownEntry && shownEntry.preview ? `${width}px` : '';
  else image.style.width = `${width * Number(zoom)}px`;
}

function downloadBlob(blob, extension, what = '') {
  const stamp = new Date().toISOString().replace(/[:.]/g, '-').slice(0, 19);
  const link = el('a', { href: URL.createObjectURL(blob), download: `nscatter-${stamp}${what ? '-' + what : ''}.${extension}` });
  document.body.append(link);
  link.click();
  link.remove();
  setTimeout(() => URL.revokeObjectURL(link.href), 10000);
}

/* The entry's image as 32-bit float EXR (kept on the entry): fetched again from its job
 * when it was one (and the server still has it), else the same scene rendered again
 * directly with Accept: image/x-exr, as Download EXR always did. */
async function entryExr(entry, { signal, retry = false, onWait } = {}) {
  if (entry.exr) return entry.exr;
  let response = null;
  if (entry.job) {
    response = await fetch(entry.job.image, { headers: { Accept: 'image/x-exr' }, signal });
    if (!response.ok) {
      await response.text().catch(() => '');
      response = null; /* expired or discarded: render it again */
    }
  }
  if (!response) response = await sendWithRetry(() => postScene(entry.sceneText, 'image/x-exr', { signal }), { retry, signal, onWait });
  if (!response.ok) throw await problemError(response);
  entry.exr = await response.blob();
  return entry.exr;
}

async function problemError(response) {
  const problem = await readProblem(response);
  return Object.assign(new Error(problem.detail || problem.title || `HTTP ${response.status}`), {
    problem, status: response.status, retryAfter: retryAfterSeconds(response),
  });
}

async function downloadExr() {
  const entry = shownEntry;
  if (!entry || entry.preview) return;
  const button = $('download-exr');
  button.disabled = true;
  button.setAttribute('aria-busy', 'true');
  if (!entry.exr) setStatus(entry.job ? 'Fetching the EXR…' : 'Rendering EXR…', 'busy');
  try {
    downloadBlob(await entryExr(entry), 'exr');
    setStatus('EXR downloaded.', 'ok');
  } catch (error) {
    if (error.problem) {
      if (error.status === 503) showBusy(error.problem, error.retryAfter);
      else showProblem(error.problem, error.status, entry.sceneText);
      setStatus('EXR render failed.', 'error');
    } else {
      showProblem({ title: 'Cannot reach the server', detail: messageOf(error) }, 0, entry.sceneText);
      setStatus('EXR render failed: the server did not answer.', 'error');
    }
  } finally {
    button.disabled = shownEntry ? Boolean(shownEntry.preview) : true;
    button.removeAttribute('aria-busy');
  }
}

/* ------------------------------------------------------------------------------------
 * OpenEXR reading, enough for the server's own files: scanline images, channels of 32-bit
 * float or half, compression NONE, ZIPS or ZIP (zlib, inflated by the browser's
 * DecompressionStream). Returns linear RGB as a Float32Array, row 0 at the top.
 * ---------------------------------------------------------------------------------- */

async function inflate(bytes) {
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('deflate'));
  return new Uint8Array(await new Response(stream).arrayBuffer());
}

/* ZIP(S) blocks store the bytes split in two interleaved halves after a delta predictor. */
function unpredictZip(t) {
  for (let i = 1; i < t.length; i++) t[i] = (t[i - 1] + t[i] - 128) & 255;
  const out = new Uint8Array(t.length);
  const half = (t.length + 1) >> 1;
  for (let i = 0, a = 0, b = half; i < t.length;) {
    out[i++] = t[a++];
    if (i < t.length) out[i++] = t[b++];
  }
  return out;
}

function halfToFloat(h) {
  const sign = h & 0x8000 ? -1 : 1;
  const exponent = (h >> 10) & 31;
  const fraction = h & 1023;
  if (exponent === 0) return sign * 2 ** -14 * (fraction / 1024);
  if (exponent === 31) return fraction ? NaN : sign * Infinity;
  return sign * 2 ** (exponent - 15) * (1 + fraction / 1024);
}

async function decodeExr(buffer) {
  const bytes = new Uint8Array(buffer);
  const view = new DataView(buffer);
  if (bytes.length < 8 || view.getUint32(0, true) !== 20000630) throw new Error('not an OpenEXR file');
  if (view.getUint32(4, true) & 0x1a00) throw new Error('tiled, deep or multi-part EXR is not read here');
  let pos = 8;
  const text = (start, end) => String.fromCharCode(...bytes.subarray(start, end));
  const readName = () => {
    const end = bytes.indexOf(0, pos);
    if (end < 0) throw new Error('EXR header is cut short');
    const name = text(pos, end);
    pos = end + 1;
    return name;
  };
  const channels = [];
  let compression = -1;
  let dataWindow = null;
  for (;;) {
    const name = readName();
    if (name === '') break;
    const type = readName();
    const size = view.getInt32(pos, true);
    const start = pos + 4;
    if (name === 'channels' && type === 'chlist') {
      let p = start;
      while (bytes[p] !== 0) {
        const end = bytes.indexOf(0, p);
        const channel = text(p, end);
        p = end + 1;
        channels.push({ name: channel, type: view.getInt32(p, true), xs: view.getInt32(p + 8, true), ys: view.getInt32(p + 12, true) });
        p += 16;
      }
    } else if (name === 'compression') compression = bytes[start];
    else if (name === 'dataWindow') dataWindow = [0, 1, 2, 3].map((k) => view.getInt32(start + 4 * k, true));
    pos = start + size;
  }
  if (!dataWindow || channels.length === 0) throw new Error('EXR header lacks channels or dataWindow');
  if (channels.some((c) => c.xs !== 1 || c.ys !== 1)) throw new Error('subsampled EXR channels are not read here');
  const linesPerBlock = { 0: 1, 2: 1, 3: 16 }[compression];
  if (!linesPerBlock) throw new Error(`EXR compression ${compression} is not read here (NONE, ZIPS and ZIP are)`);
  const width = dataWindow[2] - dataWindow[0] + 1;
  const height = dataWindow[3] - dataWindow[1] + 1;
  const sampleBytes = (c) => (c.type === 1 ? 2 : 4);
  const lineBytes = channels.reduce((n, c) => n + width * sampleBytes(c), 0);
  const targets = channels.map((c) => ({ R: [0], G: [1], B: [2], Y: [0, 1, 2] }[c.name] || []));
  const rgb = new Float32Array(width * height * 3);
  const blocks = Math.ceil(height / linesPerBlock);
  const offsets = Array.from({ length: blocks }, (_, k) => Number(view.getBigUint64(pos + 8 * k, true)));
  await Promise.all(offsets.map(async (offset) => {
    const y = view.getInt32(offset, true);
    const stored = view.getInt32(offset + 4, true);
    const lines = Math.min(linesPerBlock, dataWindow[3] - y + 1);
    const expected = lines * lineBytes;
    let data = bytes.subarray(offset + 8, offset + 8 + stored);
    /* A block that did not shrink is stored as it is. */
    if (compression !== 0 && stored < expected) data = unpredictZip(await inflate(data));
    if (data.length < expected) throw new Error(`EXR block at line ${y} is cut short`);
    const dv = new DataView(data.buffer, data.byteOffset, data.byteLength);
    let p = 0;
    for (let line = 0; line < lines; line++) {
      const row = y - dataWindow[1] + line;
      channels.forEach((channel, k) => {
        for (let x = 0; x < width; x++) {
          const v = channel.type === 2 ? dv.getFloat32(p, true) : channel.type === 1 ? halfToFloat(dv.getUint16(p, true)) : dv.getUint32(p, true);
          p += sampleBytes(channel);
          for (const t of targets[k]) rgb[(row * width + x) * 3 + t] = v;
        }
      });
    }
  }));
  return { width, height, rgb };
}

/* ------------------------------------------------------------------------------------
 * `nscatter compare`'s metrics (io/image_metrics.c), line for line: a is the image under
 * test, b the reference; linear values; non-finite values are left out; peak = the
 * reference's largest value over every pixel and channel; PSNR = 20 log10(peak / RMSE)
 * per channel and overall with that one peak.
 * ---------------------------------------------------------------------------------- */

function compareImages(a, b) {
  const sq = [0, 0, 0];
  const rel = [0, 0, 0];
  const counted = [0, 0, 0];
  let peak = 0;
  let maxAbs = 0;
  let nonfinite = 0;
  let identical = true;
  const n = a.width * a.height;
  for (let i = 0; i < n; i++) {
    for (let c = 0; c < 3; c++) {
      const va = a.rgb[3 * i + c];
      const vb = b.rgb[3 * i + c];
      if (!Number.isFinite(va) || !Number.isFinite(vb)) { nonfinite++; identical = false; continue; }
      const d = va - vb;
      if (d !== 0) identical = false;
      sq[c] += d * d;
      rel[c] += Math.abs(d) / (Math.abs(vb) + 0.01);
      counted[c]++;
      if (vb > peak) peak = vb;
      if (Math.abs(d) > maxAbs) maxAbs = Math.abs(d);
    }
  }
  const rmse = [0, 1, 2].map((c) => (counted[c] ? Math.sqrt(sq[c] / counted[c]) : NaN));
  const relerr = [0, 1, 2].map((c) => (counted[c] ? rel[c] / counted[c] : NaN));
  const all = counted[0] + counted[1] + counted[2];
  rmse.push(all ? Math.sqrt((sq[0] + sq[1] + sq[2]) / all) : NaN);
  relerr.push(all ? (rel[0] + rel[1] + rel[2]) / all : NaN);
  const psnr = rmse.map((r) => (!(peak > 0) || Number.isNaN(r) ? NaN : r === 0 ? Infinity : 20 * Math.log10(peak / r)));
  return { pixels: n, peak: all ? peak : NaN, rmse, psnr, relerr, maxAbs, nonfinite, identical: identical && n > 0 };
}

/* compare's colour ramp (image_ramp_srgb): t in [0, 1] -> sRGB in [0, 1]. */
const RAMP = [[0.000, 0.000, 0.016], [0.258, 0.039, 0.406], [0.576, 0.149, 0.404], [0.865, 0.317, 0.226], [0.988, 0.645, 0.040], [0.988, 1.000, 0.645]];
function rampSrgb(t) {
  const last = RAMP.length - 1;
  const x = Math.min(1, Math.max(0, t > 0 ? t : 0)) * last;
  const i = Math.min(Math.floor(x), last - 1);
  const f = x - i;
  return [0, 1, 2].map((c) => RAMP[i][c] + f * (RAMP[i + 1][c] - RAMP[i][c]));
}
const srgbToLinear = (v) => (v <= 0.04045 ? v / 12.92 : ((v + 0.055) / 1.055) ** 2.4);

/* compare --diff: the channel mean of |a - b| on the ramp, scaled to its largest value
 * (non-finite differences at the top), written as its PNG would show it. */
function drawDifference(canvas, a, b) {
  const n = a.width * a.height;
  const diff = new Float64Array(n);
  let scale = 0;
  for (let i = 0; i < n; i++) {
    let d = 0;
    for (let c = 0; c < 3; c++) d += Math.abs(a.rgb[3 * i + c] - b.rgb[3 * i + c]) / 3;
    diff[i] = d;
    if (Number.isFinite(d) && d > scale) scale = d;
  }
  if (!(scale > 0)) scale = 1;
  const pixels = new ImageData(a.width, a.height);
  for (let i = 0; i < n; i++) {
    const srgb = rampSrgb(Number.isFinite(diff[i]) ? diff[i] / scale : 1);
    for (let c = 0; c < 3; c++) pixels.data[4 * i + c] = linearToSrgb8(srgbToLinear(srgb[c]));
    pixels.data[4 * i + 3] = 255;
  }
  canvas.width = a.width;
  canvas.height = a.height;
  canvas.getContext('2d').putImageData(pixels, 0, 0);
  return scale;
}

/* A linear image as the server's PNG shows it: times 2^exposure, clamped, 8-bit sRGB. */
function drawLinear(canvas, image, exposure) {
  const scale = 2 ** exposure;
  const pixels = new ImageData(image.width, image.height);
  const n = image.width * image.height;
  for (let i = 0; i < n; i++) {
    for (let c = 0; c < 3; c++) pixels.data[4 * i + c] = linearToSrgb8(image.rgb[3 * i + c] * scale);
    pixels.data[4 * i + 3] = 255;
  }
  canvas.width = image.width;
  canvas.height = image.height;
  canvas.getContext('2d').putImageData(pixels, 0, 0);
}

/* ------------------------------------------------------------------------------------
 * Reference: the shown render's scene with the path tracer, as a background job, beside
 * the fast image with compare's PSNR and difference image.
 * ---------------------------------------------------------------------------------- */

const refJob = jobView('ref');
let referenceRun = null;
let shownReference = null; /* {fast, reference}: the EXR blobs the shown numbers come from */

function setRefStatus(text, kind = '') {
  const status = $('ref-status');
  status.textContent = text;
  status.className = 'status' + (kind ? ' ' + kind : '');
}

/* The same scene with "method": "pt" and the reference spp; everything else kept (the
 * components too, so like is compared with like). "vrl_beams": "bounded" and "boundary":
 * "walks" are nn/table settings the path tracer refuses (it needs neither), so they go. */
function referenceScene(scene, spp) {
  const copy = structuredClone(scene);
  const render = copy.render && typeof copy.render === 'object' ? copy.render : (copy.render = {});
  render.method = 'pt';
  render.spp = spp;
  if (render.vrl_beams === 'bounded') delete render.vrl_beams;
  if (render.boundary === 'walks') delete render.boundary;
  return copy;
}

function cancelReference({ quiet = false } = {}) {
  const run = referenceRun;
  if (!run) return;
  referenceRun = null;
  run.controller.abort();
  if (run.job) deleteJob(run.job.self);
  refJob.hide();
  $('ref-cancel').disabled = true;
  if (!quiet) setRefStatus('Reference cancelled.');
}

async function startReference() {
  const entry = shownEntry;
  if (!entry || entry.preview) return;
  const sppInput = $('ref-spp');
  const spp = Number(sppInput.value);
  if (!Number.isInteger(spp) || !sppInput.checkValidity()) {
    sppInput.setAttribute('aria-invalid', 'true');
    setRefStatus('The reference spp must be a whole number in range.', 'error');
    return;
  }
  sppInput.removeAttribute('aria-invalid');
  cancelReference({ quiet: true });
  const scene = parseSceneText(entry.sceneText);
  const run = { controller: new AbortController(), job: null, entry };
  referenceRun = run;
  const signal = run.controller.signal;
  const current = () => referenceRun === run && !signal.aborted;
  const onWait = (seconds) => { if (current()) setRefStatus(`Server busy (retry after ${seconds} s); waiting…`, 'busy'); };
  $('ref-cancel').disabled = false;
  $('ref-result').hidden = true;
  try {
    setRefStatus(entry.exr ? 'Submitting the reference…' : 'Getting the fast image as float EXR…', 'busy');
    const fastBlob = await entryExr(entry, { signal, retry: true, onWait });
    if (!current()) return;
    setRefStatus(`Reference: pt at ${spp} spp, submitting…`, 'busy');
    const refText = sceneText(referenceScene(scene, spp));
    const response = await sendWithRetry(() => postScene(refText, 'image/x-exr', { signal, async: true }), { retry: true, signal, onWait });
    let refBlob;
    if (response.status === 202) {
      const job = await response.json();
      run.job = jobUrls(response, job);
      refJob.start('queued');
      refJob.event('state', job);
      setRefStatus(`Reference: pt at ${spp} spp, running as a background job…`, 'busy');
      const final = await followJob(run.job, (name, data) => refJob.event(name, data), signal);
      if (!current()) return;
      if (final.event !== 'done') {
        const problem = final.job && final.job.error;
        throw new Error(final.event === 'cancelled' ? 'the reference job was cancelled' : `the reference job failed: ${(problem && (problem.detail || problem.title)) || 'no reason given'}`);
      }
      refJob.finish(1);
      const image = await fetch(run.job.image, { headers: { Accept: 'image/x-exr' }, signal });
      if (!image.ok) throw await problemError(image);
      refBlob = await image.blob();
    } else if (response.ok) {
      refBlob = await response.blob(); /* a server without jobs answered directly */
    } else throw await problemError(response);
    if (!current()) return;
    setRefStatus('Comparing…', 'busy');
    const [fast, reference] = await Promise.all([decodeExr(await fastBlob.arrayBuffer()), decodeExr(await refBlob.arrayBuffer())]);
    if (!current()) return;
    if (fast.width !== reference.width || fast.height !== reference.height) {
      throw new Error(`sizes differ: fast ${fast.width}×${fast.height}, reference ${reference.width}×${reference.height}`);
    }
    shownReference = { fast: fastBlob, reference: refBlob };
    showReference(entry, scene, spp, fast, reference);
    setRefStatus(`Reference done: pt at ${spp} spp against render #${entry.id}.`, 'ok');
  } catch (error) {
    if (!current() || isAbort(error)) return;
    const detail = error.problem ? `${error.problem.title || error.status}: ${error.problem.detail || ''}` : messageOf(error);
    setRefStatus(`Reference failed: ${detail}`, 'error');
  } finally {
    if (referenceRun === run) {
      referenceRun = null;
      $('ref-cancel').disabled = true;
      refJob.hide();
    }
  }
}

const formatDb = (v) => (v === Infinity ? '∞' : Number.isFinite(v) ? `${v.toFixed(2)} dB` : '—');
const formatSig = (v) => (Number.isFinite(v) ? Number(v.toPrecision(4)).toString() : '—');

function showReference(entry, scene, spp, fast, reference) {
  const exposure = scene.render && Number.isFinite(scene.render.exposure) ? scene.render.exposure : 0;
  $('ref-fast').src = entry.url;
  $('ref-fast').alt = `The fast render #${entry.id}: ${entry.caption}`;
  $('ref-fast-caption').textContent = `fast: #${entry.id} ${entry.caption}`;
  drawLinear($('ref-image'), reference, exposure);
  $('ref-image-caption').textContent = `reference: pt, ${spp} spp`;
  const metrics = compareImages(fast, reference);
  const scale = drawDifference($('ref-diff'), fast, reference);
  $('ref-diff-caption').textContent = `|fast − reference|, channel mean, white = ${formatSig(scale)}`;
  const rows = [
    ['psnr', 'PSNR', metrics.psnr, formatDb],
    ['rmse', 'RMSE', metrics.rmse, formatSig],
    ['relerr', 'mean relative error', metrics.relerr, formatSig],
  ];
  const body = document.querySelector('#ref-metrics tbody');
  body.replaceChildren(...rows.map(([key, label, values, format]) => {
    const cells = [values[3], values[0], values[1], values[2]].map((v) => {
      const td = el('td', { class: 'num', textContent: format(v) });
      td.dataset.value = String(v);
      return td;
    });
    const tr = el('tr', {}, el('th', { scope: 'row', textContent: label }), ...cells);
    tr.dataset.key = key;
    return tr;
  }), el('tr', {}, el('th', { scope: 'row', textContent: 'peak (reference max) · max |diff|' }),
    el('td', { class: 'num', colSpan: 4, textContent: `${formatSig(metrics.peak)} · ${formatSig(metrics.maxAbs)}` })));
  $('ref-result').hidden = false;
}

/* ------------------------------------------------------------------------------------
 * Sweeps: POST /v1/sweeps with a grid over one or two parameters of the chosen material,
 * progress from its events, the contact sheet fetched again as variants finish.
 * ---------------------------------------------------------------------------------- */

const sweepJob = jobView('sweep');
let sweepRun = null;
let maxSweepVariants = 256;
const SWEEP_LABELS = { g: 'g', ior: 'ior', albedo: 'albedo', mfp: 'mfp', scale: 'scale' };

function setSweepStatus(text, kind = '') {
  const status = $('sweep-status');
  status.textContent = text;
  status.className = 'status' + (kind ? ' ' + kind : '');
}

/* "0.2, 0.5 0.8" -> [0.2, 0.5, 0.8]; null when empty or when a part is not a number. */
function parseValueList(text) {
  const parts = text.split(/[\s,;]+/).filter(Boolean);
  if (parts.length === 0) return null;
  const values = parts.map(Number);
  return values.every(Number.isFinite) ? values : null;
}

/* The chosen axes [{param, values, input}], the inputs marked; null when one is invalid. */
function sweepAxes({ mark = true } = {}) {
  const axes = [];
  for (const k of [1, 2]) {
    const param = $(`sweep-param-${k}`).value;
    const input = $(`sweep-values-${k}`);
    if (!param) { input.removeAttribute('aria-invalid'); continue; }
    const values = parseValueList(input.value);
    if (mark) {
      if (values) input.removeAttribute('aria-invalid');
      else input.setAttribute('aria-invalid', 'true');
    }
    if (!values) return null;
    axes.push({ param, values, input });
  }
  if (axes.length === 2 && axes[0].param === axes[1].param) return null;
  return axes;
}

function updateSweepCount() {
  const axes = sweepAxes({ mark: false });
  const note = $('sweep-count');
  if (!axes) {
    const same = $('sweep-param-1').value === $('sweep-param-2').value;
    note.textContent = same ? 'choose two different parameters' : 'values: numbers separated by commas or spaces';
    return;
  }
  const total = axes.reduce((n, a) => n * a.values.length, 1);
  note.textContent = `${axes.map((a) => a.values.length).join(' × ')} = ${total} variant${total === 1 ? '' : 's'}`
    + (total > maxSweepVariants ? ` (at most ${maxSweepVariants})` : '');
}

/* The JSON value a sweep writes for `param` = v: g, ior and scale as they are; albedo and
 * mfp name the largest channel, and the other channels follow it as the sliders do with
 * "move together" (same slider distance: ratios of 1 - albedo, or of mfp, kept). A value
 * out of range is sent as it is, for the server to report. */
function sweepOverride(param, v, material) {
  if (param !== 'albedo' && param !== 'mfp') return v;
  const base = materialOptics(material)[param];
  if (!base) return v;
  const top = base.indexOf(Math.max(...base));
  if (param === 'albedo') {
    if (!(v >= 0 && v < 1)) return v;
    const spec = CHANNEL_FIELDS.albedo;
    const slider = (a) => Math.min(5, spec.toSlider(a));
    const delta = slider(v) - slider(base[top]);
    return compactColor(base.map((b, c) => (c === top ? v : spec.fromSlider(Math.max(0, slider(b) + delta)))));
  }
  if (!(v > 0)) return v;
  return compactColor(base.map((b, c) => (c === top ? v : Number(((b * v) / base[top]).toPrecision(3)))));
}

/* Fetches the sheet again (at most one fetch at a time; a request meanwhile makes one more
 * afterwards) and shows it. The sheet is fetched, not given to <img> by address, so that no
 * cache can show an old one. */
function reloadSheet(run) {
  if (run.sheetLoading) {
    run.sheetAgain = true;
    return run.sheetLoading;
  }
  run.sheetLoading = (async () => {
    try {
      do {
        run.sheetAgain = false;
        const response = await fetch(run.job.sheet, { cache: 'no-store', headers: { Accept: 'image/png' } });
        if (!response.ok || sweepRun !== run) break;
        const url = URL.createObjectURL(await response.blob());
        const img = $('sweep-sheet');
        const old = img.src;
        await new Promise((resolve) => {
          img.onload = resolve;
          img.onerror = resolve;
          img.src = url;
          img.hidden = false;
        });
        if (old.startsWith('blob:')) URL.revokeObjectURL(old);
        img.dataset.loads = String(Number(img.dataset.loads || 0) + 1);
      } while (run.sheetAgain && sweepRun === run);
    } catch { /* the next variant's sheet, or the last one, will do */ } finally {
      run.sheetLoading = null;
    }
  })();
  return run.sheetLoading;
}

/* The Cancel button (DELETE, then followed until the job says it stopped), or quietly
 * when a newer sweep replaces it. */
async function cancelSweep({ quiet = false } = {}) {
  const run = sweepRun;
  if (!run) return;
  if (quiet || !run.job) {
    sweepRun = null;
    run.controller.abort();
    if (run.job) deleteJob(run.job.self);
    sweepJob.hide();
    $('sweep-cancel').disabled = true;
    if (!quiet) setSweepStatus('Sweep cancelled.');
    return;
  }
  $('sweep-cancel').disabled = true;
  sweepJob.text('cancelling…');
  setSweepStatus('Cancelling the sweep…', 'busy');
  await deleteJob(run.job.self);
}

function showSweepProblem(problem, status, run) {
  const list = $('sweep-errors');
  const errors = Array.isArray(problem.errors) ? problem.errors : [];
  const labels = Object.fromEntries(run.pointers.map((pointer, k) => [escapePointerToken(pointer), run.axes[k]]));
  list.replaceChildren(...errors.filter((e) => e && typeof e === 'object').map((error) => {
    const pointer = typeof error.pointer === 'string' ? error.pointer : '';
    const item = el('li');
    const grid = /^\/grid\/([^/]+)\/(\d+)$/.exec(pointer);
    if (pointer.startsWith('/scene/') || pointer === '/scene') {
      item.append(pointerButton(pointer.slice('/scene'.length), run.text), ': ');
    } else if (grid && labels[grid[1]]) {
      const axis = labels[grid[1]];
      item.append(el('span', { class: 'pointer-static', textContent: `${SWEEP_LABELS[axis.param]} value ${Number(grid[2]) + 1} (${axis.values[Number(grid[2])]})` }), ': ');
    } else if (pointer) item.append(el('span', { class: 'pointer-static', textContent: pointer }), ': ');
    item.append(String(error.detail || ''));
    return item;
  }));
  setSweepStatus(`Sweep refused: ${problem.title || status}${problem.detail ? ` (${problem.detail})` : ''}.`, 'error');
}

async function startSweep() {
  $('sweep-errors').replaceChildren();
  const text = editor.value;
  const scene = parseSceneText(text);
  if (!scene) { setSweepStatus('The scene text is not valid JSON; fix it first.', 'error'); return; }
  const name = controls.material.value;
  const material = name && scene.materials && scene.materials[name];
  if (!material || typeof material !== 'object') { setSweepStatus('Choose a medium material in the quick controls first.', 'error'); return; }
  const axes = sweepAxes();
  if (!axes) {
    setSweepStatus($('sweep-param-1').value === $('sweep-param-2').value ? 'Choose two different parameters.' : 'The values must be numbers separated by commas or spaces.', 'error');
    return;
  }
  const total = axes.reduce((n, a) => n * a.values.length, 1);
  if (total > maxSweepVariants) { setSweepStatus(`${total} variants: the server takes at most ${maxSweepVariants}.`, 'error'); return; }
  /* albedo and mfp cannot be mixed with sigma_s / sigma_a: convert, as the sliders do. */
  if (axes.some((a) => a.param === 'albedo' || a.param === 'mfp')) toTableForm(material);
  const grid = {};
  for (const axis of axes) {
    grid[`/materials/${escapePointerToken(name)}/${axis.param}`] = axis.values.map((v) => sweepOverride(axis.param, v, material));
  }
  await cancelSweep({ quiet: true });
  const run = { controller: new AbortController(), job: null, axes, pointers: Object.keys(grid), total, finished: 0, text, started: performance.now() };
  sweepRun = run;
  const signal = run.controller.signal;
  const current = () => sweepRun === run && !signal.aborted;
  $('sweep-cancel').disabled = false;
  setSweepStatus(`Submitting ${total} variant${total === 1 ? '' : 's'}…`, 'busy');
  try {
    const response = await sendWithRetry(() => fetch('/v1/sweeps', {
      method: 'POST', headers: { 'Content-Type': 'application/json', Accept: 'application/json' }, body: JSON.stringify({ scene, grid }), signal,
    }), { retry: true, signal, onWait: (s) => { if (current()) setSweepStatus(`Server busy (retry after ${s} s); waiting…`, 'busy'); } });
    if (!current()) return;
    if (response.status !== 202) {
      const problem = await readProblem(response);
      if (response.status === 404 || response.status === 405) setSweepStatus(`This server has no sweeps (POST /v1/sweeps: ${response.status}).`, 'error');
      else showSweepProblem(problem, response.status, run);
      return;
    }
    const job = await response.json();
    run.job = jobUrls(response, job, '/v1/sweeps');
    sweepJob.start('queued');
    sweepJob.event('state', job);
    setSweepStatus(`Sweep of ${total} running as a background job…`, 'busy');
    reloadSheet(run);
    let variant = null;
    const final = await followJob(run.job, (event, data) => {
      if (event === 'variant_start') {
        variant = data.index;
        return;
      }
      if (event === 'variant_end') {
        run.finished++;
        reloadSheet(run);
        return;
      }
      const prefix = variant === null ? '' : `variant ${Math.min(run.finished + 1, total)}/${total} (#${variant}) · `;
      sweepJob.event(event, data, prefix);
    }, signal);
    if (!current()) return;
    sweepJob.finish(final.event === 'done' ? 1 : 0);
    await reloadSheet(run);
    const seconds = ((performance.now() - run.started) / 1000).toFixed(1);
    if (final.event === 'done') setSweepStatus(`Sweep done: ${total} variant${total === 1 ? '' : 's'} in ${seconds} s.`, 'ok');
    else if (final.event === 'cancelled') setSweepStatus(`Sweep cancelled after ${run.finished} of ${total} variants.`);
    else {
      const problem = final.job && final.job.error;
      setSweepStatus(`Sweep failed: ${(problem && (problem.detail || problem.title)) || 'no reason given'}.`, 'error');
    }
  } catch (error) {
    if (!current() || isAbort(error)) return;
    setSweepStatus(`Sweep failed: ${messageOf(error)}`, 'error');
  } finally {
    if (sweepRun === run) {
      sweepRun = null;
      $('sweep-cancel').disabled = true;
      sweepJob.hide();
    }
  }
}

/* ------------------------------------------------------------------------------------
 * Server info footer
 * ---------------------------------------------------------------------------------- */

function deviceName(device) {
  if (typeof device === 'string') return device;
  if (device && typeof device === 'object') return device.name || device.device_name || 'none';
  return 'unknown';
}

function applyLimits(limits) {
  if (!limits || typeof limits !== 'object') return;
  const side = limits.max_image_side || limits.max_width;
  if (Number.isInteger(side)) { controls.width.max = side; controls.height.max = limits.max_height || side; }
  if (Number.isInteger(limits.max_spp)) { controls.spp.max = limits.max_spp; $('ref-spp').max = limits.max_spp; }
  if (Number.isInteger(limits.max_sweep_variants)) { maxSweepVariants = limits.max_sweep_variants; updateSweepCount(); }
}

async function loadInfo() {
  const target = $('info-text');
  try {
    const response = await fetch('/v1/info', { headers: { Accept: 'application/json' } });
    if (!response.ok) throw new Error(`HTTP ${response.status}`);
    const info = await response.json();
    /* device: {name, driver, driver_info, api_version, is_cpu, ...}; when the server has
     * no render context, name is null and status/error say why. */
    const device = info.device && typeof info.device === 'object' ? info.device : {};
    const driver = [device.driver, device.driver_info].filter((s) => typeof s === 'string' && s).join(' ');
    const parts = [`nscatter ${info.version || '?'} · device `, el('strong', { id: 'info-device', textContent: deviceName(info.device) })];
    if (driver) parts.push(` · driver ${driver}`);
    if (device.api_version) parts.push(` · Vulkan ${device.api_version}`);
    if (info.ready === false) parts.push(` · not ready: ${device.error || device.status || 'no render context'}`);
    target.replaceChildren(...parts);
    applyLimits(info.limits);
    applyMethods(info.methods);
  } catch (error) {
    target.textContent = `Server info unavailable (${error.message}).`;
  }
}

/* ------------------------------------------------------------------------------------
 * Wiring
 * ---------------------------------------------------------------------------------- */

function init() {
  const saved = storageGet();
  setEditorText(saved && saved.trim() ? saved : sceneText(DEFAULT_SCENE));

  let typingTimer = null;
  editor.addEventListener('input', () => {
    storageSet(editor.value);
    clearTimeout(typingTimer);
    typingTimer = setTimeout(readControls, 250);
  });
  for (const type of ['keyup', 'click', 'select', 'focus']) editor.addEventListener(type, updateCursorPosition);

  document.addEventListener('keydown', (event) => {
    if ((event.ctrlKey || event.metaKey) && event.key === 'Enter') {
      event.preventDefault();
      startRender('key');
    }
  });
  $('render').addEventListener('click', () => startRender('button'));
  $('cancel').addEventListener('click', cancelRender);
  $('reset').addEventListener('click', () => { setEditorText(sceneText(DEFAULT_SCENE)); clearProblem(); });
  $('format').addEventListener('click', () => {
    const scene = parseEditor();
    if (scene) setEditorText(sceneText(scene));
    else setStatus('Cannot format: the text is not valid JSON.', 'error');
  });

  controls.material.addEventListener('change', () => { const s = parseEditor(); if (s) readMaterialControls(s); });
  controls.preset.addEventListener('change', onPresetChange);
  for (const slider of [controls.g, controls.ior, controls.scale]) {
    slider.addEventListener('input', onSliderInput);
    slider.addEventListener('change', onSliderChange);
  }
  const camera = (scene) => (scene.camera = scene.camera && typeof scene.camera === 'object' ? scene.camera : {});
  const settings = (scene) => (scene.render = scene.render && typeof scene.render === 'object' ? scene.render : {});
  controls.width.addEventListener('change', (e) => onIntegerChange(e, (s, v) => { camera(s).width = v; }));
  controls.height.addEventListener('change', (e) => onIntegerChange(e, (s, v) => { camera(s).height = v; }));
  controls.spp.addEventListener('change', (e) => onIntegerChange(e, (s, v) => { settings(s).spp = v; }));
  for (const box of controls.components) box.addEventListener('change', onComponentsChange);
  controls.method.addEventListener('change', onMethodChange);
  for (const choice of controls.scatterChoices) choice.select.addEventListener('change', () => onScatterChoiceChange(choice));
  for (const field of controls.scatterNumbers) field.input.addEventListener('change', () => onScatterNumberChange(field));
  controls.exposure.addEventListener('input', onSliderInput);
  controls.exposure.addEventListener('change', onExposureChange);
  for (const set of Object.values(controls.channels)) {
    for (const slider of set.sliders) {
      slider.addEventListener('input', onChannelInput);
      slider.addEventListener('change', onChannelChange);
    }
  }

  $('zoom').addEventListener('change', applyZoom);
  $('download-png').addEventListener('click', () => shownEntry && downloadBlob(shownEntry.blob, 'png'));
  $('download-exr').addEventListener('click', downloadExr);
  $('load-scene').addEventListener('click', () => shownEntry && setEditorText(shownEntry.sceneText));
  $('reference').addEventListener('click', startReference);
  $('ref-cancel').addEventListener('click', () => cancelReference());
  $('ref-download-fast').addEventListener('click', () => shownReference && downloadBlob(shownReference.fast, 'exr', 'fast'));
  $('ref-download-reference').addEventListener('click', () => shownReference && downloadBlob(shownReference.reference, 'exr', 'reference'));
  $('sweep-start').addEventListener('click', startSweep);
  $('sweep-cancel').addEventListener('click', () => cancelSweep());
  for (const id of ['sweep-param-1', 'sweep-param-2', 'sweep-values-1', 'sweep-values-2']) {
    $(id).addEventListener(id.includes('values') ? 'input' : 'change', updateSweepCount);
  }
  updateSweepCount();

  loadInfo();
}

init();
