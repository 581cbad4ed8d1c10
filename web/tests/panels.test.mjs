// The info panel's flag chips (src/panels.js), drawn from a contact frame as the page draws it:
// the wire text decoded, pushed into the playout buffer, sampled into the rendered contact, the
// panels written. Flags that mean the force is not what the model says (a hand pushed through,
// a device fault, the force clipped at the device's peak) are shown severe (red); the others
// light up without it. Runs in node against a small fake document.
import { before, test } from 'node:test';
import assert from 'node:assert/strict';

import { contact } from './fixtures.mjs';

/** The few parts of a DOM element the panels write. */
class FakeElement {
  constructor(tag, id = '') {
    this.tagName = tag.toUpperCase();
    this.id = id;
    this.textContent = '—';
    this.className = '';
    this.title = '';
    this.hidden = false;
    this.children = [];
  }

  appendChild(child) {
    this.children.push(child);
    return child;
  }
}

let panels;
let context;
let decodeMessage;
let CONTACT_FLAGS;
const elements = new Map();

before(async () => {
  // What the page's modules read when they load: its address (no station, no archive) and the
  // document's elements by id.
  globalThis.window = { location: { search: '' } };
  globalThis.document = {
    getElementById: (id) => {
      if (!elements.has(id)) elements.set(id, new FakeElement('div', id));
      return elements.get(id);
    },
    createElement: (tag) => new FakeElement(tag),
  };
  panels = await import('../src/panels.js');
  context = await import('../src/context.js');
  ({ decodeMessage, CONTACT_FLAGS } = await import('../src/protocol.js'));
  panels.bindPanels();
});

/** The panels as the page writes them after drawing the frame `overrides` make (at 1 s). */
function drawFrame(overrides) {
  const { buffer, rendered } = context;
  buffer.reset();
  // The frame as it comes off the wire, validated.
  const decoded = decodeMessage(JSON.stringify(contact(overrides)));
  assert.equal(decoded.kind, 'message');
  buffer.push(decoded.message, 1000);
  // Drawn the playout delay later: exactly the frame, and not stale.
  buffer.sample(1000 + context.PLAYOUT_DELAY_MS, rendered);
  assert.equal(rendered.valid, true);
  assert.equal(rendered.stale, false);
  panels.updatePanels({ connection: { lastError: null }, timeline: { visible: false } });
}

/** The chips lit, by wire name, with their class. */
function litChips() {
  const chips = elements.get('flags').children;
  assert.equal(chips.length, CONTACT_FLAGS.length, 'one chip per known flag');
  const lit = {};
  chips.forEach((chip, i) => {
    assert.equal(chip.title, CONTACT_FLAGS[i]);
    if (chip.className !== 'flag') lit[chip.title] = chip.className;
  });
  return lit;
}

test('a contact frame with pushed_through lights its chip as severe', () => {
  drawFrame({ flags: ['pushed_through'] });
  assert.deepEqual(litChips(), { pushed_through: 'flag on severe' });
  assert.equal(elements.get('contact-state').textContent, 'in contact');
});

test('a device fault and a saturated force light their chips as severe', () => {
  drawFrame({ flags: ['device_fault', 'saturated'] });
  assert.deepEqual(litChips(), { saturated: 'flag on severe', device_fault: 'flag on severe' });
});

test('benign flags light their chips without the severe mark, and a frame without flags lights none', () => {
  drawFrame({ flags: ['ramping', 'beyond_valid_depth', 'passivity_damping'] });
  assert.deepEqual(litChips(), {
    beyond_valid_depth: 'flag on',
    ramping: 'flag on',
    passivity_damping: 'flag on',
  });
  // Severe and benign together: each chip keeps its own kind.
  drawFrame({ flags: ['ramping', 'pushed_through'] });
  assert.deepEqual(litChips(), { ramping: 'flag on', pushed_through: 'flag on severe' });
  drawFrame({ flags: [] });
  assert.deepEqual(litChips(), {});
});
