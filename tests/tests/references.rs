//! Every reference to a Markdown file points at a file in the repository, and every test that
//! `docs/design.md` names as holding an invariant exists.
//!
//! A reference is any `NAME.md` or `path/NAME.md` written in the repository's sources,
//! documentation, manifests and build files (`*.rs`, `*.js`, `*.mjs`, `*.md`, `*.toml`, `*.c`,
//! `*.h`, `Makefile`, `.ci/`). It resolves when the path exists from the referring file's folder
//! or from a folder above it, up to the repository's root. The calibration's code and report also name the pages the
//! calibration writes (`report.md`, `poisson.md`, …): under `calibration/` a bare name resolves
//! in `calibration/report/` as well.
//!
//! A failure lists every dangling reference as `file:line: reference  (the line)`, so each one is
//! found in one step. This file itself is not scanned: its table below names references that do
//! not resolve yet.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use softhaptic_tests::fuzz::repo_root;

/// Dangling references known to be fixed by work on another branch, as (file, reference).
/// Each must still dangle: once its target exists or the reference is gone, the test fails
/// until the entry is removed, so this list only ever shrinks.
const PENDING: &[(&str, &str)] = &[];

/// This file, which is not scanned (its table names references that dangle on purpose).
const THIS_FILE: &str = "tests/tests/references.rs";

/// Folders never scanned: build output, installed packages, test artefacts, recordings.
const SKIPPED_DIRS: &[&str] = &["target", "node_modules", "test-results", "sessions"];

/// Where a bare file name written under a folder also resolves: pages that folder's code writes.
const OUTPUT_DIRS: &[(&str, &str)] = &[("calibration/", "calibration/report")];

fn scanned(path: &Path) -> bool {
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
    if name == "Makefile" {
        return true;
    }
    if path.components().any(|c| c.as_os_str() == ".ci") {
        return true;
    }
    matches!(
        path.extension().and_then(|e| e.to_str()),
        Some("rs" | "js" | "mjs" | "md" | "toml" | "c" | "h")
    )
}

/// Every scanned file under `dir`, relative to `root`, in a stable order.
fn files(root: &Path, dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for path in entries {
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        if path.is_dir() {
            let hidden = name.starts_with('.') && name != ".ci";
            if !hidden && !SKIPPED_DIRS.contains(&name.as_str()) {
                files(root, &path, out);
            }
        } else {
            let relative = path.strip_prefix(root).unwrap().to_path_buf();
            if scanned(&relative) && relative != Path::new(THIS_FILE) {
                out.push(relative);
            }
        }
    }
}

/// The `.md` references in one line: runs of path characters ending in `NAME.md`, not part of a
/// longer word and not a URL.
fn references(line: &str) -> Vec<&str> {
    let is_path_char = |c: char| c.is_ascii_alphanumeric() || "_./-".contains(c);
    let mut found = Vec::new();
    let bytes = line.as_bytes();
    let mut search = 0;
    while let Some(at) = line[search..].find(".md") {
        let end = search + at + 3;
        search = end;
        // `.md` must end the name: `.mdx` or `.md_old` are other names.
        if line[end..]
            .chars()
            .next()
            .is_some_and(|c| c.is_ascii_alphanumeric() || c == '_')
        {
            continue;
        }
        let mut start = end - 3;
        while start > 0 && is_path_char(bytes[start - 1] as char) {
            start -= 1;
        }
        let reference = &line[start..end];
        // A name needs a stem: `{command}.md` or `<command>.md` is a pattern, not a file.
        let stem = reference.trim_end_matches(".md");
        if stem.is_empty() || stem.ends_with('/') || stem.ends_with('.') {
            continue;
        }
        // A URL (`https://…/README.md`) points outside the repository.
        if reference.starts_with("//") || line[..start].ends_with(':') {
            continue;
        }
        // Where the Debian package installs a page (`/usr/share/doc/…`) is a path on the
        // installed system, not in the repository.
        if reference.trim_start_matches('/').starts_with("usr/share/") {
            continue;
        }
        found.push(reference);
    }
    found
}

fn resolves(root: &Path, file: &Path, reference: &str) -> bool {
    // The file's folder, then each folder above it up to the root (a crate's code names files
    // from its manifest's folder, `../docs/operating.md`).
    if file
        .ancestors()
        .skip(1)
        .any(|folder| root.join(folder).join(reference).is_file())
    {
        return true;
    }
    let bare = !reference.contains('/');
    bare && OUTPUT_DIRS.iter().any(|(under, output)| {
        file.to_string_lossy().starts_with(under) && root.join(output).join(reference).is_file()
    })
}

/// Every dangling reference as (file, line number, reference, line text).
fn dangling(root: &Path) -> Vec<(String, usize, String, String)> {
    let mut all = Vec::new();
    files(root, root, &mut all);
    assert!(
        all.iter().any(|f| f == Path::new("README.md")),
        "the scan found no README.md under {}",
        root.display()
    );
    let mut out = Vec::new();
    for file in all {
        let Ok(text) = std::fs::read_to_string(root.join(&file)) else {
            continue; // not UTF-8: no text to refer from
        };
        for (i, line) in text.lines().enumerate() {
            for reference in references(line) {
                if !resolves(root, &file, reference) {
                    out.push((
                        file.to_string_lossy().into_owned(),
                        i + 1,
                        reference.to_owned(),
                        line.trim().to_owned(),
                    ));
                }
            }
        }
    }
    out
}

#[test]
fn every_markdown_reference_points_at_a_file_in_the_repository() {
    let root = repo_root();
    let found = dangling(&root);
    let pending: BTreeSet<(&str, &str)> = PENDING.iter().copied().collect();
    let unexpected: Vec<String> = found
        .iter()
        .filter(|(file, _, reference, _)| !pending.contains(&(file.as_str(), reference.as_str())))
        .map(|(file, line, reference, text)| format!("{file}:{line}: {reference}  ({text})"))
        .collect();
    let stale: Vec<String> = PENDING
        .iter()
        .filter(|(file, reference)| !found.iter().any(|(f, _, r, _)| f == file && r == reference))
        .map(|(file, reference)| format!("{file}: {reference}"))
        .collect();
    assert!(
        unexpected.is_empty(),
        "{} reference(s) to files that are not in the repository (point each at its page under \
         docs/, or at the file's path from the repository's root):\n{}",
        unexpected.len(),
        unexpected.join("\n")
    );
    assert!(
        stale.is_empty(),
        "these entries of PENDING in tests/tests/references.rs resolve now: remove them\n{}",
        stale.join("\n")
    );
}

#[test]
fn the_reference_scan_finds_what_it_should() {
    assert_eq!(
        references("see docs/physics.md, \"Haptic stability\""),
        ["docs/physics.md"]
    );
    assert_eq!(
        references("[WIRE](../proto/WIRE.md#access)"),
        ["../proto/WIRE.md"]
    );
    assert_eq!(
        references("`<command>.md` and `{command}.md`"),
        Vec::<&str>::new()
    );
    assert_eq!(
        references("https://example.org/x/README.md"),
        Vec::<&str>::new()
    );
    assert_eq!(references("a.mdx, b.md_old"), Vec::<&str>::new());
    assert_eq!(references("(design.md, invariant 1)"), ["design.md"]);

    // Resolution: from the file's folder or one above it, and the calibration's own pages.
    let root = repo_root();
    assert!(resolves(
        &root,
        Path::new("server/src/x.rs"),
        "proto/WIRE.md"
    ));
    assert!(resolves(&root, Path::new("docs/x.md"), "../proto/WIRE.md"));
    assert!(resolves(
        &root,
        Path::new("calibration/src/report/mod.rs"),
        "report.md"
    ));
    assert!(!resolves(&root, Path::new("server/src/x.rs"), "report.md"));
    assert!(resolves(
        &root,
        Path::new("server/tests/x.rs"),
        "../docs/design.md"
    ));
    assert!(!resolves(
        &root,
        Path::new("device/src/x.rs"),
        "no-such-page.md"
    ));
    assert!(!resolves(&root, Path::new("device/src/x.rs"), "design.md"));
}

/// The test functions `docs/design.md` names: its lines `- \`PATH\`: \`name\`, …` (continued on
/// the indented lines below), with PATH a file or a folder of the repository.
fn named_tests(design: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    let mut current: Option<String> = None;
    for line in design.lines() {
        if let Some(rest) = line.strip_prefix("- `") {
            current = None;
            if let Some((path, names)) = rest.split_once("`:") {
                current = Some(path.to_owned());
                out.extend(backticked(names).map(|n| (path.to_owned(), n)));
            }
        } else if line.starts_with("  ") && !line.trim().is_empty() {
            if let Some(path) = &current {
                out.extend(backticked(line).map(|n| (path.clone(), n)));
            }
        } else {
            current = None;
        }
    }
    out
}

/// Backticked snake-case names in `text`.
fn backticked(text: &str) -> impl Iterator<Item = String> + '_ {
    text.split('`')
        .skip(1)
        .step_by(2)
        .filter(|s| {
            !s.is_empty()
                && s.chars()
                    .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
        })
        .map(str::to_owned)
}

fn rust_sources(root: &Path, path: &Path) -> Vec<PathBuf> {
    let full = root.join(path);
    if full.is_file() {
        return vec![path.to_path_buf()];
    }
    let mut all = Vec::new();
    files(root, &full, &mut all);
    all.into_iter()
        .filter(|f| f.extension().is_some_and(|e| e == "rs"))
        .collect()
}

#[test]
fn every_test_the_design_names_exists() {
    let root = repo_root();
    let design = std::fs::read_to_string(root.join("docs/design.md")).unwrap();
    let named = named_tests(&design);
    assert!(
        named.len() >= 30,
        "only {} tests found in docs/design.md",
        named.len()
    );
    let mut missing = Vec::new();
    for (path, name) in &named {
        let sources = rust_sources(&root, Path::new(path));
        let defined = sources.iter().any(|f| {
            let text = std::fs::read_to_string(root.join(f)).unwrap_or_default();
            text.contains(&format!("fn {name}("))
        });
        if !defined {
            missing.push(format!("{path}: {name}"));
        }
    }
    assert!(
        missing.is_empty(),
        "docs/design.md names tests that do not exist (renamed or moved? name the new place):\n{}",
        missing.join("\n")
    );
}
