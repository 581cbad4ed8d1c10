//! The viewer built into the binary: `softhaptic` started from an empty directory (no `web/`
//! anywhere it could look) serves the page and every module the page imports, followed through
//! its import map and each module's imports, with 200 and the right type; each file carries an
//! ETag that a revalidation answers with a bodiless 304. A `--web-dir` without three.js stops the
//! start naming the missing file and the fix.

// Test code, synchronous: a plain HTTP/1.1 client over std's TcpStream.
#![allow(clippy::disallowed_methods)]
#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

mod support;

use std::collections::{BTreeMap, BTreeSet};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

const DEADLINE: Duration = Duration::from_secs(120);

struct Answer {
    status: u16,
    headers: BTreeMap<String, String>,
    body: Vec<u8>,
}

/// `GET path` on `addr`, one connection per request; `extra` headers added.
fn get(addr: SocketAddr, path: &str, extra: &[(&str, &str)]) -> Answer {
    let mut stream = TcpStream::connect(addr).unwrap();
    stream.set_read_timeout(Some(DEADLINE)).unwrap();
    let mut request = format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n");
    for (k, v) in extra {
        request.push_str(&format!("{k}: {v}\r\n"));
    }
    request.push_str("\r\n");
    stream.write_all(request.as_bytes()).unwrap();
    let mut raw = Vec::new();
    stream.read_to_end(&mut raw).unwrap();
    let split = raw.windows(4).position(|w| w == b"\r\n\r\n").unwrap();
    let head = String::from_utf8(raw[..split].to_vec()).unwrap();
    let mut lines = head.lines();
    let status = lines.next().unwrap().split_whitespace().nth(1).unwrap();
    let headers = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_owned()))
        .collect::<BTreeMap<_, _>>();
    assert!(
        !headers
            .get("transfer-encoding")
            .is_some_and(|t| t.contains("chunked")),
        "{path}: this client reads whole bodies only"
    );
    Answer {
        status: status.parse().unwrap(),
        headers,
        body: raw[split + 4..].to_vec(),
    }
}

/// Every quoted specifier after `marker` in `text` (`from '…'`, `import '…'`, `import("…")`).
fn quoted_after(text: &str, marker: &str) -> Vec<String> {
    let mut found = Vec::new();
    let mut rest = text;
    while let Some(at) = rest.find(marker) {
        let after = rest[at + marker.len()..].trim_start();
        if let Some(quote) = after.chars().next().filter(|c| *c == '\'' || *c == '"')
            && let Some(end) = after[1..].find(quote)
        {
            found.push(after[1..1 + end].to_owned());
        }
        rest = &rest[at + marker.len()..];
    }
    found
}

/// The modules a module imports (static and dynamic, re-exports included).
fn imports(js: &str) -> Vec<String> {
    let mut all = quoted_after(js, "from");
    all.extend(quoted_after(js, "import"));
    all.extend(quoted_after(js, "import("));
    all
}

/// A specifier resolved as the browser would: the import map's exact and prefix entries, then
/// relative to the importing module's URL.
fn resolve(spec: &str, base: &str, map: &BTreeMap<String, String>) -> String {
    if let Some(exact) = map.get(spec) {
        return exact.clone();
    }
    if let Some((prefix, target)) = map
        .iter()
        .filter(|(k, _)| k.ends_with('/') && spec.starts_with(k.as_str()))
        .max_by_key(|(k, _)| k.len())
    {
        return format!("{target}{}", &spec[prefix.len()..]);
    }
    if spec.starts_with('/') {
        return spec.to_owned();
    }
    let mut parts: Vec<&str> = base.split('/').collect();
    parts.pop();
    for piece in spec.split('/') {
        match piece {
            "." => {}
            ".." => {
                parts.pop();
            }
            p => parts.push(p),
        }
    }
    parts.join("/")
}

/// The page's import map, and the files it names by `src=` or `href=` (module, style).
fn page_links(html: &str) -> (BTreeMap<String, String>, Vec<String>) {
    let start = html.find("<script type=\"importmap\">").unwrap();
    let body = &html[start..];
    let body = &body[body.find('>').unwrap() + 1..body.find("</script>").unwrap()];
    let map: serde_json::Value = serde_json::from_str(body).unwrap();
    let map = map["imports"]
        .as_object()
        .unwrap()
        .iter()
        .map(|(k, v)| (k.clone(), v.as_str().unwrap().to_owned()))
        .collect();
    let mut links = quoted_after(html, "src=");
    links.extend(quoted_after(html, "href="));
    links.retain(|l| l.starts_with('/'));
    (map, links)
}

fn expected_type(path: &str) -> &'static str {
    match path.rsplit('.').next().unwrap() {
        "js" => "text/javascript",
        "css" => "text/css",
        other => panic!("{path}: a {other} file the test does not know"),
    }
}

#[test]
fn from_an_empty_directory_the_binary_serves_the_page_and_every_module_it_imports() {
    let empty = std::env::temp_dir().join(format!("softhaptic-viewer-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&empty);
    std::fs::create_dir_all(&empty).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_softhaptic"))
        .args([
            "run",
            "--no-realtime",
            "--no-record",
            "--addr",
            "127.0.0.1:0",
        ])
        .current_dir(&empty)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let (tx, lines) = mpsc::channel();
    let stdout = child.stdout.take().unwrap();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let url = loop {
        let line = lines
            .recv_timeout(DEADLINE)
            .expect("the server prints its viewer link");
        if let Some(url) = line.strip_prefix("viewer: ") {
            break url.trim().to_owned();
        }
    };
    let addr: SocketAddr = url
        .trim_start_matches("http://")
        .trim_end_matches('/')
        .parse()
        .unwrap();

    let page = get(addr, "/", &[]);
    assert_eq!(page.status, 200);
    assert_eq!(page.headers["content-type"], "text/html; charset=utf-8");
    let html = String::from_utf8(page.body).unwrap();
    let (map, links) = page_links(&html);
    assert!(map.contains_key("three"), "{map:?}");

    // Every file reachable from the page, breadth first.
    let mut queue: Vec<String> = links;
    let mut seen = BTreeSet::new();
    while let Some(path) = queue.pop() {
        if !seen.insert(path.clone()) {
            continue;
        }
        let answer = get(addr, &path, &[]);
        assert_eq!(answer.status, 200, "{path}");
        let kind = expected_type(&path);
        assert_eq!(
            answer.headers["content-type"],
            format!("{kind}; charset=utf-8"),
            "{path}"
        );
        assert!(!answer.body.is_empty(), "{path}");
        // Revalidation: the ETag names the content; the same tag gets a 304 without a body.
        let etag = answer.headers.get("etag").expect("an ETag").clone();
        assert_eq!(answer.headers["cache-control"], "no-cache", "{path}");
        let again = get(addr, &path, &[("If-None-Match", &etag)]);
        assert_eq!(again.status, 304, "{path}");
        assert!(again.body.is_empty(), "{path}");
        if kind == "text/javascript" {
            let js = String::from_utf8(answer.body).unwrap();
            for spec in imports(&js) {
                queue.push(resolve(&spec, &path, &map));
            }
        }
    }
    // The page's own modules and the three.js files the import map leads to.
    for must in [
        "/src/main.js",
        "/src/style.css",
        "/vendor/three/three.module.js",
        "/vendor/three/three.core.js",
        "/vendor/three/addons/controls/OrbitControls.js",
    ] {
        assert!(seen.contains(must), "{must} not reached: {seen:?}");
    }
    // Nothing outside what the page needs.
    assert_eq!(get(addr, "/vendor/three/package.json", &[]).status, 404);
    assert_eq!(get(addr, "/src/../index.html", &[]).status, 404);

    let status = support::stop_with_signal(&mut child, "TERM");
    assert!(status.success(), "{status}");
    // Nothing written where it was started.
    assert_eq!(std::fs::read_dir(&empty).unwrap().count(), 0);
    std::fs::remove_dir_all(&empty).unwrap();
}

#[test]
fn a_web_dir_without_three_stops_the_start_naming_the_file_and_the_fix() {
    let dir = std::env::temp_dir().join(format!("softhaptic-webdir-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("src")).unwrap();
    std::fs::write(dir.join("index.html"), "<!doctype html>").unwrap();
    std::fs::write(dir.join("src/main.js"), "").unwrap();
    for command in [
        &["run", "--no-realtime", "--no-record"][..],
        &["hub", "--nats", "nats://127.0.0.1:1"],
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_softhaptic"))
            .args(command)
            .args(["--addr", "127.0.0.1:0", "--web-dir"])
            .arg(&dir)
            .output()
            .unwrap();
        assert!(!out.status.success(), "{command:?}");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            stderr.contains("node_modules/three/build/three.module.js")
                && stderr.contains("npm ci")
                && stderr.contains(&dir.display().to_string()),
            "{command:?}: {stderr}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
