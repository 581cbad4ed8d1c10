//! Two things the binary takes from the source tree:
//! - the viewer (`web/`), built into the binary by `server/src/viewer.rs`: the build stops here,
//!   saying what to run, when three.js (`web/node_modules/three`, installed by `npm ci`) is
//!   missing, rather than build a binary whose page cannot start; and it is built again when a
//!   file of the page is added or removed;
//! - the git commit, so that every recording names the code that made it
//!   (`BuildRecord::git_commit`). `SOFTHAPTIC_GIT_COMMIT` in the build's environment overrides
//!   it (a build from a source archive, without `.git`); without either the recording says the
//!   commit is unknown.

use std::path::Path;
use std::process::Command;

/// The files of `web/` the viewer cannot run without that `npm ci` installs (the same as
/// `viewer::REQUIRED`'s `node_modules/` entries).
const THREE_FILES: [&str; 3] = [
    "node_modules/three/build/three.module.js",
    "node_modules/three/build/three.core.js",
    "node_modules/three/examples/jsm/controls/OrbitControls.js",
];

fn main() {
    check_viewer();
    git_commit();
}

fn check_viewer() {
    let manifest = std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| ".".into());
    let web = Path::new(&manifest).join("..").join("web");
    // The embedding macro tracks the files it embeds, not the directories: a module added to
    // src/ (or three installed) must rebuild the binary too.
    for watched in ["index.html", "src", "node_modules/three/package.json"] {
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

fn git_commit() {
    println!("cargo:rerun-if-env-changed=SOFTHAPTIC_GIT_COMMIT");
    if std::env::var("SOFTHAPTIC_GIT_COMMIT").is_ok_and(|c| !c.is_empty()) {
        // Passed through as it is: rustc sees the build's environment.
        return;
    }
    let manifest = std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| ".".into());
    let git = |args: &[&str]| {
        Command::new("git")
            .args(args)
            .current_dir(&manifest)
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_owned())
    };
    // Built again when the checked-out commit changes: HEAD, and the branch it points to
    // (loose or packed). Only files that exist are watched: cargo would run a script watching a
    // missing one on every build.
    if let Some(git_dir) = git(&["rev-parse", "--absolute-git-dir"]) {
        let git_dir = Path::new(&git_dir);
        let mut watched = vec![git_dir.join("HEAD"), git_dir.join("packed-refs")];
        if let Some(branch) = git(&["symbolic-ref", "-q", "HEAD"]) {
            watched.push(git_dir.join(branch));
        }
        for file in watched.iter().filter(|f| f.is_file()) {
            println!("cargo:rerun-if-changed={}", file.display());
        }
    }
    let Some(commit) = git(&["rev-parse", "--short=12", "HEAD"]) else {
        return;
    };
    // Local changes on top of the commit are not marked: this script runs again when the commit
    // changes, not when a file does, so a mark could be stale.
    println!("cargo:rustc-env=SOFTHAPTIC_GIT_COMMIT={commit}");
}
