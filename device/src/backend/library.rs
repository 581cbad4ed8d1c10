//! Finding and loading a vendor's device library at run time, the same way for every vendor.
//!
//! The library is opened with `dlopen` when a scene asks for the device, never linked: the
//! project builds, runs and tests where the vendor's software is absent. A [`LibrarySpec`] names
//! the file, the override variable and the directories the vendor's packages install into;
//! [`load_once`] tries the override's path when it is set (and nothing else), otherwise the file
//! through the system's library search and then those directories, and says where it looked when
//! nothing loads.
//!
//! A vendor's library may start driver threads of its own when it is loaded, so unloading it
//! while they run is unsafe and loading it again starts another set: each library (by the path
//! it was found at) is loaded at most once per process and never unloaded ([`load_once`] hands
//! out `&'static` references).

use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// Where a vendor's library is looked for.
#[derive(Debug, Clone, Copy)]
pub struct LibrarySpec {
    /// The library's file name (`libHD.so`).
    pub file: &'static str,
    /// The environment variable naming the library to load instead of searching for it.
    pub env: &'static str,
    /// Directories the vendor's packages install into, searched after the system's own search.
    pub dirs: &'static [&'static str],
}

impl LibrarySpec {
    /// Where [`load_once`] looks, in order: the override alone when it is set.
    pub fn candidates(&self) -> Vec<PathBuf> {
        match std::env::var_os(self.env) {
            Some(path) if !path.is_empty() => vec![PathBuf::from(path)],
            _ => std::iter::once(PathBuf::from(self.file))
                .chain(self.dirs.iter().map(|d| Path::new(d).join(self.file)))
                .collect(),
        }
    }

    fn overridden(&self) -> bool {
        std::env::var_os(self.env).is_some_and(|p| !p.is_empty())
    }
}

/// Why no library was loaded.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LoadFailure {
    /// Nothing loaded anywhere it was looked for: each place, with why it was not used.
    NotFound { tried: Vec<String> },
    /// The override's path could not be loaded.
    Load { path: PathBuf, reason: String },
}

/// The library `spec` describes, loaded once per process: `cache` holds the libraries loaded so
/// far (`path_of` gives the candidate path each was found at), `bind` looks up the vendor's
/// symbols in a freshly loaded library (a library it refuses stays loaded, never unloaded: its
/// initialisers may have started threads), `failed` turns a [`LoadFailure`] into the vendor's
/// error.
pub fn load_once<T: Sync + 'static, E>(
    spec: &LibrarySpec,
    cache: &Mutex<Vec<&'static T>>,
    path_of: impl Fn(&T) -> &Path,
    bind: impl FnOnce(&'static libloading::Library, PathBuf) -> Result<T, E>,
    failed: impl FnOnce(LoadFailure) -> E,
) -> Result<&'static T, E> {
    let overridden = spec.overridden();
    // Held across the load, so two threads never load one library twice.
    let mut loaded = cache.lock().unwrap_or_else(|p| p.into_inner());
    let mut tried = Vec::new();
    for candidate in spec.candidates() {
        if let Some(lib) = loaded.iter().find(|l| path_of(l) == candidate) {
            return Ok(lib);
        }
        // A bare file name goes through the dynamic loader's own search; a path is used as is
        // and, when absent, skipped with a short reason rather than dlopen's longer one.
        let bare = candidate.components().count() == 1;
        if !overridden && !bare && !candidate.exists() {
            tried.push(format!("{}: no such file", candidate.display()));
            continue;
        }
        // SAFETY: loading a shared library runs its initialisers. The candidates are the
        // vendor's library (or the path the user named for it), whose initialisers only set up
        // its own state.
        match unsafe { libloading::Library::new(&candidate) } {
            Ok(library) => {
                // Never unloaded, even when refused (module docs).
                let library: &'static libloading::Library = Box::leak(Box::new(library));
                let lib: &'static T = Box::leak(Box::new(bind(library, candidate)?));
                loaded.push(lib);
                return Ok(lib);
            }
            Err(e) if overridden => {
                return Err(failed(LoadFailure::Load {
                    path: candidate,
                    reason: e.to_string(),
                }));
            }
            Err(e) if bare => tried.push(format!(
                "the system library path (LD_LIBRARY_PATH, /etc/ld.so.conf): {e}"
            )),
            Err(e) => tried.push(format!("{}: {e}", candidate.display())),
        }
    }
    if !overridden {
        tried.push(format!("{}: not set", spec.env));
    }
    Err(failed(LoadFailure::NotFound { tried }))
}

/// Looks up the function `$name` (a string literal) in `$library` (a `&'static
/// libloading::Library`) as the type of the place it is stored in; a library without it gives
/// `Err($missing($name))` from the enclosing function. For the backends' function tables: each
/// field's type is the C signature the vendor's header gives the function.
macro_rules! bind_symbol {
    ($library:expr, $name:literal, $missing:expr) => {{
        // SAFETY: the field this is stored in is declared with the signature the vendor's
        // header gives `$name`, and the library is never unloaded (module docs).
        match unsafe { $library.get(concat!($name, "\0").as_bytes()) } {
            Ok(symbol) => *symbol,
            Err(_) => return Err($missing($name)),
        }
    }};
}
pub(crate) use bind_symbol;

/// A C string a library returned, copied out (`None` for null).
///
/// # Safety
/// `text` is null or a NUL-terminated string that stays valid for the call.
pub unsafe fn c_text(text: *const std::ffi::c_char) -> Option<String> {
    if text.is_null() {
        return None;
    }
    // SAFETY: non-null and NUL-terminated (the caller's promise); copied out at once.
    Some(
        unsafe { std::ffi::CStr::from_ptr(text) }
            .to_string_lossy()
            .trim()
            .to_owned(),
    )
}
