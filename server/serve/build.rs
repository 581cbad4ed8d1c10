//! The viewer (`web/`), built into the binary by `src/viewer.rs`: the build stops here, saying
//! what to run, when three.js (`web/node_modules/three`, installed by `npm ci`) is missing, rather
//! than build a binary whose page cannot start; and it is built again when a file of the page is
//! added or removed.

use std::path::Path;

/// The files of `web/` the viewer cannot run without that `npm ci` installs (the same as
/// `viewer::REQUIRED`'s `node_modules/` entries).
const THREE_FILES: [&str; 3] = [
    "node_modules/three/build/three.module.js",
    "node_modules/three/build/three.core.js",
    "node_modules/three/examples/jsm/controls/OrbitControls.js",
];

fn main() {
    check_viewer();
}

fn check_viewer() {
    let manifest = std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| ".".into());
    let web = Path::new(&manifest).join("../../web");
    // The embedding macro tracks the files it embeds, not the directories: a module added to
    // src/ (or three installed) must rebuild the binary too.
    for watched in [
        "index.html",
        "dashboard.html",
        "src",
        "node_modules/three/package.json",
    ] {
        println!("cargo:rerun-if-changed={}", web.join(watched).display());
    }
    let missing: Vec<&str> = THREE_FILES
        .into_iter()
        .filter(|f| !web.join(f).is_file())
        .collect();
    if !missing.is_empty() {
        // A build script's panic is shown to the user with its message: the one place to say it.
        panic!(
            "\n\nthe viewer's three.js is missing: no {} in {}.\n\
             The binary embeds the viewer and its three.js; install them first:\n\n    \
             make web-deps        (or: cd web && npm ci)\n\n",
            missing.join(", "),
            web.display()
        );
    }
}
