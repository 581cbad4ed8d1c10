// The inclusions' drawing (src/inclusions.js) on a three.js scene without a renderer: what it
// draws for each message, the path it keeps, and when it forgets a revealed answer.
import { test } from 'node:test';
import assert from 'node:assert/strict';

import * as THREE from 'three';

import { InclusionsView, MAX_PATH_POINTS } from '../src/inclusions.js';

const LUMP = { centre_m: [0.01, 0.08, 0.0], radius_m: 0.005, stiffness_ratio: 4, centre_depth_m: 0.01 };

function message(revealed, index, attempt) {
  return { type: 'inclusions', revealed, exercise_index: index, attempt, inclusions: [LUMP] };
}

function frame(x, inContact = true) {
  return { in_contact: inContact, contact_point_m: [x, 0.09, 0] };
}

test('spheres are drawn where the message says, through the surface, and the path follows the contact', () => {
  const scene = new THREE.Scene();
  const view = new InclusionsView({ scene: () => scene });
  view.onExercise({ index: 0, attempt: 1, state: 'running' });
  assert.equal(view.snapshot().shown, false, 'nothing drawn before a message');
  view.onInclusions(message(false, 0, 1));
  const s = view.snapshot();
  assert.equal(s.shown, true);
  assert.deepEqual(s.spheres[0].centre, LUMP.centre_m);
  assert.equal(s.spheres[0].depthTest, false);
  // Out of contact adds nothing; a step under 0.3 mm adds nothing.
  view.onContact(frame(0, false));
  view.onContact(frame(0));
  view.onContact(frame(0.0001));
  view.onContact(frame(0.001));
  assert.equal(view.snapshot().pathPoints, 2);
  assert.equal(view.snapshot().pathDrawn, 2);
  // A long search is thinned, never cut off.
  for (let i = 0; i < MAX_PATH_POINTS + 10; i++) view.onContact(frame(0.002 + i * 0.001));
  const long = view.snapshot().pathPoints;
  assert.ok(long > MAX_PATH_POINTS / 2 && long <= MAX_PATH_POINTS, `${long}`);
  assert.equal(scene.children.length, 1);
});

test('a revealed answer is forgotten, and the path started over, when another attempt starts', () => {
  const scene = new THREE.Scene();
  const view = new InclusionsView({ scene: () => scene });
  view.onExercise({ index: 0, attempt: 1, state: 'running' });
  view.onContact(frame(0));
  view.onExercise({ index: 0, attempt: 1, state: 'ended' });
  view.onInclusions(message(true, 0, 1));
  assert.equal(view.snapshot().revealed, true);
  assert.equal(view.snapshot().pathPoints, 1, 'the ended attempt keeps its path');
  view.onExercise({ index: 0, attempt: 2, state: 'running' });
  assert.equal(view.snapshot().shown, false);
  assert.equal(view.snapshot().pathPoints, 0);
  assert.equal(scene.children.length, 0);
  // An instructor's answer for the new attempt is drawn again.
  view.onInclusions(message(false, 0, 2));
  view.onExercise({ index: 0, attempt: 2, state: 'running' });
  assert.equal(view.snapshot().shown, true);
  view.reset();
  assert.equal(view.snapshot().shown, false);
});

test('a withdrawn answer (a replay sought back before the end) is no longer drawn', () => {
  const scene = new THREE.Scene();
  const view = new InclusionsView({ scene: () => scene });
  view.onExercise({ index: 0, attempt: 1, state: 'ended' });
  view.onInclusions(message(true, 0, 1));
  assert.equal(view.snapshot().shown, true);
  view.onInclusions({ type: 'inclusions', revealed: false, exercise_index: null, attempt: null, inclusions: [] });
  assert.equal(view.snapshot().shown, false);
  assert.equal(view.snapshot().revealed, null);
});
