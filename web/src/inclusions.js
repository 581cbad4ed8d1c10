// A palpation scene's inclusions and the trainee's path, for the viewers allowed to see them.
//
// The server sends `inclusions` only to those (proto/WIRE.md, docs/roles.md): an instructor
// while an attempt runs, everyone once a palpation attempt has ended. This module draws what it
// was sent: each inclusion as a translucent sphere inside the organ, drawn over the surface (no
// depth test) so it shows through it, and the trainee's path over the surface since the attempt
// started: the contact points of the frames received, as a line. A page that was sent nothing
// draws nothing. A revealed answer is forgotten when another attempt starts.
//
// It keeps to its own objects in the three.js scene; main.js hands it the messages.

import * as THREE from 'three';

const SPHERE_COLOR = 0xff5f56;
const SPHERE_OPACITY = 0.4;
const PATH_COLOR = 0x58a6ff;
/** Points the path keeps; past it, every other point is dropped and the path goes on. */
export const MAX_PATH_POINTS = 8192;
/** A contact point nearer than this to the last one kept adds nothing to the drawn path (m). */
const PATH_STEP_M = 0.0003;
/** Drawn after the object and its marks' ring, before the marks. */
const RENDER_ORDER = 9;

export class InclusionsView {
  /** `scene`: a function giving the three.js scene (null without WebGL). */
  constructor({ scene }) {
    this.scene = scene;
    /** The last `inclusions` message drawn, or null. */
    this.message = null;
    /** The attempt the page is at (`exercise` index and attempt), or null before any. */
    this.attemptKey = null;
    this.group = null;
    this.spheres = [];
    this.path = new Float32Array(3 * MAX_PATH_POINTS);
    this.pathCount = 0;
    this.pathLine = null;
  }

  /** `inclusions`: draws them (and the path from now on). */
  onInclusions(m) {
    // No positions: the answer is withdrawn (a replay sought back before the attempt's end).
    this.message = m.inclusions.length > 0 ? m : null;
    if (m.exercise_index !== null) this.#enterAttempt(`${m.exercise_index}/${m.attempt}`);
    this.#draw();
  }

  /** `exercise`: a new attempt starts the path over, and forgets the last one's revealed answer. */
  onExercise(m) {
    this.#enterAttempt(`${m.index}/${m.attempt}`);
    const forAttempt = this.message && `${this.message.exercise_index}/${this.message.attempt}` === this.attemptKey;
    if (this.message && this.message.revealed && !forAttempt && m.state === 'running') {
      this.message = null;
      this.#draw();
    }
  }

  /** `contact`: adds its contact point to the path while in contact. */
  onContact(frame) {
    if (!frame.in_contact) return;
    const [x, y, z] = frame.contact_point_m;
    const n = this.pathCount;
    if (n > 0) {
      const j = 3 * (n - 1);
      if (Math.hypot(x - this.path[j], y - this.path[j + 1], z - this.path[j + 2]) < PATH_STEP_M) return;
    }
    if (n === MAX_PATH_POINTS) this.#thin();
    const j = 3 * this.pathCount;
    this.path[j] = x;
    this.path[j + 1] = y;
    this.path[j + 2] = z;
    this.pathCount++;
    this.#updatePath();
  }

  /** Another session: nothing of the last one is drawn. */
  reset() {
    this.message = null;
    this.attemptKey = null;
    this.pathCount = 0;
    this.#draw();
  }

  /** What is drawn, for the browser tests. */
  snapshot() {
    return {
      shown: this.group !== null && this.group.visible,
      revealed: this.message?.revealed ?? null,
      exerciseIndex: this.message?.exercise_index ?? null,
      attempt: this.message?.attempt ?? null,
      spheres: this.spheres.map((s) => ({
        centre: [s.position.x, s.position.y, s.position.z],
        radius: s.geometry.parameters.radius,
        visible: s.visible,
        opacity: s.material.opacity,
        depthTest: s.material.depthTest,
      })),
      pathPoints: this.pathCount,
      pathDrawn: this.pathLine?.geometry.drawRange.count ?? 0,
    };
  }

  #enterAttempt(key) {
    if (key === this.attemptKey) return;
    this.attemptKey = key;
    this.pathCount = 0;
    this.#updatePath();
  }

  /** Keeps every other point, so a long search still fits and still shows its whole extent. */
  #thin() {
    let k = 0;
    for (let i = 0; i < this.pathCount; i += 2, k++) {
      this.path[3 * k] = this.path[3 * i];
      this.path[3 * k + 1] = this.path[3 * i + 1];
      this.path[3 * k + 2] = this.path[3 * i + 2];
    }
    this.pathCount = k;
  }

  #updatePath() {
    if (!this.pathLine) return;
    const attr = this.pathLine.geometry.getAttribute('position');
    attr.needsUpdate = true;
    this.pathLine.geometry.setDrawRange(0, this.pathCount);
  }

  #draw() {
    const scene = this.scene();
    if (!scene) return;
    if (this.group) {
      scene.remove(this.group);
      for (const s of this.spheres) {
        s.geometry.dispose();
        s.material.dispose();
      }
      this.pathLine.geometry.dispose();
      this.pathLine.material.dispose();
      this.group = null;
      this.spheres = [];
      this.pathLine = null;
    }
    if (!this.message) return;
    this.group = new THREE.Group();
    this.group.name = 'inclusions';
    for (const inc of this.message.inclusions) {
      // Inside the organ: without a depth test they show through its surface.
      const sphere = new THREE.Mesh(
        new THREE.SphereGeometry(inc.radius_m, 24, 16),
        new THREE.MeshStandardMaterial({
          color: SPHERE_COLOR,
          emissive: 0x5a1512,
          transparent: true,
          opacity: SPHERE_OPACITY,
          depthTest: false,
          depthWrite: false,
        }),
      );
      sphere.position.set(inc.centre_m[0], inc.centre_m[1], inc.centre_m[2]);
      sphere.renderOrder = RENDER_ORDER;
      this.group.add(sphere);
      this.spheres.push(sphere);
    }
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(this.path, 3));
    this.pathLine = new THREE.Line(geometry, new THREE.LineBasicMaterial({ color: PATH_COLOR, depthTest: false }));
    this.pathLine.renderOrder = RENDER_ORDER;
    // Its points change every frame: never culled by a stale bounding sphere.
    this.pathLine.frustumCulled = false;
    this.group.add(this.pathLine);
    this.#updatePath();
    scene.add(this.group);
  }
}
