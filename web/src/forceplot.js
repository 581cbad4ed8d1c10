// The live force plot: |force_n| of the last few seconds of received frames, against device
// time, with the device's peak force as a dashed line. Samples live in a fixed ring that holds
// ten minutes of 50 Hz frames, so that a replay sought backwards still shows the seconds before
// the new position that it had already played; drawing allocates nothing.

export class ForcePlot {
  /**
   * @param {HTMLCanvasElement|null} canvas where to draw (null: keep samples only).
   * @param {{windowMs?: number, capacity?: number}} [options]
   */
  constructor(canvas, { windowMs = 5000, capacity = 30000, pixelRatio = 1 } = {}) {
    this.canvas = canvas;
    this.ctx = canvas ? canvas.getContext('2d') : null;
    // Draw in CSS pixels on a backing store `pixelRatio` times finer (sharp on HiDPI screens).
    this.pixelRatio = pixelRatio;
    this.width = canvas ? canvas.width : 0;
    this.height = canvas ? canvas.height : 0;
    this.resize();
    this.windowMs = windowMs;
    this.capacity = capacity;
    this.timeMs = new Float64Array(capacity);
    this.forceN = new Float64Array(capacity);
    this.head = 0;
    this.count = 0;
    this.peakForceN = 0;
    this.dirty = true;
    this.dash = [5, 4];
    this.noDash = [];
  }

  /** Matches the backing store to the canvas's laid-out size (call when the layout changes). */
  resize() {
    const canvas = this.canvas;
    if (!canvas) return;
    this.width = canvas.clientWidth || this.width;
    this.height = canvas.clientHeight || this.height;
    canvas.width = Math.round(this.width * this.pixelRatio);
    canvas.height = Math.round(this.height * this.pixelRatio);
    this.dirty = true;
  }

  /** Forgets the samples (new session). */
  reset() {
    this.head = 0;
    this.count = 0;
    this.dirty = true;
  }

  setPeakForce(peakForceN) {
    this.peakForceN = peakForceN;
    this.dirty = true;
  }

  /**
   * Adds the magnitude of one frame's force at its device time. A time at or before the newest
   * sample (a replay sought backwards) first drops the samples from that time on: they will come
   * again, and the ones before it stay on the plot.
   */
  push(timeMs, forceN) {
    while (this.count > 0 && this.timeMs[(this.head - 1 + this.capacity) % this.capacity] >= timeMs) {
      this.head = (this.head - 1 + this.capacity) % this.capacity;
      this.count--;
    }
    this.timeMs[this.head] = timeMs;
    this.forceN[this.head] = forceN;
    this.head = (this.head + 1) % this.capacity;
    if (this.count < this.capacity) this.count++;
    this.dirty = true;
  }

  /** Calls `fn(timeMs, forceN)` for each sample within the window, oldest first. */
  forEachVisible(fn) {
    if (this.count === 0) return;
    const newest = this.timeMs[(this.head - 1 + this.capacity) % this.capacity];
    // Samples are in time order: count back from the newest to the window's start, so a draw
    // costs the visible samples, not the whole history.
    let visible = 0;
    while (
      visible < this.count &&
      this.timeMs[(this.head - 1 - visible + 2 * this.capacity) % this.capacity] >= newest - this.windowMs
    ) {
      visible++;
    }
    for (let k = 0; k < visible; k++) {
      const i = (this.head - visible + k + this.capacity) % this.capacity;
      fn(this.timeMs[i], this.forceN[i]);
    }
  }

  /** Force axis: top of the plot, grid step and labels; they change only with the peak force. */
  #layoutAxis() {
    this.yMaxN = Math.max(1, this.peakForceN * 1.15);
    this.gridStepN = this.yMaxN > 8 ? 2 : this.yMaxN > 4 ? 1 : 0.5;
    this.forceLabels = [];
    for (let f = 0; f <= this.yMaxN; f += this.gridStepN) this.forceLabels.push(`${f} N`);
    this.timeLabels = [];
    for (let s = 0; s <= this.windowMs / 1000; s++) this.timeLabels.push(s === 0 ? 'now' : `−${s} s`);
  }

  #y(forceN, top, ph) {
    return top + ph * (1 - Math.min(forceN, this.yMaxN) / this.yMaxN);
  }

  /** Redraws when samples changed; allocates nothing. */
  draw() {
    const ctx = this.ctx;
    if (!ctx || !this.dirty) return;
    this.dirty = false;
    if (this.forceLabels === undefined || this.axisPeakN !== this.peakForceN) {
      this.axisPeakN = this.peakForceN;
      this.#layoutAxis();
    }
    const w = this.width;
    const h = this.height;
    ctx.setTransform(this.pixelRatio, 0, 0, this.pixelRatio, 0, 0);
    const left = 34;
    const right = 10;
    const top = 8;
    const bottom = 18;
    const pw = w - left - right;
    const ph = h - top - bottom;
    ctx.clearRect(0, 0, w, h);

    // Grid: one line per force step, one tick per second.
    ctx.lineWidth = 1;
    ctx.strokeStyle = 'rgba(255,255,255,0.08)';
    ctx.fillStyle = '#8b95a5';
    ctx.font = '10px system-ui, sans-serif';
    ctx.textAlign = 'right';
    ctx.textBaseline = 'middle';
    for (let k = 0; k < this.forceLabels.length; k++) {
      const y = Math.round(this.#y(k * this.gridStepN, top, ph)) + 0.5;
      ctx.beginPath();
      ctx.moveTo(left, y);
      ctx.lineTo(left + pw, y);
      ctx.stroke();
      ctx.fillText(this.forceLabels[k], left - 4, y);
    }
    ctx.textBaseline = 'top';
    for (let s = 0; s < this.timeLabels.length; s++) {
      const x = left + pw * (1 - (s * 1000) / this.windowMs);
      ctx.textAlign = s === 0 ? 'right' : 'center';
      ctx.fillText(this.timeLabels[s], x, top + ph + 4);
    }

    if (this.peakForceN > 0) {
      ctx.strokeStyle = '#f85149';
      ctx.setLineDash(this.dash);
      ctx.beginPath();
      const y = Math.round(this.#y(this.peakForceN, top, ph)) + 0.5;
      ctx.moveTo(left, y);
      ctx.lineTo(left + pw, y);
      ctx.stroke();
      ctx.setLineDash(this.noDash);
    }

    if (this.count === 0) return;
    const newest = this.timeMs[(this.head - 1 + this.capacity) % this.capacity];
    ctx.strokeStyle = '#58a6ff';
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    let first = true;
    for (let k = 0; k < this.count; k++) {
      const i = (this.head - this.count + k + this.capacity) % this.capacity;
      const age = newest - this.timeMs[i];
      if (age > this.windowMs) continue;
      const x = left + pw * (1 - age / this.windowMs);
      const y = this.#y(this.forceN[i], top, ph);
      if (first) ctx.moveTo(x, y);
      else ctx.lineTo(x, y);
      first = false;
    }
    ctx.stroke();
  }
}
