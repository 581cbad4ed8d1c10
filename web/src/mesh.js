// Render meshes: the "SHM1" binary layout the server serves at /meshes/<name>.bin, and the flat
// grids the deformation benchmark uses (the paper's Table 1 sizes).
//
// Layout (little-endian): "SHM1", u32 vertex_count, u32 triangle_count, vertex_count·3 f32
// positions (m, object frame), vertex_count·3 f32 unit normals, triangle_count·3 u32 indices
// (counter-clockwise seen from outside).

const HEADER_BYTES = 12;

/** A render mesh that breaks the layout; the message names the mesh and what is wrong. */
export class MeshError extends Error {
  constructor(name, message) {
    super(`render mesh ${name}: ${message}`);
    this.name = 'MeshError';
  }
}

/**
 * Decodes and checks an SHM1 buffer. Returns `{vertexCount, triangleCount, positions, normals,
 * indices}` as fresh typed arrays (positions and normals are copied so that the caller owns
 * them). `expectedVertexCount` (from the scene) is checked when given.
 */
export function parseRenderMesh(buffer, name = 'mesh', expectedVertexCount = undefined) {
  if (!(buffer instanceof ArrayBuffer)) throw new MeshError(name, 'expected an ArrayBuffer');
  if (buffer.byteLength < HEADER_BYTES) {
    throw new MeshError(name, `${buffer.byteLength} bytes is shorter than the 12-byte header`);
  }
  const view = new DataView(buffer);
  const magic = String.fromCharCode(view.getUint8(0), view.getUint8(1), view.getUint8(2), view.getUint8(3));
  if (magic !== 'SHM1') throw new MeshError(name, `magic is ${JSON.stringify(magic)}, expected "SHM1"`);
  const vertexCount = view.getUint32(4, true);
  const triangleCount = view.getUint32(8, true);
  const expectedBytes = HEADER_BYTES + vertexCount * 24 + triangleCount * 12;
  if (buffer.byteLength !== expectedBytes) {
    throw new MeshError(
      name,
      `${buffer.byteLength} bytes, but ${vertexCount} vertices and ${triangleCount} triangles need ${expectedBytes}`,
    );
  }
  if (expectedVertexCount !== undefined && expectedVertexCount !== vertexCount) {
    throw new MeshError(name, `vertex_count is ${vertexCount}, the scene says ${expectedVertexCount}`);
  }
  const positions = new Float32Array(vertexCount * 3);
  const normals = new Float32Array(vertexCount * 3);
  const indices = new Uint32Array(triangleCount * 3);
  // DataView reads are endian-explicit and do not need 4-byte alignment of the sections.
  let o = HEADER_BYTES;
  for (let i = 0; i < vertexCount * 3; i++, o += 4) positions[i] = view.getFloat32(o, true);
  for (let i = 0; i < vertexCount * 3; i++, o += 4) normals[i] = view.getFloat32(o, true);
  for (let i = 0; i < triangleCount * 3; i++, o += 4) indices[i] = view.getUint32(o, true);
  for (let i = 0; i < vertexCount * 3; i++) {
    if (!Number.isFinite(positions[i])) {
      throw new MeshError(name, `vertex ${Math.floor(i / 3)} position[${i % 3}] is ${positions[i]}`);
    }
  }
  for (let v = 0; v < vertexCount; v++) {
    const x = normals[3 * v],
      y = normals[3 * v + 1],
      z = normals[3 * v + 2];
    const len = Math.sqrt(x * x + y * y + z * z);
    if (!(Math.abs(len - 1) < 1e-3)) {
      throw new MeshError(name, `normal of vertex ${v} has length ${len}, expected 1`);
    }
  }
  for (let i = 0; i < indices.length; i++) {
    if (indices[i] >= vertexCount) {
      throw new MeshError(name, `triangle ${Math.floor(i / 3)} index ${indices[i]} ≥ vertex_count ${vertexCount}`);
    }
  }
  return { vertexCount, triangleCount, positions, normals, indices };
}

/** Encodes a mesh in the SHM1 layout (tests and benchmarks build meshes with it). */
export function encodeRenderMesh({ positions, normals, indices }) {
  const vertexCount = positions.length / 3;
  const triangleCount = indices.length / 3;
  const buffer = new ArrayBuffer(HEADER_BYTES + vertexCount * 24 + triangleCount * 12);
  const view = new DataView(buffer);
  'SHM1'.split('').forEach((c, i) => view.setUint8(i, c.charCodeAt(0)));
  view.setUint32(4, vertexCount, true);
  view.setUint32(8, triangleCount, true);
  let o = HEADER_BYTES;
  for (const v of positions) (view.setFloat32(o, v, true), (o += 4));
  for (const v of normals) (view.setFloat32(o, v, true), (o += 4));
  for (const v of indices) (view.setUint32(o, v, true), (o += 4));
  return buffer;
}

/**
 * A flat square grid of `side × side` vertices in the y = 0 plane, `sizeM` wide, centred on the
 * origin, normals +y: the surface models of the paper's Table 1 (40² … 100² vertices).
 */
export function flatGrid(side, sizeM) {
  const positions = new Float32Array(side * side * 3);
  const normals = new Float32Array(side * side * 3);
  const indices = new Uint32Array((side - 1) * (side - 1) * 6);
  const step = sizeM / (side - 1);
  for (let j = 0; j < side; j++) {
    for (let i = 0; i < side; i++) {
      const v = j * side + i;
      positions[3 * v] = -sizeM / 2 + i * step;
      positions[3 * v + 2] = -sizeM / 2 + j * step;
      normals[3 * v + 1] = 1;
    }
  }
  let t = 0;
  for (let j = 0; j < side - 1; j++) {
    for (let i = 0; i < side - 1; i++) {
      const v = j * side + i;
      // Counter-clockwise seen from +y.
      indices.set([v, v + side, v + 1, v + 1, v + side, v + side + 1], t);
      t += 6;
    }
  }
  return { positions, normals, indices };
}
