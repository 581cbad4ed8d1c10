// The viewer's shared state, read and written by the modules of the page: the DOM elements by
// id (`dom`), the three.js objects (`view`), what the server said (`state`), the playout buffer
// and the contact it last interpolated (`buffer`, `rendered`), the deformation's timings, and the
// scratch objects the per-frame code reuses so that a frame allocates nothing.
import * as THREE from 'three';

import { PlayoutBuffer, RenderedContact } from './interpolation.js';
import { archiveOf, stationOf } from './lab.js';

export const PLAYOUT_DELAY_MS = 50;
export const TIMING_SAMPLES = 120;

export const dom = {};
export const view = {
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
  /**
   * The radial table the meshes' vertex shaders bend them with (`shaderdeform.js`), when there
   * is WebGL; null without it.
   */
  deformationTable: null,
  /** The compiler's log when a WebGL implementation refused the bending shader, until handled. */
  shaderFailure: null,
  sectionPlane: null,
  /** The tool's materials: see-through while in contact, so the dent under it shows. */
  toolMaterials: [],
  ring: null,
  arrow: null,
  objectsGroup: null,
  /** The marks' markers on the object: `{id, mesh}`, one per mark with a point. */
  markers: [],
};
export const state = {
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
  /**
   * Whether the meshes are drawn in their rest shape although the tool presses them (a frame
   * to compare a press with: the browser tests; `setRestShape`).
   */
  restShape: false,
  /** Where the section passes: the last contact point and its normal. */
  sectionPoint: [0, 0, 0],
  sectionNormal: [0, 1, 0],
  /**
   * Where the meshes are bent: `gpu`, by their vertex shaders (the default with WebGL), or
   * `cpu`, by `MeshDeformer` into the vertex buffers (without WebGL, or with `?deform=cpu`).
   */
  deformation: 'cpu',
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
export const buffer = new PlayoutBuffer({ delayMs: PLAYOUT_DELAY_MS });
export const rendered = new RenderedContact();
export const timings = {
  ms: new Float64Array(TIMING_SAMPLES),
  sorted: new Float64Array(TIMING_SAMPLES),
  count: 0,
  head: 0,
  moved: 0,
};
export const frameTimes = { ms: new Float64Array(128), head: 0, count: 0 };

// Scratch objects reused every frame.
export const scratch = {
  contact: {
    inContact: false,
    depthM: 0,
    contactRadiusM: 0,
    deformedRadiusM: 0,
    inclusionForceRatio: 1,
    point: new Float64Array(3),
    normal: new Float64Array(3),
  },
  v: new THREE.Vector3(),
  n: new THREE.Vector3(),
  p: new THREE.Vector3(),
  q: new THREE.Quaternion(),
  up: new THREE.Vector3(0, 1, 0),
  profile: {},
  /** The `fem` profile prepared for the GPU path's table. */
  surfaceProfile: {},
  /** The radial table of this frame's profile, for the GPU path. */
  table: {},
};
