// The viewer: connects to the server that served this page, loads the scene and its render
// meshes, and each animation frame draws the interpolated contact: tool pose, the mesh bent by
// the Bézier profile (paper §3.3), the deformed-region ring, the force arrow and plot.
//
// Reading order: `init()` builds everything once; `onMessage()` takes the server's messages;
// `animate()` runs per screen refresh and allocates nothing; `testhook.js` is what the browser
// tests read (installed only under automation). When the server replays a recording, the timeline panel (`replay.js`)
// shows where the replay stands and sends the instructor's pause, play, seek and speed.
//
// Access (`access.js`): the token of the page's link is presented on every connection and with
// every fetch from the server; `hello` says the role it grants (instructor or observer), shown
// in the panel. When the server wants a token the viewer has not got, or refuses the one it
// has (WebSocket close 4401, HTTP 401), the viewer stops and asks for the link in a prompt.

import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

import { AccessPrompt, TokenKeeper } from './access.js';
import { MeshDeformer, profileSetup, surfaceFamilyFromJson, toolFromJson } from './deformation.js';
import { ForcePlot } from './forceplot.js';
import { PlayoutBuffer, RenderedContact } from './interpolation.js';
import { parseRenderMesh } from './mesh.js';
import {
  CONTACT_FLAGS,
  deviceStatusMessage,
  encodeMark,
  forceFeedbackOf,
  ViewerConnection,
  accessOf,
  contactModelOf,
  validateMessage,
  webSocketUrl,
} from './protocol.js';
import { ReplayTimeline } from './replay.js';
import { StationList, archiveOf, stationOf, withStation } from './lab.js';
import { installTestHook } from './testhook.js';

/**
 * Flags that mean the force is not what the model says (shown in red rather than amber);
 * `pushed_through`: a hand has pushed the tool past what the collision measures and the contact
 * is held on the side it entered, which an instructor should see at once.
 */
const SEVERE_FLAGS = new Set(['device_fault', 'saturated', 'degenerate_normal', 'pushed_through']);
const PLAYOUT_DELAY_MS = 50;
/**
 * The tool's opacity while it touches the object: the dent it makes is under it, and from most
 * viewpoints an opaque tool hides it entirely.
 */
const TOOL_OPACITY_IN_CONTACT = 0.3;
/** The depression map's colour at full scale (multiplies the object's). */
const DEPRESSION_COLOR = [0.25, 0.45, 1.0];
/** How often a hub's page asks for its station list again. */
const STATION_LIST_REFRESH_MS = 2000;
const TIMING_SAMPLES = 120;

const dom = {};
const view = {
  renderer: null,
  scene: null,
  camera: null,
  controls: null,
  toolGroup: null,
  /**
   * The section view's clipping planes, shared by the objects' materials: empty when off, one
   * plane through the contact along its normal, facing the camera, when on.
   */
  sectionPlanes: [],
  sectionPlane: null,
  /** The tool's materials: see-through while in contact, so the dent under it shows. */
  toolMaterials: [],
  ring: null,
  arrow: null,
  objectsGroup: null,
};
const state = {
  sceneJson: null,
  sceneKey: '',
  tool: null,
  /** The `fem` profile's family when the scene draws it (`render_profile`), else null: the paper's Bézier. */
  surface: null,
  meshes: [], // {name, positions, normals, rest, deformer, geometry, mesh, objectPosition, objectInverse}
  sessionId: null,
  lastStats: null,
  loadError: null,
  sceneLoads: 0,
  /** The active contact model as shown (see `contactModelOf`). */
  contactModel: null,
  contactFrames: 0,
  /** While paused the view keeps drawing the last interpolated contact (inspection, tests). */
  paused: false,
  /** What the last `hello` granted: `instructor` or `observer`, and `live` or `replay`. */
  role: null,
  /** The lab station the address names (`?station=`, on a hub's page); null on a station's. */
  station: stationOf(window.location),
  /** The station's archived recording the address names (`&archive=`), replayed; or null. */
  archive: archiveOf(window.location),
  /** Whether the object is cut open through the contact (the section view). */
  section: false,
  /** Where the section passes: the last contact point and its normal. */
  sectionPoint: [0, 0, 0],
  sectionNormal: [0, 1, 0],
  /** Whether the render mesh is coloured by how far each vertex moved (the depression map). */
  depressionMap: false,
  /** The depression at which the map reaches its full colour: 5 mm. */
  depressionScaleM: 0.005,
  /** The instructors' marks by id: `{id, time_ns, note, point_m}`. */
  marks: new Map(),
  /** The last `metrics` message: the trainee's metrics, from the server. */
  lastMetrics: null,
  /** Whether the trainee feels the force (`hello.force_feedback`); true until a `hello` says. */
  forceFeedback: true,
  mode: null,
};
const buffer = new PlayoutBuffer({ delayMs: PLAYOUT_DELAY_MS });
const rendered = new RenderedContact();
const timings = {
  ms: new Float64Array(TIMING_SAMPLES),
  sorted: new Float64Array(TIMING_SAMPLES),
  count: 0,
  head: 0,
  moved: 0,
};
const frameTimes = { ms: new Float64Array(128), head: 0, count: 0 };
let plot = null;
let connection = null;
let timeline = null;
let stationList = null;
let keeper = null;
let prompt = null;

/** A fetch the server answered 401: the token sent (null: none) was missing or not valid. */
class Unauthorized extends Error {
  constructor(url, token) {
    super(`GET ${url} answered 401: a token is needed`);
    this.name = 'Unauthorized';
    this.token = token;
  }
}

// Scratch objects reused every frame.
const scratch = {
  contact: {
    inContact: false,
    depthM: 0,
    contactRadiusM: 0,
    deformedRadiusM: 0,
    point: new Float64Array(3),
    normal: new Float64Array(3),
  },
  v: new THREE.Vector3(),
  n: new THREE.Vector3(),
  p: new THREE.Vector3(),
  q: new THREE.Quaternion(),
  up: new THREE.Vector3(0, 1, 0),
  profile: {},
};

function init() {
  for (const id of [
    'view',
    'webgl-message',
    'conn-state',
    'contact-state',
    'conn-error',
    'v-depth',
    'v-rd',
    'v-force',
    'v-material',
    'v-device',
    'v-model',
    'model-details',
    'm-corrections',
    'm-depth',
    'm-inclination',
    'm-source',
    'mode',
    'feedback',
    'role',
    'token-prompt',
    'token-prompt-detail',
    'token-input',
    'token-connect',
    'token-prompt-note',
    'replay-hint',
    'replay-refused',
    'replay-panel',
    'replay-play',
    'replay-speed',
    'replay-scrubber',
    'replay-time',
    'replay-file',
    'replay-gaps',
    'map-toggle',
    'map-scale',
    'section-toggle',
    'mark-form',
    'mark-note',
    'mark-list',
    't-peak',
    't-above',
    't-contact',
    't-path',
    't-pushes',
    't-jerk',
    't-flags',
    'stations-panel',
    'stations-list',
    'flags',
    's-rate',
    's-jitter',
    's-compute',
    's-overruns',
    's-viewers',
    's-device',
    'w-rx',
    'w-fps',
    'w-deform',
    'w-moved',
    'w-delay',
    'force-plot',
  ]) {
    dom[id] = document.getElementById(id);
  }
  dom.flagChips = CONTACT_FLAGS.map((name) => {
    const chip = document.createElement('span');
    chip.className = 'flag';
    chip.textContent = name.replaceAll('_', ' ');
    chip.title = name;
    dom.flags.appendChild(chip);
    return chip;
  });
  dom['w-delay'].textContent = `${PLAYOUT_DELAY_MS} ms`;
  plot = new ForcePlot(dom['force-plot'], { pixelRatio: Math.min(window.devicePixelRatio || 1, 2) });

  initThree();
  // Only under automation (the browser tests): see testhook.js.
  installTestHook({
    state,
    view,
    dom,
    rendered,
    buffer,
    timings,
    get connection() {
      return connection;
    },
    get timeline() {
      return timeline;
    },
    get keeper() {
      return keeper;
    },
    get prompt() {
      return prompt;
    },
    get plot() {
      return plot;
    },
    get stationList() {
      return stationList;
    },
    animate,
    flagNames,
    fps,
    median,
    setDepressionMap,
    setSection,
    sectionPlane: () => view.sectionPlane,
  });

  keeper = new TokenKeeper({ storage: sessionStorageOrNull() });
  keeper.adopt(window.location, window.history);
  prompt = new AccessPrompt({
    panel: dom['token-prompt'],
    detail: dom['token-prompt-detail'],
    input: dom['token-input'],
    button: dom['token-connect'],
    note: dom['token-prompt-note'],
    onToken: useToken,
  });
  // A new link opened in this tab changes only the fragment: the page is not reloaded.
  window.addEventListener('hashchange', () => {
    const token = keeper.takeFragment(window.location, window.history);
    if (token !== null) useToken(token);
  });

  connection = new ViewerConnection({
    url: withStation(webSocketUrl(window.location), state.station, state.archive),
    token: keeper.token,
    onMessage,
    onStateChange: onConnectionState,
  });
  timeline = new ReplayTimeline({
    panel: dom['replay-panel'],
    playButton: dom['replay-play'],
    speedSelect: dom['replay-speed'],
    scrubber: dom['replay-scrubber'],
    timeText: dom['replay-time'],
    fileText: dom['replay-file'],
    hintText: dom['replay-hint'],
    refusedText: dom['replay-refused'],
    gapLayer: dom['replay-gaps'],
    send: (text) => connection.send(text),
  });
  stationList = new StationList({
    panel: dom['stations-panel'],
    list: dom['stations-list'],
    fetchJson: async (url) => (await fetchFromServer(url)).json(),
    current: state.station,
    currentArchive: state.archive,
  });
  startStream();
  if (view.renderer) view.renderer.setAnimationLoop(animate);
  else
    requestAnimationFrame(function loop(t) {
      animate(t);
      requestAnimationFrame(loop);
    });
  window.addEventListener('resize', onWindowResize);
  dom['map-toggle'].addEventListener('change', () => setDepressionMap(dom['map-toggle'].checked));
  dom['section-toggle'].addEventListener('change', () => setSection(dom['section-toggle'].checked));
  dom['mark-form'].addEventListener('submit', (e) => {
    e.preventDefault();
    // The mark goes where the tool touches now, if it does.
    const point = rendered.valid && rendered.inContact ? [...rendered.point] : null;
    try {
      if (connection.send(encodeMark(dom['mark-note'].value, point))) dom['mark-note'].value = '';
    } catch (err) {
      dom['mark-note'].setCustomValidity(err.message);
      dom['mark-note'].reportValidity();
      dom['mark-note'].setCustomValidity('');
    }
  });
  setInterval(updatePanels, 250);
}

/**
 * Starts the stream: at once when the address names a station (on a hub) or the server is a
 * station; a hub's page without a station shows the list and waits for a pick.
 */
async function startStream() {
  let hub = false;
  try {
    hub = await stationList.refresh();
  } catch (e) {
    if (e instanceof Unauthorized) {
      sceneLoadFailed(e);
      return;
    }
    console.warn(`softhaptic: no station list: ${e.message}`);
  }
  if (hub) setInterval(() => stationList.refresh().catch(() => {}), STATION_LIST_REFRESH_MS);
  if (hub && state.station === null) {
    showConnectionState('pick a station');
    return;
  }
  connection.start();
  loadSceneOverHttp();
}

/** Creates the WebGL renderer and the static scene; without WebGL, says so and goes on. */
function initThree() {
  view.scene = new THREE.Scene();
  view.scene.background = new THREE.Color(0x14171c);
  view.camera = new THREE.PerspectiveCamera(40, window.innerWidth / window.innerHeight, 0.001, 10);
  view.camera.position.set(0.18, 0.16, 0.26);

  view.scene.add(new THREE.HemisphereLight(0xdde6ff, 0x2a2018, 1.2));
  const key = new THREE.DirectionalLight(0xffffff, 2.2);
  key.position.set(0.3, 0.6, 0.4);
  view.scene.add(key);
  const rim = new THREE.DirectionalLight(0x88aaff, 0.8);
  rim.position.set(-0.4, 0.2, -0.3);
  view.scene.add(rim);

  const grid = new THREE.GridHelper(0.4, 20, 0x3a4250, 0x262c36);
  grid.position.y = -0.08;
  view.scene.add(grid);

  view.objectsGroup = new THREE.Group();
  view.scene.add(view.objectsGroup);

  // The deformed-region ring: a thin unit annulus in the xz plane, scaled to R_d and turned to
  // the contact normal each frame. Drawn over the surface so the dimple cannot hide it.
  const ringGeometry = new THREE.RingGeometry(0.965, 1, 128, 1);
  ringGeometry.rotateX(-Math.PI / 2);
  view.ring = new THREE.Mesh(
    ringGeometry,
    new THREE.MeshBasicMaterial({
      color: 0xffa657,
      side: THREE.DoubleSide,
      depthTest: false,
      transparent: true,
      opacity: 0.95,
    }),
  );
  view.ring.renderOrder = 2;
  view.ring.visible = false;
  view.scene.add(view.ring);

  view.arrow = new THREE.ArrowHelper(new THREE.Vector3(0, 1, 0), new THREE.Vector3(), 0.02, 0x58a6ff, 0.008, 0.005);
  view.arrow.visible = false;
  // The arrow starts at the tip, inside the tool: draw it through the tool.
  for (const part of [view.arrow.line, view.arrow.cone]) {
    part.material.depthTest = false;
    part.material.transparent = true;
    part.renderOrder = 3;
  }
  view.scene.add(view.arrow);

  try {
    // On a software rasteriser (SwiftShader, llvmpipe: no GPU) multisampling costs more than the
    // mesh itself; drop it there and keep the frame rate.
    view.gpuName = webglRendererName();
    view.software = /swiftshader|llvmpipe|softpipe|software/i.test(view.gpuName ?? '');
    const renderer = new THREE.WebGLRenderer({ antialias: !view.software });
    renderer.setPixelRatio(Math.min(window.devicePixelRatio, view.software ? 1 : 2));
    renderer.setSize(window.innerWidth, window.innerHeight);
    dom.view.appendChild(renderer.domElement);
    // The section view clips the object's material only.
    renderer.localClippingEnabled = true;
    view.renderer = renderer;
    view.controls = new OrbitControls(view.camera, renderer.domElement);
    view.controls.target.set(0, 0, 0);
    view.controls.enableDamping = true;
  } catch (e) {
    view.renderer = null;
    dom['webgl-message'].hidden = false;
    console.warn(`softhaptic: WebGL unavailable (${e.message}); drawing panels only`);
  }
}

/** The WebGL implementation's name, or null when WebGL is unavailable. */
function webglRendererName() {
  const gl = document.createElement('canvas').getContext('webgl2');
  if (!gl) return null;
  const info = gl.getExtension('WEBGL_debug_renderer_info');
  const name = String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
  gl.getExtension('WEBGL_lose_context')?.loseContext();
  return name;
}

function onWindowResize() {
  plot.resize();
  if (!view.renderer) return;
  view.camera.aspect = window.innerWidth / window.innerHeight;
  view.camera.updateProjectionMatrix();
  view.renderer.setSize(window.innerWidth, window.innerHeight);
}

// ----- access: the token, the prompt, the role -----

/** This tab's sessionStorage, or null where the browser gives none (it may throw on access). */
function sessionStorageOrNull() {
  try {
    return window.sessionStorage ?? null;
  } catch {
    return null;
  }
}

/** A token from the prompt or a new link: kept, presented on a fresh connection at once. */
function useToken(token) {
  keeper.set(token);
  connection.setToken(token);
  connection.reconnectNow();
  loadSceneOverHttp();
}

/**
 * The server wants a token the viewer has not got (`needs_token`) or refused the one it
 * presented (`token_refused`): a refused token is forgotten, the connection stays closed, and
 * the prompt asks for the link.
 */
function requireToken(reason) {
  if (reason === 'token_refused') {
    keeper.forget();
    connection.setToken(null);
  }
  prompt.show(reason);
}

function onConnectionState(s, detail) {
  if (s === 'unauthorized') requireToken(detail.reason);
  showConnectionState(s, detail);
}

/**
 * GETs `url`; a URL of the page's own server carries the token, when the viewer has one, in an
 * `Authorization: Bearer` header (never to another origin). Throws `Unauthorized` on a 401.
 */
async function fetchFromServer(url) {
  const token = keeper.token;
  const ownServer = new URL(url, window.location.href).origin === window.location.origin;
  const init = token !== null && ownServer ? { headers: { Authorization: `Bearer ${token}` } } : {};
  const response = await fetch(url, init);
  if (response.status === 401) throw new Unauthorized(url, token);
  if (!response.ok) {
    const e = new Error(`GET ${url} answered ${response.status}`);
    e.status = response.status;
    throw e;
  }
  return response;
}

/** A failed load of the scene or a mesh: a 401 asks for the link, anything else is shown. */
function sceneLoadFailed(e) {
  if (e instanceof Unauthorized) {
    // An answer to a token that was replaced meanwhile says nothing about the new one.
    if (e.token !== keeper.token) return;
    const reason = e.token === null ? 'needs_token' : 'token_refused';
    connection.stop();
    requireToken(reason);
    showConnectionState('unauthorized', { reason });
    return;
  }
  state.loadError = `scene: ${e.message}`;
  console.warn(`softhaptic: ${state.loadError}`);
}

function showRole(role) {
  state.role = role;
  setBadge(dom.role, role ?? '—', role === 'instructor' ? 'active' : '');
  dom.role.title =
    role === 'instructor'
      ? 'instructor: watches, and moves a replay for everyone'
      : role === 'observer'
        ? 'observer: watches; the instructor moves a replay'
        : '';
}

/** Whether the trainee feels the force: an input-only device (a SpaceMouse) renders none. */
function showForceFeedback(felt) {
  state.forceFeedback = felt;
  setBadge(dom.feedback, felt ? 'felt' : 'not felt', felt ? '' : 'warn');
  dom.feedback.title = felt
    ? 'the haptic device renders the force to the trainee'
    : 'input-only device (SpaceMouse): the force is computed, shown and recorded, but the trainee does not feel it';
}

async function loadSceneOverHttp() {
  try {
    const response = await fetchFromServer(withStation('/api/scene', state.station, state.archive));
    const scene = validateMessage({ type: 'scene', ...(await response.json()) });
    await applyScene(scene);
  } catch (e) {
    // The WebSocket's scene message will try again.
    sceneLoadFailed(e);
  }
}

/**
 * The family of the `fem` deformation profile when the scene asks for it, else null (the paper's
 * Bézier, also what a scene without `render_profile` was drawn with). A family the viewer cannot
 * use falls back to the paper's profile rather than drawing nothing.
 */
function surfaceOf(scene) {
  if (scene.render_profile !== 'fem') return null;
  try {
    return surfaceFamilyFromJson(scene.calibration.surface);
  } catch (e) {
    console.warn(`render_profile "fem": ${e.message}; drawing the paper's profile`);
    return null;
  }
}

/** Builds the tool and loads the render meshes of a scene, once per distinct scene. */
async function applyScene(scene) {
  // The same scene arrives twice (GET /api/scene and the WebSocket); load it once.
  const key = JSON.stringify(scene, (k, v) => (k === 'type' ? undefined : v));
  if (key === state.sceneKey) return;
  state.sceneKey = key;
  state.sceneJson = scene;
  state.tool = toolFromJson(scene.tool);
  state.surface = surfaceOf(scene);
  plot.setPeakForce(scene.device.peak_force_n);
  dom['v-material'].textContent = `E ${formatPa(scene.material.youngs_modulus_pa)}, ν ${scene.material.poisson_ratio}`;
  const device = scene.device;
  dom['v-device'].textContent = device.name;
  dom['v-device'].title =
    `peak ${device.peak_force_n} N, continuous ${device.continuous_force_n} N, ` +
    `stiffness ≤ ${device.max_stiffness_n_per_m} N/m, damping ≤ ${device.damping_n_s_per_m} N·s/m`;
  showContactModel(contactModelOf(scene));
  buildTool(scene.tool);

  for (const m of state.meshes) {
    view.objectsGroup.remove(m.mesh);
    m.geometry.dispose();
  }
  state.meshes = [];
  let loaded;
  try {
    loaded = await Promise.all(
      scene.render_meshes.map(async (desc) => {
        const response = await fetchFromServer(desc.url);
        return { desc, data: parseRenderMesh(await response.arrayBuffer(), desc.name, desc.vertex_count) };
      }),
    );
  } catch (e) {
    // Let the next scene message (e.g. after a reconnection) try again.
    if (state.sceneKey === key) state.sceneKey = '';
    throw e;
  }
  if (key !== state.sceneKey) return; // a newer scene arrived while loading
  for (const { desc, data } of loaded) state.meshes.push(buildMesh(desc, data));
  state.loadError = null;
  state.sceneLoads++;
  frameCamera();
}

function buildTool(tool) {
  if (view.toolGroup) {
    view.scene.remove(view.toolGroup);
    view.toolGroup.traverse((o) => o.geometry?.dispose());
  }
  const group = new THREE.Group();
  // Transparent from the start (only the opacity changes with contact, no shader rebuild).
  const material = new THREE.MeshStandardMaterial({
    color: 0xc9d1d9,
    metalness: 0.6,
    roughness: 0.3,
    transparent: true,
  });
  const R = tool.radius_m;
  let tipLength;
  if (tool.shape === 'sphere') {
    // The tool frame's origin is the tip: the bottom of the sphere.
    const ball = new THREE.Mesh(new THREE.SphereGeometry(R, 48, 24), material);
    ball.position.y = R;
    group.add(ball);
    tipLength = R;
  } else {
    const height = R / Math.tan(tool.half_angle_rad);
    const cone = new THREE.Mesh(new THREE.ConeGeometry(R, height, 48, 1, false), material);
    cone.rotation.x = Math.PI; // apex down, at the origin
    cone.position.y = height / 2;
    group.add(cone);
    tipLength = height;
  }
  const shaftLength = 0.12;
  const shaft = new THREE.Mesh(
    new THREE.CylinderGeometry(R * 0.35, R * 0.35, shaftLength, 24),
    new THREE.MeshStandardMaterial({ color: 0x6e7681, metalness: 0.4, roughness: 0.5, transparent: true }),
  );
  shaft.position.y = tipLength + shaftLength / 2;
  group.add(shaft);
  view.toolMaterials = [material, shaft.material];
  view.toolGroup = group;
  view.scene.add(group);
}

function buildMesh(desc, data) {
  const positions = Float32Array.from(data.positions);
  const normals = Float32Array.from(data.normals);
  const geometry = new THREE.BufferGeometry();
  const positionAttr = new THREE.BufferAttribute(positions, 3);
  const normalAttr = new THREE.BufferAttribute(normals, 3);
  positionAttr.setUsage(THREE.DynamicDrawUsage);
  normalAttr.setUsage(THREE.DynamicDrawUsage);
  geometry.setAttribute('position', positionAttr);
  geometry.setAttribute('normal', normalAttr);
  // The depression map's colours, multiplied with the object's: white (no change) until it is on.
  const colors = new Float32Array(positions.length).fill(1);
  const colorAttr = new THREE.BufferAttribute(colors, 3);
  colorAttr.setUsage(THREE.DynamicDrawUsage);
  geometry.setAttribute('color', colorAttr);
  geometry.setIndex(new THREE.BufferAttribute(data.indices, 1));
  geometry.computeBoundingSphere();
  // The dimple stays inside the rest bounds grown by the deepest press; skip per-frame bounds.
  geometry.boundingSphere.radius *= 1.2;
  const mesh = new THREE.Mesh(
    geometry,
    new THREE.MeshStandardMaterial({
      color: 0xd98c8c,
      roughness: 0.55,
      metalness: 0.0,
      vertexColors: true,
      // Seen from inside too, where the section view cuts it open.
      side: THREE.DoubleSide,
      clippingPlanes: view.sectionPlanes,
    }),
  );
  const [px, py, pz] = desc.object_in_world.position_m;
  const [qx, qy, qz, qw] = desc.object_in_world.orientation;
  mesh.position.set(px, py, pz);
  mesh.quaternion.set(qx, qy, qz, qw).normalize();
  view.objectsGroup.add(mesh);
  return {
    name: desc.name,
    positions,
    normals,
    positionAttr,
    normalAttr,
    colors,
    colorAttr,
    rest: data.positions,
    restNormals: data.normals,
    deformer: new MeshDeformer(data.positions, data.normals),
    geometry,
    mesh,
    range: { start: 0, count: 0 },
    objectPosition: new THREE.Vector3(px, py, pz),
    objectInverse: mesh.quaternion.clone().invert(),
  };
}

/** Points the camera at the loaded meshes. */
function frameCamera() {
  const box = new THREE.Box3();
  for (const m of state.meshes) box.expandByObject(m.mesh);
  if (box.isEmpty()) return;
  const centre = box.getCenter(new THREE.Vector3());
  const size = box.getSize(new THREE.Vector3()).length();
  view.camera.position.set(centre.x + size * 0.55, centre.y + size * 0.5, centre.z + size * 0.85);
  view.camera.near = size / 200;
  view.camera.far = size * 20;
  view.camera.updateProjectionMatrix();
  if (view.controls) {
    view.controls.target.copy(centre);
    view.controls.update();
  }
}

/** The active contact model in the info panel: its label, and on expanding, its limits. */
function showContactModel(model) {
  state.contactModel = model;
  dom['v-model'].textContent = model.label;
  const corrections = model.corrections.length
    ? model.corrections.map((c) => c.replaceAll('_', ' ')).join(', ')
    : "none: the paper's law";
  const depth = model.validDepthM === null ? 'not stated' : `${(model.validDepthM * 1e3).toFixed(1)} mm`;
  const inclination =
    model.validInclinationRad === null
      ? 'not stated'
      : `${((model.validInclinationRad * 180) / Math.PI).toFixed(1)}° (${model.validInclinationRad.toFixed(2)} rad)`;
  const source = model.limitsSource ?? 'not stated by this server';
  dom['m-corrections'].textContent = corrections;
  dom['m-depth'].textContent = depth;
  dom['m-inclination'].textContent = inclination;
  dom['m-source'].textContent = source;
  // The same on hover, for a glance without expanding.
  dom['model-details'].title =
    `corrections: ${corrections}\nvalid to depth ${depth}, inclination ${inclination}\nlimits from: ${source}\n` +
    'beyond them the flags "beyond valid depth" and "beyond valid inclination" light up';
}

function setMode(replay) {
  setText(dom.mode, replay ? 'replay' : 'live view');
}

function onMessage(message, receivedAtMs) {
  switch (message.type) {
    case 'hello':
      if (state.sessionId !== null && state.sessionId !== message.session_id) {
        buffer.reset();
        plot.reset();
        // Another session: a replay's timeline stays only if this one is a replay too.
        timeline.hide();
        buffer.restartClock(receivedAtMs, 1);
        setMode(false);
      }
      {
        const access = accessOf(message);
        state.mode = access.mode;
        showRole(access.role);
        // Instructors mark a live session; a replay's marks are the recording's.
        dom['mark-form'].hidden = !(access.role === 'instructor' && access.mode === 'live');
        showForceFeedback(forceFeedbackOf(message));
        timeline.setControllable(access.role === 'instructor');
        if (access.mode === 'replay') {
          timeline.show();
          setMode(true);
        }
      }
      prompt.hide();
      state.sessionId = message.session_id;
      break;
    case 'refused':
      if (message.request === 'replay_control') timeline.showRefused(message.reason, receivedAtMs);
      else console.warn(`softhaptic: the server refused ${message.request}: ${message.reason}`);
      break;
    case 'replay':
      if (timeline.onStatus(message, receivedAtMs)) {
        // Play, seek or a new speed: the frames that follow are timed afresh, at the new rate.
        buffer.restartClock(receivedAtMs, message.speed);
      }
      setMode(true);
      break;
    case 'scene':
      applyScene(message).catch(sceneLoadFailed);
      break;
    case 'contact':
      state.contactFrames++;
      buffer.push(message, receivedAtMs);
      plot.push(message.time_ns / 1e6, Math.hypot(message.force_n[0], message.force_n[1], message.force_n[2]));
      break;
    case 'stats':
      state.lastStats = message;
      break;
    case 'metrics':
      state.lastMetrics = message;
      break;
    case 'mark':
      addMark(message);
      break;
    default:
      break;
  }
}

/** One screen refresh: interpolate, deform, draw. Allocates nothing. */
function animate(nowMs) {
  frameTimes.ms[frameTimes.head] = nowMs;
  frameTimes.head = (frameTimes.head + 1) % frameTimes.ms.length;
  if (frameTimes.count < frameTimes.ms.length) frameTimes.count++;

  const now = performance.now();
  if (!state.paused) {
    buffer.sample(now, rendered);
    deformMeshes();
  }
  timeline.frame(now);
  placeToolAndMarkers();
  placeSection();
  plot.draw();
  if (view.renderer) {
    view.controls.update();
    view.renderer.render(view.scene, view.camera);
  }
}

function deformMeshes() {
  if (!state.tool || state.meshes.length === 0) return;
  const c = scratch.contact;
  c.inContact = rendered.valid && rendered.inContact;
  c.depthM = rendered.depthM;
  c.contactRadiusM = rendered.contactRadiusM;
  c.deformedRadiusM = rendered.deformedRadiusM;
  const t0 = performance.now();
  let moved = 0;
  let touchedAny = false;
  for (let k = 0; k < state.meshes.length; k++) {
    const m = state.meshes[k];
    if (c.inContact) {
      // World → object frame: p_obj = q⁻¹(p − t), n_obj = q⁻¹ n.
      scratch.v
        .set(rendered.point[0], rendered.point[1], rendered.point[2])
        .sub(m.objectPosition)
        .applyQuaternion(m.objectInverse);
      scratch.n.set(rendered.normal[0], rendered.normal[1], rendered.normal[2]).applyQuaternion(m.objectInverse);
      c.point[0] = scratch.v.x;
      c.point[1] = scratch.v.y;
      c.point[2] = scratch.v.z;
      c.normal[0] = scratch.n.x;
      c.normal[1] = scratch.n.y;
      c.normal[2] = scratch.n.z;
    }
    const touched = m.deformer.apply(m.positions, m.normals, c, state.tool, state.surface);
    moved += m.deformer.movedCount;
    if (touched > 0) {
      // Upload only the span of vertex indices written this frame (moved or restored).
      const list = m.deformer.touched;
      let lo = list[0];
      let hi = list[0];
      for (let j = 1; j < touched; j++) {
        const i = list[j];
        if (i < lo) lo = i;
        else if (i > hi) hi = i;
      }
      m.range.start = 3 * lo;
      m.range.count = 3 * (hi - lo + 1);
      // three.js empties updateRanges after each upload; the same range object is pushed back.
      m.positionAttr.updateRanges.length = 0;
      m.positionAttr.updateRanges.push(m.range);
      m.normalAttr.updateRanges.length = 0;
      m.normalAttr.updateRanges.push(m.range);
      m.positionAttr.needsUpdate = true;
      m.normalAttr.needsUpdate = true;
      if (state.depressionMap) paintDepression(m, list, touched);
      touchedAny = true;
    }
  }
  if (c.inContact || touchedAny) {
    timings.ms[timings.head] = performance.now() - t0;
    timings.head = (timings.head + 1) % TIMING_SAMPLES;
    if (timings.count < TIMING_SAMPLES) timings.count++;
  }
  timings.moved = moved;
}

/**
 * The depression map: each vertex written this frame coloured by how far it moved, from white
 * (none) to the map's colour at the scale's full depth.
 */
function paintDepression(m, list, count) {
  const scaleM = state.depressionScaleM;
  for (let j = 0; j < count; j++) {
    const i = list[j];
    const dx = m.positions[3 * i] - m.rest[3 * i];
    const dy = m.positions[3 * i + 1] - m.rest[3 * i + 1];
    const dz = m.positions[3 * i + 2] - m.rest[3 * i + 2];
    const t = Math.min(Math.hypot(dx, dy, dz) / scaleM, 1);
    m.colors[3 * i] = 1 - t * (1 - DEPRESSION_COLOR[0]);
    m.colors[3 * i + 1] = 1 - t * (1 - DEPRESSION_COLOR[1]);
    m.colors[3 * i + 2] = 1 - t * (1 - DEPRESSION_COLOR[2]);
  }
  m.colorAttr.updateRanges.length = 0;
  m.colorAttr.updateRanges.push(m.range);
  m.colorAttr.needsUpdate = true;
}

/** Shows a mark (once per id): in the list, and as a small marker at its point. */
function addMark(m) {
  if (state.marks.has(m.id)) return;
  state.marks.set(m.id, m);
  const item = document.createElement('li');
  item.value = m.id;
  item.dataset.mark = String(m.id);
  item.textContent = `${(m.time_ns / 1e9).toFixed(1)} s: ${m.note}`;
  dom['mark-list'].append(item);
  if (m.point_m !== null && view.scene) {
    const marker = new THREE.Mesh(
      new THREE.SphereGeometry(0.0025, 16, 8),
      new THREE.MeshStandardMaterial({ color: 0xffd33d, emissive: 0x664d00 }),
    );
    marker.position.set(m.point_m[0], m.point_m[1], m.point_m[2]);
    view.scene.add(marker);
  }
}

/** Turns the section view on or off. */
function setSection(on) {
  state.section = Boolean(on);
  dom['section-toggle'].checked = state.section;
  view.sectionPlanes.length = 0;
  if (state.section) {
    view.sectionPlane ??= new THREE.Plane();
    view.sectionPlanes.push(view.sectionPlane);
  }
}

/**
 * Places the section plane: through the contact point (the last one, while free), containing
 * the contact normal, turned to face the camera as far as that allows, and cutting away the half
 * nearer the camera, so the dent's profile shows against the surface beside it.
 */
function placeSection() {
  if (!state.section || !view.sectionPlane || !view.camera) return;
  if (rendered.valid && rendered.inContact) {
    state.sectionPoint[0] = rendered.point[0];
    state.sectionPoint[1] = rendered.point[1];
    state.sectionPoint[2] = rendered.point[2];
    state.sectionNormal[0] = rendered.normal[0];
    state.sectionNormal[1] = rendered.normal[1];
    state.sectionNormal[2] = rendered.normal[2];
  }
  const n = scratch.n.set(state.sectionNormal[0], state.sectionNormal[1], state.sectionNormal[2]);
  const toCamera = scratch.v
    .copy(view.camera.position)
    .sub(scratch.p.set(state.sectionPoint[0], state.sectionPoint[1], state.sectionPoint[2]));
  toCamera.addScaledVector(n, -toCamera.dot(n));
  if (toCamera.lengthSq() < 1e-12) toCamera.set(1, 0, 0);
  // Keep what lies away from the camera: the plane's normal points away from it.
  view.sectionPlane.setFromNormalAndCoplanarPoint(toCamera.normalize().negate(), scratch.p);
}

/** Turns the depression map on or off; off, every vertex gets its own colour back. */
function setDepressionMap(on) {
  state.depressionMap = Boolean(on);
  dom['map-toggle'].checked = state.depressionMap;
  dom['map-scale'].hidden = !state.depressionMap;
  setText(dom['map-scale'], `white 0 … blue ${(state.depressionScaleM * 1e3).toFixed(0)} mm`);
  if (state.depressionMap) return;
  for (const m of state.meshes) {
    m.colors.fill(1);
    m.colorAttr.updateRanges.length = 0;
    m.colorAttr.needsUpdate = true;
  }
}

function placeToolAndMarkers() {
  if (!view.toolGroup || !rendered.valid) return;
  view.toolGroup.position.set(rendered.position[0], rendered.position[1], rendered.position[2]);
  view.toolGroup.quaternion.set(
    rendered.orientation[0],
    rendered.orientation[1],
    rendered.orientation[2],
    rendered.orientation[3],
  );

  const inContact = rendered.inContact && state.tool !== null;
  const opacity = inContact ? TOOL_OPACITY_IN_CONTACT : 1;
  for (const m of view.toolMaterials) {
    if (m.opacity !== opacity) m.opacity = opacity;
  }
  view.ring.visible = inContact;
  if (inContact) {
    const p = profileSetup(
      state.tool,
      rendered.depthM,
      rendered.contactRadiusM,
      rendered.deformedRadiusM,
      scratch.profile,
    );
    scratch.n.set(rendered.normal[0], rendered.normal[1], rendered.normal[2]);
    view.ring.position.set(rendered.point[0], rendered.point[1], rendered.point[2]);
    view.ring.quaternion.setFromUnitVectors(scratch.up, scratch.n);
    view.ring.scale.setScalar(Math.max(p.rdEff, 1e-6));
  }
  const f = rendered.forceMagnitudeN;
  view.arrow.visible = f > 1e-3;
  if (view.arrow.visible) {
    scratch.v.set(rendered.force[0] / f, rendered.force[1] / f, rendered.force[2] / f);
    view.arrow.position.set(rendered.position[0], rendered.position[1], rendered.position[2]);
    view.arrow.setDirection(scratch.v);
    // 1 cm per newton, so the arrow reads as a force scale next to a 1 cm tool.
    view.arrow.setLength(0.01 * f + 0.004, 0.006, 0.004);
  }
}

// ----- panels (4 Hz; text only changes when a value does) -----

function setText(el, text) {
  if (el.textContent !== text) el.textContent = text;
}

function setBadge(el, text, kind) {
  setText(el, text);
  const cls = `badge ${kind}`;
  if (el.className !== cls) el.className = cls;
}

function showConnectionState(s, detail) {
  const kind = s === 'open' ? 'ok' : s === 'connecting' || s === 'pick a station' ? 'warn' : 'bad';
  let text = s;
  if (s === 'reconnecting' && detail) text = `reconnecting in ${(detail.delayMs / 1000).toFixed(1)} s`;
  else if (s === 'unauthorized') text = detail?.reason === 'token_refused' ? 'token refused' : 'needs token';
  setBadge(dom['conn-state'], text, kind);
}

function formatPa(pa) {
  if (pa >= 1e9) return `${(pa / 1e9).toPrecision(3)} GPa`;
  if (pa >= 1e6) return `${(pa / 1e6).toPrecision(3)} MPa`;
  if (pa >= 1e3) return `${(pa / 1e3).toPrecision(3)} kPa`;
  return `${pa.toPrecision(3)} Pa`;
}

/** A duration given in µs, in µs below 10 ms and in ms above, so the panel stays narrow. */
function formatUs(us) {
  if (us >= 10000) return `${(us / 1000).toFixed(0)} ms`;
  if (us >= 100) return `${us.toFixed(0)} µs`;
  return `${us.toFixed(1)} µs`;
}

function median(t) {
  if (t.count === 0) return NaN;
  const sorted = t.sorted.subarray(0, t.count);
  sorted.set(t.ms.subarray(0, t.count));
  sorted.sort();
  return sorted[t.count >> 1];
}

function fps() {
  if (frameTimes.count < 2) return 0;
  const n = frameTimes.ms.length;
  const newest = frameTimes.ms[(frameTimes.head - 1 + n) % n];
  const oldest = frameTimes.ms[(frameTimes.head - frameTimes.count + n) % n];
  return newest > oldest ? ((frameTimes.count - 1) * 1000) / (newest - oldest) : 0;
}

function updatePanels() {
  const error = connection.lastError ?? state.loadError;
  setText(dom['conn-error'], error ?? '');
  const replayPaused = timeline.visible && timeline.clock.known && timeline.clock.paused;
  if (!rendered.valid) setBadge(dom['contact-state'], replayPaused ? 'paused' : 'no data', '');
  else if (replayPaused) setBadge(dom['contact-state'], rendered.inContact ? 'in contact, paused' : 'free, paused', '');
  else if (rendered.stale) setBadge(dom['contact-state'], 'stale', 'warn');
  else if (rendered.inContact) setBadge(dom['contact-state'], 'in contact', 'active');
  else setBadge(dom['contact-state'], 'free', 'ok');
  if (rendered.valid) {
    setText(dom['v-depth'], `${(rendered.depthM * 1e3).toFixed(2)} mm`);
    setText(dom['v-rd'], rendered.inContact ? `${(rendered.deformedRadiusM * 1e3).toFixed(1)} mm` : '—');
    setText(dom['v-force'], `${rendered.forceMagnitudeN.toFixed(2)} N`);
  }
  for (let i = 0; i < CONTACT_FLAGS.length; i++) {
    const on = rendered.valid && (rendered.flags & (1 << i)) !== 0;
    const cls = on ? (SEVERE_FLAGS.has(CONTACT_FLAGS[i]) ? 'flag on severe' : 'flag on') : 'flag';
    if (dom.flagChips[i].className !== cls) dom.flagChips[i].className = cls;
  }
  const s = state.lastStats;
  if (s) {
    setText(dom['s-rate'], `${s.loop_rate_hz.toFixed(1)} Hz`);
    setText(dom['s-jitter'], `${formatUs(s.period_error_us.p99)}, ${formatUs(s.period_error_us.max)}`);
    setText(dom['s-compute'], formatUs(s.compute_us.p99));
    setText(dom['s-overruns'], `${s.overruns} / ${s.standby_ticks}`);
    setText(dom['s-viewers'], `${s.viewers} / ${s.dropped_frames}`);
    const device = s.device ?? 'ok';
    setText(dom['s-device'], deviceStatusMessage(device, state.forceFeedback));
    const deviceClass = device === 'ok' ? '' : 'severe';
    if (dom['s-device'].className !== deviceClass) dom['s-device'].className = deviceClass;
  }
  const m = state.lastMetrics;
  if (m) {
    setText(dom['t-peak'], `${m.peak_force_n.toFixed(2)} N at ${m.peak_force_time_s.toFixed(1)} s`);
    setText(dom['t-above'], `${m.time_above_safe_s.toFixed(2)} s over ${m.safe_force_n} N`);
    const above = m.time_above_safe_s > 0 ? 'severe' : '';
    if (dom['t-above'].className !== above) dom['t-above'].className = above;
    setText(dom['t-contact'], `${m.time_in_contact_s.toFixed(1)} s`);
    setText(dom['t-path'], `${(m.path_length_in_contact_m * 1e3).toFixed(1)} mm`);
    setText(dom['t-pushes'], String(m.pushes));
    setText(dom['t-jerk'], `${m.mean_squared_jerk_m2_s6.toExponential(2)} m²/s⁶`);
    const flags = Object.values(m.flags_raised).reduce((a, b) => a + b, 0);
    setText(dom['t-flags'], `${m.device_fault_ticks} / ${flags}`);
  }
  setText(dom['w-rx'], `${buffer.arrivalsSince(performance.now())} /s`);
  const gl = view.renderer === null ? ' (no WebGL)' : view.software ? ' (software GL)' : '';
  setText(dom['w-fps'], `${fps().toFixed(0)} fps${gl}`);
  const med = median(timings);
  setText(dom['w-deform'], Number.isNaN(med) ? '—' : `${med.toFixed(2)} ms`);
  setText(dom['w-moved'], String(timings.moved));
}

// ----- test hook -----

function flagNames(bits) {
  return CONTACT_FLAGS.filter((_, i) => (bits & (1 << i)) !== 0);
}

init();
