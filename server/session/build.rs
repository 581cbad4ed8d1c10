//! The git commit, so that every recording names the code that made it
//! (`BuildRecord::git_commit`, from `git_commit()` in src/lib.rs). `SOFTHAPTIC_GIT_COMMIT` in the
//! build's environment overrides it (a build from a source archive, without `.git`); without
//! either the recording says the commit is unknown.

use std::path::Path;
use std::process::Command;

fn main() {
    git_commit();
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
