//! The render mesh's binary layout, "SHM1" (proto/WIRE.md, "Render mesh binary layout"): what
//! `GET /meshes/<name>.bin` answers, and what `web/src/mesh.js` decodes and checks.

use glam::DVec3;

/// The first four bytes of every SHM1 buffer.
pub const MAGIC: [u8; 4] = *b"SHM1";

/// The bytes before the vertex data: the magic, the vertex count, the triangle count.
pub const HEADER_LEN: usize = 12;

/// Encodes a mesh in the object's frame: the magic, u32 vertex count, u32 triangle count, f32
/// positions (metres), f32 unit normals (one per position), u32 indices (counter-clockwise seen
/// from outside), all little-endian with no padding: 12 + 24 n + 12 t bytes.
pub fn encode(positions_m: &[DVec3], normals: &[DVec3], triangles: &[[u32; 3]]) -> Vec<u8> {
    let n = positions_m.len();
    let t = triangles.len();
    let mut out = Vec::with_capacity(HEADER_LEN + n * 24 + t * 12);
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&(n as u32).to_le_bytes());
    out.extend_from_slice(&(t as u32).to_le_bytes());
    for list in [positions_m, normals] {
        for v in list {
            for c in v.to_array() {
                out.extend_from_slice(&(c as f32).to_le_bytes());
            }
        }
    }
    for tri in triangles {
        for i in tri {
            out.extend_from_slice(&i.to_le_bytes());
        }
    }
    out
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn the_layout_is_the_header_then_positions_normals_and_indices() {
        // Two triangles of a unit square in the xz-plane, facing +y.
        let positions_m = [
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(0.0, 0.0, 1.0),
            DVec3::new(1.0, 0.0, 1.0),
            DVec3::new(1.0, 0.0, 0.0),
        ];
        let normals = [DVec3::Y; 4];
        let triangles = [[0, 1, 2], [0, 2, 3]];
        let bytes = encode(&positions_m, &normals, &triangles);
        let u32_at = |off: usize| u32::from_le_bytes(bytes[off..off + 4].try_into().unwrap());
        let f32_at = |off: usize| f32::from_le_bytes(bytes[off..off + 4].try_into().unwrap());
        assert_eq!(bytes[0..4], MAGIC);
        let (n, t) = (u32_at(4) as usize, u32_at(8) as usize);
        assert_eq!((n, t), (4, 2));
        assert_eq!(bytes.len(), HEADER_LEN + n * 24 + t * 12);
        // The third vertex's x, the first normal's y, the last index.
        assert_eq!(f32_at(HEADER_LEN + 2 * 12), 1.0);
        assert_eq!(f32_at(HEADER_LEN + n * 12 + 4), 1.0);
        assert_eq!(u32_at(bytes.len() - 4), 3);
    }
}
