//! The viewer's files: the page (`web/index.html`), its modules and style (`web/src/`), and
//! three.js with the one addon the page imports (OrbitControls), as the page's import map names
//! them (`/vendor/three/…`).
//!
//! By default they are the copies built into the binary (`rust-embed`, embedded in every
//! profile), so that the binary alone serves a working page from any directory; `build.rs`
//! refuses to build without three.js. `--web-dir DIR` serves a checkout's `web/` instead, for
//! developing the viewer without rebuilding. Nothing is ever taken from the working directory.
//!
//! A [`Viewer`] is checked before a server starts ([`Viewer::check`]): a page whose three.js is
//! missing would stay at "starting" with two 404s and nothing in the log, so a server that would
//! serve it refuses to start and says which file is missing.
//!
//! Embedded files carry an `ETag` (the SHA-256 of their content, computed at build time) and
//! `Cache-Control: no-cache`: the page's URLs carry no version, so a browser revalidates each
//! file and gets a bodiless 304 while the binary is unchanged, and the new file after an upgrade.

use std::borrow::Cow;
use std::path::{Path, PathBuf};

use axum::Router;
use axum::body::Body;
use axum::http::{HeaderMap, HeaderValue, StatusCode, Uri, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, get_service};
use rust_embed::RustEmbed;
use tower_http::services::{ServeDir, ServeFile};

use crate::files::{self, FileKind};

/// The viewer's files as built into the binary; paths relative to `web/`. The list of three.js
/// files follows the page's imports (`three` → three.module.js → three.core.js; the addon
/// `controls/OrbitControls.js`): a test fetches every module the page imports from a binary run
/// outside the source tree.
#[derive(RustEmbed)]
#[folder = "../../web/"]
#[include = "index.html"]
#[include = "dashboard.html"]
#[include = "src/*.js"]
#[include = "src/*.css"]
#[include = "node_modules/three/build/three.module.js"]
#[include = "node_modules/three/build/three.core.js"]
#[include = "node_modules/three/examples/jsm/controls/OrbitControls.js"]
struct Embedded;

/// URL prefixes and the directories of `web/` they serve, most specific first.
const MOUNTS: [(&str, &str); 3] = [
    ("/vendor/three/addons/", "node_modules/three/examples/jsm/"),
    ("/vendor/three/", "node_modules/three/build/"),
    ("/src/", "src/"),
];

/// The files without which the page cannot run (paths relative to `web/`): the page, its entry
/// module, and three.js with the addon it imports.
pub const REQUIRED: [&str; 5] = [
    "index.html",
    "src/main.js",
    THREE_MODULE,
    "node_modules/three/build/three.core.js",
    "node_modules/three/examples/jsm/controls/OrbitControls.js",
];

const THREE_MODULE: &str = "node_modules/three/build/three.module.js";

/// Why the viewer's files cannot be served.
#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    #[error(
        "--web-dir {}: no {file}: the page would load without it and stay at \"starting\"; {hint}",
        dir.display()
    )]
    Missing {
        dir: PathBuf,
        file: &'static str,
        hint: &'static str,
    },
    #[error(
        "this binary was built without the viewer's {file}: rebuild it after `npm ci` in web/, \
         or serve a checkout's viewer with --web-dir"
    )]
    NotEmbedded { file: &'static str },
    #[error("--web-dir {}: could not read index.html: {source}", dir.display())]
    Page {
        dir: PathBuf,
        #[source]
        source: files::ReadError,
    },
}

/// Where the viewer's files come from.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Viewer {
    /// `None`: the files built into the binary.
    dir: Option<PathBuf>,
}

impl Viewer {
    /// The files built into the binary.
    pub fn embedded() -> Self {
        Self { dir: None }
    }

    /// A checkout's `web/` (index.html, src/, node_modules/three), checked as [`Viewer::check`]
    /// does.
    pub fn from_dir(dir: impl Into<PathBuf>) -> Result<Self, ViewerError> {
        let viewer = Self {
            dir: Some(dir.into()),
        };
        viewer.check()?;
        Ok(viewer)
    }

    /// `--web-dir` when given, else the embedded files; checked.
    pub fn from_option(dir: Option<PathBuf>) -> Result<Self, ViewerError> {
        match dir {
            Some(dir) => Self::from_dir(dir),
            None => {
                let viewer = Self::embedded();
                viewer.check()?;
                Ok(viewer)
            }
        }
    }

    /// The directory served, `None` for the embedded files.
    pub fn dir(&self) -> Option<&Path> {
        self.dir.as_deref()
    }

    /// Refuses a viewer missing a file the page needs ([`REQUIRED`]), naming it.
    pub fn check(&self) -> Result<(), ViewerError> {
        for file in REQUIRED {
            match &self.dir {
                None if Embedded::get(file).is_none() => {
                    return Err(ViewerError::NotEmbedded { file });
                }
                Some(dir) if !dir.join(file).is_file() => {
                    let hint = if file.starts_with("node_modules/") {
                        "run `npm ci` in that directory, or leave out --web-dir to serve the \
                         viewer built into the binary"
                    } else {
                        "give the web/ directory of a checkout, or leave out --web-dir to serve \
                         the viewer built into the binary"
                    };
                    return Err(ViewerError::Missing {
                        dir: dir.clone(),
                        file,
                        hint,
                    });
                }
                _ => {}
            }
        }
        Ok(())
    }

    /// The page's HTML (for the Content-Security-Policy's hashes of its inline scripts).
    pub fn page_html(&self) -> Result<String, ViewerError> {
        match &self.dir {
            None => Embedded::get("index.html")
                .map(|f| String::from_utf8_lossy(&f.data).into_owned())
                .ok_or(ViewerError::NotEmbedded { file: "index.html" }),
            Some(dir) => {
                files::read_text(&dir.join("index.html"), FileKind::Page).map_err(|source| {
                    ViewerError::Page {
                        dir: dir.clone(),
                        source,
                    }
                })
            }
        }
    }

    /// The route of a lab hub's dashboard page, `/dashboard` (`web/dashboard.html`; its modules
    /// are the viewer's `/src/*`). It needs no token: the page asks for one as the viewer does.
    pub fn dashboard_routes<S: Clone + Send + Sync + 'static>(&self) -> Router<S> {
        match &self.dir {
            None => Router::new().route("/dashboard", get(embedded_file)),
            Some(dir) => Router::new().route_service(
                "/dashboard",
                get_service(ServeFile::new(dir.join("dashboard.html"))),
            ),
        }
    }

    /// The routes of the viewer's files: `/`, `/src/*`, `/vendor/three/*`. They need no token.
    pub fn routes<S: Clone + Send + Sync + 'static>(&self) -> Router<S> {
        match &self.dir {
            None => Router::new()
                .route("/", get(embedded_file))
                .route("/src/{*file}", get(embedded_file))
                .route("/vendor/three/{*file}", get(embedded_file)),
            Some(dir) => {
                let three = dir.join("node_modules").join("three");
                Router::new()
                    .route_service("/", get_service(ServeFile::new(dir.join("index.html"))))
                    .nest_service("/src", ServeDir::new(dir.join("src")))
                    .nest_service(
                        "/vendor/three/addons",
                        ServeDir::new(three.join("examples").join("jsm")),
                    )
                    .nest_service("/vendor/three", ServeDir::new(three.join("build")))
            }
        }
    }
}

/// The embedded file a URL path names (a path relative to `web/`), if any.
fn embedded_path(url_path: &str) -> Option<String> {
    match url_path {
        "/" => return Some("index.html".to_owned()),
        "/dashboard" => return Some("dashboard.html".to_owned()),
        _ => {}
    }
    MOUNTS.iter().find_map(|(prefix, dir)| {
        url_path
            .strip_prefix(prefix)
            .map(|rest| format!("{dir}{rest}"))
    })
}

/// The `Content-Type` of an embedded file: its type by extension, text in UTF-8 (RFC 9239 names
/// JavaScript `text/javascript`).
fn content_type(mime: &str) -> String {
    let mime = if mime == "application/javascript" {
        "text/javascript"
    } else {
        mime
    };
    if mime.starts_with("text/") {
        format!("{mime}; charset=utf-8")
    } else {
        mime.to_owned()
    }
}

/// Whether an `If-None-Match` header names `etag` (or is `*`); weak tags compare as strong, as
/// RFC 9110 says for this header.
fn none_match(headers: &HeaderMap, etag: &str) -> bool {
    headers
        .get_all(header::IF_NONE_MATCH)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .map(|tag| tag.trim())
        .any(|tag| tag == "*" || tag.strip_prefix("W/").unwrap_or(tag) == etag)
}

async fn embedded_file(uri: Uri, headers: HeaderMap) -> Response {
    let Some(file) = embedded_path(uri.path()).and_then(|path| Embedded::get(&path)) else {
        return (StatusCode::NOT_FOUND, "not found").into_response();
    };
    let hash = file.metadata.sha256_hash();
    // 128 bits of the SHA-256 name the content; the quotes are part of an entity tag.
    let etag = format!(
        "\"{}\"",
        hash[..16]
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect::<String>()
    );
    let etag_header = HeaderValue::from_str(&etag).unwrap_or(HeaderValue::from_static("\"\""));
    let cache = (header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    if none_match(&headers, &etag) {
        return (
            StatusCode::NOT_MODIFIED,
            [(header::ETAG, etag_header), cache],
        )
            .into_response();
    }
    let mime = content_type(file.metadata.mimetype());
    let content_type = HeaderValue::from_str(&mime)
        .unwrap_or(HeaderValue::from_static("application/octet-stream"));
    let body = match file.data {
        Cow::Borrowed(bytes) => Body::from(bytes),
        Cow::Owned(bytes) => Body::from(bytes),
    };
    (
        [
            (header::CONTENT_TYPE, content_type),
            (header::ETAG, etag_header),
            cache,
        ],
        body,
    )
        .into_response()
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn the_binary_holds_every_file_the_page_needs() {
        Viewer::embedded().check().unwrap();
        let page = Viewer::embedded().page_html().unwrap();
        assert!(page.contains("/vendor/three/three.module.js"), "{page}");
    }

    #[test]
    fn urls_map_to_the_files_of_web() {
        assert_eq!(embedded_path("/").as_deref(), Some("index.html"));
        assert_eq!(
            embedded_path("/src/main.js").as_deref(),
            Some("src/main.js")
        );
        assert_eq!(
            embedded_path("/vendor/three/three.module.js").as_deref(),
            Some(THREE_MODULE)
        );
        assert_eq!(
            embedded_path("/vendor/three/addons/controls/OrbitControls.js").as_deref(),
            Some("node_modules/three/examples/jsm/controls/OrbitControls.js")
        );
        assert_eq!(embedded_path("/index.html"), None);
        assert_eq!(embedded_path("/node_modules/three/package.json"), None);
    }

    #[test]
    fn a_web_dir_without_three_is_refused_naming_the_file_and_the_fix() {
        let dir = std::env::temp_dir().join(format!("softhaptic-viewer-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("src")).unwrap();
        std::fs::write(dir.join("index.html"), "<!doctype html>").unwrap();
        std::fs::write(dir.join("src/main.js"), "").unwrap();
        let e = Viewer::from_dir(&dir).unwrap_err().to_string();
        assert!(e.contains(THREE_MODULE) && e.contains("npm ci"), "{e}");
        assert!(e.contains(&dir.display().to_string()), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn if_none_match_lists_and_weak_tags() {
        let mut h = HeaderMap::new();
        assert!(!none_match(&h, "\"ab\""));
        h.insert(
            header::IF_NONE_MATCH,
            HeaderValue::from_static("\"x\", W/\"ab\""),
        );
        assert!(none_match(&h, "\"ab\""));
        assert!(!none_match(&h, "\"cd\""));
    }
}
