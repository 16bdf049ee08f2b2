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
  { key: 'vrls', id: 'vrls', integer: true },
  { key: 'gather_tile', id: 'gather-tile', integer: true },
  { key: 'gather_levels', id: 'gather-levels', integer: true },
  { key: 'gather_tolerance', id: 'gather-tolerance', integer: false },
  { key: 'single_samples', id: 'single-samples', integer: true },
  { key: 'cull_solid_angle', id: 'cull-solid-angle', integer: false },
];
/* The scattering choices: a select per render key, with the server's default. */
const SCATTER_CHOICES = [
  { key: 'accumulation', id: 'accumulation', fallback: 'exact' },
  { key: 'vrl_beams', id: 'vrl-beams', fallback: 'endless' },
];

/* X-Nscatter-Stats keys shown under the timings, in this order. */
const COUNT_ROWS = [
  { key: 'vrl_count', label: 'VRLs' },
  { key: 'vrl_paths', label: 'light paths traced' },
  { key: 'camera_segments', label: 'camera segments in media' },
  { key: 'gather_segments', label: 'segments gathered' },
  { key: 'tiles_interpolated', label: 'tiles interpolated' },
  { key: 'interactions', label: 'VRL–segment interactions' },
  { key: 'cells_culled', label: 'grid cells culled' },
  { key: 'cells_represented', label: 'grid cells by representative' },
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
  for (const choice of controls.scatterChoices) {
    setSelectValue(choice.select, render[choice.key] === undefined ? choice.fallback : String(render[choice.key]));
  }
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

/* Applies `change` to the parsed scene and writes it back formatted. */
function editScene(change) {
  const scene = parseEditor();
  if (scene === null) return;
  change(scene);
  setEditorText(sceneText(scene), { keepControls: false });
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
let rendering = false;
let nextId = 1;

async function postScene(text, accept) {
  return fetch('/v1/renders', {
    method: 'POST',
    headers: { 'Content-Type': 'application/json', Accept: accept },
    body: text,
  });
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

async function render() {
  if (rendering) return;
  rendering = true;
  readControls(); /* the controls may still be waiting for the typing pause */
  const button = $('render');
  button.setAttribute('aria-busy', 'true');
  button.disabled = true;
  button.textContent = 'Rendering…';
  setStatus('Rendering…', 'busy');
  const text = editor.value;
  const started = performance.now();
  try {
    const response = await postScene(text, 'image/png');
    const roundTripMs = performance.now() - started;
    if (!response.ok) {
      const problem = await readProblem(response);
      if (response.status === 503) {
        const retry = Number.parseInt(response.headers.get('Retry-After') || '', 10);
        showBusy(problem, Number.isFinite(retry) && retry >= 0 ? retry : 1);
      } else {
        showProblem(problem, response.status, text);
        setStatus(`Render failed: ${problem.title || response.status}.`, 'error');
      }
      return;
    }
    const blob = await response.blob();
    const entry = {
      id: nextId++,
      sceneText: text,
      blob,
      url: URL.createObjectURL(blob),
      timings: parseServerTiming(response.headers.get('Server-Timing')),
      device: response.headers.get('X-Nscatter-Device') || '(not reported)',
      counts: parseCounts(response.headers.get('X-Nscatter-Stats')),
      roundTripMs,
      caption: describeScene(text),
      when: new Date(),
    };
    clearProblem();
    addToHistory(entry);
    await showEntry(entry);
    setStatus(`Rendered in ${formatMs(roundTripMs)} ms (round trip).`, 'ok');
  } catch (error) {
    showProblem({ title: 'Cannot reach the server', detail: String(error && error.message ? error.message : error) }, 0, text);
    setStatus('Render failed: the server did not answer.', 'error');
  } finally {
    rendering = false;
    button.removeAttribute('aria-busy');
    button.disabled = false;
    button.textContent = 'Render';
  }
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
  shownEntry = entry;
  $('viewer').classList.remove('stale');
  const image = $('image');
  image.alt = `Render #${entry.id}: ${entry.caption}`;
  const loaded = new Promise((resolve) => {
    image.onload = resolve;
    image.onerror = resolve;
  });
  image.src = entry.url;
  image.hidden = false;
  $('placeholder').hidden = true;
  await loaded;
  $('image-meta').textContent = `#${entry.id} · ${image.naturalWidth}×${image.naturalHeight} · ${entry.caption}`;
  applyZoom();
  showTimings(entry);
  showCounts(entry);
  $('device').textContent = entry.device;
  for (const id of ['download-png', 'download-exr', 'load-scene']) $(id).disabled = false;
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
  image.style.width = zoom === 'fit' || !image.naturalWidth ? '' : `${image.naturalWidth * Number(zoom)}px`;
}

function downloadBlob(blob, extension) {
  const stamp = new Date().toISOString().replace(/[:.]/g, '-').slice(0, 19);
  const link = el('a', { href: URL.createObjectURL(blob), download: `nscatter-${stamp}.${extension}` });
  document.body.append(link);
  link.click();
  link.remove();
  setTimeout(() => URL.revokeObjectURL(link.href), 10000);
}

/* EXR cannot be shown in a browser, so it is rendered on demand for the scene shown. */
async function downloadExr() {
  if (!shownEntry) return;
  const button = $('download-exr');
  button.disabled = true;
  button.setAttribute('aria-busy', 'true');
  setStatus('Rendering EXR…', 'busy');
  try {
    const response = await postScene(shownEntry.sceneText, 'image/x-exr');
    if (!response.ok) {
      const problem = await readProblem(response);
      if (response.status === 503) {
        const retry = Number.parseInt(response.headers.get('Retry-After') || '', 10);
        showBusy(problem, Number.isFinite(retry) ? retry : 1);
      } else showProblem(problem, response.status, shownEntry.sceneText);
      setStatus('EXR render failed.', 'error');
      return;
    }
    downloadBlob(await response.blob(), 'exr');
    setStatus('EXR downloaded.', 'ok');
  } catch (error) {
    showProblem({ title: 'Cannot reach the server', detail: String(error && error.message ? error.message : error) }, 0, shownEntry.sceneText);
    setStatus('EXR render failed: the server did not answer.', 'error');
  } finally {
    button.disabled = false;
    button.removeAttribute('aria-busy');
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
  if (Number.isInteger(limits.max_spp)) controls.spp.max = limits.max_spp;
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
      render();
    }
  });
  $('render').addEventListener('click', render);
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

  loadInfo();
}

init();
