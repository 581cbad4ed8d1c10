//! Where an installed `softhaptic` finds its shared files without a source tree: the scenes and
//! the calibration tables beside them (`scenes/calibration/`), and the exercises, which the
//! Debian package installs under `/usr/share/softhaptic/scenes/` and `…/exercises/`.
//!
//! A scene named on the command line is looked for, in order: as given (absolute, or relative
//! to the working directory, as a developer in a checkout names `scenes/cone.toml`); then in
//! each data directory, as given and under its `scenes/` (so `--scene cone.toml` and `--scene
//! scenes/cone.toml` both name the installed scene). The data directories are
//! `<the executable's directory>/../share/softhaptic` (an install under another prefix, or a
//! package unpacked with `dpkg-deb -x`), then [`SYSTEM_DATA_DIR`]. A scene's own files (its
//! table, its meshes) are then relative to the scene file, wherever it was found. An exercise
//! named by `--exercises` is looked for the same way, under `exercises/`; the scene it names is
//! relative to it (the installed exercises name `../scenes/…`).

use std::path::{Path, PathBuf};

/// The packaged data directory.
pub const SYSTEM_DATA_DIR: &str = "/usr/share/softhaptic";

/// A scene or an exercise found nowhere, with every place looked.
#[derive(Debug, thiserror::Error)]
#[error("{option} {}: no such file; looked at {}", given.display(), tried_list(tried))]
pub struct NotFound {
    /// The command-line option that named it.
    pub option: &'static str,
    pub given: PathBuf,
    pub tried: Vec<PathBuf>,
}

fn tried_list(tried: &[PathBuf]) -> String {
    tried
        .iter()
        .map(|p| p.display().to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

/// The data directories, in search order, without repeats.
pub fn data_dirs() -> Vec<PathBuf> {
    let beside_exe = std::env::current_exe().ok().and_then(|exe| {
        exe.parent()
            .and_then(Path::parent)
            .map(|prefix| prefix.join("share").join("softhaptic"))
    });
    data_dirs_from(beside_exe)
}

fn data_dirs_from(beside_exe: Option<PathBuf>) -> Vec<PathBuf> {
    let mut dirs: Vec<PathBuf> = beside_exe.into_iter().collect();
    let system = PathBuf::from(SYSTEM_DATA_DIR);
    if !dirs.contains(&system) {
        dirs.push(system);
    }
    dirs
}

/// The scene file `given` names (see the module's search order).
pub fn find_scene(given: &Path) -> Result<PathBuf, NotFound> {
    find_in(given, &data_dirs(), "scenes", "--scene")
}

/// The exercise file `given` names (the same search, under `exercises/`).
pub fn find_exercise(given: &Path) -> Result<PathBuf, NotFound> {
    find_in(given, &data_dirs(), "exercises", "--exercises")
}

fn find_in(
    given: &Path,
    data_dirs: &[PathBuf],
    subdir: &str,
    option: &'static str,
) -> Result<PathBuf, NotFound> {
    let mut tried = vec![given.to_path_buf()];
    if given.is_relative() {
        for dir in data_dirs {
            tried.push(dir.join(given));
            tried.push(dir.join(subdir).join(given));
        }
    }
    match tried.iter().find(|p| p.is_file()) {
        Some(found) => Ok(found.clone()),
        None => Err(NotFound {
            option,
            given: given.to_path_buf(),
            tried,
        }),
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    fn find_scene_in(given: &Path, data_dirs: &[PathBuf]) -> Result<PathBuf, NotFound> {
        find_in(given, data_dirs, "scenes", "--scene")
    }

    #[test]
    fn the_executables_share_comes_before_the_systems_and_neither_twice() {
        let dirs = data_dirs_from(Some("/opt/x/share/softhaptic".into()));
        assert_eq!(
            dirs,
            [
                PathBuf::from("/opt/x/share/softhaptic"),
                PathBuf::from(SYSTEM_DATA_DIR)
            ]
        );
        assert_eq!(
            data_dirs_from(Some(SYSTEM_DATA_DIR.into())),
            [PathBuf::from(SYSTEM_DATA_DIR)]
        );
    }

    #[test]
    fn a_scene_is_found_as_given_then_in_the_data_directories() {
        let root = std::env::temp_dir().join(format!("softhaptic-datadir-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let share = root.join("share");
        std::fs::create_dir_all(share.join("scenes")).unwrap();
        std::fs::write(share.join("scenes/cone.toml"), "").unwrap();
        let dirs = [root.join("missing"), share.clone()];

        let found = find_scene_in(Path::new("cone.toml"), &dirs).unwrap();
        assert_eq!(found, share.join("scenes/cone.toml"));
        let found = find_scene_in(Path::new("scenes/cone.toml"), &dirs);
        // From the test's working directory (server/) there is no scenes/cone.toml, so the
        // data directory's answers.
        assert_eq!(found.unwrap(), share.join("scenes/cone.toml"));
        let absolute = share.join("scenes/cone.toml");
        assert_eq!(find_scene_in(&absolute, &[]).unwrap(), absolute);

        let e = find_scene_in(Path::new("sphere.toml"), &dirs).unwrap_err();
        assert_eq!(e.tried.len(), 5);
        let text = e.to_string();
        assert!(
            text.starts_with("--scene sphere.toml: no such file")
                && text.contains(&share.join("scenes/sphere.toml").display().to_string()),
            "{text}"
        );
        // An absolute path is looked for where it says only.
        let e = find_scene_in(&root.join("nope.toml"), &dirs).unwrap_err();
        assert_eq!(e.tried, [root.join("nope.toml")]);
        std::fs::remove_dir_all(&root).unwrap();
    }
}
