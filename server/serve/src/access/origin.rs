//! The Host and Origin rules: a request must name the server by an IP address, `localhost` or a
//! `--host-name` (a DNS-rebinding page names its own domain), and a WebSocket upgrade that
//! carries an `Origin` is accepted only from the server's own origin or an `--allow-origin`.

use std::fmt;
use std::net::{Ipv4Addr, Ipv6Addr};

use axum::http::{HeaderMap, header};

use super::Access;

/// An origin, `scheme://host[:port]`, with the host in lower case and the port made explicit,
/// so two spellings of the same origin compare equal.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Origin {
    scheme: String,
    host: String,
    port: u16,
}

impl fmt::Display for Origin {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}://{}:{}", self.scheme, self.host, self.port)
    }
}

impl Origin {
    /// The origin's host, lower case (an IPv6 literal in brackets).
    pub fn host(&self) -> &str {
        &self.host
    }

    /// Parses an `Origin` header or an `--allow-origin` value (one trailing `/` is tolerated in
    /// the latter's spelling).
    pub fn parse(text: &str) -> Result<Origin, &'static str> {
        let (scheme, rest) = text
            .split_once("://")
            .ok_or("an origin is scheme://host[:port], e.g. https://lab.example:8443")?;
        let scheme = scheme.to_ascii_lowercase();
        let default_port = match scheme.as_str() {
            "http" => 80,
            "https" => 443,
            _ => return Err("the scheme must be http or https"),
        };
        let rest = rest.strip_suffix('/').unwrap_or(rest);
        if rest.contains(['/', '?', '#', '@']) {
            return Err("an origin has no path, query, fragment or user");
        }
        let (host, port) = split_host_port(rest).ok_or("the host or the port is not valid")?;
        Ok(Origin {
            scheme,
            host,
            port: port.unwrap_or(default_port),
        })
    }
}

/// Splits `host[:port]` (an IPv6 address in brackets) into the lower-case host and the port;
/// `None` when either is malformed.
fn split_host_port(text: &str) -> Option<(String, Option<u16>)> {
    let (host, port) = if let Some(rest) = text.strip_prefix('[') {
        let (v6, after) = rest.split_once(']')?;
        v6.parse::<Ipv6Addr>().ok()?;
        let port = match after {
            "" => None,
            p => Some(p.strip_prefix(':')?),
        };
        (format!("[{v6}]"), port)
    } else {
        match text.rsplit_once(':') {
            Some((h, p)) => (h.to_owned(), Some(p)),
            None => (text.to_owned(), None),
        }
    };
    if host.is_empty()
        || !host.bytes().all(|b| {
            b.is_ascii_alphanumeric() || matches!(b, b'.' | b'-' | b'_' | b'[' | b']' | b':')
        })
    {
        return None;
    }
    let port = match port {
        None => None,
        Some(p) => Some(p.parse::<u16>().ok()?),
    };
    Some((host.to_ascii_lowercase(), port))
}

/// Whether `host` (a `Host` header's host, lower case, without the port) is an IP-address
/// literal: any address is a name the server may be reached by, while a DNS-rebinding page
/// always names its own domain.
fn is_ip_literal(host: &str) -> bool {
    if let Some(v6) = host.strip_prefix('[').and_then(|h| h.strip_suffix(']')) {
        return v6.parse::<Ipv6Addr>().is_ok();
    }
    host.parse::<Ipv4Addr>().is_ok()
}

/// The host a request names: its `Host` header, else its URI's authority (HTTP/2).
pub(super) fn request_host(headers: &HeaderMap) -> Option<String> {
    headers
        .get(header::HOST)
        .and_then(|h| h.to_str().ok())
        .map(str::to_owned)
}

impl Access {
    /// Whether a request naming `host` (a `Host` header, with or without port) is for this
    /// server: an IP-address literal, `localhost`, or a `--host-name`.
    pub fn host_allowed(&self, host: &str) -> bool {
        let Some((name, _)) = split_host_port(host) else {
            return false;
        };
        let name = name.trim_end_matches('.');
        is_ip_literal(name)
            || name == "localhost"
            || self.config.host_names.iter().any(|n| n == name)
    }

    /// The Origin rule of a WebSocket upgrade: no `Origin` (not a browser: the token guards
    /// it), the server's own (same scheme, host and port as the request's `Host`), or an
    /// `--allow-origin`. `Ok` carries the origin for the audit line; `Err` says why not.
    pub fn check_origin(&self, headers: &HeaderMap) -> Result<Option<String>, String> {
        let Some(value) = headers.get(header::ORIGIN) else {
            return Ok(None);
        };
        let text = value
            .to_str()
            .map_err(|_| "the Origin header is not text".to_owned())?;
        let origin = Origin::parse(text)
            .map_err(|problem| format!("Origin {text:?} is not an origin: {problem}"))?;
        if self.config.allowed_origins.contains(&origin) {
            return Ok(Some(text.to_owned()));
        }
        let scheme = if self.config.secure_transport {
            "https"
        } else {
            "http"
        };
        let own = request_host(headers)
            .and_then(|h| split_host_port(&h))
            .map(|(host, port)| Origin {
                scheme: scheme.to_owned(),
                host,
                port: port.unwrap_or(if self.config.secure_transport {
                    443
                } else {
                    80
                }),
            });
        match own {
            Some(own) if own == origin => Ok(Some(text.to_owned())),
            Some(own) => Err(format!(
                "Origin {text:?} is neither this server's own ({own}) nor given with --allow-origin"
            )),
            None => Err(format!("Origin {text:?} with no Host to compare it with")),
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use crate::access::AccessConfig;
    use crate::access::testing::access;
    use axum::http::HeaderValue;

    #[test]
    fn hosts_are_ip_literals_localhost_or_given_names() {
        let a = access(AccessConfig {
            host_names: vec!["lab.example".into()],
            ..AccessConfig::default()
        });
        for ok in [
            "127.0.0.1:8080",
            "10.1.2.3",
            "[::1]:8080",
            "[fe80::1]",
            "localhost:8080",
            "LOCALHOST",
            "localhost.",
            "lab.example:8443",
            "LAB.example",
        ] {
            assert!(a.host_allowed(ok), "{ok}");
        }
        for refused in [
            "evil.example",
            "evil.example:8080",
            "lab.example.evil.example",
            "127.0.0.1.nip.io",
            "2130706433",
            "",
            "[::1",
            "localhost:port",
            "a b",
        ] {
            assert!(!a.host_allowed(refused), "{refused}");
        }
    }

    fn headers(pairs: &[(header::HeaderName, &str)]) -> HeaderMap {
        let mut h = HeaderMap::new();
        for (name, value) in pairs {
            h.insert(name.clone(), HeaderValue::from_str(value).unwrap());
        }
        h
    }

    #[test]
    fn an_origin_is_accepted_when_it_is_the_servers_own_or_allowed() {
        let a = access(AccessConfig {
            allowed_origins: vec![Origin::parse("https://portal.example/").unwrap()],
            ..AccessConfig::default()
        });
        let check = |origin: Option<&str>, host: &str| {
            let mut pairs = vec![(header::HOST, host)];
            if let Some(o) = origin {
                pairs.push((header::ORIGIN, o));
            }
            a.check_origin(&headers(&pairs))
        };
        assert_eq!(check(None, "127.0.0.1:8080"), Ok(None));
        for (origin, host) in [
            ("http://127.0.0.1:8080", "127.0.0.1:8080"),
            ("http://LOCALHOST:8080", "localhost:8080"),
            ("http://lab", "lab:80"),
            ("http://[::1]:8080", "[::1]:8080"),
            ("https://portal.example", "127.0.0.1:8080"),
            ("https://portal.example:443", "127.0.0.1:8080"),
        ] {
            assert_eq!(
                check(Some(origin), host),
                Ok(Some(origin.to_owned())),
                "{origin} {host}"
            );
        }
        for (origin, host) in [
            ("http://evil.example", "127.0.0.1:8080"),
            ("http://127.0.0.1:8081", "127.0.0.1:8080"),
            ("https://127.0.0.1:8080", "127.0.0.1:8080"),
            ("null", "127.0.0.1:8080"),
            ("http://portal.example", "127.0.0.1:8080"),
        ] {
            assert!(check(Some(origin), host).is_err(), "{origin} {host}");
        }
        let tls = access(AccessConfig {
            secure_transport: true,
            ..AccessConfig::default()
        });
        let h = headers(&[
            (header::HOST, "lab:8443"),
            (header::ORIGIN, "https://lab:8443"),
        ]);
        assert!(tls.check_origin(&h).is_ok());
        let h = headers(&[
            (header::HOST, "lab:8443"),
            (header::ORIGIN, "http://lab:8443"),
        ]);
        assert!(tls.check_origin(&h).is_err());
        assert!(Origin::parse("ftp://x").is_err());
        assert!(Origin::parse("https://x/path").is_err());
    }
}
