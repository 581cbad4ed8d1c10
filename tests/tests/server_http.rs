//! The HTTP routes of the real server: scene JSON, render meshes, viewer files.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use softhaptic_proto::wire::ServerMessage;
use softhaptic_tests::{http_get, start_default, test_options};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scene_and_render_mesh_are_served_and_parse() {
    let server = start_default(test_options()).await;
    let addr = server.local_addr();

    let (status, body) = http_get(addr, "/api/scene").await;
    assert_eq!(status, 200);
    let ServerMessage::Scene(scene) =
        ServerMessage::decode(std::str::from_utf8(&body).unwrap()).unwrap()
    else {
        panic!("/api/scene is a scene message")
    };
    assert_eq!(&*scene, server.scene_message());

    let mesh = &scene.render_meshes[0];
    let (status, bytes) = http_get(addr, &mesh.url).await;
    assert_eq!(status, 200);
    assert_eq!(&bytes[0..4], b"SHM1");
    let u32_at = |i: usize| u32::from_le_bytes(bytes[i..i + 4].try_into().unwrap());
    let f32_at = |i: usize| f32::from_le_bytes(bytes[i..i + 4].try_into().unwrap());
    let (n, t) = (u32_at(4) as usize, u32_at(8) as usize);
    assert_eq!(n, mesh.vertex_count as usize);
    assert!(n >= 100_000, "render mesh has {n} vertices");
    assert_eq!(bytes.len(), 12 + n * 24 + t * 12);
    let normals = 12 + n * 12;
    let indices = normals + n * 12;
    for v in (0..n).step_by(997) {
        let p = [0, 1, 2].map(|k| f32_at(12 + v * 12 + k * 4));
        assert!(p.iter().all(|c| c.is_finite() && c.abs() < 0.5), "{p:?}");
        let nn = [0, 1, 2].map(|k| f32_at(normals + v * 12 + k * 4));
        let len = (nn[0] * nn[0] + nn[1] * nn[1] + nn[2] * nn[2]).sqrt();
        assert!((len - 1.0).abs() < 1e-4, "normal {v} has length {len}");
    }
    assert!((0..t * 3).all(|k| (u32_at(indices + k * 4) as usize) < n));

    let (status, _) = http_get(addr, "/meshes/spleen.bin").await;
    assert_eq!(status, 404);

    // The viewer page and three.js, built into the binary: the source tree's files.
    let web = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../web");
    let (status, page) = http_get(addr, "/").await;
    assert_eq!(status, 200);
    assert_eq!(page, std::fs::read(web.join("index.html")).unwrap());
    let three = web.join("node_modules/three/build/three.module.js");
    let (status, js) = http_get(addr, "/vendor/three/three.module.js").await;
    assert_eq!(status, 200);
    assert_eq!(js, std::fs::read(three).unwrap());
    let (status, _) = http_get(addr, "/vendor/three/addons/controls/OrbitControls.js").await;
    assert_eq!(status, 200);

    server.shutdown().await;
}
