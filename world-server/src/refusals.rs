//! Refused logins on the sim plane, in the world-server's log: who tried, from where, and why — the
//! first refusal from an address at once, later ones from it counted, one line per
//! [`REPORT_EVERY`](crate::refusals::REPORT_EVERY), so that an attacker who retries in a loop
//! cannot flood the log.
//!
//! Where a refusal can be seen. zenoh 1.10 checks a client's user and password inside its
//! transport, in the handshake that establishes the link (the `auth_usrpwd` extension of the accept
//! state machine, `zenoh-transport`'s `unicast/establishment`), before any transport or session
//! exists. A refused client therefore never reaches what the application can hook: transport event
//! handlers, the interceptors of access control and the admin space all start from an established
//! transport, and the session API has no callback for a failed accept. What zenoh does is log it,
//! with `tracing`, from the task that accepts the link (target
//! [`ACCEPT_TARGET`](crate::refusals::ACCEPT_TARGET)): at trace, the InitSyn it received
//! ("Establishment Accept InitSyn: {local} => {remote}. Received: …", which holds the client's
//! zenoh id), and at debug the error that ended the handshake ("UsrPwd extension - Recv OpenSyn.
//! Invalid password.", "… Invalid user.", "UsrPwd extension - Recv InitSyn. Expected extension."
//! for a client without a login). zenoh accepts each link in a task of its own, so `RefusalLayer`,
//! a `tracing` layer with its own filter (only that target; the stderr log's filter is untouched),
//! ties the two events together by the tokio task id and records a
//! [`Refusal`](crate::refusals::Refusal). This depends on the wording of zenoh's messages, which a
//! minor zenoh release may change: `tests/confine.rs` fails when refusals stop being reported. The
//! user name tried is in neither event (zenoh keeps it inside the encoded OpenSyn extension), so
//! "who" is the client's zenoh id.
//!
//! The layer only records: `tracing` drops events emitted while it dispatches another, so the lines
//! are logged by [`Refusals::report`](crate::refusals::Refusals::report), a task of the
//! world-server.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use tokio::sync::Notify;
use tracing::field::{Field, Visit};
use tracing::{Event, Level, Subscriber};
use tracing_subscriber::filter::Targets;
use tracing_subscriber::layer::{Context, Layer};
use tracing_subscriber::registry::LookupSpan;

/// The target of zenoh's events about accepting a link (its module path).
pub const ACCEPT_TARGET: &str = "zenoh_transport::unicast::establishment::accept";

/// How often the refusals counted since the last line are logged.
pub const REPORT_EVERY: Duration = Duration::from_secs(10);

/// Addresses counted apart; refusals from further addresses share one entry.
const MAX_PEERS: usize = 1024;

/// Links whose handshake is under way (zenoh bounds them by `transport/unicast/accept_pending`,
/// 100 by default); the oldest is forgotten beyond this.
const MAX_PENDING: usize = 256;

/// Why zenoh refused a login.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Reason {
    /// A user of the dictionary with another password.
    WrongPassword,
    /// A user the dictionary does not hold.
    UnknownUser,
    /// The client offered no user and password.
    NoLogin,
    /// The login extension did not decode.
    Malformed,
}

impl std::fmt::Display for Reason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Reason::WrongPassword => "wrong password",
            Reason::UnknownUser => "unknown user",
            Reason::NoLogin => "no login offered",
            Reason::Malformed => "malformed login",
        })
    }
}

impl Reason {
    /// The reason of a handshake error zenoh logged, if it is a refused login.
    pub fn of_error(message: &str) -> Option<Reason> {
        if !message.contains("UsrPwd extension") && !message.contains("Auth extension") {
            return None;
        }
        Some(if message.contains("Invalid password") {
            Reason::WrongPassword
        } else if message.contains("Invalid user") {
            Reason::UnknownUser
        } else if message.contains("Expected extension") {
            Reason::NoLogin
        } else {
            Reason::Malformed
        })
    }
}

/// One refused login.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Refusal {
    /// The client's end of the link, e.g. `127.0.0.1:53422` (`None`: not seen).
    pub from: Option<String>,
    /// The zenoh id the client gave.
    pub zid: Option<String>,
    pub reason: Reason,
}

impl Refusal {
    /// The address without its port: what refusals are counted by.
    fn host(&self) -> String {
        let Some(from) = &self.from else {
            return "an unknown address".into();
        };
        match from.parse::<std::net::SocketAddr>() {
            Ok(a) => a.ip().to_string(),
            Err(_) => from.clone(),
        }
    }

    fn who(&self) -> String {
        format!(
            "{} (zenoh id {})",
            self.from.as_deref().unwrap_or("an unknown address"),
            self.zid.as_deref().unwrap_or("unknown")
        )
    }
}

/// What a link's InitSyn said: the client's address and zenoh id.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
struct Hello {
    from: Option<String>,
    zid: Option<String>,
}

impl Hello {
    /// Reads zenoh's "Establishment Accept InitSyn: {local} => {remote}. Received: {msg:?}".
    fn parse(message: &str) -> Option<Hello> {
        let rest = message.strip_prefix("Establishment Accept InitSyn: ")?;
        let (link, received) = rest.split_once(". Received: ").unwrap_or((rest, ""));
        let from = link.split_once(" => ").map(|(_, remote)| {
            // A locator: `tcp/127.0.0.1:53422`, maybe with `?metadata` or `#config`.
            let remote = remote.split(['?', '#']).next().unwrap_or(remote);
            remote
                .split_once('/')
                .map_or(remote, |(_, addr)| addr)
                .to_string()
        });
        let zid = received.split_once("zid: ").map(|(_, z)| {
            z.chars()
                .take_while(char::is_ascii_hexdigit)
                .collect::<String>()
        });
        Some(Hello {
            from,
            zid: zid.filter(|z| !z.is_empty()),
        })
    }
}

/// Refusals by address: what to log at once and what to count.
#[derive(Debug, Default)]
pub struct Tally {
    peers: HashMap<String, Peer>,
}

/// The refusals from one address since its last line.
#[derive(Debug, Default)]
struct Peer {
    counted: BTreeMap<Reason, u64>,
    last: Option<Refusal>,
}

/// The key refusals from addresses beyond [`MAX_PEERS`] are counted under.
const OTHERS: &str = "other addresses";

impl Tally {
    /// Takes one refusal: the line to log now when its address has had none since the last
    /// [`Tally::flush`] that found it quiet; `None` when it is only counted.
    pub fn record(&mut self, r: Refusal) -> Option<String> {
        let mut host = r.host();
        if !self.peers.contains_key(&host) && self.peers.len() >= MAX_PEERS {
            host = OTHERS.into();
        }
        match self.peers.get_mut(&host) {
            Some(peer) => {
                *peer.counted.entry(r.reason).or_default() += 1;
                peer.last = Some(r);
                None
            }
            None => {
                let line = format!(
                    "refused login from {}: {}; more from {host} are counted, one line every {} s",
                    r.who(),
                    r.reason,
                    REPORT_EVERY.as_secs()
                );
                self.peers.insert(host, Peer::default());
                Some(line)
            }
        }
    }

    /// A line for every address with refusals counted since its last line (by address); an
    /// address with none is forgotten, so that its next refusal is logged at once again.
    pub fn flush(&mut self) -> Vec<String> {
        let mut lines = Vec::new();
        self.peers.retain(|host, peer| {
            let Some(last) = peer.last.take() else {
                return false;
            };
            let total: u64 = peer.counted.values().sum();
            let by: Vec<String> = peer
                .counted
                .iter()
                .map(|(reason, n)| format!("{reason} {n}"))
                .collect();
            lines.push(format!(
                "refused logins from {host}: {total} more ({}), the last from {}",
                by.join(", "),
                last.who()
            ));
            peer.counted.clear();
            true
        });
        lines.sort();
        lines
    }
}

/// What the layer and the reporting task share.
#[derive(Debug, Default)]
struct Shared {
    state: Mutex<State>,
    /// Wakes the reporting task when a line waits.
    wake: Notify,
}

#[derive(Debug, Default)]
struct State {
    /// Links whose InitSyn was seen and whose handshake has not ended, by zenoh's accept task.
    pending: VecDeque<(tokio::task::Id, Hello)>,
    tally: Tally,
    /// Lines to log at once.
    lines: Vec<String>,
}

impl Shared {
    /// The state; a poisoned lock (a panic elsewhere while holding it) still holds a usable
    /// state.
    fn state(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// Refused logins, seen by [`Refusals::layer`] and logged by [`Refusals::report`].
#[derive(Clone, Debug, Default)]
pub struct Refusals {
    shared: Arc<Shared>,
}

impl Refusals {
    /// The `tracing` layer that sees zenoh's accept events (and nothing else).
    pub fn layer<S>(&self) -> impl Layer<S> + Send + Sync
    where
        S: Subscriber + for<'a> LookupSpan<'a>,
    {
        RefusalLayer {
            shared: self.shared.clone(),
        }
        .with_filter(Targets::new().with_target(ACCEPT_TARGET, Level::TRACE))
    }

    /// Logs refusals until the task is dropped: an address's first at once, the counts every
    /// `every`.
    pub async fn report(self, every: Duration) {
        let mut tick = tokio::time::interval_at(tokio::time::Instant::now() + every, every);
        loop {
            tokio::select! {
                _ = self.shared.wake.notified() => {
                    let lines = std::mem::take(&mut self.shared.state().lines);
                    log(lines);
                }
                _ = tick.tick() => self.flush(),
            }
        }
    }

    /// Logs what is waiting and every count (at the end of the process, so none is lost).
    pub fn flush(&self) {
        let lines = {
            let mut state = self.shared.state();
            let mut lines = std::mem::take(&mut state.lines);
            lines.extend(state.tally.flush());
            lines
        };
        log(lines);
    }
}

fn log(lines: Vec<String>) {
    for line in lines {
        tracing::warn!("{line}");
    }
}

/// The layer of [`Refusals`]: ties zenoh's InitSyn and handshake-error events of one accept task
/// together.
struct RefusalLayer {
    shared: Arc<Shared>,
}

/// The `message` field of an event, formatted.
#[derive(Default)]
struct Message(String);

impl Visit for Message {
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            self.0 = format!("{value:?}");
        }
    }

    fn record_str(&mut self, field: &Field, value: &str) {
        if field.name() == "message" {
            self.0 = value.to_string();
        }
    }
}

impl<S: Subscriber> Layer<S> for RefusalLayer {
    fn on_event(&self, event: &Event<'_>, _ctx: Context<'_, S>) {
        let meta = event.metadata();
        if meta.target() != ACCEPT_TARGET {
            return;
        }
        let level = *meta.level();
        if level != Level::TRACE && level != Level::DEBUG {
            return;
        }
        let mut message = Message::default();
        event.record(&mut message);
        let task = tokio::task::try_id();
        let mut state = self.shared.state();
        if level == Level::TRACE {
            if let (Some(task), Some(hello)) = (task, Hello::parse(&message.0)) {
                if state.pending.len() >= MAX_PENDING {
                    state.pending.pop_front();
                }
                state.pending.push_back((task, hello));
            }
            return;
        }
        // Debug: the handshake ended, accepted or not.
        let hello = task
            .and_then(|task| state.pending.iter().position(|(t, _)| *t == task))
            .and_then(|i| state.pending.remove(i))
            .map(|(_, hello)| hello)
            .unwrap_or_default();
        let Some(reason) = Reason::of_error(&message.0) else {
            return;
        };
        let refusal = Refusal {
            from: hello.from,
            zid: hello.zid,
            reason,
        };
        if let Some(line) = state.tally.record(refusal) {
            state.lines.push(line);
            drop(state);
            self.shared.wake.notify_one();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn refusal(from: &str, reason: Reason) -> Refusal {
        Refusal {
            from: Some(from.into()),
            zid: Some("a1b2".into()),
            reason,
        }
    }

    #[test]
    fn zenohs_handshake_errors_give_the_reason() {
        for (message, want) in [
            (
                "UsrPwd extension - Recv OpenSyn. Invalid password. at src/x.rs:424.",
                Some(Reason::WrongPassword),
            ),
            (
                "UsrPwd extension - Recv OpenSyn. Invalid user.",
                Some(Reason::UnknownUser),
            ),
            (
                "UsrPwd extension - Recv InitSyn. Expected extension.",
                Some(Reason::NoLogin),
            ),
            (
                "Auth extension - Recv OpenSyn. Decoding error.",
                Some(Reason::Malformed),
            ),
            ("Received invalid message instead of an InitSyn", None),
            ("New transport link accepted from a1 to b2", None),
        ] {
            assert_eq!(Reason::of_error(message), want, "{message}");
        }
    }

    #[test]
    fn the_init_syn_gives_the_remote_address_and_zenoh_id() {
        let m = "Establishment Accept InitSyn: tcp/127.0.0.1:7447 => tcp/127.0.0.1:53422. \
                 Received: TransportMessage { body: InitSyn(InitSyn { version: 9, whatami: \
                 Client, zid: 9f3ac1, resolution: Resolution(42) }) }";
        assert_eq!(
            Hello::parse(m),
            Some(Hello {
                from: Some("127.0.0.1:53422".into()),
                zid: Some("9f3ac1".into()),
            })
        );
        let v6 =
            "Establishment Accept InitSyn: tcp/[::1]:7447 => tcp/[::1]:5000?prio=1. Received: x";
        assert_eq!(
            Hello::parse(v6).and_then(|h| h.from),
            Some("[::1]:5000".into())
        );
        assert_eq!(Hello::parse("Establishment Accept OpenSyn: a => b"), None);
    }

    #[test]
    fn an_address_is_logged_once_then_counted_and_forgotten_when_quiet() {
        let mut t = Tally::default();
        let first = t.record(refusal("10.0.0.7:4000", Reason::WrongPassword));
        assert!(first.as_deref().is_some_and(
            |l| l.contains("refused login from 10.0.0.7:4000 (zenoh id a1b2): wrong password")
        ));
        // Another port of the same host, and another host.
        assert_eq!(
            t.record(refusal("10.0.0.7:4001", Reason::WrongPassword)),
            None
        );
        assert_eq!(
            t.record(refusal("10.0.0.7:4002", Reason::UnknownUser)),
            None
        );
        assert!(t
            .record(refusal("10.0.0.8:4000", Reason::NoLogin))
            .is_some());
        assert_eq!(
            t.flush(),
            [
                "refused logins from 10.0.0.7: 2 more (wrong password 1, unknown user 1), \
              the last from 10.0.0.7:4002 (zenoh id a1b2)"
            ]
        );
        // 10.0.0.7 is still counted; 10.0.0.8 had nothing more and is forgotten.
        assert_eq!(
            t.record(refusal("10.0.0.7:4003", Reason::WrongPassword)),
            None
        );
        assert!(t.flush()[0].contains("10.0.0.7: 1 more"));
        assert!(t.flush().is_empty());
        assert!(t
            .record(refusal("10.0.0.7:4004", Reason::WrongPassword))
            .is_some());
        assert!(t
            .record(refusal("10.0.0.8:4001", Reason::NoLogin))
            .is_some());
    }

    #[test]
    fn many_addresses_share_one_entry_beyond_the_limit() {
        let mut t = Tally::default();
        let logged = (0..MAX_PEERS + 50)
            .filter(|i| {
                let from = format!("10.{}.{}.1:1", i / 256, i % 256);
                t.record(refusal(&from, Reason::WrongPassword)).is_some()
            })
            .count();
        assert_eq!(logged, MAX_PEERS + 1);
        assert!(t
            .flush()
            .iter()
            .any(|l| l.contains("other addresses: 49 more")));
    }

    /// The layer in a subscriber, fed zenoh's events from tasks as zenoh's accept tasks emit
    /// them: refusals are tied to their links by task, accepted links are not refusals.
    #[tokio::test]
    async fn the_layer_ties_a_refusal_to_its_link_by_task() {
        use tracing_subscriber::layer::SubscriberExt;
        let refusals = Refusals::default();
        let subscriber = tracing_subscriber::registry().with(refusals.layer());
        let _guard = tracing::subscriber::set_default(subscriber);
        // A current-thread runtime: the tasks run on this thread, under its default subscriber.
        let accept = |port: u16, zid: &'static str, end: &'static str| {
            tokio::spawn(async move {
                tracing::trace!(
                    target: ACCEPT_TARGET,
                    "Establishment Accept InitSyn: tcp/127.0.0.1:7447 => tcp/127.0.0.1:{port}. \
                     Received: InitSyn {{ zid: {zid}, batch_size: 1 }}"
                );
                tokio::task::yield_now().await;
                tracing::debug!(target: ACCEPT_TARGET, "{end}");
            })
        };
        let a = accept(
            5001,
            "aa11",
            "UsrPwd extension - Recv OpenSyn. Invalid password.",
        );
        let b = accept(
            5002,
            "bb22",
            "New transport link accepted from bb22 to cc33",
        );
        let c = accept(
            5003,
            "cc33",
            "UsrPwd extension - Recv InitSyn. Expected extension.",
        );
        for t in [a, b, c] {
            t.await.expect("the task ends");
        }
        // Another target is not seen.
        tracing::debug!(target: "other", "UsrPwd extension - Recv OpenSyn. Invalid user.");
        let mut state = refusals.shared.state();
        assert!(state.pending.is_empty());
        // The runtime decides which refusal comes first: that one is logged, the other counted,
        // each with its own address, zenoh id and reason; the accepted link is neither.
        let (a, c) = (
            ("127.0.0.1:5001 (zenoh id aa11)", "wrong password"),
            ("127.0.0.1:5003 (zenoh id cc33)", "no login offered"),
        );
        let (first, then) = if state.lines.iter().any(|l| l.contains(a.0)) {
            (a, c)
        } else {
            (c, a)
        };
        assert_eq!(
            state.lines,
            [format!(
                "refused login from {}: {}; more from 127.0.0.1 are counted, one line every 10 s",
                first.0, first.1
            )]
        );
        assert_eq!(
            state.tally.flush(),
            [format!(
                "refused logins from 127.0.0.1: 1 more ({} 1), the last from {}",
                then.1, then.0
            )]
        );
    }
}
