// The browser tests' window onto the page: `window.__softhaptic`, installed only when the page
// runs under automation (`navigator.webdriver`, as playwright drives Chromium). `main.js` imports
// this module dynamically and only then, so a trainee's or an instructor's browser neither
// downloads it nor carries a test surface; the tests wait for `window.__softhaptic` to appear.
// Every function returns plain data, so a test can take a consistent snapshot of one rendered
// frame inside a single `page.evaluate`.
//
// `ctx` gives the page's parts: the objects it keeps for its whole life, and getters for those it
// makes later (the connection, the timeline, the token keeper and prompt, the station list).

import * as THREE from 'three';

import { depressionAt, profileSetup } from './deformation.js';
import { encodeReplayControl } from './protocol.js';

/** Installs `window.__softhaptic` over the page's parts when the page is driven by a test. */
export function installTestHook(ctx) {
  if (!navigator.webdriver) return;
  const { state, view, dom, rendered, buffer, timings } = ctx;
  window.__softhaptic = {
    ready: () => state.meshes.length > 0 && state.tool !== null,
    webgl: () => view.renderer !== null,
    gpu: () => ({ name: view.gpuName ?? null, software: Boolean(view.software) }),
    scene: () => state.sceneJson,
    /** The device's state as the last `stats` message gave it, and the words shown for it. */
    device: () => {
      const status = state.lastStats ? (state.lastStats.device ?? 'ok') : null;
      return { status, shown: dom['s-device'].textContent };
    },
    /** The lab: whether the server is a hub, the station shown, and the list as drawn. */
    stations: () => ({
      isHub: ctx.stationList?.isHub ?? null,
      current: state.station,
      archive: state.archive,
      listed: [...dom['stations-list'].querySelectorAll('li[data-station]')].map((li) => ({
        name: li.dataset.station,
        current: li.classList.contains('current'),
        text: li.textContent,
        href: li.querySelector('a')?.getAttribute('href') ?? null,
        archived: [...li.querySelectorAll('li[data-archive]')].map((a) => ({
          file: a.dataset.archive,
          href: a.querySelector('a')?.getAttribute('href') ?? null,
        })),
      })),
    }),
    /** Whether `hello` said the force is felt, and the words the page shows for it. */
    forceFeedback: () => ({ felt: state.forceFeedback, shown: dom.feedback.textContent }),
    sceneLoads: () => state.sceneLoads,
    /** A palpation scene's inclusions and the trainee's path as drawn (inclusions.js). */
    inclusions: () => ctx.inclusionsView?.snapshot() ?? null,
    connection: () => ({
      state: ctx.connection.state,
      stats: { ...ctx.connection.stats },
      lastError: ctx.connection.lastError,
      sessionId: state.sessionId,
    }),
    /** The interpolated contact the last animation frame drew. */
    contact: () => ({
      valid: rendered.valid,
      stale: rendered.stale,
      deviceTimeMs: rendered.deviceTimeMs,
      seq: rendered.seq,
      inContact: rendered.inContact,
      depthM: rendered.depthM,
      contactRadiusM: rendered.contactRadiusM,
      deformedRadiusM: rendered.deformedRadiusM,
      inclusionForceRatio: rendered.inclusionForceRatio,
      normal: [...rendered.normal],
      point: [...rendered.point],
      position: [...rendered.position],
      orientation: [...rendered.orientation],
      force: [...rendered.force],
      forceMagnitudeN: rendered.forceMagnitudeN,
      flags: ctx.flagNames(rendered.flags),
    }),
    vertexCount: (mesh = 0) => state.meshes[mesh]?.deformer.vertexCount ?? 0,
    /**
     * Where the meshes are bent, `gpu` or `cpu`; with an argument, bends them there from now on.
     * The hooks below report what is drawn either way (`drawnMesh`).
     */
    deformation: (mode) => {
      if (mode !== undefined) ctx.setDeformation(mode);
      return state.deformation;
    },
    /**
     * Makes the meshes' bending shader fail to compile from the next draw, as a WebGL
     * implementation that refuses it would (the page must go back to the CPU path).
     */
    breakDeformationShader: () => {
      for (const m of state.meshes) {
        const material = m.mesh.material;
        const install = material.onBeforeCompile;
        material.onBeforeCompile = (shader) => {
          install(shader);
          shader.vertexShader = shader.vertexShader.replace('void main() {', 'void main() {\n  not glsl;');
        };
        material.customProgramCacheKey = () => 'softhaptic-deformation-refused';
        material.needsUpdate = true;
      }
    },
    /** Rest and current position of vertex i in the world frame, and how far it moved (m). */
    vertex: (i, mesh = 0) => {
      const m = state.meshes[mesh];
      const drawn = ctx.drawnMesh(m);
      const rest = new THREE.Vector3()
        .fromArray(m.rest, 3 * i)
        .applyQuaternion(m.mesh.quaternion)
        .add(m.objectPosition);
      const now = new THREE.Vector3()
        .fromArray(drawn.positions, 3 * i)
        .applyQuaternion(m.mesh.quaternion)
        .add(m.objectPosition);
      return { rest: rest.toArray(), now: now.toArray(), displacementM: rest.distanceTo(now) };
    },
    vertexDisplacement: (i, mesh = 0) => window.__softhaptic.vertex(i, mesh).displacementM,
    /** Index of the render vertex whose rest position is nearest the world point (x, y, z). */
    findVertexNear: (x, y, z, mesh = 0) => {
      const m = state.meshes[mesh];
      const p = new THREE.Vector3(x, y, z).sub(m.objectPosition).applyQuaternion(m.objectInverse);
      let best = -1;
      let bestD = Infinity;
      for (let i = 0; i < m.deformer.vertexCount; i++) {
        const d = (m.rest[3 * i] - p.x) ** 2 + (m.rest[3 * i + 1] - p.y) ** 2 + (m.rest[3 * i + 2] - p.z) ** 2;
        if (d < bestD) [best, bestD] = [i, d];
      }
      return { index: best, distanceM: Math.sqrt(bestD) };
    },
    /** Vertices currently displaced from rest (index, world rest position, displacement). */
    movedVertices: (mesh = 0) => {
      const { deformer } = ctx.drawnMesh(state.meshes[mesh]);
      const out = [];
      for (let k = 0; k < deformer.movedCount; k++) out.push(deformer.moved[k]);
      return out;
    },
    /** The deformation profile evaluated for the rendered contact at radial distance r. */
    profileAt: (r) =>
      state.tool
        ? depressionAt(profileSetup(state.tool, rendered.depthM, rendered.contactRadiusM, rendered.deformedRadiusM), r)
        : 0,
    deformationTimings: () => ({
      samplesMs: Array.from(timings.ms.subarray(0, timings.count)),
      medianMs: ctx.median(timings),
      movedVertices: timings.moved,
    }),
    forcePlotSamples: () => {
      const out = [];
      ctx.plot.forEachVisible((t, f) => out.push({ timeMs: t, forceN: f }));
      return out;
    },
    peakForceN: () => ctx.plot.peakForceN,
    fps: ctx.fps,
    framesReceivedPerSecond: () => buffer.arrivalsSince(performance.now()),
    /** Contact frames received since the page loaded. */
    contactFrames: () => state.contactFrames,
    /** The active contact model as the info panel shows it. */
    contactModel: () => state.contactModel,
    /** The replay timeline: what it shows and what the server last said. */
    replay: () => ({
      visible: ctx.timeline.visible,
      panelVisible: !dom['replay-panel'].hidden,
      known: ctx.timeline.clock.known,
      durationS: ctx.timeline.clock.durationS,
      positionS: ctx.timeline.positionS(performance.now()),
      paused: ctx.timeline.clock.paused,
      speed: ctx.timeline.clock.speed,
      file: ctx.timeline.clock.file,
      statuses: ctx.timeline.clock.statuses,
      lastStatus: ctx.timeline.lastStatus,
      scrubber: { value: dom['replay-scrubber'].valueAsNumber, max: Number(dom['replay-scrubber'].max) },
      timeText: dom['replay-time'].textContent,
      sent: ctx.timeline.sent.slice(),
      statusLog: ctx.timeline.statusLog.slice(),
      statusesReceived: ctx.timeline.statusesReceived,
      controllable: ctx.timeline.controllable,
      refusals: ctx.timeline.refusals.slice(),
      refusedShown: !dom['replay-refused'].hidden,
      refusedText: dom['replay-refused'].textContent,
      clockRestarts: buffer.clockRestarts,
      /** The gap marks drawn on the track: cause, title, and the left edge in percent. */
      gaps: [...dom['replay-gaps'].children].map((m) => ({
        cause: ['damaged', 'above_safe', 'mark'].find((c) => m.classList.contains(c)) ?? 'lost_ticks',
        title: m.title,
        leftPct: parseFloat(m.style.left),
      })),
    }),
    lastStats: () => state.lastStats,
    /** The last metrics message, and the panel's text for it. */
    metrics: () => ({
      last: state.lastMetrics,
      peakShown: dom['t-peak'].textContent,
      shown: {
        contact: dom['t-contact'].textContent,
        path: dom['t-path'].textContent,
        pushes: dom['t-pushes'].textContent,
      },
    }),
    /** The role the server granted (`instructor`, `observer`; null before a `hello`). */
    role: () => state.role,
    /** `live` or `replay`, as the server's `hello` said; null before one. */
    mode: () => state.mode,
    /** The prompt for a link or a token: whether it is shown, why, and what its note says. */
    prompt: () => ({
      shown: ctx.prompt.shown,
      reason: ctx.prompt.reason,
      detail: dom['token-prompt-detail'].textContent,
      note: dom['token-prompt-note'].textContent,
      visible: !dom['token-prompt'].hidden,
    }),
    /** Whether the viewer holds a token (never the token itself). */
    hasToken: () => ctx.keeper.token !== null,
    /**
     * Sends a replay control past the page's controls, as a viewer of another role might: for
     * the tests of the server's refusal. Returns whether it was sent.
     */
    sendReplayControl: (action, options) => ctx.connection.send(encodeReplayControl(action, options)),
    /** Freezes (true) or resumes (false) the drawn contact; frames keep arriving meanwhile. */
    pause: (paused) => {
      state.paused = Boolean(paused);
    },
    /** Stops (false) or restarts (true) the animation loop, so a benchmark has the CPU alone. */
    animation: (on) => {
      if (view.renderer) view.renderer.setAnimationLoop(on ? ctx.animate : null);
    },
    /** The marks received, in id order, and the list's text. */
    marks: () => ({
      marks: [...state.marks.values()].sort((a, b) => a.id - b.id),
      listed: [...dom['mark-list'].children].map((li) => li.textContent),
      formShown: !dom['mark-form'].hidden,
    }),
    /** The guidance as drawn: the ghost tool, the path's split, the guiding force's arrow. */
    guide: () => ctx.guideView.snapshot(rendered),
    /** The exercise panel as shown, and the task as drawn in the 3-D view. */
    exercise: () => ctx.exercisePanel.snapshot(performance.now()),
    /** Presses an exercise button (`next`, `repeat`, `stop`), as an instructor does. */
    exerciseButton: (action) => ctx.dom[`ex-${action}`].click(),
    /** Sends an exercise control whether or not the page offers its button (an observer's). */
    sendExerciseControl: (action) => ctx.exercisePanel.control(action),
    /** Types a note and submits the mark form, as an instructor does. */
    submitMark: (note) => {
      dom['mark-note'].value = note;
      dom['mark-form'].requestSubmit();
    },
    /** Turns the depression map on or off, as its checkbox does. */
    depressionMap: (on) => ctx.setDepressionMap(on),
    /** A render vertex's colour multiplier (RGB; white when the map is off or it did not move). */
    vertexColor: (i, mesh = 0) => {
      const m = state.meshes[mesh];
      if (!m) return null;
      const { colors } = ctx.drawnMesh(m);
      return [colors[3 * i], colors[3 * i + 1], colors[3 * i + 2]];
    },
    /** Turns the section view on or off, and where its plane is (normal, constant) when on. */
    section: (on) => {
      if (on !== undefined) ctx.setSection(on);
      const p = state.section ? ctx.sectionPlane() : null;
      return p ? { on: true, normal: p.normal.toArray(), constant: p.constant } : { on: false };
    },
    /**
     * The section's line of the undeformed surface: its segments (all meshes) and whether it is
     * drawn. With an argument, shows or hides it until the section is turned on or off again (a
     * frame of the cut without it, to compare).
     */
    sectionReference: (visible) => {
      let segments = 0;
      let shown = false;
      for (const m of state.meshes) {
        if (!m.section) continue;
        if (visible !== undefined) m.section.line.visible = Boolean(visible);
        segments += m.section.buffer.segments;
        shown ||= m.section.line.visible;
      }
      return { segments, visible: shown };
    },
    /**
     * Draws the meshes in their rest shape (true) or bent (false) from now on, the tool still
     * placed and see-through as the contact says: a pressed frame and the same frame undeformed
     * differ by the dent alone.
     */
    restShape: (on) => ctx.setRestShape(on),
    /** The instructors' markers on the object: each mark's id and the marker's world position. */
    markers: () =>
      view.markers.map(({ id, mesh }) => ({ id, position: mesh.position.toArray(), visible: mesh.visible })),
    /** Shows or hides the markers (a frame without them, to compare). */
    markersVisible: (on) => {
      for (const { mesh } of view.markers) mesh.visible = Boolean(on);
    },
    /** Puts the camera back where the page put it when the scene loaded (the default view). */
    resetCamera: () => ctx.frameCamera(),
    /** The tool's opacity now (1 free, less in contact). */
    toolOpacity: () => view.toolMaterials[0]?.opacity ?? null,
    /** Shows or hides the tool (a screenshot of the surface alone). */
    toolVisible: (on) => {
      if (view.toolGroup) view.toolGroup.visible = Boolean(on);
    },
    /** A world point's position on the page, CSS pixels from the canvas' top left. */
    toScreen: (point) => {
      // The camera may have moved since the last draw (`focusCamera`), which updates its matrices.
      view.camera.updateMatrixWorld();
      const v = new THREE.Vector3(point[0], point[1], point[2]).project(view.camera);
      const el = view.renderer?.domElement;
      if (!el) return null;
      return { x: ((v.x + 1) / 2) * el.clientWidth, y: ((1 - v.y) / 2) * el.clientHeight };
    },
    /**
     * The drawn pixels (RGBA, rows from the bottom) of a square of `sizePx` CSS pixels centred on
     * a page position, rendered now: what the canvas shows there, read back from WebGL.
     */
    regionPixels: (x, y, sizePx) => {
      if (!view.renderer) return null;
      view.renderer.render(view.scene, view.camera);
      const gl = view.renderer.getContext();
      const ratio = view.renderer.getPixelRatio();
      const h = view.renderer.domElement.height;
      const size = Math.round(sizePx * ratio);
      const px = Math.round(x * ratio - size / 2);
      const py = Math.round(h - y * ratio - size / 2);
      const out = new Uint8Array(size * size * 4);
      gl.readPixels(px, py, size, size, gl.RGBA, gl.UNSIGNED_BYTE, out);
      return Array.from(out);
    },
    /**
     * Moves the camera to look at a world point from `distanceM` away, `elevationRad` above the
     * horizontal (screenshots; a low camera shows the dimple's profile beside the tool).
     */
    focusCamera: (point, distanceM, elevationRad = 0.6) => {
      const h = distanceM * Math.cos(elevationRad);
      view.camera.position.set(point[0] + h * 0.6, point[1] + distanceM * Math.sin(elevationRad), point[2] + h * 0.8);
      if (view.controls) {
        view.controls.target.set(point[0], point[1], point[2]);
        view.controls.update();
      }
    },
  };
}
