//! Runtime control over HTTP, in toxiproxy's model so that its clients and `curl` work
//! (docs/design.md §5 "Faults … injected at runtime through a control endpoint"; "names and
//! semantics follow toxiproxy").
//!
//! Every robot pair is a proxy named `r{a}-r{b}`; faults are toxics. Routes:
//! `GET /proxies`, `GET /proxies/{name}`, `POST|PATCH /proxies/{name}` (`{"enabled": bool}`:
//! false = cut, true = restore), `GET|POST /proxies/{name}/toxics`,
//! `GET|POST|PATCH|DELETE /proxies/{name}/toxics/{toxic}`, `POST /reset`, `GET /version`, and
//! ours: `GET /metrics` (Prometheus text) and `GET /links` (the telemetry rows as JSON, without
//! resetting the per-step counters), and `POST /processes/{name}` (a process fault — kill,
//! restart, freeze, thaw — handed on to the launcher; see `process_fault`). Proxies
//! are fixed by the scenario: creating or deleting one (`POST /proxies`, `POST /populate`,
//! `DELETE /proxies/{name}`) is `405`, and an update that would move one (another `listen` or
//! `upstream`) or rename it is `409` — the body is well-formed and toxiproxy would honour it, but
//! it conflicts with the proxy as the scenario fixed it; nothing of such an update is applied.
//! Like toxiproxy, requests from browsers (`User-Agent: Mozilla/…`) are refused, so that a web
//! page cannot drive the API (the run's viewer forwards a click from its own server instead).
//!
//! When the run set a token, every request carries it in one of three ways (`gate`):
//! `Authorization: Bearer <token>`; `Authorization: Basic` whose password (any user name) or whose
//! user name (empty password) is the token — what Go's net/http, Python's requests and curl send
//! for a base URL `http://:<token>@host:port`; or a base URL whose path starts `/token/<token>`
//! (`http://host:port/token/<token>`: toxiproxy's clients append `/proxies…` to their base URL,
//! and fetch-based ones such as toxiproxy-node-client refuse credentials in a URL). Tokens are
//! compared in time independent of where they differ.
//!
//! HTTP itself is axum's (on hyper): the request head is bounded by hyper, a body by
//! [`MAX_BODY_BYTES`](crate::http::MAX_BODY_BYTES) (`413` past it). What is ours is what a request
//! means: the routes below, JSON bodies decoded totally into
//! [`ProxyUpdate`](crate::http::ProxyUpdate), [`ToxicWire`](crate::faults::ToxicWire) and a
//! [`ProcessAction`](proto::process::ProcessAction) (fuzzed:
//! [`decode_only`](crate::http::decode_only)), every error in toxiproxy's shape `{"error": "...",
//! "status": N}`.

use std::sync::Arc;
use std::time::Duration;

use axum::body::Bytes;
use axum::extract::{DefaultBodyLimit, Path, Request, State};
use axum::http::header::{AUTHORIZATION, CONTENT_TYPE, USER_AGENT};
use axum::http::{HeaderName, Method, StatusCode};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::Router;
use proto::msg::ProcessOrder;
use proto::scenario::{Process, ProcessAction};
use serde::Serialize;
use tokio::net::TcpListener;
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use crate::control::{lock, NetemError, Shared};
use crate::faults::{Fault, Toxic, ToxicWire};
use crate::link::{stopped, Link};

/// The largest request body the API reads; a larger one is `413`.
pub const MAX_BODY_BYTES: usize = 64 * 1024;
/// After netem's stop, requests in flight get this long to finish.
const STOP_GRACE: Duration = Duration::from_millis(500);

type Sh = State<Arc<Shared>>;

/// A JSON response.
fn json<T: Serialize>(status: StatusCode, v: &T) -> Response {
    match serde_json::to_vec(v) {
        Ok(body) => (status, [(CONTENT_TYPE, "application/json")], body).into_response(),
        Err(e) => error(
            StatusCode::INTERNAL_SERVER_ERROR,
            &format!("cannot encode the response: {e}"),
        ),
    }
}

/// toxiproxy's error shape: `{"error": "...", "status": N}`.
fn error(status: StatusCode, msg: &str) -> Response {
    let body = serde_json::json!({ "error": msg, "status": status.as_u16() }).to_string();
    (status, [(CONTENT_TYPE, "application/json")], body).into_response()
}

fn netem_error(e: &NetemError) -> Response {
    let status = match e {
        NetemError::UnknownLink(_) | NetemError::UnknownToxic { .. } => StatusCode::NOT_FOUND,
        NetemError::ToxicExists { .. } => StatusCode::CONFLICT,
        NetemError::Bind { .. } => StatusCode::INTERNAL_SERVER_ERROR,
        _ => StatusCode::BAD_REQUEST,
    };
    let msg = match e {
        NetemError::UnknownLink(_) => format!("proxy not found: {e}"),
        NetemError::UnknownToxic { .. } => format!("toxic not found: {e}"),
        NetemError::ToxicExists { .. } => format!("toxic already exists: {e}"),
        _ => e.to_string(),
    };
    error(status, &msg)
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

/// Everything the control API decodes from a request body, without acting on any of it: the
/// body as a proxy update, as a toxic (validated and applied as a patch to itself) and as a
/// process fault. The fuzz target `netem_http` (`fuzz/`); never panics.
pub fn decode_only(body: &[u8]) {
    let _ = body_json::<ProxyUpdate>(body);
    if let Ok(wire) = body_json::<ToxicWire>(body) {
        if let Ok(t) = Toxic::try_from(wire.clone()) {
            let _ = t.patched(wire);
        }
    }
    let _ = process_action(Process::Robot(0), body);
}

/// Whether `a` and `b` are equal, in time independent of where the first difference is.
fn same(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// Whether an `Authorization` header carries `Bearer <token>`, compared in time independent of
/// where the first difference is.
pub fn bearer_matches(header: Option<&str>, token: &str) -> bool {
    let Some(given) = header.and_then(|h| h.trim().strip_prefix("Bearer ")) else {
        return false;
    };
    same(given.trim().as_bytes(), token.as_bytes())
}

/// Whether an `Authorization` header carries `Basic base64(user:password)` with the token as the
/// password (any user name) or as the user name with an empty password: what HTTP clients send
/// for a URL `http://:<token>@host` or `http://<token>@host`. Compared like [`bearer_matches`].
pub fn basic_matches(header: Option<&str>, token: &str) -> bool {
    use base64::Engine;
    let Some(given) = header.and_then(|h| h.trim().strip_prefix("Basic ")) else {
        return false;
    };
    let Ok(decoded) = base64::engine::general_purpose::STANDARD.decode(given.trim()) else {
        return false;
    };
    let colon = decoded.iter().position(|&c| c == b':');
    let (user, password) = match colon {
        Some(i) => (&decoded[..i], &decoded[i + 1..]),
        None => (&decoded[..], &[][..]),
    };
    let (token, empty) = (token.as_bytes(), password.is_empty());
    // Both compared, whatever the first says.
    let by_password = same(password, token);
    let by_user = same(user, token) & empty;
    !token.is_empty() & (by_password | by_user)
}

/// The path prefix that carries the token in a base URL: `/token/<token>/…`.
pub const TOKEN_PREFIX: &str = "/token/";

/// A path that starts with [`TOKEN_PREFIX`]: the token it names and the rest of the path
/// (`/` if none); `None` for any other path.
pub fn split_token_path(path: &str) -> Option<(&str, &str)> {
    let rest = path.strip_prefix(TOKEN_PREFIX)?;
    Some(match rest.find('/') {
        Some(i) => (&rest[..i], &rest[i..]),
        None => (rest, "/"),
    })
}

/// A request refused: its status and why (sent in toxiproxy's error shape).
struct Refusal(StatusCode, String);

impl IntoResponse for Refusal {
    fn into_response(self) -> Response {
        error(self.0, &self.1)
    }
}

fn bad_body(e: impl std::fmt::Display) -> Refusal {
    Refusal(StatusCode::BAD_REQUEST, format!("bad request body: {e}"))
}

/// A body as JSON; an empty (or blank) body is `{}`.
fn body_json<T: serde::de::DeserializeOwned>(body: &[u8]) -> Result<T, Refusal> {
    let body: &[u8] = if body.iter().all(u8::is_ascii_whitespace) {
        b"{}"
    } else {
        body
    };
    serde_json::from_slice(body).map_err(bad_body)
}

/// The body of `POST|PATCH /proxies/{name}`. toxiproxy's clients send the whole proxy back
/// (`name`, `listen`, `upstream`, `enabled`); only `enabled` may change here.
#[derive(serde::Deserialize)]
pub struct ProxyUpdate {
    pub enabled: Option<bool>,
    pub name: Option<String>,
    pub listen: Option<String>,
    pub upstream: Option<String>,
}

impl ProxyUpdate {
    /// Why this update cannot be made to the proxy `name` on `listen` forwarding to `upstream`
    /// (which the scenario fixed), if it cannot: it names another name or address. An address
    /// equal to the proxy's, written otherwise (`127.0.0.1:08474`), is the same.
    pub fn refusal(
        &self,
        name: &str,
        listen: std::net::SocketAddr,
        upstream: std::net::SocketAddr,
    ) -> Option<String> {
        let moved = |given: &Option<String>, fixed: std::net::SocketAddr| {
            given
                .as_deref()
                .is_some_and(|g| g.trim().parse::<std::net::SocketAddr>().ok() != Some(fixed))
        };
        if self.name.as_deref().is_some_and(|n| n != name) {
            Some(format!(
                "proxy {name} cannot be renamed: its name is its robot pair's"
            ))
        } else if moved(&self.listen, listen) {
            Some(format!(
                "proxy {name} listens on {listen}, fixed by the scenario (the lower robot's radio \
                 connects there): it cannot move to {:?}; leave listen out or send it unchanged",
                self.listen.as_deref().unwrap_or_default()
            ))
        } else if moved(&self.upstream, upstream) {
            Some(format!(
                "proxy {name} forwards to {upstream}, the higher robot's radio listener, fixed \
                 by the scenario: it cannot forward to {:?}; leave upstream out or send it \
                 unchanged",
                self.upstream.as_deref().unwrap_or_default()
            ))
        } else {
            None
        }
    }
}

/// The API on `shared`: [`gate`] around the routes. The routes are the fallback of an outer
/// router that has no routes of its own, so the gate runs before they route and can take a
/// token off the path first (a layer on the routes themselves would run after routing).
pub(crate) fn app(shared: Arc<Shared>) -> Router {
    Router::new()
        .fallback_service(router(Arc::clone(&shared)))
        .layer(middleware::from_fn_with_state(shared, gate))
}

/// The API's routes on `shared`.
fn router(shared: Arc<Shared>) -> Router {
    Router::new()
        .route("/proxies", get(list).post(fixed))
        .route("/populate", post(fixed))
        .route(
            "/proxies/{name}",
            get(show).post(update).patch(update).delete(fixed),
        )
        .route("/proxies/{name}/toxics", get(toxics).post(add_toxic))
        .route(
            "/proxies/{name}/toxics/{toxic}",
            get(show_toxic)
                .post(set_toxic)
                .patch(set_toxic)
                .delete(remove_toxic),
        )
        .route("/reset", post(reset))
        .route("/version", get(version))
        .route("/metrics", get(metrics))
        .route("/links", get(links))
        .route("/processes/{name}", post(process_fault))
        .method_not_allowed_fallback(not_allowed)
        .fallback(not_found)
        .layer(DefaultBodyLimit::max(MAX_BODY_BYTES))
        .with_state(shared)
}

/// Refuses browsers (`403`, as toxiproxy does) and, when the run set a token, requests without
/// it (`401`); takes a token off the path (`/token/<token>/…`, also when the run set none);
/// logs what it lets through (without the token).
async fn gate(State(sh): Sh, mut req: Request, next: Next) -> Response {
    let path_token = match split_token_path(req.uri().path()) {
        Some((token, rest)) => {
            let token = token.to_string();
            let query = req
                .uri()
                .query()
                .map(|q| format!("?{q}"))
                .unwrap_or_default();
            match format!("{rest}{query}").parse::<axum::http::Uri>() {
                Ok(uri) => *req.uri_mut() = uri,
                Err(e) => return error(StatusCode::BAD_REQUEST, &format!("bad path: {e}")),
            }
            Some(token)
        }
        None => None,
    };
    if let Some(refused) = refused(&sh, req.headers(), path_token.as_deref()) {
        return refused;
    }
    let (method, uri) = (req.method().clone(), req.uri().clone());
    let response = next.run(req).await;
    tracing::debug!(%method, %uri, status = response.status().as_u16(), "http");
    response
}

/// Why [`gate`] refuses a request with these headers (and the token its path carried), if it
/// does.
fn refused(
    sh: &Shared,
    headers: &axum::http::HeaderMap,
    path_token: Option<&str>,
) -> Option<Response> {
    let header = |h: HeaderName| headers.get(h).and_then(|v| v.to_str().ok());
    if header(USER_AGENT).is_some_and(|ua| ua.starts_with("Mozilla/")) {
        return Some(error(StatusCode::FORBIDDEN, "User agent not allowed"));
    }
    let token = sh.api_token.as_deref()?;
    let auth = header(AUTHORIZATION);
    let by_path = path_token.is_some_and(|p| same(p.as_bytes(), token.as_bytes()));
    if by_path | bearer_matches(auth, token) | basic_matches(auth, token) {
        return None;
    }
    Some(error(
        StatusCode::UNAUTHORIZED,
        "this API needs the run's token (netem.token): \"Authorization: Bearer <token>\", \
         Basic auth with the token as password (a base URL http://:<token>@host:port), or a base \
         URL http://host:port/token/<token>",
    ))
}

async fn fixed() -> Response {
    error(
        StatusCode::METHOD_NOT_ALLOWED,
        "proxies are fixed by the scenario (one per robot pair)",
    )
}

async fn not_allowed(method: Method) -> Response {
    error(
        StatusCode::METHOD_NOT_ALLOWED,
        &format!("method {method} not allowed here"),
    )
}

async fn not_found() -> Response {
    error(StatusCode::NOT_FOUND, "not found")
}

async fn list(State(sh): Sh) -> Response {
    let map: serde_json::Map<String, serde_json::Value> = sh
        .links
        .iter()
        .map(|l| {
            let v = serde_json::to_value(proxy_json(l)).unwrap_or(serde_json::Value::Null);
            (l.name.clone(), v)
        })
        .collect();
    json(StatusCode::OK, &map)
}

async fn show(State(sh): Sh, Path(name): Path<String>) -> Response {
    with_link(&sh, &name, |l| json(StatusCode::OK, &proxy_json(l)))
}

async fn update(State(sh): Sh, Path(name): Path<String>, body: Bytes) -> Response {
    with_link(&sh, &name, |l| {
        let upd: ProxyUpdate = match body_json(&body) {
            Ok(u) => u,
            Err(r) => return r.into_response(),
        };
        // A proxy that listens while its link is up may have moved port since the client read
        // it: any port it listened on is its own.
        let listen = (upd.listen.as_deref())
            .and_then(|g| g.trim().parse().ok())
            .filter(|&a| l.listened_at(a))
            .unwrap_or_else(|| l.listen());
        if let Some(why) = upd.refusal(&l.name, listen, l.params.target) {
            return error(StatusCode::CONFLICT, &why);
        }
        let pair = (l.params.a, l.params.b);
        let fault = match upd.enabled {
            Some(false) => Some(Fault::Cut { pair }),
            Some(true) => Some(Fault::Restore { pair }),
            None => None,
        };
        match fault.map(|f| sh.apply(&f)) {
            Some(Err(e)) => netem_error(&e),
            _ => json(StatusCode::OK, &proxy_json(l)),
        }
    })
}

async fn toxics(State(sh): Sh, Path(name): Path<String>) -> Response {
    with_link(&sh, &name, |l| {
        let toxics: Vec<Toxic> = l.toxics().iter().map(|t| t.toxic.clone()).collect();
        json(StatusCode::OK, &toxics)
    })
}

/// A toxic from a body, or the `400` that says why not.
fn toxic_from(body: &[u8], patching: Option<&Toxic>) -> Result<Toxic, Refusal> {
    let wire: ToxicWire = body_json(body)?;
    let toxic = match patching {
        Some(t) => t.patched(wire),
        None => Toxic::try_from(wire),
    };
    toxic.map_err(bad_body)
}

async fn add_toxic(State(sh): Sh, Path(name): Path<String>, body: Bytes) -> Response {
    with_link(&sh, &name, |l| {
        let toxic = match toxic_from(&body, None) {
            Ok(t) => t,
            Err(r) => return r.into_response(),
        };
        let pair = Some((l.params.a, l.params.b));
        match sh.apply(&Fault::AddToxic {
            pair,
            toxic: toxic.clone(),
        }) {
            Ok(()) => json(StatusCode::OK, &toxic),
            Err(e) => netem_error(&e),
        }
    })
}

async fn show_toxic(State(sh): Sh, Path((name, toxic)): Path<(String, String)>) -> Response {
    with_toxic(&sh, &name, &toxic, |_, t| json(StatusCode::OK, t))
}

async fn set_toxic(
    State(sh): Sh,
    Path((name, toxic)): Path<(String, String)>,
    body: Bytes,
) -> Response {
    with_toxic(&sh, &name, &toxic, |l, t| {
        let toxic = match toxic_from(&body, Some(t)) {
            Ok(t) => t,
            Err(r) => return r.into_response(),
        };
        let pair = Some((l.params.a, l.params.b));
        match sh.apply(&Fault::SetToxic {
            pair,
            toxic: toxic.clone(),
        }) {
            Ok(()) => json(StatusCode::OK, &toxic),
            Err(e) => netem_error(&e),
        }
    })
}

async fn remove_toxic(State(sh): Sh, Path((name, toxic)): Path<(String, String)>) -> Response {
    with_link(&sh, &name, |l| {
        let pair = Some((l.params.a, l.params.b));
        match sh.apply(&Fault::RemoveToxic { pair, name: toxic }) {
            Ok(()) => StatusCode::NO_CONTENT.into_response(),
            Err(e) => netem_error(&e),
        }
    })
}

async fn reset(State(sh): Sh) -> Response {
    match sh.apply(&Fault::ResetAll) {
        Ok(()) => StatusCode::NO_CONTENT.into_response(),
        Err(e) => netem_error(&e),
    }
}

async fn version() -> Response {
    json(
        StatusCode::OK,
        &serde_json::json!({ "version": concat!("netem ", env!("CARGO_PKG_VERSION"), " (toxiproxy API 2)") }),
    )
}

/// `GET /metrics`: OpenMetrics, or the classic text format when `Accept` prefers it
/// ([`crate::metrics::Format::negotiate`]).
async fn metrics(State(sh): Sh, headers: axum::http::HeaderMap) -> Response {
    let accept = headers
        .get(axum::http::header::ACCEPT)
        .and_then(|v| v.to_str().ok());
    let format = crate::metrics::Format::negotiate(accept);
    let nodes = lock(&sh.channel).totals().clone();
    let text = crate::metrics::render(format, &sh.snapshots(), &nodes, sh.step(), sh.now());
    (
        StatusCode::OK,
        [(CONTENT_TYPE, format.content_type())],
        text,
    )
        .into_response()
}

async fn links(State(sh): Sh) -> Response {
    json(StatusCode::OK, &sh.rows())
}

/// A process fault from `POST /processes/{name}`'s body (`{"kind": …}`; the process is the
/// path's), or the `400` that says why not.
fn process_action(process: Process, body: &[u8]) -> Result<ProcessAction, Refusal> {
    let mut map: serde_json::Map<String, serde_json::Value> = body_json(body)?;
    if map.contains_key("process") {
        return Err(bad_body("the process is named by the path"));
    }
    map.insert(
        "process".into(),
        serde_json::Value::String(process.to_string()),
    );
    serde_json::from_value(serde_json::Value::Object(map)).map_err(bad_body)
}

/// `POST /processes/<name>` with `{"kind": "kill" | "restart" | "freeze" | "thaw"}` (and
/// `"restart_after": k` for a kill): a process fault, checked against the run's scenario and
/// handed on to the launcher, which carries it out at its next step (`202`: accepted, not yet
/// done — `summary.json`'s `process_events` says when it was, with cause `api`).
async fn process_fault(State(sh): Sh, Path(name): Path<String>, body: Bytes) -> Response {
    let desk = lock(&sh.process_desk);
    let Some(desk) = desk.as_ref() else {
        return error(
            StatusCode::NOT_IMPLEMENTED,
            "this netem is not following a run: nobody to carry out process faults",
        );
    };
    let process: Process = match name.parse() {
        Ok(p) if desk.scenario.has_process(p) => p,
        _ => {
            return error(
                StatusCode::NOT_FOUND,
                &format!("no process {name:?} in this run"),
            )
        }
    };
    let action = match process_action(process, &body) {
        Ok(a) => a,
        Err(r) => return r.into_response(),
    };
    if let Err((value, why)) = desk.scenario.check_process_action(&action) {
        return error(StatusCode::BAD_REQUEST, &format!("{value}: {why}"));
    }
    match desk.orders.try_send(ProcessOrder::from(&action)) {
        Ok(()) => json(StatusCode::ACCEPTED, &action),
        Err(mpsc::error::TrySendError::Full(_)) => error(
            StatusCode::SERVICE_UNAVAILABLE,
            "too many process faults waiting for the next step",
        ),
        Err(mpsc::error::TrySendError::Closed(_)) => {
            error(StatusCode::SERVICE_UNAVAILABLE, "the run is ending")
        }
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

/// Serves the API on `listener` until `shutdown` becomes true; requests still in flight then get
/// [`STOP_GRACE`].
pub(crate) fn serve(
    shared: Arc<Shared>,
    listener: TcpListener,
    shutdown: watch::Receiver<bool>,
) -> JoinHandle<()> {
    tokio::spawn(async move {
        let (mut stop, mut grace) = (shutdown.clone(), shutdown);
        let server = axum::serve(listener, app(shared))
            .with_graceful_shutdown(async move { stopped(&mut stop).await });
        tokio::select! {
            r = server => if let Err(e) = r {
                tracing::warn!("the HTTP API stopped: {e}");
            },
            () = async {
                stopped(&mut grace).await;
                tokio::time::sleep(STOP_GRACE).await;
            } => tracing::debug!("HTTP requests still open at the stop were dropped"),
        }
    })
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

    #[test]
    fn basic_auth_carries_the_token_as_password_or_user_name() {
        use base64::Engine;
        let t = "0123456789abcdef0123456789abcdef";
        let basic = |s: &str| {
            format!(
                "Basic {}",
                base64::engine::general_purpose::STANDARD.encode(s)
            )
        };
        for good in [
            format!(":{t}"),
            format!("user:{t}"),
            format!("{t}:"),
            t.to_string(),
        ] {
            assert!(basic_matches(Some(&basic(&good)), t), "{good}");
        }
        for bad in [
            format!("{t}:{t}x"),
            format!("{t}x:"),
            format!(":{}", &t[1..]),
            ":".to_string(),
            String::new(),
        ] {
            assert!(!basic_matches(Some(&basic(&bad)), t), "{bad}");
        }
        assert!(!basic_matches(Some("Basic ***"), t));
        assert!(!basic_matches(None, t));
        assert!(
            !basic_matches(Some(&basic(":")), ""),
            "an empty token never matches"
        );
        assert_eq!(
            split_token_path("/token/abc/proxies/r0-r1"),
            Some(("abc", "/proxies/r0-r1"))
        );
        assert_eq!(split_token_path("/token/abc"), Some(("abc", "/")));
        assert_eq!(split_token_path("/proxies"), None);
    }

    #[test]
    fn bodies_decode_totally() {
        for body in [
            &b""[..],
            b"   ",
            b"{not json",
            b"\xff\xfe",
            b"[]",
            b"{\"enabled\": 3}",
            b"{\"type\":\"latency\",\"attributes\":{\"latency\":-1}}",
            b"{\"kind\":\"kill\",\"restart_after\":18446744073709551616}",
            b"{\"type\":\"slicer\",\"attributes\":{\"average_size\":0,\"size_variation\":18446744073709551615}}",
            b"{\"type\":\"slow_close\",\"attributes\":{\"delay\":-5}}",
            b"{\"listen\":7,\"upstream\":null,\"name\":[]}",
        ] {
            decode_only(body);
        }
        assert!(body_json::<ProxyUpdate>(b" ").is_ok_and(|u| u.enabled.is_none()));
        assert!(body_json::<ProxyUpdate>(b"{\"enabled\":false}")
            .is_ok_and(|u| u.enabled == Some(false)));
    }

    mod api {
        use crate::control::PROCESS_ORDERS_QUEUED;
        use crate::netem::{start, Netem, NetemConfig, PairSpec};
        use proptest::prelude::*;
        use proto::scenario::{Medium, Radio, RadioModel};
        use std::net::SocketAddr;
        use std::time::Duration;
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        use tokio::net::TcpStream;

        async fn netem() -> Netem {
            netem_with(None).await
        }

        async fn netem_with(token: Option<&str>) -> Netem {
            let target: SocketAddr = "127.0.0.1:9".parse().unwrap();
            let pair = |a, b| PairSpec {
                a,
                b,
                listen: "127.0.0.1:0".parse().unwrap(),
                target,
                while_up: false,
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
            cfg.api_token = token.map(str::to_string);
            let n = start(cfg).await.unwrap();
            n.on_step(0, &[]);
            n
        }

        /// Writes `bytes` on a new connection (then ends its sending side if `half_close`: for
        /// bytes that may not end a request) and reads the answer to its end.
        async fn send_with(n: &Netem, bytes: &[u8], half_close: bool) -> Vec<u8> {
            let mut s = TcpStream::connect(n.http_addr().unwrap()).await.unwrap();
            s.write_all(bytes).await.unwrap();
            if half_close {
                s.shutdown().await.unwrap();
            }
            let mut out = Vec::new();
            tokio::time::timeout(Duration::from_secs(5), s.read_to_end(&mut out))
                .await
                .unwrap()
                .unwrap();
            out
        }

        async fn send(n: &Netem, bytes: &[u8]) -> Vec<u8> {
            send_with(n, bytes, false).await
        }

        /// (status, body) of an answer.
        /// The first answer's status and body (bytes that follow a request whose
        /// `Connection: close` a mangling broke are answered again, after its body).
        fn answer(out: &[u8]) -> (u16, String) {
            let text = String::from_utf8_lossy(out);
            let status = text.get(9..12).and_then(|s| s.parse().ok()).unwrap_or(0);
            let Some((head, body)) = text.split_once("\r\n\r\n") else {
                return (status, String::new());
            };
            let length = head.lines().find_map(|l| {
                let (name, value) = l.split_once(':')?;
                name.eq_ignore_ascii_case("content-length")
                    .then(|| value.trim().parse::<usize>().ok())?
            });
            let body = match length {
                Some(n) => body.get(..n).unwrap_or(body),
                None => body,
            };
            (status, body.to_string())
        }

        /// A request's bytes with `Connection: close`.
        fn render(method: &str, path: &str, headers: &[(String, String)], body: &[u8]) -> Vec<u8> {
            let mut s = format!("{method} {path} HTTP/1.1\r\nHost: x\r\n");
            for (n, v) in headers {
                s.push_str(&format!("{n}: {v}\r\n"));
            }
            s.push_str(&format!(
                "Connection: close\r\nContent-Length: {}\r\n\r\n",
                body.len()
            ));
            let mut b = s.into_bytes();
            b.extend_from_slice(body);
            b
        }

        /// One request with `Connection: close`; returns (status, body).
        async fn call(
            n: &Netem,
            method: &str,
            path: &str,
            body: &str,
            extra: &str,
        ) -> (u16, String) {
            let headers: Vec<(String, String)> = extra
                .lines()
                .filter_map(|l| l.split_once(": "))
                .map(|(n, v)| (n.to_string(), v.to_string()))
                .collect();
            answer(&send(n, &render(method, path, &headers, body.as_bytes())).await)
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
            // toxiproxy's slicer and slow_close, with its attributes; a slicer without a size
            // is refused with the reason.
            let slicer = r#"{"name":"cut","type":"slicer","attributes":{"average_size":32,"size_variation":8,"delay":100}}"#;
            let (st, body) = call(&n, "POST", "/proxies/r0-r1/toxics", slicer, "").await;
            assert_eq!(st, 200, "{body}");
            assert_eq!(json(&body)["attributes"]["size_variation"], 8);
            let slow = r#"{"type":"slow_close","stream":"upstream","attributes":{"delay":1500}}"#;
            let (st, body) = call(&n, "POST", "/proxies/r0-r1/toxics", slow, "").await;
            assert_eq!(st, 200, "{body}");
            assert_eq!(json(&body)["name"], "slow_close_upstream");
            assert_eq!(json(&body)["attributes"]["delay"], 1500);
            let (st, body) = call(
                &n,
                "POST",
                "/proxies/r0-r1/toxics",
                r#"{"type":"slicer"}"#,
                "",
            )
            .await;
            assert_eq!(st, 400);
            assert!(json(&body)["error"]
                .as_str()
                .is_some_and(|e| e.contains("average_size")));
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
        async fn an_update_that_moves_or_renames_a_proxy_is_refused_and_changes_nothing() {
            let n = netem().await;
            let (_, body) = call(&n, "GET", "/proxies/r0-r1", "", "").await;
            let p = json(&body);
            let (listen, upstream) = (
                p["listen"].as_str().unwrap(),
                p["upstream"].as_str().unwrap(),
            );
            // What toxiproxy's clients send: the whole proxy back, with `enabled` changed.
            let same = serde_json::json!({"name": "r0-r1", "listen": listen, "upstream": upstream, "enabled": false});
            let (st, body) = call(&n, "POST", "/proxies/r0-r1", &same.to_string(), "").await;
            assert_eq!(st, 200, "{body}");
            assert!(!n.snapshot()[0].up);
            for body in [
                serde_json::json!({"listen": "127.0.0.1:1", "enabled": true}),
                serde_json::json!({"listen": "nowhere", "enabled": true}),
                serde_json::json!({"upstream": "127.0.0.1:10", "enabled": true}),
                serde_json::json!({"name": "r0-r2", "enabled": true}),
            ] {
                let (st, text) = call(&n, "POST", "/proxies/r0-r1", &body.to_string(), "").await;
                assert_eq!(st, 409, "{body}: {text}");
                let e = json(&text);
                assert_eq!(e["status"], 409);
                assert!(
                    e["error"].as_str().is_some_and(|e| e.contains("r0-r1")),
                    "{text}"
                );
                assert!(
                    !n.snapshot()[0].up,
                    "a refused update changed the link: {body}"
                );
            }
            let (_, body) = call(&n, "GET", "/proxies/r0-r1", "", "").await;
            assert_eq!(json(&body)["listen"], listen);
            n.shutdown().await;
        }

        #[tokio::test]
        async fn the_token_passes_as_bearer_basic_or_base_url_path() {
            use base64::Engine;
            let t = "0123456789abcdef0123456789abcdef";
            let n = netem_with(Some(t)).await;
            let b64 = |s: &str| base64::engine::general_purpose::STANDARD.encode(s);
            let get = |path: &'static str, auth: String| {
                let n = &n;
                async move { call(n, "GET", path, "", &auth).await.0 }
            };
            assert_eq!(get("/proxies", String::new()).await, 401);
            for ok in [
                format!("Authorization: Bearer {t}\r\n"),
                format!("Authorization: Basic {}\r\n", b64(&format!(":{t}"))),
                format!(
                    "Authorization: Basic {}\r\n",
                    b64(&format!("toxiproxy:{t}"))
                ),
                format!("Authorization: Basic {}\r\n", b64(&format!("{t}:"))),
            ] {
                assert_eq!(get("/proxies", ok.clone()).await, 200, "{ok}");
            }
            for bad in [
                format!("Authorization: Basic {}\r\n", b64(&format!("{t}:x"))),
                format!("Authorization: Basic {}\r\n", b64("x:0123456789abcdef")),
                format!("Authorization: Basic {t}\r\n"),
                "Authorization: Basic !!!\r\n".to_string(),
                format!("Authorization: Bearer {}\r\n", b64(&format!(":{t}"))),
            ] {
                assert_eq!(get("/proxies", bad.clone()).await, 401, "{bad}");
            }
            // The token as the base URL's path: every route under it, the token not routed.
            let (st, body) = call(&n, "GET", &format!("/token/{t}/proxies/r0-r1"), "", "").await;
            assert_eq!(st, 200, "{body}");
            assert_eq!(json(&body)["name"], "r0-r1");
            let (st, _) = call(
                &n,
                "POST",
                &format!("/token/{t}/proxies/r0-r1/toxics"),
                r#"{"type":"latency","attributes":{"latency":10}}"#,
                "",
            )
            .await;
            assert_eq!(st, 200);
            assert_eq!(
                call(&n, "GET", &format!("/token/{t}/nothing"), "", "")
                    .await
                    .0,
                404
            );
            assert_eq!(call(&n, "GET", &format!("/token/{t}"), "", "").await.0, 404);
            let (st, body) = call(&n, "GET", &format!("/token/{t}/metrics?x=1"), "", "").await;
            assert_eq!(st, 200, "{body}");
            for bad in [
                "/token/0123456789abcdef0123456789abcdee/proxies",
                "/token//proxies",
                "/token/proxies",
                "/tokens/0123456789abcdef0123456789abcdef/proxies",
            ] {
                assert_eq!(call(&n, "GET", bad, "", "").await.0, 401, "{bad}");
            }
            n.shutdown().await;
            // Without a token the prefix is taken off and the request served.
            let n = netem().await;
            assert_eq!(
                call(&n, "GET", "/token/anything/proxies", "", "").await.0,
                200
            );
            n.shutdown().await;
        }

        #[tokio::test]
        async fn metrics_negotiate_the_format() {
            let n = netem().await;
            let content_type = |accept: &'static str| {
                let n = &n;
                async move {
                    let out = send(
                        n,
                        &render("GET", "/metrics", &[("Accept".into(), accept.into())], b""),
                    )
                    .await;
                    let text = String::from_utf8_lossy(&out).to_ascii_lowercase();
                    let (_, body) = answer(&out);
                    let ct = text
                        .lines()
                        .find_map(|l| l.strip_prefix("content-type: ").map(str::to_string));
                    (ct.unwrap_or_default(), body)
                }
            };
            let (ct, body) = content_type("*/*").await;
            assert!(ct.starts_with("application/openmetrics-text"), "{ct}");
            assert!(body.contains("# TYPE netem_link_bytes counter") && body.ends_with("# EOF\n"));
            let (ct, body) = content_type("text/plain;version=0.0.4;q=1,*/*;q=0.1").await;
            assert_eq!(ct, "text/plain; version=0.0.4; charset=utf-8");
            assert!(
                body.contains("# TYPE netem_link_bytes_total counter") && !body.contains("# EOF")
            );
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
            let out = send(
                &n,
                b"GET /version HTTP/1.1\r\n\r\nGET /version HTTP/1.1\r\n\r\n\x00\x01garbage\r\n\r\n",
            )
            .await;
            let text = String::from_utf8_lossy(&out);
            assert_eq!(text.matches("HTTP/1.1 200 OK").count(), 2, "{text}");
            assert!(text.contains("HTTP/1.1 400 Bad Request"), "{text}");
            // A body past the limit.
            let big = vec![b' '; super::super::MAX_BODY_BYTES + 1];
            let (st, _) = answer(&send(&n, &render("POST", "/proxies/r0-r1", &[], &big)).await);
            assert_eq!(st, 413);
            n.shutdown().await;
        }

        /// Statuses the API answers with (axum's and hyper's own included).
        const DOCUMENTED: [u16; 12] = [200, 202, 204, 400, 403, 404, 405, 409, 413, 501, 503, 505];

        fn request() -> impl Strategy<Value = (String, String, Vec<(String, String)>, Vec<u8>)> {
            let seg = prop::sample::select(vec![
                "proxies",
                "r0-r1",
                "r2-r1",
                "r0-r9",
                "toxics",
                "lag",
                "bandwidth_downstream",
                "reset",
                "version",
                "metrics",
                "links",
                "processes",
                "robot-0",
                "netem",
                "populate",
                "token",
                "0123",
                "x",
                "%41",
                "%ff",
                "%zz",
            ]);
            let method =
                prop::sample::select(vec!["GET", "POST", "PATCH", "DELETE", "PUT", "OPTIONS"]);
            let body = prop_oneof![
                prop::collection::vec(any::<u8>(), 0..120),
                prop::sample::select(vec![
                    r#"{"enabled":false}"#,
                    r#"{"enabled":true}"#,
                    r#"{"type":"latency","attributes":{"latency":100}}"#,
                    r#"{"name":"lag","type":"latency"}"#,
                    r#"{"type":"bandwidth","attributes":{"rate":1}}"#,
                    r#"{"kind":"kill"}"#,
                    r#"{"type":"slicer","attributes":{"average_size":1}}"#,
                    r#"{"type":"slow_close","attributes":{"delay":10}}"#,
                    r#"{"listen":"127.0.0.1:1","enabled":true}"#,
                    "{}",
                    "",
                ])
                .prop_map(|s| s.as_bytes().to_vec()),
            ];
            // Headers that frame the request or pass the gate are the test's own.
            let ours = [
                "host",
                "content-length",
                "transfer-encoding",
                "connection",
                "expect",
                "upgrade",
                "te",
                "trailer",
                "keep-alive",
                "user-agent",
                "authorization",
            ];
            let header = ("[A-Za-z][A-Za-z0-9-]{0,11}", "[!-~]([ -~]{0,18}[!-~])?")
                .prop_filter("a framing header", move |(n, _)| {
                    !ours.contains(&n.to_ascii_lowercase().as_str())
                });
            (
                method,
                prop::collection::vec(seg, 1..5),
                prop::collection::vec(header, 0..6),
                body,
            )
                .prop_map(|(m, segs, h, b)| (m.to_string(), format!("/{}", segs.join("/")), h, b))
        }

        /// The request parser's property tests, now against the API over a socket: any request,
        /// well-formed or mangled, and any bytes get an answer with a documented status (or a
        /// closed connection), an error of ours in toxiproxy's shape, and the API keeps answering.
        #[test]
        fn any_request_or_bytes_get_a_documented_answer_and_the_api_stays_up() {
            let rt = tokio::runtime::Runtime::new().unwrap();
            let n = rt.block_on(netem());
            let mangled = (request(), any::<prop::sample::Index>(), any::<u8>()).prop_map(
                |((m, p, h, b), at, junk)| {
                    let mut bytes = render(&m, &p, &h, &b);
                    bytes.insert(at.index(bytes.len() + 1), junk);
                    bytes
                },
            );
            let input = prop_oneof![
                request().prop_map(|(m, p, h, b)| (render(&m, &p, &h, &b), true)),
                mangled.prop_map(|b| (b, false)),
                prop::collection::vec(any::<u8>(), 0..600).prop_map(|b| (b, false)),
            ];
            proptest!(ProptestConfig::with_cases(160), |((bytes, whole) in input)| {
                let out = rt.block_on(send_with(&n, &bytes, !whole));
                prop_assert!(!whole || !out.is_empty(), "no answer to a whole request");
                if !out.is_empty() {
                    let (status, body) = answer(&out);
                    prop_assert!(DOCUMENTED.contains(&status), "{status}: {body}");
                    if [403, 404, 405, 409, 501, 503].contains(&status) {
                        prop_assert!(json(&body)["error"].is_string(), "{body}");
                    }
                }
                let (st, _) = rt.block_on(call(&n, "GET", "/version", "", ""));
                prop_assert_eq!(st, 200);
            });
            rt.block_on(n.shutdown());
        }
    }
}
