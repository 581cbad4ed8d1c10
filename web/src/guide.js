// Guidance along an expert's recorded path, as the trainee and the instructors see it: the
// expert's tool drawn as a ghost where the guide's target is (where the expert's tool was at the
// trainee's progress), the path ahead of it bright and the part already covered dim, and the
// guiding force as an arrow of its own beside the total force's, with its gain in the panel.
//
// The path comes with the `scene` message (`scene.guide`, thinned to at most 2 000 points evenly
// spaced along it, so a frame's `progress` × (n − 1) indexes its target); each frame's
// `contact.guide` places the ghost and the arrow (interpolated by the playout buffer with the
// rest of the frame). A scene without a guide hides all of it.

import * as THREE from 'three';

/** The ghost's and the path's colour, and the guiding force's arrow's. */
const GUIDE_COLOR = 0x3fb950;
/** The ghost's opacity at full gain; it fades with the gain, never below the floor. */
const GHOST_OPACITY = 0.45;
const GHOST_OPACITY_FLOOR = 0.15;
/** The path's tube: 0.4 mm thick, six-sided. */
const PATH_RADIUS_M = 0.0004;
const PATH_SIDES = 6;
/** The arrow's scale: 1 cm per newton, as the total force's arrow. */
const ARROW_M_PER_N = 0.01;

export class GuideView {
  /** @param {THREE.Scene} scene */
  constructor(scene) {
    this.scene = scene;
    this.info = null;
    this.ghost = null;
    this.ghostMaterial = new THREE.MeshBasicMaterial({
      color: GUIDE_COLOR,
      transparent: true,
      opacity: GHOST_OPACITY,
      depthWrite: false,
    });
    this.ahead = null;
    this.behind = null;
    this.pointCount = 0;
    this.arrow = new THREE.ArrowHelper(
      new THREE.Vector3(0, 1, 0),
      new THREE.Vector3(),
      0.02,
      GUIDE_COLOR,
      0.006,
      0.004,
    );
    this.arrow.visible = false;
    // Drawn through the tool and the object, as the total force's arrow is.
    for (const part of [this.arrow.line, this.arrow.cone]) {
      part.material.depthTest = false;
      part.material.transparent = true;
      part.renderOrder = 3;
    }
    scene?.add(this.arrow);
    this.direction = new THREE.Vector3();
    /** What the last frame drew, for the panel and the tests. */
    this.drawn = { ghostVisible: false, arrowVisible: false, arrowLengthM: 0, aheadFrom: 0 };
  }

  /** The scene's guide (`scene.guide`, or absent) and its tool (`scene.tool`): builds or clears. */
  setScene(guide, tool) {
    this.clear();
    this.info = guide ?? null;
    if (!this.info || !this.scene) return;
    this.ghost = ghostOf(tool, this.ghostMaterial);
    this.ghost.visible = false;
    this.scene.add(this.ghost);
    const points = this.info.path_m;
    this.pointCount = points.length;
    // A thin tube rather than a line: WebGL draws lines one pixel wide, lost beside the tool.
    const curve = new THREE.CatmullRomCurve3(
      points.map((p) => new THREE.Vector3(p[0], p[1], p[2])),
      false,
      'centripetal',
    );
    const geometry = new THREE.TubeGeometry(curve, points.length - 1, PATH_RADIUS_M, PATH_SIDES, false);
    this.ahead = pathTube(geometry, { color: GUIDE_COLOR, opacity: 0.9 });
    this.behind = pathTube(geometry.clone(), { color: GUIDE_COLOR, opacity: 0.25 });
    this.scene.add(this.ahead, this.behind);
  }

  clear() {
    for (const o of [this.ghost, this.ahead, this.behind]) {
      if (!o) continue;
      this.scene?.remove(o);
      o.traverse((c) => c.geometry?.dispose());
    }
    this.ghost = this.ahead = this.behind = null;
    this.info = null;
    this.pointCount = 0;
    this.arrow.visible = false;
    this.drawn.ghostVisible = this.drawn.arrowVisible = false;
  }

  /** Places the ghost, the path's split and the arrow for the interpolated frame `r`. */
  place(r) {
    const on = this.info !== null && r.valid && r.guided;
    if (this.ghost) this.ghost.visible = on;
    if (this.ahead) this.ahead.visible = this.info !== null;
    if (this.behind) this.behind.visible = this.info !== null;
    this.drawn.ghostVisible = on;
    if (!on) {
      this.arrow.visible = false;
      this.drawn.arrowVisible = false;
      return;
    }
    const t = r.guideTarget;
    this.ghost.position.set(t[0], t[1], t[2]);
    // Held as the trainee holds the tool: the path says where, not how.
    this.ghost.quaternion.set(r.orientation[0], r.orientation[1], r.orientation[2], r.orientation[3]);
    this.ghostMaterial.opacity = GHOST_OPACITY_FLOOR + (GHOST_OPACITY - GHOST_OPACITY_FLOOR) * r.guideGain;
    // The path is evenly spaced: the target's index is its progress along it.
    const split = Math.min(this.pointCount - 1, Math.max(0, Math.round(r.guideProgress * (this.pointCount - 1))));
    // The tube's segment i joins points i and i + 1 (an even spacing along the path, as the
    // tube's own); each segment is PATH_SIDES quads of two triangles.
    const perSegment = PATH_SIDES * 6;
    this.ahead.geometry.setDrawRange(split * perSegment, (this.pointCount - 1 - split) * perSegment);
    this.behind.geometry.setDrawRange(0, split * perSegment);
    this.drawn.aheadFrom = split;
    const f = Math.hypot(r.guideForce[0], r.guideForce[1], r.guideForce[2]);
    this.arrow.visible = f > 1e-3;
    this.drawn.arrowVisible = this.arrow.visible;
    this.drawn.arrowLengthM = this.arrow.visible ? ARROW_M_PER_N * f + 0.004 : 0;
    if (this.arrow.visible) {
      this.direction.set(r.guideForce[0] / f, r.guideForce[1] / f, r.guideForce[2] / f);
      this.arrow.position.set(r.position[0], r.position[1], r.position[2]);
      this.arrow.setDirection(this.direction);
      this.arrow.setLength(this.drawn.arrowLengthM, 0.005, 0.0035);
    }
  }

  /** The panel's words for frame `r`: null without a guide. */
  summary(r) {
    if (!this.info) return null;
    if (!r.valid || !r.guided) return `${this.info.source}: waiting`;
    const f = Math.hypot(r.guideForce[0], r.guideForce[1], r.guideForce[2]);
    const state = r.guideEngaged ? `${f.toFixed(2)} N` : 'let go';
    const pass = this.info.gain.mode === 'schedule' ? ` · pass ${r.guidePass + 1}` : '';
    return `gain ${Math.round(r.guideGain * 100)} % · ${state} · ${Math.round(r.guideProgress * 100)} % along${pass}`;
  }

  /** What is drawn (the browser tests). */
  snapshot(r) {
    return {
      source: this.info?.source ?? null,
      pathPoints: this.pointCount,
      ghostVisible: this.drawn.ghostVisible,
      ghostPosition: this.ghost ? this.ghost.position.toArray() : null,
      arrowVisible: this.drawn.arrowVisible,
      arrowLengthM: this.drawn.arrowLengthM,
      aheadFrom: this.drawn.aheadFrom,
      gain: r.guided ? r.guideGain : null,
      effectiveGain: r.guided ? r.guideEffectiveGain : null,
      engaged: r.guided ? r.guideEngaged : null,
      pass: r.guided ? r.guidePass : null,
      summary: this.summary(r),
    };
  }
}

/** A translucent copy of the tool's tip: the tool frame's origin at the tip, as `buildTool`'s. */
function ghostOf(tool, material) {
  const group = new THREE.Group();
  const R = tool.radius_m;
  if (tool.shape === 'sphere') {
    const ball = new THREE.Mesh(new THREE.SphereGeometry(R, 32, 16), material);
    ball.position.y = R;
    group.add(ball);
  } else {
    const height = R / Math.tan(tool.half_angle_rad);
    const cone = new THREE.Mesh(new THREE.ConeGeometry(R, height, 32, 1, false), material);
    cone.rotation.x = Math.PI;
    cone.position.y = height / 2;
    group.add(cone);
  }
  group.renderOrder = 1;
  return group;
}

function pathTube(geometry, { color, opacity }) {
  const tube = new THREE.Mesh(
    geometry,
    new THREE.MeshBasicMaterial({ color, transparent: true, opacity, depthTest: false, depthWrite: false }),
  );
  tube.renderOrder = 2;
  return tube;
}
