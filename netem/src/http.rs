//! Runtime control over HTTP, in toxiproxy's model so that its clients and `curl` work (docs/design.md
//! §5 "Faults … injected at runtime through a control endpoint"; "names and semantics follow
//! toxiproxy").
//!
//! Every robot pair is a proxy named `r{a}-r{b}`; faults are toxics. Routes:
//! `GET /proxies`, `GET /proxies/{name}`, `POST|PATCH /proxies/{name}` (`{"enabled": bool}`:
//! false = cut, true = restore), `GET|POST /proxies/{name}/toxics`,
//! `GET|POST|PATCH|DELETE /proxies/{name}/toxics/{toxic}`, `POST /reset`, `GET /version`, and
//! ours: `GET /metrics` (Prometheus text) and `GET /links` (the telemetry rows as JSON, without
//! resetting the per-step counters), and `POST /processes/{name}` (a process fault — kill,
//! restart, freeze, thaw — handed on to the launcher; see [`process_fault`]). Proxies
//! are fixed by the scenario: creating or deleting one is `405`. Like toxiproxy, requests from
//! browsers (`User-Agent: Mozilla/…`) are refused, so that a web page cannot drive the API.
//!
//! The HTTP/1.1 request parser is ours, small and total (`parse`): request line, headers,
//! `Content-Length` body; no chunked encoding; every size bounded; any byte string gives a
//! request, "need more bytes", or an error with a status code — never a panic (property-tested).

use std::sync::Arc;
use std::time::Duration;

use proto::msg::ProcessOrder;
use proto::scenario::{Process, ProcessAction};
use serde::Serialize;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{mpsc, watch, Semaphore};
use tokio::task::JoinHandle;

use crate::faults::{Fault, Toxic, ToxicWire};
use crate::link::{stopped, Link};
use crate::netem::{NetemError, Shared};

/// Size limits of a request.
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    /// Request line plus headers, bytes.
    pub max_head_bytes: usize,
    pub max_headers: usize,
    pub max_target_bytes: usize,
    pub max_body_bytes: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_head_bytes: 16 * 1024,
            max_headers: 64,
            max_target_bytes: 2048,
            max_body_bytes: 64 * 1024,
        }
    }
}

/// A parsed request.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Request {
    pub method: String,
    /// The request target as sent (path and query).
    pub target: String,
    /// 0 for HTTP/1.0, 1 for HTTP/1.1.
    pub minor_version: u8,
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl Request {
    /// The first header of that name (case-insensitive).
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(n, _)| n.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }

    /// The target without its query.
    pub fn path(&self) -> &str {
        self.target.split(['?', '#']).next().unwrap_or("")
    }

    /// HTTP/1.1 keeps the connection unless `Connection: close`; 1.0 only with `keep-alive`.
    pub fn keep_alive(&self) -> bool {
        let conn = self.header("connection").map(str::to_ascii_lowercase);
        match self.minor_version {
            0 => conn.is_some_and(|c| c.contains("keep-alive")),
            _ => !conn.is_some_and(|c| c.contains("close")),
        }
    }
}

/// What [`parse`] found.
#[derive(Debug, PartialEq, Eq)]
pub enum Parsed {
    /// A whole request, which took the first `consumed` bytes of the buffer.
    Complete { request: Request, consumed: usize },
    /// A prefix of a request: read more.
    Partial,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ParseError {
    #[error("malformed request line")]
    RequestLine,
    #[error("request target too long")]
    TargetTooLong,
    #[error("unsupported HTTP version")]
    Version,
    #[error("malformed header line")]
    HeaderLine,
    #[error("request head too large")]
    HeadTooLarge,
    #[error("too many headers")]
    TooManyHeaders,
    #[error("invalid Content-Length")]
    ContentLength,
    #[error("request body too large")]
    BodyTooLarge,
    #[error("Transfer-Encoding is not supported; send a Content-Length")]
    TransferEncoding,
}

impl ParseError {
    pub fn status(self) -> u16 {
        match self {
            ParseError::TargetTooLong => 414,
            ParseError::Version => 505,
            ParseError::HeadTooLarge | ParseError::TooManyHeaders => 431,
            ParseError::BodyTooLarge => 413,
            ParseError::TransferEncoding => 501,
            _ => 400,
        }
    }
}

fn is_tchar(b: u8) -> bool {
    b.is_ascii_alphanumeric() || b"!#$%&'*+-.^_`|~".contains(&b)
}

/// The end of the head (index just past its empty line), if the buffer holds one. A line ends
/// with LF, optionally preceded by CR.
fn head_end(buf: &[u8]) -> Option<usize> {
    let mut i = 0;
    while let Some(off) = buf[i..].iter().position(|&b| b == b'\n') {
        let nl = i + off;
        let next = nl + 1;
        match buf.get(next) {
            Some(b'\n') => return Some(next + 1),
            Some(b'\r') if buf.get(next + 1) == Some(&b'\n') => return Some(next + 2),
            _ => i = next,
        }
    }
    None
}

/// Parses one request from the start of `buf`. Total: never panics, whatever the bytes.
pub fn parse(buf: &[u8], limits: &Limits) -> Result<Parsed, ParseError> {
    // RFC 9112 §2.2: ignore (a few) empty lines before the request line.
    let skip = buf
        .iter()
        .take(8)
        .take_while(|&&b| b == b'\r' || b == b'\n')
        .count();
    let rest = &buf[skip..];
    let window = &rest[..rest.len().min(limits.max_head_bytes)];
    let Some(head_len) = head_end(window) else {
        return if rest.len() >= limits.max_head_bytes {
            Err(ParseError::HeadTooLarge)
        } else {
            Ok(Parsed::Partial)
        };
    };
    let head = &rest[..head_len];
    let mut lines = head
        .split(|&b| b == b'\n')
        .map(|l| l.strip_suffix(b"\r").unwrap_or(l));
    let (method, target, minor_version) = request_line(lines.next().unwrap_or(b""), limits)?;
    let mut headers = Vec::new();
    let mut content_length: Option<u64> = None;
    for line in lines.filter(|l| !l.is_empty()) {
        if headers.len() >= limits.max_headers {
            return Err(ParseError::TooManyHeaders);
        }
        let colon = line
            .iter()
            .position(|&b| b == b':')
            .ok_or(ParseError::HeaderLine)?;
        let (name, value) = (&line[..colon], &line[colon + 1..]);
        if name.is_empty() || !name.iter().all(|&b| is_tchar(b)) {
            return Err(ParseError::HeaderLine);
        }
        let value = value.trim_ascii();
        if value.iter().any(|&b| (b < 0x20 && b != b'\t') || b == 0x7f) {
            return Err(ParseError::HeaderLine);
        }
        let name = String::from_utf8_lossy(name).into_owned();
        let value = String::from_utf8_lossy(value).into_owned();
        if name.eq_ignore_ascii_case("transfer-encoding") {
            return Err(ParseError::TransferEncoding);
        }
        if name.eq_ignore_ascii_case("content-length") {
            let n = parse_length(&value)?;
            if content_length.is_some_and(|c| c != n) {
                return Err(ParseError::ContentLength);
            }
            content_length = Some(n);
        }
        headers.push((name, value));
    }
    let body_len = content_length.unwrap_or(0);
    if body_len > limits.max_body_bytes as u64 {
        return Err(ParseError::BodyTooLarge);
    }
    let start = skip + head_len;
    let end = start + body_len as usize;
    if buf.len() < end {
        return Ok(Parsed::Partial);
    }
    Ok(Parsed::Complete {
        request: Request {
            method,
            target,
            minor_version,
            headers,
            body: buf[start..end].to_vec(),
        },
        consumed: end,
    })
}

fn request_line(line: &[u8], limits: &Limits) -> Result<(String, String, u8), ParseError> {
    let mut parts = line.split(|&b| b == b' ');
    let (Some(method), Some(target), Some(version), None) =
        (parts.next(), parts.next(), parts.next(), parts.next())
    else {
        return Err(ParseError::RequestLine);
    };
    if method.is_empty() || method.len() > 16 || !method.iter().all(|&b| is_tchar(b)) {
        return Err(ParseError::RequestLine);
    }
    if target.is_empty() || !target.iter().all(|&b| (0x21..0x7f).contains(&b)) {
        return Err(ParseError::RequestLine);
    }
    if target.len() > limits.max_target_bytes {
        return Err(ParseError::TargetTooLong);
    }
    let minor = match version {
        b"HTTP/1.1" => 1,
        b"HTTP/1.0" => 0,
        v if v.starts_with(b"HTTP/") => return Err(ParseError::Version),
        _ => return Err(ParseError::RequestLine),
    };
    // Both are ASCII by the checks above.
    Ok((
        String::from_utf8_lossy(method).into_owned(),
        String::from_utf8_lossy(target).into_owned(),
        minor,
    ))
}

fn parse_length(v: &str) -> Result<u64, ParseError> {
    if v.is_empty() || v.len() > 18 || !v.bytes().all(|b| b.is_ascii_digit()) {
        return Err(ParseError::ContentLength);
    }
    v.parse().map_err(|_| ParseError::ContentLength)
}

/// Percent-decodes a path segment (invalid escapes are kept as they are).
fn decode_segment(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let hex = |c: u8| (c as char).to_digit(16);
        match (
            b[i],
            b.get(i + 1).and_then(|&c| hex(c)),
            b.get(i + 2).and_then(|&c| hex(c)),
        ) {
            (b'%', Some(h), Some(l)) => {
                out.push((h * 16 + l) as u8);
                i += 3;
            }
            (c, _, _) => {
                out.push(c);
                i += 1;
            }
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// A response to send.
#[derive(Debug, PartialEq)]
pub struct Response {
    pub status: u16,
    pub content_type: &'static str,
    pub body: Vec<u8>,
}

impl Response {
    fn json<T: Serialize>(status: u16, v: &T) -> Response {
        match serde_json::to_vec(v) {
            Ok(body) => Response {
                status,
                content_type: "application/json",
                body,
            },
            Err(e) => Response::error(500, &format!("cannot encode the response: {e}")),
        }
    }

    /// toxiproxy's error shape: `{"error": "...", "status": N}`.
    fn error(status: u16, msg: &str) -> Response {
        let body = serde_json::json!({ "error": msg, "status": status })
            .to_string()
            .into_bytes();
        Response {
            status,
            content_type: "application/json",
            body,
        }
    }

    fn no_content() -> Response {
        Response {
            status: 204,
            content_type: "application/json",
            body: Vec::new(),
        }
    }

    /// The bytes on the wire.
    pub fn to_bytes(&self, close: bool) -> Vec<u8> {
        let mut out = format!("HTTP/1.1 {} {}\r\n", self.status, reason(self.status));
        if self.status != 204 {
            out.push_str(&format!(
                "Content-Type: {}\r\nContent-Length: {}\r\n",
                self.content_type,
                self.body.len()
            ));
        }
        if close {
            out.push_str("Connection: close\r\n");
        }
        out.push_str("\r\n");
        let mut bytes = out.into_bytes();
        bytes.extend_from_slice(&self.body);
        bytes
    }
}

fn reason(status: u16) -> &'static str {
    match status {
        200 => "OK",
        201 => "Created",
        202 => "Accepted",
        204 => "No Content",
        400 => "Bad Request",
        401 => "Unauthorized",
        403 => "Forbidden",
        404 => "Not Found",
        405 => "Method Not Allowed",
        409 => "Conflict",
        413 => "Content Too Large",
        414 => "URI Too Long",
        431 => "Request Header Fields Too Large",
        501 => "Not Implemented",
        503 => "Service Unavailable",
        505 => "HTTP Version Not Supported",
        _ => "Internal Server Error",
    }
}

fn netem_error(e: &NetemError) -> Response {
    let status = match e {
        NetemError::UnknownLink(_) | NetemError::UnknownToxic { .. } => 404,
        NetemError::ToxicExists { .. } => 409,
        NetemError::Bind { .. } => 500,
        _ => 400,
    };
    let msg = match e {
        NetemError::UnknownLink(_) => format!("proxy not found: {e}"),
        NetemError::UnknownToxic { .. } => format!("toxic not found: {e}"),
        NetemError::ToxicExists { .. } => format!("toxic already exists: {e}"),
        _ => e.to_string(),
    };
    Response::error(status, &msg)
}

/// toxiproxy's JSON of a proxy, plus our `up` and `down_reason`.
#[derive(Serialize)]
struct ProxyJson {
    name: String,
    listen: String,
    upstream: String,
    enabled: bool,
    up: bool,
    down_reason: Option<&'static str>,
    toxics: Vec<Toxic>,
}

fn proxy_json(l: &Link) -> ProxyJson {
    let s = l.snapshot();
    ProxyJson {
        name: s.name,
        listen: s.listen.to_string(),
        upstream: s.target.to_string(),
        enabled: s.enabled,
        up: s.up,
        down_reason: s.down_reason.map(|r| r.as_str()),
        toxics: s.toxics,
    }
}

/// Everything the control API decodes from a connection's bytes, without acting on any of it:
/// the requests (one after another, as on a kept-alive connection), each one's JSON body as a
/// proxy update and as a toxic, the toxic validated and applied as a patch to a toxic. The
/// fuzz target `netem_http` (`fuzz/`); never panics.
pub fn decode_only(mut buf: &[u8]) {
    let limits = Limits::default();
    for _ in 0..MAX_REQUESTS {
        let Ok(Parsed::Complete {
            request: req,
            consumed: used,
        }) = parse(buf, &limits)
        else {
            return;
        };
        let _ = req.path();
        let _ = req.keep_alive();
        let _ = body_json::<ProxyUpdate>(&req);
        if let Ok(wire) = body_json::<ToxicWire>(&req) {
            if let Ok(t) = Toxic::try_from(wire.clone()) {
                let _ = t.patched(wire);
            }
        }
        if used == 0 || used > buf.len() {
            return;
        }
        buf = &buf[used..];
    }
}

/// Whether an `Authorization` header carries `Bearer <token>`, compared in time independent of
/// where the first difference is.
pub fn bearer_matches(header: Option<&str>, token: &str) -> bool {
    let Some(given) = header.and_then(|h| h.trim().strip_prefix("Bearer ")) else {
        return false;
    };
    let (a, b) = (given.trim().as_bytes(), token.as_bytes());
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

fn body_json<T: serde::de::DeserializeOwned>(req: &Request) -> Result<T, Response> {
    let body: &[u8] = if req.body.iter().all(u8::is_ascii_whitespace) {
        b"{}"
    } else {
        &req.body
    };
    serde_json::from_slice(body)
        .map_err(|e| Response::error(400, &format!("bad request body: {e}")))
}

#[derive(serde::Deserialize)]
struct ProxyUpdate {
    enabled: Option<bool>,
}

/// Answers one request.
pub(crate) fn route(sh: &Shared, req: &Request) -> Response {
    if req
        .header("user-agent")
        .is_some_and(|ua| ua.starts_with("Mozilla/"))
    {
        return Response::error(403, "User agent not allowed");
    }
    if let Some(token) = &sh.api_token {
        if !bearer_matches(req.header("authorization"), token) {
            return Response::error(
                401,
                "this API needs \"Authorization: Bearer <token>\" (the run's netem.token)",
            );
        }
    }
    let segs: Vec<String> = req
        .path()
        .trim_matches('/')
        .split('/')
        .filter(|s| !s.is_empty())
        .map(decode_segment)
        .collect();
    let segs: Vec<&str> = segs.iter().map(String::as_str).collect();
    let m = req.method.as_str();
    let fixed = "proxies are fixed by the scenario (one per robot pair)";
    match (m, segs.as_slice()) {
        ("GET", ["proxies"]) => {
            let map: serde_json::Map<String, serde_json::Value> = sh
                .links
                .iter()
                .map(|l| {
                    let v = serde_json::to_value(proxy_json(l)).unwrap_or(serde_json::Value::Null);
                    (l.name.clone(), v)
                })
                .collect();
            Response::json(200, &map)
        }
        ("POST", ["proxies"]) | ("POST", ["populate"]) => Response::error(405, fixed),
        ("GET", ["proxies", name]) => with_link(sh, name, |l| Response::json(200, &proxy_json(l))),
        ("POST" | "PATCH", ["proxies", name]) => with_link(sh, name, |l| {
            let upd: ProxyUpdate = match body_json(req) {
                Ok(u) => u,
                Err(r) => return r,
            };
            let pair = (l.params.a, l.params.b);
            let fault = match upd.enabled {
                Some(false) => Some(Fault::Cut { pair }),
                Some(true) => Some(Fault::Restore { pair }),
                None => None,
            };
            match fault.map(|f| sh.apply(&f)) {
                Some(Err(e)) => netem_error(&e),
                _ => Response::json(200, &proxy_json(l)),
            }
        }),
        ("DELETE", ["proxies", _]) => Response::error(405, fixed),
        ("GET", ["proxies", name, "toxics"]) => with_link(sh, name, |l| {
            let toxics: Vec<Toxic> = l.toxics().iter().map(|t| t.toxic.clone()).collect();
            Response::json(200, &toxics)
        }),
        ("POST", ["proxies", name, "toxics"]) => with_link(sh, name, |l| {
            let wire: ToxicWire = match body_json(req) {
                Ok(w) => w,
                Err(r) => return r,
            };
            let toxic = match Toxic::try_from(wire) {
                Ok(t) => t,
                Err(e) => return Response::error(400, &format!("bad request body: {e}")),
            };
            let pair = Some((l.params.a, l.params.b));
            match sh.apply(&Fault::AddToxic {
                pair,
                toxic: toxic.clone(),
            }) {
                Ok(()) => Response::json(200, &toxic),
                Err(e) => netem_error(&e),
            }
        }),
        ("GET", ["proxies", name, "toxics", toxic]) => {
            with_toxic(sh, name, toxic, |_, t| Response::json(200, t))
        }
        ("POST" | "PATCH", ["proxies", name, "toxics", toxic]) => {
            with_toxic(sh, name, toxic, |l, t| {
                let patch: ToxicWire = match body_json(req) {
                    Ok(w) => w,
                    Err(r) => return r,
                };
                let toxic = match t.patched(patch) {
                    Ok(t) => t,
                    Err(e) => return Response::error(400, &format!("bad request body: {e}")),
                };
                let pair = Some((l.params.a, l.params.b));
                match sh.apply(&Fault::SetToxic {
                    pair,
                    toxic: toxic.clone(),
                }) {
                    Ok(()) => Response::json(200, &toxic),
                    Err(e) => netem_error(&e),
                }
            })
        }
        ("DELETE", ["proxies", name, "toxics", toxic]) => with_link(sh, name, |l| {
            let pair = Some((l.params.a, l.params.b));
            match sh.apply(&Fault::RemoveToxic {
                pair,
                name: (*toxic).to_string(),
            }) {
                Ok(()) => Response::no_content(),
                Err(e) => netem_error(&e),
            }
        }),
        ("POST", ["reset"]) => match sh.apply(&Fault::ResetAll) {
            Ok(()) => Response::no_content(),
            Err(e) => netem_error(&e),
        },
        ("GET", ["version"]) => Response::json(
            200,
            &serde_json::json!({ "version": concat!("netem ", env!("CARGO_PKG_VERSION"), " (toxiproxy API 2)") }),
        ),
        ("GET", ["metrics"]) => Response {
            status: 200,
            content_type: crate::metrics::CONTENT_TYPE,
            body: crate::metrics::render(&sh.snapshots(), sh.step(), sh.now()).into_bytes(),
        },
        ("GET", ["links"]) => Response::json(200, &sh.rows()),
        ("POST", ["processes", name]) => process_fault(sh, name, req),
        (
            _,
            ["proxies" | "reset" | "version" | "metrics" | "links" | "populate" | "processes", ..],
        ) => Response::error(405, &format!("method {m} not allowed here")),
        _ => Response::error(404, "not found"),
    }
}

/// `POST /processes/<name>` with `{"kind": "kill" | "restart" | "freeze" | "thaw"}` (and
/// `"restart_after": k` for a kill): a process fault, checked against the run's scenario and
/// handed on to the launcher, which carries it out at its next step (`202`: accepted, not yet
/// done — `summary.json`'s `process_events` says when it was, with cause `api`).
fn process_fault(sh: &Shared, name: &str, req: &Request) -> Response {
    let desk = crate::netem::lock(&sh.process_desk);
    let Some(desk) = desk.as_ref() else {
        return Response::error(
            501,
            "this netem is not following a run: nobody to carry out process faults",
        );
    };
    let process: Process = match name.parse() {
        Ok(p) if desk.scenario.has_process(p) => p,
        _ => return Response::error(404, &format!("no process {name:?} in this run")),
    };
    let mut body: serde_json::Map<String, serde_json::Value> = match body_json(req) {
        Ok(b) => b,
        Err(r) => return r,
    };
    if body.contains_key("process") {
        return Response::error(400, "bad request body: the process is named by the path");
    }
    body.insert(
        "process".into(),
        serde_json::Value::String(process.to_string()),
    );
    let action: ProcessAction = match serde_json::from_value(serde_json::Value::Object(body)) {
        Ok(a) => a,
        Err(e) => return Response::error(400, &format!("bad request body: {e}")),
    };
    if let Err((value, why)) = desk.scenario.check_process_action(&action) {
        return Response::error(400, &format!("{value}: {why}"));
    }
    match desk.orders.try_send(ProcessOrder::from(&action)) {
        Ok(()) => Response::json(202, &action),
        Err(mpsc::error::TrySendError::Full(_)) => {
            Response::error(503, "too many process faults waiting for the next step")
        }
        Err(mpsc::error::TrySendError::Closed(_)) => Response::error(503, "the run is ending"),
    }
}

fn with_link(sh: &Shared, name: &str, f: impl FnOnce(&Link) -> Response) -> Response {
    match sh.link_by_name(name) {
        Ok(l) => f(l),
        Err(e) => netem_error(&e),
    }
}

fn with_toxic(
    sh: &Shared,
    name: &str,
    toxic: &str,
    f: impl FnOnce(&Link, &Toxic) -> Response,
) -> Response {
    with_link(sh, name, |l| {
        let list = l.toxics();
        match list.iter().find(|t| t.toxic.name == toxic) {
            Some(t) => f(l, &t.toxic),
            None => netem_error(&NetemError::UnknownToxic {
                link: l.name.clone(),
                name: toxic.to_string(),
            }),
        }
    })
}

/// Most simultaneous API connections; more are closed at once.
const MAX_CONNECTIONS: usize = 32;
/// Most requests on one kept-alive connection.
const MAX_REQUESTS: usize = 1000;
/// A connection idle this long (wall) is closed.
const IDLE: Duration = Duration::from_secs(30);

/// Serves the API on `listener` until `shutdown` becomes true.
pub(crate) fn serve(
    shared: Arc<Shared>,
    listener: TcpListener,
    mut shutdown: watch::Receiver<bool>,
) -> JoinHandle<()> {
    tokio::spawn(async move {
        let slots = Arc::new(Semaphore::new(MAX_CONNECTIONS));
        loop {
            tokio::select! {
                () = stopped(&mut shutdown) => break,
                accepted = listener.accept() => match accepted {
                    Ok((stream, _)) => match Arc::clone(&slots).try_acquire_owned() {
                        Ok(slot) => {
                            let (sh, stop) = (Arc::clone(&shared), shutdown.clone());
                            tokio::spawn(async move {
                                connection(&sh, stream, stop).await;
                                drop(slot);
                            });
                        }
                        Err(_) => tracing::warn!("too many HTTP connections; closing one"),
                    },
                    Err(e) => {
                        tracing::warn!("HTTP accept failed: {e}");
                        tokio::time::sleep(Duration::from_millis(20)).await;
                    }
                },
            }
        }
    })
}

async fn connection(sh: &Shared, mut s: TcpStream, mut shutdown: watch::Receiver<bool>) {
    let limits = Limits::default();
    let max_buffer = limits.max_head_bytes + limits.max_body_bytes + 8;
    let mut buf = Vec::with_capacity(4096);
    let mut chunk = [0u8; 4096];
    for _ in 0..MAX_REQUESTS {
        let (request, consumed) = loop {
            match parse(&buf, &limits) {
                Ok(Parsed::Complete { request, consumed }) => break (request, consumed),
                Ok(Parsed::Partial) if buf.len() < max_buffer => {
                    let n = tokio::select! {
                        r = tokio::time::timeout(IDLE, s.read(&mut chunk)) => match r {
                            Ok(Ok(n)) if n > 0 => n,
                            _ => return,
                        },
                        () = stopped(&mut shutdown) => return,
                    };
                    buf.extend_from_slice(&chunk[..n]);
                }
                Ok(Parsed::Partial) => {
                    let _ = s
                        .write_all(&Response::error(413, "request too large").to_bytes(true))
                        .await;
                    return;
                }
                Err(e) => {
                    let _ = s
                        .write_all(&Response::error(e.status(), &e.to_string()).to_bytes(true))
                        .await;
                    return;
                }
            }
        };
        buf.drain(..consumed);
        let response = route(sh, &request);
        tracing::debug!(method = %request.method, target = %request.target, status = response.status, "http");
        let close = !request.keep_alive();
        if s.write_all(&response.to_bytes(close)).await.is_err() || close {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_exact_bearer_token_passes() {
        let t = "0123456789abcdef0123456789abcdef";
        assert!(bearer_matches(Some(&format!("Bearer {t}")), t));
        assert!(bearer_matches(Some(&format!("  Bearer {t} ")), t));
        for bad in [
            None,
            Some(""),
            Some("Bearer"),
            Some("Bearer "),
            Some("bearer 0123456789abcdef0123456789abcdef"),
            Some("Basic 0123456789abcdef0123456789abcdef"),
            Some("Bearer 0123456789abcdef0123456789abcdee"),
            Some("Bearer 0123456789abcdef0123456789abcdef0"),
            Some("Bearer 0123456789abcdef"),
        ] {
            assert!(!bearer_matches(bad, t), "{bad:?}");
        }
    }
    use proptest::prelude::*;

    fn complete(bytes: &[u8]) -> (Request, usize) {
        match parse(bytes, &Limits::default()) {
            Ok(Parsed::Complete { request, consumed }) => (request, consumed),
            other => panic!("{other:?} for {:?}", String::from_utf8_lossy(bytes)),
        }
    }

    #[test]
    fn parses_a_toxiproxy_client_request() {
        let raw = b"POST /proxies/r0-r1/toxics HTTP/1.1\r\nHost: localhost:8474\r\nContent-Type: application/json\r\nContent-Length: 17\r\n\r\n{\"type\":\"latency\"}GET";
        let (r, consumed) = complete(raw);
        assert_eq!(r.method, "POST");
        assert_eq!(r.path(), "/proxies/r0-r1/toxics");
        assert_eq!(r.header("content-type"), Some("application/json"));
        assert_eq!(r.body, b"{\"type\":\"latency\"}"[..17].to_vec());
        assert_eq!(&raw[consumed..], b"}GET");
        assert!(r.keep_alive());
    }

    #[test]
    fn accepts_bare_lf_and_leading_empty_lines() {
        let (r, _) = complete(b"\r\nGET /version?x=1 HTTP/1.0\nConnection: keep-alive\n\n");
        assert_eq!(r.path(), "/version");
        assert_eq!(r.minor_version, 0);
        assert!(r.keep_alive());
    }

    #[test]
    fn refuses_garbage_with_the_right_status() {
        let l = Limits::default();
        let err = |b: &[u8]| parse(b, &l).err().map(ParseError::status);
        assert_eq!(err(b"GET\r\n\r\n"), Some(400));
        assert_eq!(err(b"GET / HTTP/2.0\r\n\r\n"), Some(505));
        assert_eq!(err(b"GET / HTTP/1.1\r\n bad fold\r\n\r\n"), Some(400));
        assert_eq!(
            err(b"GET / HTTP/1.1\r\nContent-Length: -1\r\n\r\n"),
            Some(400)
        );
        assert_eq!(
            err(b"GET / HTTP/1.1\r\nContent-Length: 1\r\nContent-Length: 2\r\n\r\n"),
            Some(400)
        );
        assert_eq!(
            err(b"GET / HTTP/1.1\r\nContent-Length: 99999999\r\n\r\n"),
            Some(413)
        );
        assert_eq!(
            err(b"POST / HTTP/1.1\r\nTransfer-Encoding: chunked\r\n\r\n"),
            Some(501)
        );
        let long = format!("GET /{} HTTP/1.1\r\n\r\n", "a".repeat(3000));
        assert_eq!(err(long.as_bytes()), Some(414));
        let many: String = (0..100).map(|i| format!("X-{i}: y\r\n")).collect();
        assert_eq!(
            err(format!("GET / HTTP/1.1\r\n{many}\r\n").as_bytes()),
            Some(431)
        );
        assert_eq!(err(&vec![b'a'; 20_000]), Some(431));
        assert_eq!(
            parse(b"GET / HTTP/1.1\r\nHost: x\r\n", &l),
            Ok(Parsed::Partial)
        );
    }

    #[test]
    fn percent_decoding_is_total() {
        assert_eq!(decode_segment("a%2Fb"), "a/b");
        assert_eq!(decode_segment("%zz%"), "%zz%");
        assert_eq!(decode_segment("%ff"), "\u{fffd}");
    }

    fn token() -> impl Strategy<Value = String> {
        "[A-Za-z0-9!#$%&'*+.^_`|~-]{1,12}"
    }

    prop_compose! {
        fn request()(
            method in prop::sample::select(vec!["GET", "POST", "PATCH", "DELETE"]),
            path in "(/[a-z0-9_-]{1,8}){1,4}",
            headers in prop::collection::vec((token(), "[ -~]{0,20}"), 0..8),
            body in prop::collection::vec(any::<u8>(), 0..200),
        ) -> (String, String, Vec<(String, String)>, Vec<u8>) {
            let headers = headers
                .into_iter()
                .filter(|(n, _)| !n.eq_ignore_ascii_case("content-length") && !n.eq_ignore_ascii_case("transfer-encoding"))
                .map(|(n, v)| (n, v.trim().to_string()))
                .collect();
            (method.to_string(), path, headers, body)
        }
    }

    fn render(
        (method, path, headers, body): &(String, String, Vec<(String, String)>, Vec<u8>),
    ) -> Vec<u8> {
        let mut s = format!("{method} {path} HTTP/1.1\r\n");
        for (n, v) in headers {
            s.push_str(&format!("{n}: {v}\r\n"));
        }
        s.push_str(&format!("Content-Length: {}\r\n\r\n", body.len()));
        let mut b = s.into_bytes();
        b.extend_from_slice(body);
        b
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]

        #[test]
        fn never_panics_on_arbitrary_bytes(bytes in prop::collection::vec(any::<u8>(), 0..2048)) {
            if let Ok(Parsed::Complete { consumed, .. }) = parse(&bytes, &Limits::default()) {
                prop_assert!(consumed <= bytes.len());
            }
        }

        #[test]
        fn never_panics_on_mangled_requests(r in request(), cut in 0usize..400, junk in any::<u8>()) {
            let mut bytes = render(&r);
            let i = cut % (bytes.len() + 1);
            bytes.insert(i, junk);
            let _ = parse(&bytes, &Limits::default());
        }

        #[test]
        fn valid_requests_round_trip_and_every_prefix_is_partial(r in request()) {
            let bytes = render(&r);
            let (req, consumed) = complete(&bytes);
            prop_assert_eq!(consumed, bytes.len());
            prop_assert_eq!(&req.method, &r.0);
            prop_assert_eq!(&req.target, &r.1);
            prop_assert_eq!(&req.body, &r.3);
            prop_assert_eq!(req.headers.len(), r.2.len() + 1);
            for (got, want) in req.headers.iter().zip(&r.2) {
                prop_assert_eq!(got, want);
            }
            for k in 0..bytes.len() {
                prop_assert_eq!(parse(&bytes[..k], &Limits::default()), Ok(Parsed::Partial));
            }
            // Pipelined: the second request starts where the first ended.
            let mut two = bytes.clone();
            two.extend_from_slice(&bytes);
            let (_, c1) = complete(&two);
            prop_assert_eq!(c1, bytes.len());
        }
    }

    mod api {
        use crate::netem::{start, Netem, NetemConfig, PairSpec, PROCESS_ORDERS_QUEUED};
        use proto::scenario::{Medium, Radio, RadioModel};
        use std::net::SocketAddr;
        use std::time::Duration;
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        use tokio::net::TcpStream;

        async fn netem() -> Netem {
            let target: SocketAddr = "127.0.0.1:9".parse().unwrap();
            let pair = |a, b| PairSpec {
                a,
                b,
                listen: "127.0.0.1:0".parse().unwrap(),
                target,
            };
            let radio = Radio {
                model: RadioModel::Always,
                range_m: 1.0,
                bandwidth_bytes_per_s: 1000,
                medium: Medium::PerLink,
                ..Radio::default()
            };
            let mut cfg = NetemConfig::new(vec![pair(0, 1), pair(0, 2), pair(1, 2)], radio);
            cfg.http = Some("127.0.0.1:0".parse().unwrap());
            let n = start(cfg).await.unwrap();
            n.on_step(0, &[]);
            n
        }

        /// One request with `Connection: close`; returns (status, body).
        async fn call(
            n: &Netem,
            method: &str,
            path: &str,
            body: &str,
            extra: &str,
        ) -> (u16, String) {
            let mut s = TcpStream::connect(n.http_addr().unwrap()).await.unwrap();
            let req = format!(
                "{method} {path} HTTP/1.1\r\nHost: x\r\n{extra}Connection: close\r\nContent-Length: {}\r\n\r\n{body}",
                body.len()
            );
            s.write_all(req.as_bytes()).await.unwrap();
            let mut out = Vec::new();
            tokio::time::timeout(Duration::from_secs(5), s.read_to_end(&mut out))
                .await
                .unwrap()
                .unwrap();
            let text = String::from_utf8(out).unwrap();
            let status = text[9..12].parse().unwrap();
            let body = text
                .split_once("\r\n\r\n")
                .map(|(_, b)| b.to_string())
                .unwrap_or_default();
            (status, body)
        }

        fn json(s: &str) -> serde_json::Value {
            serde_json::from_str(s).unwrap_or_else(|e| panic!("{e}: {s}"))
        }

        #[tokio::test]
        async fn process_faults_are_checked_and_handed_on_for_the_launcher() {
            use proto::msg::{Order, ProcessOrder};
            use proto::scenario::Process;
            let n = netem().await;
            let kill = r#"{"kind":"kill","restart_after":3}"#;
            // Nobody follows a run yet: nobody to carry it out.
            assert_eq!(
                call(&n, "POST", "/processes/robot-1", kill, "").await.0,
                501
            );
            let mut s = proto::scenario::Scenario::default();
            s.robots.count = 3;
            let mut orders = n.process_orders(&s);
            let (st, body) = call(&n, "POST", "/processes/robot-1", kill, "").await;
            assert_eq!(st, 202, "{body}");
            assert_eq!(
                json(&body),
                serde_json::json!({"kind": "kill", "process": "robot-1", "restart_after": 3})
            );
            let (st, _) = call(&n, "POST", "/processes/netem", r#"{"kind":"restart"}"#, "").await;
            assert_eq!(st, 202);
            assert_eq!(
                orders.try_recv().ok(),
                Some(ProcessOrder {
                    process: Process::Robot(1),
                    order: Order::Kill {
                        restart_after: Some(3)
                    }
                })
            );
            assert_eq!(
                orders.try_recv().ok().map(|o| o.order),
                Some(Order::Restart)
            );
            // Refused, and nothing handed on: a process not in the run, a name that is none,
            // an action that does not suit the process, a bad body, a wrong method.
            for (path, body, status) in [
                ("/processes/robot-3", kill, 404),
                ("/processes/base-station", kill, 404),
                ("/processes/robot", kill, 404),
                ("/processes/world-server", r#"{"kind":"restart"}"#, 400),
                ("/processes/netem", r#"{"kind":"freeze"}"#, 400),
                ("/processes/robot-0", r#"{"kind":"explode"}"#, 400),
                (
                    "/processes/robot-0",
                    r#"{"kind":"kill","process":"robot-2"}"#,
                    400,
                ),
                ("/processes/robot-0", "{not json", 400),
                ("/processes/robot-0", "", 400),
            ] {
                let (st, text) = call(&n, "POST", path, body, "").await;
                assert_eq!(st, status, "{path} {body}: {text}");
                assert!(json(&text)["error"].is_string(), "{text}");
            }
            assert_eq!(call(&n, "GET", "/processes/robot-0", "", "").await.0, 405);
            assert!(orders.try_recv().is_err(), "a refused fault was handed on");
            // The world-server can be killed (the run ends), not restarted.
            let (st, _) = call(
                &n,
                "POST",
                "/processes/world-server",
                r#"{"kind":"kill"}"#,
                "",
            )
            .await;
            assert_eq!(st, 202);
            // A full queue refuses more; a closed one too.
            for _ in 1..PROCESS_ORDERS_QUEUED {
                call(&n, "POST", "/processes/robot-0", r#"{"kind":"freeze"}"#, "").await;
            }
            let (st, _) = call(&n, "POST", "/processes/robot-0", r#"{"kind":"thaw"}"#, "").await;
            assert_eq!(st, 503);
            drop(orders);
            let (st, _) = call(&n, "POST", "/processes/robot-0", r#"{"kind":"thaw"}"#, "").await;
            assert_eq!(st, 503);
        }

        #[tokio::test]
        async fn proxies_can_be_listed_cut_and_restored() {
            let n = netem().await;
            let (st, body) = call(&n, "GET", "/proxies", "", "").await;
            assert_eq!(st, 200);
            let v = json(&body);
            assert_eq!(v["r0-r1"]["enabled"], true);
            assert_eq!(v["r1-r2"]["upstream"], "127.0.0.1:9");
            assert_eq!(v.as_object().unwrap().len(), 3);
            let (st, body) = call(&n, "POST", "/proxies/r1-r0", r#"{"enabled": false}"#, "").await;
            assert_eq!(st, 200, "{body}");
            assert_eq!(json(&body)["enabled"], false);
            assert!(!n.snapshot()[0].up);
            let (st, _) = call(&n, "PATCH", "/proxies/r0-r1", r#"{"enabled": true}"#, "").await;
            assert_eq!(st, 200);
            assert!(n.snapshot()[0].up);
            assert_eq!(call(&n, "GET", "/proxies/r0-r9", "", "").await.0, 404);
            assert_eq!(
                call(&n, "POST", "/proxies", r#"{"name":"x"}"#, "").await.0,
                405
            );
            assert_eq!(call(&n, "DELETE", "/proxies/r0-r1", "", "").await.0, 405);
            assert_eq!(
                call(&n, "POST", "/proxies/r0-r1", "{not json", "").await.0,
                400
            );
            assert_eq!(call(&n, "GET", "/nothing", "", "").await.0, 404);
            assert_eq!(
                call(&n, "GET", "/proxies", "", "User-Agent: Mozilla/5.0\r\n")
                    .await
                    .0,
                403
            );
            n.shutdown().await;
        }

        #[tokio::test]
        async fn toxics_have_the_toxiproxy_lifecycle() {
            let n = netem().await;
            let latency = r#"{"name":"lag","type":"latency","stream":"upstream","attributes":{"latency":200,"jitter":20}}"#;
            let (st, body) = call(&n, "POST", "/proxies/r0-r1/toxics", latency, "").await;
            assert_eq!(st, 200, "{body}");
            assert_eq!(json(&body)["attributes"]["latency"], 200);
            assert_eq!(
                call(&n, "POST", "/proxies/r0-r1/toxics", latency, "")
                    .await
                    .0,
                409
            );
            let (st, body) = call(&n, "GET", "/proxies/r0-r1/toxics", "", "").await;
            assert_eq!(st, 200);
            assert_eq!(json(&body)[0]["name"], "lag");
            let (st, body) = call(
                &n,
                "PATCH",
                "/proxies/r0-r1/toxics/lag",
                r#"{"attributes":{"latency":50}}"#,
                "",
            )
            .await;
            assert_eq!(st, 200, "{body}");
            assert_eq!(json(&body)["attributes"]["latency"], 50);
            assert_eq!(json(&body)["attributes"]["jitter"], 20);
            let (_, body) = call(&n, "GET", "/proxies/r0-r1/toxics/lag", "", "").await;
            assert_eq!(json(&body)["stream"], "upstream");
            let bw = r#"{"type":"bandwidth","attributes":{"rate":2}}"#;
            let (st, body) = call(&n, "POST", "/proxies/r0-r1/toxics", bw, "").await;
            assert_eq!(st, 200, "{body}");
            assert_eq!(json(&body)["name"], "bandwidth_downstream");
            assert_eq!(json(&body)["attributes"]["rate_bytes_per_s"], 2000);
            assert_eq!(
                call(
                    &n,
                    "POST",
                    "/proxies/r0-r1/toxics",
                    r#"{"type":"slicer"}"#,
                    ""
                )
                .await
                .0,
                400
            );
            assert_eq!(
                call(&n, "DELETE", "/proxies/r0-r1/toxics/lag", "", "")
                    .await
                    .0,
                204
            );
            assert_eq!(
                call(&n, "DELETE", "/proxies/r0-r1/toxics/lag", "", "")
                    .await
                    .0,
                404
            );
            assert_eq!(
                call(&n, "GET", "/proxies/r0-r1/toxics/lag", "", "").await.0,
                404
            );
            call(&n, "POST", "/proxies/r1-r2", r#"{"enabled":false}"#, "").await;
            assert_eq!(call(&n, "POST", "/reset", "", "").await.0, 204);
            let (_, body) = call(&n, "GET", "/proxies", "", "").await;
            let v = json(&body);
            assert_eq!(v["r1-r2"]["enabled"], true);
            assert_eq!(v["r0-r1"]["toxics"].as_array().unwrap().len(), 0);
            n.shutdown().await;
        }

        #[tokio::test]
        async fn metrics_links_version_keep_alive_and_garbage() {
            let n = netem().await;
            let (st, body) = call(&n, "GET", "/metrics", "", "").await;
            assert_eq!(st, 200);
            assert!(body.contains("netem_link_bytes_total{link=\"r0-r1\",direction=\"a_to_b\"} 0"));
            assert!(body.contains("netem_link_up{link=\"r1-r2\"} 1"));
            let (st, body) = call(&n, "GET", "/links", "", "").await;
            assert_eq!(st, 200);
            let rows = json(&body);
            assert_eq!(rows.as_array().unwrap().len(), 3);
            assert_eq!(rows[0]["up"], true);
            assert_eq!(rows[0]["bytes_a_to_b_total"], 0);
            assert_eq!(call(&n, "GET", "/version", "", "").await.0, 200);

            // Two requests on one connection, then garbage: 400 and the connection closes.
            let mut s = TcpStream::connect(n.http_addr().unwrap()).await.unwrap();
            s.write_all(b"GET /version HTTP/1.1\r\n\r\nGET /version HTTP/1.1\r\n\r\n\x00\x01garbage\r\n\r\n")
                .await
                .unwrap();
            let mut out = Vec::new();
            tokio::time::timeout(Duration::from_secs(5), s.read_to_end(&mut out))
                .await
                .unwrap()
                .unwrap();
            let text = String::from_utf8_lossy(&out);
            assert_eq!(text.matches("HTTP/1.1 200 OK").count(), 2, "{text}");
            assert!(text.contains("HTTP/1.1 400 Bad Request"), "{text}");
            n.shutdown().await;
        }
    }
}
