// The viewer: connects to the server that served this page, loads the scene and its render
// meshes, and each animation frame draws the interpolated contact: tool pose, the mesh bent by
// the Bézier profile (paper §3.3), the deformed-region ring, the force arrow and plot.
//
// Reading order: `init()` builds everything once; `onMessage()` takes the server's messages;
// `animate()` runs per screen refresh and allocates nothing. The 3-D view is `scene3d.js`, the
// panels `panels.js`, the state they share `context.js`; `testhook.js` is what the browser
// tests read, fetched only under automation (a dynamic import), so no other browser downloads
// it. When the server replays a recording, the timeline panel (`replay.js`) shows where the
// replay stands and sends the instructor's pause, play, seek and speed.
//
// Access (`access.js`): the token of the page's link is presented on every connection and with
// every fetch from the server; `hello` says the role it grants (instructor or observer), shown
// in the panel. When the server wants a token the viewer has not got, or refuses the one it
// has (WebSocket close 4401, HTTP 401), the viewer stops and asks for the link in a prompt.

import { AccessPrompt, TokenKeeper, storageOrNull } from './access.js';
import { buffer, dom, frameTimes, rendered, state, timings, view } from './context.js';
import { surfaceFamilyFromJson, toolFromJson } from './deformation.js';
import { ExercisePanel } from './exercise.js';
import { GuideView } from './guide.js';
import { ForcePlot } from './forceplot.js';
import { InclusionsView } from './inclusions.js';
import { parseRenderMesh } from './mesh.js';
import { ViewerConnection, webSocketUrl } from './connection.js';
import {
  encodeMark,
  encodeRearm,
  forceFeedbackOf,
  accessOf,
  contactModelOf,
  marksAcceptedOf,
  validateMessage,
} from './protocol.js';
import {
  bindPanels,
  flagNames,
  fps,
  formatPa,
  listMark,
  median,
  setMode,
  showConnectionState,
  showContactModel,
  showForceFeedback,
  showRole,
  updatePanels,
} from './panels.js';
import { ReplayTimeline } from './replay.js';
import {
  addMarker,
  buildMesh,
  buildTool,
  deformMeshes,
  drawnMesh,
  frameCamera,
  initThree,
  placeSection,
  placeToolAndMarkers,
  resizeView,
  setDeformation,
  setDepressionMap,
  setRestShape,
  setSection,
} from './scene3d.js';
import { StationList, withStation } from './lab.js';

/** How often a hub's page asks for its station list again. */
const STATION_LIST_REFRESH_MS = 2000;

let plot = null;
let exercisePanel = null;
let guideView = null;
let inclusionsView = null;
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

/** The page's parts the test hook reads (`testhook.js`); later ones through getters. */
function testHookParts() {
  return {
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
    get exercisePanel() {
      return exercisePanel;
    },
    get guideView() {
      return guideView;
    },
    get inclusionsView() {
      return inclusionsView;
    },
    get stationList() {
      return stationList;
    },
    animate,
    flagNames,
    fps,
    median,
    setDepressionMap,
    setDeformation,
    drawnMesh,
    setSection,
    setRestShape,
    frameCamera,
    sectionPlane: () => view.sectionPlane,
  };
}

function init() {
  bindPanels();
  plot = new ForcePlot(dom['force-plot'], { pixelRatio: Math.min(window.devicePixelRatio || 1, 2) });
  exercisePanel = new ExercisePanel({
    dom,
    scene: () => view.scene,
    send: (text) => connection?.send(text) ?? false,
  });
  inclusionsView = new InclusionsView({ scene: () => view.scene });

  initThree();
  guideView = new GuideView(view.scene);
  // Only under automation (the browser tests, whose pages wait for `window.__softhaptic`): see
  // testhook.js. A static import would make every browser download it.
  if (navigator.webdriver) {
    import('./testhook.js')
      .then(({ installTestHook }) => installTestHook(testHookParts()))
      .catch((e) => console.warn(`softhaptic: no test hook: ${e.message}`));
  }

  keeper = new TokenKeeper({ storage: storageOrNull(() => window.sessionStorage) });
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
  dom['rearm-device'].addEventListener('click', () => connection.send(encodeRearm()));
  setInterval(() => updatePanels({ connection, timeline, guideView }), 250);
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

function onWindowResize() {
  plot.resize();
  resizeView();
}

// ----- access: the token, the prompt, the role -----

/**
 * A token from the prompt or a new link (with the role the link names, when it does): kept,
 * presented on a fresh connection at once.
 */
function useToken(token, role) {
  keeper.set(token, role);
  connection.setToken(token);
  connection.reconnectNow();
  loadSceneOverHttp();
}

/**
 * The server wants a token the viewer has not got (`needs_token`) or refused the one it
 * presented (`token_refused`, or `token_expired` when it greeted this tab with it before): a
 * refused token is forgotten, the connection stays closed, and the prompt asks for the link.
 */
function requireToken(reason) {
  const linkRole = keeper.role;
  let why = reason;
  if (reason === 'token_refused') {
    why = keeper.refusal();
    keeper.forget();
    connection.setToken(null);
  }
  prompt.show(why, { linkRole });
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
  guideView.setScene(scene.guide, scene.tool);
  dom['guide-row'].hidden = !scene.guide;

  for (const m of state.meshes) {
    view.objectsGroup.remove(m.mesh);
    m.geometry.dispose();
    m.section?.line.geometry.dispose();
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

/** Keeps a mark (once per id): listed under the form, and a marker at its point. */
function addMark(m) {
  if (state.marks.has(m.id)) return;
  state.marks.set(m.id, m);
  listMark(m);
  addMarker(m);
}

function onMessage(message, receivedAtMs) {
  switch (message.type) {
    case 'hello':
      if (state.sessionId !== null && state.sessionId !== message.session_id) {
        buffer.reset();
        plot.reset();
        // Another session: a replay's timeline stays only if this one is a replay too.
        timeline.hide();
        exercisePanel.reset();
        inclusionsView.reset();
        buffer.restartClock(receivedAtMs, 1);
        setMode(false);
      }
      {
        const access = accessOf(message);
        state.mode = access.mode;
        showRole(access.role);
        // Instructors mark a live session; a replay's marks are the recording's, and a hub
        // (a station's stream in a teaching lab) records nothing and refuses them.
        const onHub = state.station !== null || stationList.isHub === true;
        dom['mark-form'].hidden = !(
          access.role === 'instructor' &&
          access.mode === 'live' &&
          marksAcceptedOf(message, onHub)
        );
        showForceFeedback(forceFeedbackOf(message));
        timeline.setControllable(access.role === 'instructor');
        exercisePanel.setAccess(access.role, access.mode);
        if (access.mode === 'replay') {
          timeline.show();
          setMode(true);
        }
      }
      // The prompt goes, unless the link was given for another role than the server grants.
      prompt.greeted(keeper.greeted(accessOf(message).role));
      state.sessionId = message.session_id;
      break;
    case 'refused':
      if (message.request === 'replay_control') timeline.showRefused(message.reason, receivedAtMs);
      else if (message.request === 'exercise_control') exercisePanel.showRefused(message.reason);
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
      inclusionsView.onContact(message);
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
    case 'exercise':
      exercisePanel.onMessage(message, receivedAtMs);
      inclusionsView.onExercise(message);
      break;
    case 'inclusions':
      inclusionsView.onInclusions(message);
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
  exercisePanel.tick(now);
  placeToolAndMarkers();
  guideView.place(rendered);
  placeSection();
  plot.draw();
  if (view.renderer) {
    view.controls.update();
    view.renderer.render(view.scene, view.camera);
  }
}

init();
