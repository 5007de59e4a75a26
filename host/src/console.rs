//! The browser console: a page lluavd serves itself, on its own port.
//!
//! The assets under `host/console/` are compiled into the binary, so there is
//! nothing to install and nothing is fetched from elsewhere. The network
//! layer reads the HTTP request head; a request that is not a WebSocket
//! upgrade is answered here ([`handler`], which the daemon passes to the
//! network layer, and [`respond`]), and never reaches the protocol.
//! The page then opens a WebSocket to the same origin and is just another
//! client of the protocol, and a second one to `/events` for its event log.
//!
//! Only `GET` and `HEAD` exist. Every answer forbids sniffing and framing;
//! the page's Content-Security-Policy admits scripts, styles and images from
//! the page's own origin only, and connections (the WebSocket) to that same
//! origin only.

use std::fmt::Write as _;
use std::sync::Arc;

use crate::net::Http;

/// Content-Security-Policy of the page and its assets: everything from the
/// page's own origin, nothing inline, no plugins, no framing. CSP level 3
/// `'self'` in `connect-src` also admits `ws:`/`wss:` to the same host and
/// port, where both WebSockets the page opens go (commands, `/events`).
const PAGE_POLICY: &str = "default-src 'none'; script-src 'self'; style-src 'self'; \
    img-src 'self'; connect-src 'self'; base-uri 'none'; form-action 'none'; \
    frame-ancestors 'none'";

/// Content-Security-Policy of error answers: nothing at all.
const ERROR_POLICY: &str = "default-src 'none'; frame-ancestors 'none'";

/// One embedded file: where it is served and what it is.
struct Asset {
    path: &'static str,
    content_type: &'static str,
    body: &'static [u8],
}

/// An asset of `host/console/`, served at `/` followed by its file name.
macro_rules! asset {
    ($file:literal, $content_type:expr) => {
        Asset {
            path: concat!("/", $file),
            content_type: $content_type,
            body: include_bytes!(concat!("../console/", $file)),
        }
    };
}

const JAVASCRIPT: &str = "text/javascript; charset=utf-8";

/// The page and its assets. `/` serves the first.
const ASSETS: &[Asset] = &[
    asset!("index.html", "text/html; charset=utf-8"),
    asset!("console.css", "text/css; charset=utf-8"),
    asset!("main.js", JAVASCRIPT),
    asset!("protocol.js", JAVASCRIPT),
    asset!("vehicle.js", JAVASCRIPT),
    asset!("plot.js", JAVASCRIPT),
    asset!("panels.js", JAVASCRIPT),
    asset!("events.js", JAVASCRIPT),
    asset!("favicon.svg", "image/svg+xml"),
];

/// The methods that exist, as the `Allow` header lists them.
const ALLOWED: &str = "GET, HEAD";

/// An HTTP answer to a request that is not a WebSocket upgrade.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Response {
    /// Status code.
    pub status: u16,
    /// Reason phrase.
    pub reason: &'static str,
    /// Headers other than `Content-Length` and `Connection`, which
    /// [`Response::to_bytes`] adds.
    pub headers: Vec<(&'static str, String)>,
    /// The body (also what `Content-Length` counts for `HEAD`).
    pub body: &'static [u8],
}

impl Response {
    /// The whole HTTP/1.1 message (Content-Length, Connection: close), body
    /// omitted for HEAD.
    pub fn to_bytes(&self, head_only: bool) -> Vec<u8> {
        let mut head = format!("HTTP/1.1 {} {}\r\n", self.status, self.reason);
        for (name, value) in &self.headers {
            // Writing to a String cannot fail.
            let _ = write!(head, "{name}: {value}\r\n");
        }
        let _ = write!(
            head,
            "Content-Length: {}\r\nConnection: close\r\n\r\n",
            self.body.len()
        );
        let mut bytes = head.into_bytes();
        if !head_only {
            bytes.extend_from_slice(self.body);
        }
        bytes
    }

    /// The header `name` (ASCII case-insensitive), if present.
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(n, _)| n.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }

    fn asset(asset: &Asset) -> Response {
        Response {
            status: 200,
            reason: "OK",
            headers: vec![
                ("Content-Type", asset.content_type.to_owned()),
                ("Content-Security-Policy", PAGE_POLICY.to_owned()),
                ("X-Content-Type-Options", "nosniff".to_owned()),
                ("Referrer-Policy", "no-referrer".to_owned()),
                // The assets change with the binary: always revalidate.
                ("Cache-Control", "no-cache".to_owned()),
            ],
            body: asset.body,
        }
    }

    fn error(status: u16, reason: &'static str, body: &'static [u8]) -> Response {
        Response {
            status,
            reason,
            headers: vec![
                ("Content-Type", "text/plain; charset=utf-8".to_owned()),
                ("Content-Security-Policy", ERROR_POLICY.to_owned()),
                ("X-Content-Type-Options", "nosniff".to_owned()),
                ("Cache-Control", "no-store".to_owned()),
            ],
            body,
        }
    }

    fn not_found() -> Response {
        Response::error(404, "Not Found", b"Not found\n")
    }

    fn method_not_allowed() -> Response {
        let mut r = Response::error(405, "Method Not Allowed", b"Only GET and HEAD\n");
        r.headers.push(("Allow", ALLOWED.to_owned()));
        r
    }
}

/// The answer to `method target` when it is not a WebSocket upgrade.
/// `enabled` is false with `--no-console`: then every path answers 404.
///
/// `target` is the request target as sent: origin-form (`/plot.js?x`) or
/// absolute-form (`http://host/plot.js`); the query is ignored.
pub fn respond(enabled: bool, method: &str, target: &str) -> Response {
    if !enabled {
        return Response::not_found();
    }
    if method != "GET" && method != "HEAD" {
        return Response::method_not_allowed();
    }
    let path = path_of(target);
    let wanted = if path == "/" { "/index.html" } else { path };
    match ASSETS.iter().find(|a| a.path == wanted) {
        Some(asset) => Response::asset(asset),
        None => Response::not_found(),
    }
}

/// The console as the network layer's answer to plain HTTP requests
/// (`enabled`: false with `--no-console`, when every path answers 404).
pub fn handler(enabled: bool) -> Http {
    Arc::new(move |method: &str, target: &str| respond(enabled, method, target).to_bytes(method == "HEAD"))
}

/// The path of a request target, without query or fragment; the
/// absolute-form's scheme and authority are dropped.
fn path_of(target: &str) -> &str {
    let rest = ["http://", "https://"]
        .iter()
        .find_map(|scheme| {
            let head = target.get(..scheme.len())?;
            head.eq_ignore_ascii_case(scheme).then(|| &target[scheme.len()..])
        })
        .map_or(target, |after| after.find('/').map_or("/", |i| &after[i..]));
    let end = rest.find(['?', '#']).unwrap_or(rest.len());
    &rest[..end]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn text(r: &Response, head_only: bool) -> String {
        String::from_utf8(r.to_bytes(head_only)).expect("answers are UTF-8")
    }

    #[test]
    fn root_serves_the_page_with_a_strict_policy() {
        let r = respond(true, "GET", "/");
        assert_eq!(r.status, 200);
        assert_eq!(r.header("content-type"), Some("text/html; charset=utf-8"));
        assert_eq!(r.header("X-Content-Type-Options"), Some("nosniff"));
        assert_eq!(r.header("Cache-Control"), Some("no-cache"));
        let policy = r.header("Content-Security-Policy").expect("a policy");
        assert!(policy.contains("default-src 'none'"));
        assert!(policy.contains("script-src 'self'"));
        assert!(policy.contains("connect-src 'self'"));
        assert!(policy.contains("frame-ancestors 'none'"));
        assert!(!policy.contains("unsafe"));
        assert!(
            std::str::from_utf8(r.body)
                .expect("UTF-8")
                .contains("<title>lluav console</title>")
        );
    }

    #[test]
    fn index_html_is_the_same_page_as_root() {
        assert_eq!(respond(true, "GET", "/index.html"), respond(true, "GET", "/"));
    }

    #[test]
    fn every_asset_is_served_with_its_type() {
        for (path, ty) in [
            ("/console.css", "text/css; charset=utf-8"),
            ("/main.js", "text/javascript; charset=utf-8"),
            ("/protocol.js", "text/javascript; charset=utf-8"),
            ("/vehicle.js", "text/javascript; charset=utf-8"),
            ("/plot.js", "text/javascript; charset=utf-8"),
            ("/panels.js", "text/javascript; charset=utf-8"),
            ("/events.js", "text/javascript; charset=utf-8"),
            ("/favicon.svg", "image/svg+xml"),
        ] {
            let r = respond(true, "GET", path);
            assert_eq!(r.status, 200, "{path}");
            assert_eq!(r.header("Content-Type"), Some(ty), "{path}");
            assert!(!r.body.is_empty(), "{path}");
        }
    }

    #[test]
    fn every_module_the_page_imports_is_served() {
        for asset in ASSETS.iter().filter(|a| a.path.ends_with(".js")) {
            let source = std::str::from_utf8(asset.body).expect("UTF-8");
            // `import ... from './x.js';`, also when the names span lines
            // (`} from './x.js';` ends the statement).
            let statements = source
                .lines()
                .filter(|l| (l.starts_with("import ") || l.starts_with("} from ")) && l.contains(" from "));
            for line in statements {
                let from = line.rsplit(['\'', '"']).nth(1).expect("a quoted module");
                let path = from.trim_start_matches('.');
                assert_eq!(
                    respond(true, "GET", path).status,
                    200,
                    "{} imports {from}",
                    asset.path
                );
            }
        }
    }

    #[test]
    fn query_and_absolute_form_name_the_same_path() {
        assert_eq!(respond(true, "GET", "/?ws=ws://x/").status, 200);
        assert_eq!(respond(true, "GET", "/plot.js#top").status, 200);
        assert_eq!(respond(true, "GET", "http://127.0.0.1:53001/plot.js").status, 200);
        assert_eq!(
            respond(true, "GET", "HTTPS://vehicle").body,
            respond(true, "GET", "/").body
        );
    }

    #[test]
    fn unknown_paths_answer_404() {
        for target in [
            "/nope",
            "/console.css/",
            "/../Cargo.toml",
            "//plot.js",
            "*",
            "",
            "/INDEX.HTML",
        ] {
            let r = respond(true, "GET", target);
            assert_eq!(r.status, 404, "{target:?}");
            assert_eq!(r.header("Content-Type"), Some("text/plain; charset=utf-8"));
        }
    }

    #[test]
    fn other_methods_answer_405_with_allow() {
        for method in ["POST", "PUT", "DELETE", "OPTIONS", "PATCH", "get", "CONNECT"] {
            let r = respond(true, method, "/");
            assert_eq!(r.status, 405, "{method}");
            assert_eq!(r.header("Allow"), Some("GET, HEAD"));
        }
    }

    #[test]
    fn disabled_console_answers_404_everywhere() {
        for (method, target) in [
            ("GET", "/"),
            ("HEAD", "/plot.js"),
            ("POST", "/"),
            ("GET", "/nope"),
        ] {
            assert_eq!(respond(false, method, target).status, 404, "{method} {target}");
        }
    }

    #[test]
    fn message_has_length_and_close_and_head_omits_the_body() {
        let r = respond(true, "GET", "/console.css");
        let full = r.to_bytes(false);
        let head = text(&r, true);
        assert!(head.starts_with("HTTP/1.1 200 OK\r\n"));
        assert!(head.contains(&format!("\r\nContent-Length: {}\r\n", r.body.len())));
        assert!(head.contains("\r\nConnection: close\r\n"));
        assert!(head.ends_with("\r\n\r\n"));
        assert_eq!(&full[..head.len()], head.as_bytes());
        assert_eq!(&full[head.len()..], r.body);
    }

    #[test]
    fn head_answers_like_get_without_a_body() {
        let get = respond(true, "GET", "/main.js");
        let head = respond(true, "HEAD", "/main.js");
        assert_eq!(get, head);
        assert!(text(&head, true).contains(&format!("Content-Length: {}", get.body.len())));
    }

    #[test]
    fn error_answers_say_why_in_plain_text() {
        let r = text(&respond(true, "DELETE", "/"), false);
        assert!(r.starts_with("HTTP/1.1 405 Method Not Allowed\r\n"));
        assert!(r.contains("\r\nAllow: GET, HEAD\r\n"));
        assert!(r.ends_with("\r\n\r\nOnly GET and HEAD\n"));
        assert!(text(&respond(true, "GET", "/x"), false).starts_with("HTTP/1.1 404 Not Found\r\n"));
    }
}
