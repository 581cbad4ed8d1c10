// Where a plane cuts a triangle mesh: the line segments of the cut, for the section view's line
// of the undeformed surface (drawn beside the cut of the bent mesh, so the dent's profile shows
// against the surface it was pressed into). Plain arrays in and out, no three.js, so the unit
// tests run it in Node.
//
// Each vertex is put on one side of the plane by its signed distance d (d ≥ 0 counts as the
// positive side), and a triangle whose vertices are not all on one side is cut along the two
// edges that change side. A vertex lying on the plane thus belongs to exactly one side: an edge
// lying in the plane is drawn once (by the triangle on its negative side), a triangle that only
// touches the plane at a vertex gives no segment, and the division below never divides by zero
// (the two ends of a cut edge are on opposite sides, so their distances differ).

/**
 * A growable buffer of segments: `positions` holds `segments` pairs of points (x, y, z each),
 * six floats per segment. `cutMesh` grows it (allocates) only when a cut has more segments than
 * it has ever held, so a view that cuts the same mesh every frame allocates nothing after the
 * first frames.
 */
export function segmentBuffer(initialSegments = 256) {
  return { positions: new Float32Array(6 * Math.max(1, initialSegments)), segments: 0 };
}

/**
 * Cuts the mesh (`positions`: x, y, z per vertex; `indices`: three per triangle) by the plane
 * of points p with n · p + constant = 0, where `normal` = n = [nx, ny, nz] (of unit length, so
 * distances are in the positions' unit). `distances` is scratch of one float per vertex (at
 * least `positions.length / 3`); `out` a `segmentBuffer`, whose `segments` it sets. Returns the
 * number of segments.
 */
export function cutMesh(positions, indices, normal, constant, distances, out) {
  const nx = normal[0];
  const ny = normal[1];
  const nz = normal[2];
  const vertexCount = Math.floor(positions.length / 3);
  if (distances.length < vertexCount) {
    throw new Error(`cutMesh: ${distances.length} distances for ${vertexCount} vertices`);
  }
  for (let i = 0; i < vertexCount; i++) {
    distances[i] = nx * positions[3 * i] + ny * positions[3 * i + 1] + nz * positions[3 * i + 2] + constant;
  }
  let count = 0;
  const triangles = Math.floor(indices.length / 3);
  for (let t = 0; t < triangles; t++) {
    const a = indices[3 * t];
    const b = indices[3 * t + 1];
    const c = indices[3 * t + 2];
    const da = distances[a];
    const db = distances[b];
    const dc = distances[c];
    const sa = da >= 0;
    const sb = db >= 0;
    const sc = dc >= 0;
    // All on one side (a NaN distance counts as the negative side: no segment from it unless
    // its neighbours are positive, and then a NaN point, which the line simply does not draw).
    if (sa === sb && sb === sc) continue;
    if (6 * (count + 1) > out.positions.length) {
      const grown = new Float32Array(2 * out.positions.length);
      grown.set(out.positions);
      out.positions = grown;
    }
    let k = 6 * count;
    // The two edges that change side; the vertex alone on its side is their common end.
    if (sa !== sb) k = edgePoint(positions, a, b, da, db, out.positions, k);
    if (sb !== sc) k = edgePoint(positions, b, c, db, dc, out.positions, k);
    if (sc !== sa) edgePoint(positions, c, a, dc, da, out.positions, k);
    // A vertex on the plane alone on its side: both cut edges end there, a point, not a line.
    const o = 6 * count;
    const q = out.positions;
    if (q[o] === q[o + 3] && q[o + 1] === q[o + 4] && q[o + 2] === q[o + 5]) continue;
    count++;
  }
  out.segments = count;
  return count;
}

/** Writes the point where the plane crosses edge (i, j) at `out[k ..]`; returns k + 3. */
function edgePoint(positions, i, j, di, dj, out, k) {
  const t = di / (di - dj);
  for (let axis = 0; axis < 3; axis++) {
    const pi = positions[3 * i + axis];
    out[k + axis] = pi + t * (positions[3 * j + axis] - pi);
  }
  return k + 3;
}
