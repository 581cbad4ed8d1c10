// The exercise panel: what a station running exercises asks of its trainee, and how the attempt
// went. From each `exercise` message it shows the task (its name, instructions and target), the
// time left (counted down on this page's clock between messages, which come about once a
// second), and, once the attempt has ended, the verdict with each pass mark's value; in the 3-D
// view it draws the task: the press site's ring (its radius is how near the tool must be) or
// the path to trace. An instructor on a live station also gets the buttons that start the next
// exercise, repeat this one or stop it; an observer (a trainee's own screen, a class) does not.
// A palpation's lumps are not drawn here: the message holds only the area to search (the
// `inclusions` message, sent by role, is drawn by inclusions.js).

import * as THREE from 'three';

import { encodeExerciseControl } from './protocol.js';

/** Lifts the drawn task off the surface along its normal (m), so the object does not hide it. */
const LIFT_M = 0.0006;
const TASK_COLOR = 0x2fbf71;

function formatSeconds(s) {
  return `${s.toFixed(1)} s`;
}

/** The target in words: the force window and hold, or the path's tolerance. */
export function targetText(task) {
  if (task.kind === 'press') {
    return (
      `press ${task.target_force_n} ± ${task.tolerance_n} N within ${(task.site_radius_m * 1e3).toFixed(0)} mm ` +
      `of the ring, hold ${task.hold_s} s; stay below ${task.safe_force_n} N`
    );
  }
  if (task.kind === 'follow') {
    return `follow ${task.expert}'s path once, to its end, then lift away; stay below ${task.safe_force_n} N`;
  }
  if (task.kind === 'palpation') {
    return (
      `find the lumps within the ${(task.area_radius_m * 1e3).toFixed(0)} mm circle and mark each with ` +
      `the button; stay below ${task.safe_force_n} N`
    );
  }
  const force = task.target_force_n == null ? '' : ` at ${task.target_force_n} ± ${task.force_tolerance_n} N`;
  return (
    `trace the line within ${(task.tolerance_m * 1e3).toFixed(1)} mm${force}, ` +
    `${Math.round(task.min_coverage * 100)} % of it; stay below ${task.safe_force_n} N`
  );
}

/** A pass mark's outcome in words: `hold_force_sd_n 0.0625 ≤ 0.15: met`. */
export function markText(m) {
  const bound = m.mark.at_least != null ? `≥ ${m.mark.at_least}` : `≤ ${m.mark.at_most}`;
  const value = Number.isFinite(m.value) ? Number(m.value.toPrecision(4)) : m.value;
  return `${m.mark.metric} ${value} ${bound}: ${m.met ? 'met' : 'missed'}`;
}

export class ExercisePanel {
  /**
   * `dom`: the page's elements by id; `scene`: a function giving the three.js scene (null
   * without WebGL); `send`: sends a text message to the server, false when it cannot.
   */
  constructor({ dom, scene, send }) {
    this.dom = dom;
    this.scene = scene;
    this.send = send;
    /** The last message, and this page's clock when it came. */
    this.last = null;
    this.receivedAtMs = 0;
    this.instructor = false;
    this.live = true;
    /** What the 3-D view shows of the task: `{kind, points, object}`. */
    this.drawn = null;
    this.drawnKey = '';
    for (const action of ['next', 'repeat', 'stop']) {
      dom[`ex-${action}`].addEventListener('click', () => this.control(action));
    }
  }

  /** The connection's role and mode (from `hello`): only an instructor on a live station acts. */
  setAccess(role, mode) {
    this.instructor = role === 'instructor';
    this.live = mode === 'live';
    this.showControls();
  }

  showControls() {
    this.dom['ex-controls'].hidden = !(this.instructor && this.live && this.last !== null);
  }

  /** Sends an instructor's control; false when it could not be sent. */
  control(action) {
    return this.send(encodeExerciseControl(action));
  }

  /** Takes an `exercise` message. */
  onMessage(m, receivedAtMs) {
    this.last = m;
    this.receivedAtMs = receivedAtMs;
    const d = this.dom;
    d['exercise-panel'].hidden = false;
    d['ex-progress'].textContent = `${m.index + 1} of ${m.count} · attempt ${m.attempt} · ${m.trainee}`;
    d['ex-name'].textContent = m.exercise.name;
    d['ex-instructions'].textContent = m.exercise.instructions;
    d['ex-target'].textContent = targetText(m.exercise.task);
    const result = m.result;
    d['ex-result'].hidden = result === null;
    if (result !== null) {
      const ended =
        { completed: 'goal reached', time_limit: 'time up', stopped: 'stopped' }[result.ended] ?? result.ended;
      d['ex-verdict'].textContent = result.passed ? 'passed' : 'not passed';
      d['ex-verdict'].className = `badge ${result.passed ? 'ok' : 'bad'}`;
      let how = `${ended}${result.score.safe ? '' : ', above the safe force'}`;
      if (m.exercise.task.kind === 'palpation') {
        // Said once the time is up, to the trainee too: which were found.
        const sm = result.score.metrics;
        how += ` · found ${sm.found} of ${sm.found + sm.missed}, ${sm.false_marks} false marks`;
      }
      d['ex-ended'].textContent = how;
      d['ex-marks'].replaceChildren(
        ...result.marks.map((mark) => {
          const li = document.createElement('li');
          li.textContent = markText(mark);
          li.className = mark.met ? 'met' : 'missed';
          return li;
        }),
      );
      d['ex-next-in'].textContent =
        m.next_in_s === null
          ? m.index + 1 < m.count
            ? 'the next exercise starts when the instructor says'
            : 'all exercises done'
          : `next exercise in ${Math.ceil(m.next_in_s)} s`;
    }
    this.showControls();
    this.drawTask(m);
    this.tick(receivedAtMs);
  }

  /** Another session: nothing of this one's exercise stays. */
  reset() {
    this.last = null;
    this.drawnKey = '';
    const scene = this.scene();
    if (scene && this.drawn?.object) scene.remove(this.drawn.object);
    this.drawn = null;
    this.dom['exercise-panel'].hidden = true;
    this.dom['ex-refused'].textContent = '';
    this.showControls();
  }

  /** The server refused a control (shown under the buttons). */
  showRefused(reason) {
    this.dom['ex-refused'].textContent = reason;
  }

  /** Seconds left now, on this page's clock since the last message. */
  remainingS(nowMs) {
    const m = this.last;
    if (m === null || m.state !== 'running') return 0;
    return Math.max(0, m.remaining_s - (nowMs - this.receivedAtMs) / 1000);
  }

  /** Per animation frame: the countdown. */
  tick(nowMs) {
    if (this.last === null) return;
    const text = this.last.state === 'running' ? formatSeconds(this.remainingS(nowMs)) : 'ended';
    if (this.dom['ex-countdown'].textContent !== text) this.dom['ex-countdown'].textContent = text;
  }

  /** Draws the task in the 3-D view (once per exercise: its geometry does not change). */
  drawTask(m) {
    const scene = this.scene();
    const key = `${m.index}:${m.exercise.name}`;
    if (!scene || key === this.drawnKey) return;
    if (this.drawn?.object) {
      scene.remove(this.drawn.object);
      this.drawn.object.geometry.dispose();
    }
    this.drawnKey = key;
    const task = m.exercise.task;
    if (task.kind === 'follow') {
      // Its path is the guide's, drawn with the guide.
      this.drawn = { kind: task.kind, points: [], object: null };
      return;
    }
    const n = new THREE.Vector3(...task.normal).normalize();
    const lift = n.clone().multiplyScalar(LIFT_M);
    let points;
    let object;
    const material = new THREE.LineBasicMaterial({ color: TASK_COLOR, depthTest: false });
    if (task.kind === 'press' || task.kind === 'palpation') {
      // A circle around the site (of its radius), or around the area to search (of the
      // area's), in the plane of the surface there. Never the lumps: the task has none.
      const palpation = task.kind === 'palpation';
      const radius = palpation ? task.area_radius_m : task.site_radius_m;
      const centre = new THREE.Vector3(...(palpation ? task.area_centre_m : task.site_m)).add(lift);
      const u = new THREE.Vector3(1, 0, 0);
      if (Math.abs(u.dot(n)) > 0.9) u.set(0, 0, 1);
      u.sub(n.clone().multiplyScalar(u.dot(n))).normalize();
      const v = n.clone().cross(u);
      points = [];
      for (let i = 0; i <= 48; i++) {
        const a = (2 * Math.PI * i) / 48;
        points.push(
          centre
            .clone()
            .addScaledVector(u, radius * Math.cos(a))
            .addScaledVector(v, radius * Math.sin(a)),
        );
      }
      object = new THREE.LineLoop(new THREE.BufferGeometry().setFromPoints(points), material);
    } else {
      points = task.path_m.map((p) => new THREE.Vector3(...p).add(lift));
      object = new THREE.Line(new THREE.BufferGeometry().setFromPoints(points), material);
    }
    // Drawn over the object, where the trainee must see it even inside a dent.
    object.renderOrder = 10;
    scene.add(object);
    this.drawn = { kind: task.kind, points: points.map((p) => p.toArray()), object };
  }

  /** What the browser tests read. */
  snapshot(nowMs) {
    const d = this.dom;
    return {
      shown: !d['exercise-panel'].hidden,
      progress: d['ex-progress'].textContent,
      name: d['ex-name'].textContent,
      target: d['ex-target'].textContent,
      countdown: d['ex-countdown'].textContent,
      remainingS: this.remainingS(nowMs),
      state: this.last?.state ?? null,
      index: this.last?.index ?? null,
      attempt: this.last?.attempt ?? null,
      resultShown: !d['ex-result'].hidden,
      verdict: d['ex-verdict'].textContent,
      ended: d['ex-ended'].textContent,
      marks: [...d['ex-marks'].children].map((li) => li.textContent),
      nextIn: d['ex-next-in'].textContent,
      controlsShown: !d['ex-controls'].hidden,
      refused: d['ex-refused'].textContent,
      drawn: this.drawn
        ? { kind: this.drawn.kind, points: this.drawn.points, visible: this.drawn.object.visible }
        : null,
    };
  }
}
