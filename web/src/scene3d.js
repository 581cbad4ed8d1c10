// The 3-D view: the three.js scene (lights, grid, the deformed-region ring, the force arrow),
// the tool and the render meshes of a scene, and what each animation frame does to them: bend
// the meshes with the scene's deformation profile, place the tool, the ring, the arrow and the
// section plane and the section's line of the undeformed surface (cut by `section.js`), colour
// the depression map. With WebGL the meshes' vertex shaders bend them (`shaderdeform.js`: one
// radial table per frame, whatever the mesh's size); without it, or with `?deform=cpu` in the
// address, `MeshDeformer` bends the vertex buffers, and the panels and the tests read them even
// when nothing is drawn.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

import {
  profileSetup,
  profileTable,
  stiffenSurface,
  stiffenedDeformedRadius,
  surfaceSetup,
  surfaceTable,
} from './deformation.js';
import { MeshDeformer } from './deformer.js';
import { cutMesh, segmentBuffer } from './section.js';
import { DeformationTable } from './shaderdeform.js';
import { TIMING_SAMPLES, dom, rendered, scratch, state, timings, view } from './context.js';
import { setText } from './panels.js';

/**
 * The tool's opacity while it touches the object: the dent it makes is under it, and from most
 * viewpoints an opaque tool hides it entirely.
 */
const TOOL_OPACITY_IN_CONTACT = 0.3;
/** The depression map's colour at full scale (multiplies the object's). */
const DEPRESSION_COLOR = [0.25, 0.45, 1.0];
/**
 * The colour of the section's line of the undeformed surface: a green found nowhere else in the
 * view (the object is pink, the map blue, the ring orange, the markers yellow).
 */
const SECTION_REFERENCE_COLOR = 0x7ee787;
/**
 * How far the section plane (object frame) must move before the undeformed mesh is cut again:
 * 10⁻⁶ of the normal's components and 0.1 µm of the offset, far below a pixel.
 */
const SECTION_RECUT_NORMAL = 1e-6;
const SECTION_RECUT_OFFSET_M = 1e-7;

/** Creates the WebGL renderer and the static scene; without WebGL, says so and goes on. */
export function initThree() {
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
    view.deformationTable = new DeformationTable();
    state.deformation = new URLSearchParams(window.location.search).get('deform') === 'cpu' ? 'cpu' : 'gpu';
    // A WebGL implementation that refuses the bending shader must not leave the object undrawn:
    // the next frame goes back to the CPU path (`fallBackToCpu`).
    renderer.debug.onShaderError = (gl, program, vertexShader, fragmentShader) => {
      const log = [program, vertexShader, fragmentShader]
        .map((o, i) => (i === 0 ? gl.getProgramInfoLog(o) : gl.getShaderInfoLog(o)) ?? '')
        .map((l) => l.trim())
        .filter((l) => l !== '')
        .join('\n');
      console.error(`softhaptic: a shader did not compile:\n${log}`);
      if ((gl.getShaderSource(vertexShader) ?? '').includes('shTable')) view.shaderFailure = log || 'no log';
    };
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

/** Fits the renderer and the camera to the window. */
export function resizeView() {
  if (!view.renderer) return;
  view.camera.aspect = window.innerWidth / window.innerHeight;
  view.camera.updateProjectionMatrix();
  view.renderer.setSize(window.innerWidth, window.innerHeight);
}

export function buildTool(tool) {
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

export function buildMesh(desc, data) {
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
  const material = meshMaterial();
  // Every mesh's shader can bend it, so that the page can change paths while it runs.
  const uniforms = view.deformationTable ? view.deformationTable.install(material, DEPRESSION_COLOR) : null;
  const mesh = new THREE.Mesh(geometry, material);
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
    /** The triangles (three vertex indices each), for the section's cut of the rest shape. */
    indices: data.indices,
    /** The section's line of the undeformed surface (`sectionReference`), made when first shown. */
    section: null,
    deformer: new MeshDeformer(data.positions, data.normals),
    uniforms,
    /** The contact of the last frame in the object frame, for `drawnMesh`. */
    contact: { ...scratch.contact, point: new Float64Array(3), normal: new Float64Array(3), version: 0 },
    /** `drawnMesh`'s evaluation of what the shader draws (allocated when first asked). */
    reference: null,
    geometry,
    mesh,
    range: { start: 0, count: 0 },
    objectPosition: new THREE.Vector3(px, py, pz),
    objectInverse: mesh.quaternion.clone().invert(),
  };
}

/** The render meshes' material (the GPU path adds its bending to it). */
function meshMaterial() {
  return new THREE.MeshStandardMaterial({
    color: 0xd98c8c,
    roughness: 0.55,
    metalness: 0.0,
    vertexColors: true,
    // Seen from inside too, where the section view cuts it open.
    side: THREE.DoubleSide,
    clippingPlanes: view.sectionPlanes,
  });
}

/** Points the camera at the loaded meshes. */
export function frameCamera() {
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

export function deformMeshes() {
  if (view.shaderFailure !== null) fallBackToCpu();
  if (!state.tool || state.meshes.length === 0) return;
  const c = scratch.contact;
  // Drawn undeformed on request (`setRestShape`): the tool and the ring still show the contact.
  c.inContact = rendered.valid && rendered.inContact && !state.restShape;
  c.depthM = rendered.depthM;
  c.contactRadiusM = rendered.contactRadiusM;
  // Over a stiffer inclusion the drawn surface dents less (deformation.js, `stiffen…`).
  c.inclusionForceRatio = rendered.inclusionForceRatio;
  c.deformedRadiusM = stiffenedDeformedRadius(rendered.contactRadiusM, rendered.deformedRadiusM, c.inclusionForceRatio);
  const t0 = performance.now();
  const gpu = state.deformation === 'gpu';
  // Out of contact the shaders draw the rest shape (`place` sets their reach to 0).
  if (gpu && c.inContact) view.deformationTable.update(profileTableOf(c));
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
    if (gpu) {
      copyContact(c, m.contact);
      const scaleM = state.depressionMap ? state.depressionScaleM : 0;
      view.deformationTable.place(m.uniforms, c.inContact, c.point, c.normal, scaleM);
      continue;
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
  // The shader does not say how many vertices it moved.
  timings.moved = gpu ? null : moved;
}

/** This frame's radial table for the vertex shaders: the scene's profile for contact `c`. */
function profileTableOf(c) {
  if (state.surface !== null) {
    const p = surfaceSetup(state.surface, state.tool, c.depthM, scratch.surfaceProfile);
    return surfaceTable(stiffenSurface(p, c.inclusionForceRatio), scratch.table);
  }
  const p = profileSetup(state.tool, c.depthM, c.contactRadiusM, c.deformedRadiusM, scratch.profile);
  return profileTable(p, scratch.table);
}

function copyContact(from, to) {
  to.inContact = from.inContact;
  to.depthM = from.depthM;
  to.contactRadiusM = from.contactRadiusM;
  to.deformedRadiusM = from.deformedRadiusM;
  to.inclusionForceRatio = from.inclusionForceRatio;
  to.point.set(from.point);
  to.normal.set(from.normal);
  to.version++;
}

/**
 * Draws the meshes in their rest shape (true) or bent by the contact (false), from now on; the
 * tool, the ring and the arrow still show the contact. A frame pressed and the same frame
 * undeformed differ by the dent alone (the browser tests compare them).
 */
export function setRestShape(on) {
  state.restShape = Boolean(on);
  deformMeshes();
}

/**
 * Changes where the meshes are bent (`gpu` or `cpu`, see `state.deformation`) and bends them
 * there at once. Without WebGL only `cpu` is possible.
 */
export function setDeformation(mode) {
  if (mode !== 'gpu' && mode !== 'cpu')
    throw new Error(`deformation must be "gpu" or "cpu", got ${JSON.stringify(mode)}`);
  if (mode === 'gpu' && !view.deformationTable)
    throw new Error('the GPU path needs WebGL, which this page does not have');
  if (mode === state.deformation) return;
  state.deformation = mode;
  for (const m of state.meshes) {
    if (mode === 'gpu') {
      // The vertex buffers go back to rest, all of them uploaded once.
      m.deformer.apply(m.positions, m.normals, { inContact: false }, state.tool, state.surface);
      m.colors.fill(1);
      for (const attr of [m.positionAttr, m.normalAttr, m.colorAttr]) {
        attr.updateRanges.length = 0;
        attr.needsUpdate = true;
      }
    } else if (m.uniforms) {
      m.uniforms.shReach.value = 0;
      m.uniforms.shDepressionScale.value = 0;
    }
  }
  deformMeshes();
}

/**
 * After the bending shader failed to compile (`initThree`): every mesh gets a plain material
 * and the CPU path, for the rest of the page's life.
 */
function fallBackToCpu() {
  console.warn(
    `softhaptic: the GPU path's shader did not compile; bending the meshes on the CPU (${view.shaderFailure})`,
  );
  view.shaderFailure = null;
  setDeformation('cpu');
  view.deformationTable = null;
  for (const m of state.meshes) {
    const failed = m.mesh.material;
    m.mesh.material = meshMaterial();
    failed.dispose();
    m.uniforms = null;
  }
}

/**
 * What a mesh is drawn with this frame: `{positions, colors, deformer}`, its vertex positions
 * (object frame), the depression map's colours and the `MeshDeformer` that moved them. On the
 * CPU path these are the vertex buffers; on the GPU path they are evaluated here, with the
 * reference `MeshDeformer` and the last frame's contact, as the shader draws them (for the test
 * hooks and the panels; the frames never call this).
 */
export function drawnMesh(m) {
  if (state.deformation === 'cpu') return { positions: m.positions, colors: m.colors, deformer: m.deformer };
  m.reference ??= {
    positions: Float32Array.from(m.rest),
    colors: new Float32Array(m.rest.length).fill(1),
    deformer: new MeshDeformer(m.rest, null),
    version: -1,
  };
  const ref = m.reference;
  // Once per frame: a test reads many vertices of one frame.
  if (ref.version !== m.contact.version) {
    ref.deformer.apply(ref.positions, null, m.contact, state.tool, state.surface);
    ref.version = m.contact.version;
  }
  ref.colors.fill(1);
  if (state.depressionMap) {
    const { moved, movedCount } = ref.deformer;
    paintColors(ref.positions, m.rest, ref.colors, moved, movedCount);
  }
  return ref;
}

/**
 * The depression map: each vertex written this frame coloured by how far it moved, from white
 * (none) to the map's colour at the scale's full depth.
 */
function paintDepression(m, list, count) {
  paintColors(m.positions, m.rest, m.colors, list, count);
  m.colorAttr.updateRanges.length = 0;
  m.colorAttr.updateRanges.push(m.range);
  m.colorAttr.needsUpdate = true;
}

/** The depression map's colours of vertices `list[0 .. count]` (the shader's tint, on the CPU). */
function paintColors(positions, rest, colors, list, count) {
  const scaleM = state.depressionScaleM;
  for (let j = 0; j < count; j++) {
    const i = list[j];
    const dx = positions[3 * i] - rest[3 * i];
    const dy = positions[3 * i + 1] - rest[3 * i + 1];
    const dz = positions[3 * i + 2] - rest[3 * i + 2];
    const t = Math.min(Math.hypot(dx, dy, dz) / scaleM, 1);
    colors[3 * i] = 1 - t * (1 - DEPRESSION_COLOR[0]);
    colors[3 * i + 1] = 1 - t * (1 - DEPRESSION_COLOR[1]);
    colors[3 * i + 2] = 1 - t * (1 - DEPRESSION_COLOR[2]);
  }
}

/** A small marker at a mark's point on the object, when it has one. */
export function addMarker(m) {
  if (m.point_m === null || !view.scene) return;
  // Drawn over the object: a mark made during a press sits at the bottom of the dent, inside the
  // surface once it springs back, and would otherwise be hidden.
  const marker = new THREE.Mesh(
    new THREE.SphereGeometry(0.0025, 16, 8),
    new THREE.MeshStandardMaterial({ color: 0xffd33d, emissive: 0x664d00, depthTest: false }),
  );
  marker.renderOrder = 10;
  marker.position.set(m.point_m[0], m.point_m[1], m.point_m[2]);
  view.scene.add(marker);
  view.markers.push({ id: m.id, mesh: marker });
}

/** Turns the section view on or off. */
export function setSection(on) {
  state.section = Boolean(on);
  dom['section-toggle'].checked = state.section;
  dom['section-key'].hidden = !state.section;
  view.sectionPlanes.length = 0;
  if (state.section) {
    view.sectionPlane ??= new THREE.Plane();
    view.sectionPlanes.push(view.sectionPlane);
  }
  for (const m of state.meshes) if (m.section) m.section.line.visible = state.section;
}

/**
 * Places the section plane: through the contact point (the last one, while free), containing
 * the contact normal, turned to face the camera as far as that allows, and cutting away the half
 * nearer the camera, so the dent's profile shows against the surface beside it.
 */
export function placeSection() {
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
  // Without WebGL nothing is drawn: no line to cut.
  if (view.renderer) for (const m of state.meshes) placeSectionReference(m, view.sectionPlane);
}

/**
 * The section's line of the undeformed surface of mesh `m`: where the plane cuts its rest shape
 * (`section.js`), drawn through everything, over the cut of the bent mesh, so the dent shows as
 * the bent surface's profile dipping below the line. The clipping plane hides all of the object
 * on the camera's side of the plane and the line lies in the plane, so nothing of the object can
 * stand in front of it. A child of the mesh, so its points stay in the object frame; cut again
 * only when the plane moved (about 1 ms per 100 000 vertices), allocating only when a cut has
 * more segments than any before it.
 */
function placeSectionReference(m, plane) {
  if (m.section === null) m.section = sectionReference(m);
  const s = m.section;
  // The plane in the object frame: n · (q p_obj + t) + c = n_obj · p_obj + (c + n · t), with
  // n_obj = q⁻¹ n.
  const n = scratch.n.copy(plane.normal).applyQuaternion(m.objectInverse);
  const offset = plane.constant + plane.normal.dot(m.objectPosition);
  const last = s.plane;
  if (
    Math.abs(n.x - last[0]) < SECTION_RECUT_NORMAL &&
    Math.abs(n.y - last[1]) < SECTION_RECUT_NORMAL &&
    Math.abs(n.z - last[2]) < SECTION_RECUT_NORMAL &&
    Math.abs(offset - last[3]) < SECTION_RECUT_OFFSET_M
  )
    return;
  last[0] = n.x;
  last[1] = n.y;
  last[2] = n.z;
  last[3] = offset;
  const held = s.buffer.positions;
  const segments = cutMesh(m.rest, m.indices, last, offset, s.distances, s.buffer);
  if (s.buffer.positions !== held) {
    // A longer cut than ever: a buffer of the new size on the GPU too.
    s.line.geometry.dispose();
    s.line.geometry = sectionGeometry(s);
  }
  s.line.geometry.setDrawRange(0, 2 * segments);
  if (segments > 0) {
    s.range.count = 6 * segments;
    s.attr.updateRanges.length = 0;
    s.attr.updateRanges.push(s.range);
    s.attr.needsUpdate = true;
  }
}

/** Makes mesh `m`'s line of the undeformed surface for the section view (hidden when off). */
function sectionReference(m) {
  const s = {
    buffer: segmentBuffer(4096),
    distances: new Float32Array(m.rest.length / 3),
    /** The plane last cut, in the object frame: normal x, y, z and offset (m); NaN before any. */
    plane: new Float64Array(4).fill(NaN),
    range: { start: 0, count: 0 },
    attr: null,
    line: null,
  };
  s.line = new THREE.LineSegments(
    sectionGeometry(s),
    new THREE.LineBasicMaterial({ color: SECTION_REFERENCE_COLOR, depthTest: false, transparent: true }),
  );
  // After the see-through tool, the ring and the arrow; its points change, so no bounds either.
  s.line.renderOrder = 4;
  s.line.frustumCulled = false;
  s.line.visible = state.section;
  m.mesh.add(s.line);
  return s;
}

/** A geometry over the section line's buffer of segments (sets `s.attr`). */
function sectionGeometry(s) {
  const geometry = new THREE.BufferGeometry();
  s.attr = new THREE.BufferAttribute(s.buffer.positions, 3);
  s.attr.setUsage(THREE.DynamicDrawUsage);
  geometry.setAttribute('position', s.attr);
  geometry.setDrawRange(0, 0);
  return geometry;
}

/** Turns the depression map on or off; off, every vertex gets its own colour back. */
export function setDepressionMap(on) {
  state.depressionMap = Boolean(on);
  dom['map-toggle'].checked = state.depressionMap;
  dom['map-scale'].hidden = !state.depressionMap;
  setText(dom['map-scale'], `white 0 … blue ${(state.depressionScaleM * 1e3).toFixed(0)} mm`);
  if (state.deformation === 'gpu') {
    // The shaders tint from the next draw on.
    for (const m of state.meshes) m.uniforms.shDepressionScale.value = state.depressionMap ? state.depressionScaleM : 0;
    return;
  }
  if (state.depressionMap) return;
  for (const m of state.meshes) {
    m.colors.fill(1);
    m.colorAttr.updateRanges.length = 0;
    m.colorAttr.needsUpdate = true;
  }
}

export function placeToolAndMarkers() {
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
