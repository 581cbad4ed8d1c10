//! The OBJ reader: a scene's haptic and render meshes, polygons triangulated.
//!
//! `tobj` reads the file; this module refuses first what it would mishandle (a non-finite
//! vertex, an attribute index outside the file, which it would overflow on) and names the line.

use std::path::Path;

use glam::DVec3;
use softhaptic_device::mesh::HapticMesh;

use super::SceneError;
use crate::files::{self, FileKind};

/// Refuses a face, line or point whose texture-coordinate or normal index falls outside the
/// file's `vt` or `vn` lines. The OBJ reader refuses these too, but only after multiplying the
/// index (`vt * 2`, `vn * 3`): a relative index reaching before the first `vt` (`f 1/-9 ...`)
/// or a huge one overflows there, which panics in a build with overflow checks and in release
/// silently wraps. Indices are resolved as the reader resolves them (1-based; negative counts
/// back from the lines read so far; 0 and empty mean none) and checked, as it checks them,
/// against the whole file's count when the file has any.
fn check_attribute_indices(text: &str) -> Result<(), String> {
    let count = |kind: &str| {
        text.lines()
            .filter(|l| l.split_whitespace().next() == Some(kind))
            .count()
    };
    let totals = [count("vt"), count("vn")];
    let names = ["texture coordinate", "normal"];
    let mut so_far = [0usize; 2];
    for (line_index, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("vt") => so_far[0] += 1,
            Some("vn") => so_far[1] += 1,
            Some("f" | "l" | "p") => {
                for word in words {
                    // Part 0 is the position (the reader checks it without overflow).
                    for (slot, part) in word.split('/').skip(1).take(2).enumerate() {
                        // Not a number: the reader refuses the face itself.
                        let Ok(x) = part.parse::<i128>() else {
                            continue;
                        };
                        let index = if x < 0 {
                            so_far[slot] as i128 + x
                        } else {
                            x - 1
                        };
                        // -1 from a 0 is the reader's "missing"; with no such lines at all the
                        // reader ignores the index.
                        if x == 0 || totals[slot] == 0 {
                            continue;
                        }
                        if !(0..totals[slot] as i128).contains(&index) {
                            return Err(format!(
                                "line {}: {word:?} names {} {x}, but the file has {} of them",
                                line_index + 1,
                                names[slot],
                                totals[slot]
                            ));
                        }
                    }
                }
            }
            _ => {}
        }
    }
    Ok(())
}

/// Reads an OBJ file and parses it as a mesh ([`parse_obj`]).
pub(super) fn load_obj(
    mesh: &Path,
    scene: &Path,
    field: &'static str,
) -> Result<HapticMesh, SceneError> {
    let error = |reason: String| SceneError::Mesh {
        path: scene.to_owned(),
        field,
        mesh: mesh.to_owned(),
        reason,
    };
    let text = files::read_text(mesh, FileKind::Mesh).map_err(|e| error(e.to_string()))?;
    parse_obj(&text, mesh, scene, field)
}

/// Parses OBJ text (polygons triangulated) into a mesh; `mesh`, `scene` and `field` only name
/// the file in errors. Non-finite vertices are refused with their line and their index in the
/// file (0-based), found before the OBJ reader reorders anything. Public so the fuzz targets
/// (`tests/src/fuzz.rs`) reach the parser without a file.
pub fn parse_obj(
    text: &str,
    mesh: &Path,
    scene: &Path,
    field: &'static str,
) -> Result<HapticMesh, SceneError> {
    let error = |reason: String| SceneError::Mesh {
        path: scene.to_owned(),
        field,
        mesh: mesh.to_owned(),
        reason,
    };
    let mut vertex = 0usize;
    for (line_index, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        if words.next() != Some("v") {
            continue;
        }
        let coordinates: Vec<&str> = words.take(3).collect();
        let finite = coordinates.len() == 3
            && coordinates
                .iter()
                .all(|w| w.parse::<f64>().is_ok_and(f64::is_finite));
        if !finite {
            return Err(error(format!(
                "line {}: vertex {vertex} is not finite: {:?}",
                line_index + 1,
                coordinates.join(" ")
            )));
        }
        vertex += 1;
    }
    check_attribute_indices(text).map_err(error)?;
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ..Default::default()
    };
    // Materials do not matter to the simulation: any `mtllib` is ignored.
    let (models, _materials) = tobj::load_obj_buf(&mut text.as_bytes(), &options, |_| {
        Err(tobj::LoadError::OpenFileFailed)
    })
    .map_err(|e| error(e.to_string()))?;
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    for model in &models {
        let m = &model.mesh;
        let offset = positions.len() as u32;
        positions.extend(
            m.positions
                .chunks_exact(3)
                .map(|p| DVec3::new(p[0], p[1], p[2])),
        );
        for tri in m.indices.chunks_exact(3) {
            triangles.push([tri[0] + offset, tri[1] + offset, tri[2] + offset]);
        }
    }
    HapticMesh::new(positions, triangles).map_err(|e| error(e.to_string()))
}
