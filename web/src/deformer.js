// `MeshDeformer` moves the vertices of a render mesh around a contact: it keeps a uniform spatial
// grid over the rest positions so that a frame visits only the cells near the contact, restores
// the vertices it moved the frame before, writes analytic normals for the moved vertices, and
// allocates nothing after construction. The `fem` profile reaches far (to where the FEM block's
// surface settles, tens of millimetres), so a frame may move most of a 100 000-vertex mesh: it
// is drawn from a radial table of the profile (`surfaceTable`, proto's `SurfaceTable`) sampled
// once per frame, one lookup per vertex. Besides sinking along −n, a vertex of the `fem` profile
// moves sideways (radially, away from the contact axis or towards it) when the calibration's
// table carries the FEM surface's radial displacement; a table without it costs nothing more.

import {
  SURFACE_TABLE_INTERVALS,
  evaluateAt,
  profileSetup,
  stiffenSurface,
  surfaceSetup,
  surfaceTable,
} from './deformation.js';

/**
 * Deforms one render mesh in its object frame. Built once per mesh; `apply` is called each
 * animation frame and allocates nothing.
 */
export class MeshDeformer {
  /**
   * @param {Float32Array} restPositions xyz per vertex, object frame (m); not modified.
   * @param {Float32Array|null} restNormals unit xyz per vertex, or null when normals are not kept.
   * @param {{cellSizeM?: number, maxCells?: number}} [options] grid cell edge (default: the
   *   larger of 1/48 of the largest extent and what keeps the grid under `maxCells` cells).
   */
  constructor(restPositions, restNormals = null, options = {}) {
    if (!(restPositions instanceof Float32Array) || restPositions.length % 3 !== 0) {
      throw new Error('restPositions must be a Float32Array of xyz triples');
    }
    const n = restPositions.length / 3;
    if (
      restNormals !== null &&
      (!(restNormals instanceof Float32Array) || restNormals.length !== restPositions.length)
    ) {
      throw new Error(`restNormals must be a Float32Array of ${restPositions.length} values`);
    }
    this.vertexCount = n;
    this.restPositions = restPositions;
    this.restNormals = restNormals;

    let minX = Infinity,
      minY = Infinity,
      minZ = Infinity;
    let maxX = -Infinity,
      maxY = -Infinity,
      maxZ = -Infinity;
    for (let i = 0; i < n; i++) {
      const x = restPositions[3 * i],
        y = restPositions[3 * i + 1],
        z = restPositions[3 * i + 2];
      if (!(Number.isFinite(x) && Number.isFinite(y) && Number.isFinite(z))) {
        throw new Error(`vertex ${i} has a non-finite position (${x}, ${y}, ${z})`);
      }
      if (x < minX) minX = x;
      if (y < minY) minY = y;
      if (z < minZ) minZ = z;
      if (x > maxX) maxX = x;
      if (y > maxY) maxY = y;
      if (z > maxZ) maxZ = z;
    }
    if (n === 0) {
      minX = minY = minZ = 0;
      maxX = maxY = maxZ = 0;
    }
    const maxCells = options.maxCells ?? 1 << 20;
    const extent = Math.max(maxX - minX, maxY - minY, maxZ - minZ, 1e-9);
    let cell = options.cellSizeM ?? extent / 48;
    const cellsFor = (h) =>
      (Math.floor((maxX - minX) / h) + 1) * (Math.floor((maxY - minY) / h) + 1) * (Math.floor((maxZ - minZ) / h) + 1);
    while (cellsFor(cell) > maxCells) cell *= 1.25;
    this.cellSizeM = cell;
    this.origin = [minX, minY, minZ];
    this.dims = [
      Math.floor((maxX - minX) / cell) + 1,
      Math.floor((maxY - minY) / cell) + 1,
      Math.floor((maxZ - minZ) / cell) + 1,
    ];
    const cellCount = this.dims[0] * this.dims[1] * this.dims[2];
    // Compressed cell lists: the vertices of cell k are cellVertices[cellStart[k] .. cellStart[k+1]].
    const cellOf = new Uint32Array(n);
    this.cellStart = new Uint32Array(cellCount + 1);
    for (let i = 0; i < n; i++) {
      const k = this.#cellIndex(restPositions[3 * i], restPositions[3 * i + 1], restPositions[3 * i + 2]);
      cellOf[i] = k;
      this.cellStart[k + 1]++;
    }
    for (let k = 0; k < cellCount; k++) this.cellStart[k + 1] += this.cellStart[k];
    const fill = this.cellStart.slice(0, cellCount);
    this.cellVertices = new Uint32Array(n);
    for (let i = 0; i < n; i++) this.cellVertices[fill[cellOf[i]]++] = i;
    // The rest position and normal of each vertex again, in the cell lists' order and side by
    // side (x, y, z, nx, ny, nz): a frame reads them in one sweep through memory instead of
    // jumping between vertex indices in two arrays (8% less time per frame on a 100 000-vertex
    // grid, for 24 bytes per vertex).
    this.cellRest = new Float32Array(6 * n);
    for (let s = 0; s < n; s++) {
      const i = this.cellVertices[s];
      for (let c = 0; c < 3; c++) {
        this.cellRest[6 * s + c] = restPositions[3 * i + c];
        this.cellRest[6 * s + 3 + c] = restNormals === null ? 0 : restNormals[3 * i + c];
      }
    }

    // Per-frame bookkeeping, preallocated: the vertices written this frame, those it moved
    // first and then those it put back to rest (`written`), and the same list of the frame
    // before (`writtenSpare`; the two swap each frame), whose first entries are the vertices
    // to restore unless this frame moves them. A stamp marks the vertices moved this frame, so
    // that one moved in both frames is written once, not restored and then moved; it is a byte
    // (the frame number counts 1 … 255, and every stamp is cleared when it starts again at 1)
    // to keep down the memory each vertex costs per frame.
    this.written = new Int32Array(n);
    this.writtenSpare = new Int32Array(n);
    this.movedCount = 0;
    this.touchedCount = 0;
    this.stamp = new Uint8Array(n);
    this.frame = 0;
    this.profile = {};
    this.surfaceProfile = surfaceSetup(null, { valid: false }, 0, {});
    this.table = surfaceTable(this.surfaceProfile, {});
    this.evaluation = new Float64Array(3);
    this.lastVisitedCells = 0;
  }

  #cellIndex(x, y, z) {
    const [nx, ny, nz] = this.dims;
    const h = this.cellSizeM;
    const ix = Math.min(nx - 1, Math.max(0, Math.floor((x - this.origin[0]) / h)));
    const iy = Math.min(ny - 1, Math.max(0, Math.floor((y - this.origin[1]) / h)));
    const iz = Math.min(nz - 1, Math.max(0, Math.floor((z - this.origin[2]) / h)));
    return (iz * ny + iy) * nx + ix;
  }

  /** The vertices the last `apply` moved: `moved[0 .. movedCount]`. */
  get moved() {
    return this.written;
  }

  /** The vertices the last `apply` wrote, moved or restored: `touched[0 .. touchedCount]`. */
  get touched() {
    return this.written;
  }

  /**
   * Deforms `positionsOut` (and `normalsOut`, when given) for one contact, in the object frame.
   *
   * `contact`: `{inContact, depthM, contactRadiusM, deformedRadiusM, inclusionForceRatio (optional,
   * 1 without inclusions: see `stiffenSurface`), point: [x,y,z], normal:
   * [x,y,z]}` with point and normal already in the mesh's object frame; `tool` from
   * `toolFromJson`; `surface` the `fem` profile's family (`surfaceFamilyFromJson`) to draw it,
   * or null for the paper's Bézier. A vertex v moves by −n·z(r) when r is inside the profile's
   * reach (R_d_eff for the paper's) and |(v − c)·n| is too (the far side never moves), and for
   * `fem` also by u(r) along its radial direction e/r (e = v − c − ((v − c)·n)·n, |e| = r; not
   * sideways at r = 0); the vertices moved by the previous call and not by this one go back to
   * rest.
   *
   * Returns the number of vertices written (moved or restored); their indices are
   * `this.touched[0 .. count]`, for partial normal or buffer updates.
   */
  apply(positionsOut, normalsOut, contact, tool, surface = null) {
    this.frame = this.frame === 255 ? 1 : this.frame + 1;
    if (this.frame === 1) this.stamp.fill(0);
    const previous = this.written;
    const previousCount = this.movedCount;
    this.written = this.writtenSpare;
    this.writtenSpare = previous;
    this.movedCount = 0;
    this.touchedCount = 0;
    this.lastVisitedCells = 0;
    this.#move(positionsOut, normalsOut, contact, tool, surface);
    // Then back to rest every vertex moved the frame before and not this one (the stamp marks
    // the ones moved this frame).
    const rest = this.restPositions;
    const restN = normalsOut ? this.restNormals : null;
    const stamp = this.stamp;
    const frame = this.frame;
    const written = this.written;
    let count = this.movedCount;
    for (let m = 0; m < previousCount; m++) {
      const i = previous[m];
      if (stamp[i] === frame) continue;
      const j = 3 * i;
      positionsOut[j] = rest[j];
      positionsOut[j + 1] = rest[j + 1];
      positionsOut[j + 2] = rest[j + 2];
      if (restN !== null) {
        normalsOut[j] = restN[j];
        normalsOut[j + 1] = restN[j + 1];
        normalsOut[j + 2] = restN[j + 2];
      }
      written[count++] = i;
    }
    this.touchedCount = count;
    return count;
  }

  /** The moving half of `apply`: writes and lists the vertices the contact moves this frame. */
  #move(positionsOut, normalsOut, contact, tool, surface) {
    if (!contact || !contact.inContact) return;

    const fem = surface !== null;
    let reach;
    if (fem) {
      const p = stiffenSurface(
        surfaceSetup(surface, tool, contact.depthM, this.surfaceProfile),
        contact.inclusionForceRatio ?? 1,
      );
      if (p.depthM === 0) return;
      reach = p.reachM;
    } else {
      const p = profileSetup(tool, contact.depthM, contact.contactRadiusM, contact.deformedRadiusM, this.profile);
      if (p.depthM === 0) return;
      reach = p.rdEff;
    }
    if (!(reach > 0)) return;
    let nx = contact.normal[0],
      ny = contact.normal[1],
      nz = contact.normal[2];
    const nLen = Math.sqrt(nx * nx + ny * ny + nz * nz);
    if (!(nLen > 0 && Number.isFinite(nLen))) return;
    nx /= nLen;
    ny /= nLen;
    nz /= nLen;
    const cx = contact.point[0],
      cy = contact.point[1],
      cz = contact.point[2];
    if (!(Number.isFinite(cx) && Number.isFinite(cy) && Number.isFinite(cz))) return;
    if (fem) surfaceTable(this.surfaceProfile, this.table);

    // A vertex that may move is u = h·n + e with |h| < reach and |e| < reach; along axis i that
    // is at most reach·(|n_i| + √(1 − n_i²)) from c (reach·√2 at worst, reach along n's own
    // axis and across it), so only the cells of that box are visited.
    const h = this.cellSizeM;
    const origin = this.origin;
    const dims = this.dims;
    const dx = dims[0],
      dy = dims[1],
      dz = dims[2];
    const bx = reach * (Math.abs(nx) + Math.sqrt(Math.max(0, 1 - nx * nx)));
    const by = reach * (Math.abs(ny) + Math.sqrt(Math.max(0, 1 - ny * ny)));
    const bz = reach * (Math.abs(nz) + Math.sqrt(Math.max(0, 1 - nz * nz)));
    const ix0 = Math.max(0, Math.floor((cx - bx - origin[0]) / h));
    const iy0 = Math.max(0, Math.floor((cy - by - origin[1]) / h));
    const iz0 = Math.max(0, Math.floor((cz - bz - origin[2]) / h));
    const ix1 = Math.min(dx - 1, Math.floor((cx + bx - origin[0]) / h));
    const iy1 = Math.min(dy - 1, Math.floor((cy + by - origin[1]) / h));
    const iz1 = Math.min(dz - 1, Math.floor((cz + bz - origin[2]) / h));
    if (ix0 > ix1 || iy0 > iy1 || iz0 > iz1) return;

    // The hot loop reads everything from locals: a property of `this` or of the profile would
    // be loaded again for every vertex, since the stores in the loop could have changed it.
    const restN = normalsOut ? this.restNormals : null;
    const cellStart = this.cellStart;
    const cellVertices = this.cellVertices;
    const cellRest = this.cellRest;
    const moved = this.written;
    const stamp = this.stamp;
    const frame = this.frame;
    let movedCount = 0;
    const reach2 = reach * reach;
    // `fem`: the radial table of this update; `paper`: its exact profile, per vertex.
    const tableZ = this.table.z;
    const tableU = this.table.u;
    const samplesPerM = this.table.samplesPerM;
    // Whether this update's table moves anything sideways (its u is all 0 otherwise, unread).
    const lateral = fem && this.table.lateral;
    const lastInterval = SURFACE_TABLE_INTERVALS - 1;
    const p = this.profile;
    const ev = this.evaluation;
    // A cell whose bounding sphere lies beyond the reach, radially or along n, holds no vertex
    // that moves: skipped whole (a quarter of the box's cells when the reach circle fits it).
    // The sphere is taken 0.1% wider than the cell's, far above the rounding of the test.
    const halfDiagonal = 0.5 * Math.sqrt(3) * h * 1.001;
    const cellReach = reach + halfDiagonal;
    const cellReach2 = cellReach * cellReach;
    let visited = 0;
    for (let iz = iz0; iz <= iz1; iz++) {
      const wz = origin[2] + (iz + 0.5) * h - cz;
      for (let iy = iy0; iy <= iy1; iy++) {
        const wy = origin[1] + (iy + 0.5) * h - cy;
        const row = (iz * dy + iy) * dx;
        for (let ix = ix0; ix <= ix1; ix++) {
          const wx = origin[0] + (ix + 0.5) * h - cx;
          const cellAxial = wx * nx + wy * ny + wz * nz;
          if (cellAxial > cellReach || cellAxial < -cellReach) continue;
          const cellR2 = wx * wx + wy * wy + wz * wz - cellAxial * cellAxial;
          if (cellR2 >= cellReach2) continue;
          visited++;
          const end = cellStart[row + ix + 1];
          for (let s = cellStart[row + ix]; s < end; s++) {
            const i = cellVertices[s];
            const j = 3 * i;
            const q = 6 * s;
            const px = cellRest[q],
              py = cellRest[q + 1],
              pz = cellRest[q + 2];
            const vx = px - cx,
              vy = py - cy,
              vz = pz - cz;
            const axial = vx * nx + vy * ny + vz * nz;
            if (axial > reach || axial < -reach) continue;
            const ex = vx - axial * nx,
              ey = vy - axial * ny,
              ez = vz - axial * nz;
            const r2 = ex * ex + ey * ey + ez * ez;
            if (r2 >= reach2) continue;
            const r = Math.sqrt(r2);
            // z, the sideways displacement over r (w = u/r, the factor of e) and the normal's
            // axial and radial components (normal ∝ a·n + b·e_r).
            let z, a, b;
            let w = 0;
            if (fem) {
              const x = r * samplesPerM;
              // x ≥ 0, so truncation is the floor; x < N but for rounding.
              let k = x | 0;
              if (k > lastInterval) k = lastInterval;
              const f = x - k;
              const z0 = tableZ[k];
              const rise = tableZ[k + 1] - z0;
              z = z0 + f * rise;
              // Perpendicular to the drawn surface in the table interval r lies in: the surface
              // point is −z·n + (r + u)·e_r, its tangent −z′·n + (1 + u′)·e_r.
              a = 1;
              b = rise * samplesPerM;
              if (lateral) {
                const u0 = tableU[k];
                const riseU = tableU[k + 1] - u0;
                a = 1 + riseU * samplesPerM;
                if (r > 0) w = (u0 + f * riseU) / r;
              }
            } else {
              evaluateAt(p, r, ev);
              z = ev[0];
              a = ev[1];
              b = ev[2];
            }
            if (w === 0) {
              if (!(z > 0)) continue;
              positionsOut[j] = px - nx * z;
              positionsOut[j + 1] = py - ny * z;
              positionsOut[j + 2] = pz - nz * z;
            } else {
              positionsOut[j] = px - nx * z + ex * w;
              positionsOut[j + 1] = py - ny * z + ey * w;
              positionsOut[j + 2] = pz - nz * z + ez * w;
            }
            if (restN !== null) {
              // Analytic normal: the profile's (axial, radial) components applied to the rest
              // normal and the radial direction, so curved objects keep their own shading.
              const rnx = cellRest[q + 3],
                rny = cellRest[q + 4],
                rnz = cellRest[q + 5];
              let ox = rnx * a,
                oy = rny * a,
                oz = rnz * a;
              if (r > 0) {
                const br = b / r;
                ox += ex * br;
                oy += ey * br;
                oz += ez * br;
              } else {
                ox = rnx;
                oy = rny;
                oz = rnz;
              }
              const len2 = ox * ox + oy * oy + oz * oz;
              if (len2 > 0) {
                const inv = 1 / Math.sqrt(len2);
                normalsOut[j] = ox * inv;
                normalsOut[j + 1] = oy * inv;
                normalsOut[j + 2] = oz * inv;
              }
            }
            // Each vertex lies in one cell, so it is met once: no need to check the stamp.
            moved[movedCount++] = i;
            stamp[i] = frame;
          }
        }
      }
    }
    this.movedCount = movedCount;
    this.lastVisitedCells = visited;
  }
}
