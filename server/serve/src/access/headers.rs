//! The security headers of every response: the Content-Security-Policy of the served page (its
//! inline scripts allowed by their hashes), `nosniff`, no referrer, no framing.

use axum::Router;
use axum::http::{HeaderValue, header};
use base64::Engine;
use sha2::{Digest, Sha256};
use tower_http::set_header::SetResponseHeaderLayer;

/// The Content-Security-Policy for a viewer page: only the server's own scripts (and the page's
/// inline scripts, by their hashes), styles and WebSocket; no plugins, no framing, no forms.
pub fn content_security_policy(page_html: &str) -> String {
    let mut script_src = String::from("'self'");
    for hash in inline_script_hashes(page_html) {
        script_src.push_str(&format!(" 'sha256-{hash}'"));
    }
    format!(
        "default-src 'self'; script-src {script_src}; style-src 'self'; connect-src 'self'; \
         img-src 'self' data:; object-src 'none'; base-uri 'none'; form-action 'none'; \
         frame-ancestors 'none'"
    )
}

/// SHA-256 (base64) of the text of every inline `<script>` (one without `src`) of a page, as
/// CSP hashes them: the exact characters between the tags.
pub fn inline_script_hashes(page_html: &str) -> Vec<String> {
    // ASCII lower-casing keeps every byte offset, so positions found in `lower` index `page_html`.
    let lower = page_html.to_ascii_lowercase();
    let mut hashes = Vec::new();
    let mut at = 0;
    while let Some(found) = lower[at..].find("<script") {
        let tag_start = at + found;
        let Some(tag_len) = lower[tag_start..].find('>') else {
            break;
        };
        let tag = &lower[tag_start + "<script".len()..tag_start + tag_len];
        let content_start = tag_start + tag_len + 1;
        let Some(content_len) = lower[content_start..].find("</script") else {
            break;
        };
        let has_src = tag
            .split(|c: char| c.is_ascii_whitespace())
            .any(|attr| attr == "src" || attr.starts_with("src="));
        if !has_src {
            let content = &page_html[content_start..content_start + content_len];
            hashes.push(base64::engine::general_purpose::STANDARD.encode(Sha256::digest(content)));
        }
        at = content_start + content_len;
    }
    hashes
}

/// `Strict-Transport-Security` of a server with a CA's certificate: a year.
pub const STRICT_TRANSPORT: &str = "max-age=31536000";

/// Adds the security headers to every response of `router` (pages, scripts, API, errors):
/// the CSP, `nosniff`, no referrer, no framing; and with `strict_transport` (a CA's
/// certificate, see `AccessConfig::strict_transport`), `Strict-Transport-Security`.
pub fn with_security_headers(router: Router, csp: HeaderValue, strict_transport: bool) -> Router {
    let router = if strict_transport {
        router.layer(SetResponseHeaderLayer::overriding(
            header::STRICT_TRANSPORT_SECURITY,
            HeaderValue::from_static(STRICT_TRANSPORT),
        ))
    } else {
        router
    };
    router
        .layer(SetResponseHeaderLayer::overriding(
            header::CONTENT_SECURITY_POLICY,
            csp,
        ))
        .layer(SetResponseHeaderLayer::overriding(
            header::X_CONTENT_TYPE_OPTIONS,
            HeaderValue::from_static("nosniff"),
        ))
        .layer(SetResponseHeaderLayer::overriding(
            header::REFERRER_POLICY,
            HeaderValue::from_static("no-referrer"),
        ))
        .layer(SetResponseHeaderLayer::overriding(
            header::X_FRAME_OPTIONS,
            HeaderValue::from_static("DENY"),
        ))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[tokio::test]
    async fn strict_transport_is_sent_only_when_asked() {
        use tower::ServiceExt;
        for asked in [false, true] {
            let router = Router::new().route("/", axum::routing::get(|| async { "page" }));
            let response = with_security_headers(router, HeaderValue::from_static("x"), asked)
                .oneshot(
                    axum::http::Request::get("/")
                        .body(axum::body::Body::empty())
                        .unwrap(),
                )
                .await
                .unwrap();
            let sent = response.headers().get(header::STRICT_TRANSPORT_SECURITY);
            assert_eq!(
                sent.map(|v| v.to_str().unwrap()),
                asked.then_some(STRICT_TRANSPORT)
            );
            assert!(response.headers().contains_key(header::X_FRAME_OPTIONS));
        }
    }

    #[test]
    fn the_csp_allows_exactly_the_pages_inline_script_by_its_hash() {
        let page = "<html><head><script type=\"importmap\">\n {\"imports\": {}}\n </script>\n\
                    <script type=\"module\" src=\"/src/main.js\"></script></head></html>";
        let hashes = inline_script_hashes(page);
        let expected = base64::engine::general_purpose::STANDARD
            .encode(Sha256::digest("\n {\"imports\": {}}\n "));
        assert_eq!(hashes, vec![expected.clone()]);
        let csp = content_security_policy(page);
        assert!(
            csp.contains(&format!("script-src 'self' 'sha256-{expected}';")),
            "{csp}"
        );
        assert!(csp.contains("frame-ancestors 'none'") && csp.contains("object-src 'none'"));
        assert_eq!(
            content_security_policy(""),
            content_security_policy("<p>no scripts</p>")
        );
    }
}
