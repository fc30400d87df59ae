//! The live page (`[outputs] http`): one HTML page, embedded in the binary
//! and needing nothing from the network, that shows each sensor's points as
//! they arrive around the fitted circle, the rotation's coverage with the
//! missing headings, the acceptance numbers against their limits, the last
//! CALIBRATION, and a button that recalibrates.
//!
//! # API
//! - `GET /`: the page.
//! - `GET /api/config`: the sensors with their model, acceptance limits
//!   and rotation settings, and how many points the page keeps.
//! - `GET /api/events`: server-sent events. Each event's data is one or more
//!   of the daemon's JSON lines (READING, STATUS, CALIBRATION, ERROR), one a
//!   line. The connection is a subscriber of the same [`Hub`] as the TCP
//!   and Unix-socket clients, with the same bounded queue: a slow browser
//!   loses its oldest readings (counted in STATUS `dropped`, and told to the
//!   page in a `{"class":"SUBSCRIBER","id":..,"dropped":..}` line), never
//!   slows the daemon. It starts with the current state: each sensor's last
//!   accepted and last CALIBRATION, the latest readings, the last STATUS.
//!   At `[outputs] max_subscribers` an event stream is refused with 503.
//! - `POST /api/recalibrate`: body empty (every sensor) or
//!   `{"sensor":"NAME"}`, with `"token":"..."` where `[outputs] token_file`
//!   is set. The same command a TCP client sends; answers 200 with the
//!   daemon's STATUS reply, 400 for a bad body, 403 when the live page may
//!   not recalibrate (`"http"` not in `[outputs] recalibrate_from` and no
//!   matching token), 404 for an unknown sensor, 503 when the daemon takes
//!   no commands, 504 when it did not answer in time. `/api/config` says
//!   whether the button works (`"recalibrate": {"allowed", "token",
//!   "reason"}`), and the page disables it with the reason otherwise.
//! - `POST /api/rollback`: the same body, rights and answers for
//!   `{"command":"rollback"}` (back to each sensor's previous
//!   calibration), with 409 when a sensor keeps no earlier calibration.
//!
//! Connections are bounded ([`conn`]): at most [`conn::PAGE_REQUESTS`]
//! that are not event streams, each closed after [`conn::IDLE`] with
//! nothing read or written.

use std::convert::Infallible;
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::body::Bytes;
use axum::extract::{ConnectInfo, State};
use axum::http::{Method, StatusCode, header};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use serde_json::{Value, json};
use tokio::sync::{mpsc, watch};

use super::{Access, ClientCommand, Hub, MAX_COMMAND_LEN, Origin, ReplyTo, SubscribeError};
use crate::daemon::config::{Config, SensorGeometry};
use crate::model::effects::{model_name, parse_list};
use conn::{BoundedListener, Peer};
pub use conn::{ConnectionLimits, FIRST_BYTES, WAITING};

pub mod conn;
pub mod guard;

/// The page: HTML, CSS and script in one file, drawn by hand on a canvas.
pub const PAGE: &str = include_str!("live.html");

/// Readings the hub keeps for a page that connects late, so it draws the
/// rotation so far at once: a default 36-sector rotation at 3 to 10 samples
/// a sector is 100 to 360 readings; 2000 also covers several sensors.
pub const REPLAY_READINGS: usize = 2000;
/// Points the page keeps per sensor; older ones are forgotten, so a page
/// left open for days stays small.
pub const PAGE_POINTS: usize = 3000;
/// Lines sent in one server-sent event at most.
const EVENT_LINES: usize = 256;
/// How long the recalibrate request waits for the daemon's answer; the
/// daemon's loop answers within one reading's handling.
const ANSWER_TIMEOUT: Duration = Duration::from_secs(3);
/// Lines of the daemon's answer read at most before giving up on finding
/// its STATUS.
const ANSWER_LINES: usize = 64;

#[derive(Clone)]
struct App {
    hub: Hub,
    commands: mpsc::Sender<(ClientCommand, ReplyTo)>,
    /// `/api/config`'s body, replaced when a reload changes the sensors.
    config_json: watch::Receiver<Arc<str>>,
    access: Access,
}

/// The daemon's handle on what `/api/config` serves: a reload that changes
/// the sensors (their model, limits, rotation or sphere rules) updates it,
/// so a page opened after the reload judges numbers by the limits in force.
#[derive(Debug)]
pub struct PageConfig(watch::Sender<Arc<str>>);

impl PageConfig {
    /// Serves `config`'s sensors from now on.
    pub fn update(&self, config: &Config) {
        let body: Arc<str> = Arc::from(page_config(config).to_string());
        self.0.send_if_modified(|old| {
            let changed = *old != body;
            if changed {
                *old = body;
            }
            changed
        });
    }
}

/// What `/api/config` serves: the sensors with the limits their fits are
/// judged by, for the page to show each number against its limit.
pub fn page_config(config: &Config) -> Value {
    let sensors: Vec<Value> = config
        .sensors
        .iter()
        .map(|s| match &s.geometry {
            SensorGeometry::Sphere(three) => json!({
                "name": s.name,
                "source": s.source,
                "axes": 3,
                "model": three.model.name(),
                "sphere": three.sphere,
                "tilt": three.tilt.as_ref().map(|t| t.sensor.as_str()),
            }),
            SensorGeometry::Plane(plane) => json!({
                "name": s.name,
                "source": s.source,
                "axes": 2,
                "model": parse_list(&plane.effects.join(","))
                    .map(|e| model_name(&e))
                    .unwrap_or_else(|_| plane.effects.join("+")),
                "limits": plane.limits,
                "rotation": plane.rotation,
            }),
        })
        .collect();
    let access = &config.outputs.access;
    let allowed = access.allows(Origin::Http);
    let token = !allowed && access.token.as_ref().is_some_and(|t| !t.is_empty());
    let reason = (!allowed).then(|| {
        if token {
            "the live page needs the token of [outputs] token_file to recalibrate".to_owned()
        } else {
            access
                .check_recalibrate(Origin::Http, None)
                .err()
                .unwrap_or_default()
        }
    });
    json!({
        "sensors": sensors,
        "max_points": PAGE_POINTS,
        // The equal-area regions of the sphere (elevation low, high;
        // azimuth low, high; degrees), for the map of a 3-axis sensor.
        "sphere_regions": (0..crate::model::sphere::REGIONS)
            .map(|k| {
                let r = crate::model::sphere::region(k);
                [r.elevation_deg.0, r.elevation_deg.1, r.azimuth_deg.0, r.azimuth_deg.1]
            })
            .collect::<Vec<_>>(),
        "recalibrate": { "allowed": allowed, "token": token, "reason": reason },
    })
}

/// The page's routes, served by [`serve`]. `commands` is the daemon's
/// command channel, as the TCP clients use it.
pub fn router(
    hub: Hub,
    commands: mpsc::Sender<(ClientCommand, ReplyTo)>,
    config: &Config,
) -> Router {
    router_with_config(hub, commands, config).0
}

/// [`router`], and the handle that updates `/api/config` after a reload.
pub fn router_with_config(
    hub: Hub,
    commands: mpsc::Sender<(ClientCommand, ReplyTo)>,
    config: &Config,
) -> (Router, PageConfig) {
    let (tx, rx) = watch::channel(Arc::from(page_config(config).to_string()));
    let app = App {
        hub,
        commands,
        config_json: rx,
        access: config.outputs.access.clone(),
    };
    let router = Router::new()
        .route("/", get(page))
        .route("/api/config", get(api_config))
        .route("/api/events", get(events))
        .route("/api/recalibrate", post(recalibrate))
        .route("/api/rollback", post(rollback))
        .fallback(not_found)
        .with_state(app)
        .layer(axum::middleware::from_fn_with_state(
            guard::Hosts::new(&http_hosts(config)),
            guard::guard,
        ));
    (router, PageConfig(tx))
}

/// The names the page answers to beside IP addresses and this machine's
/// own (`[outputs] http_hosts`).
fn http_hosts(config: &Config) -> Vec<String> {
    config
        .outputs
        .outputs
        .iter()
        .find_map(|o| match o {
            crate::daemon::output_kinds::Output::Http(h) => Some(h.hosts.clone()),
            _ => None,
        })
        .unwrap_or_default()
}

/// Serves `router` on `listener` until `shutdown` turns true, with the
/// default [`ConnectionLimits`]. Event streams end when the hub closes.
pub async fn serve(
    listener: tokio::net::TcpListener,
    router: Router,
    shutdown: watch::Receiver<bool>,
) {
    serve_with(listener, router, shutdown, ConnectionLimits::default()).await
}

/// [`serve`] with chosen connection limits.
pub async fn serve_with(
    listener: tokio::net::TcpListener,
    router: Router,
    mut shutdown: watch::Receiver<bool>,
    limits: ConnectionLimits,
) {
    let listener = BoundedListener::new(listener, limits);
    let service = router.into_make_service_with_connect_info::<Peer>();
    let stop = async move {
        while !*shutdown.borrow_and_update() {
            if shutdown.changed().await.is_err() {
                std::future::pending::<()>().await;
            }
        }
    };
    if let Err(e) = axum::serve(listener, service)
        .with_graceful_shutdown(stop)
        .await
    {
        tracing::warn!(error = %e, "the live page's server stopped");
    }
}

async fn page() -> Response {
    (
        [
            (header::CONTENT_TYPE, "text/html; charset=utf-8"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        PAGE,
    )
        .into_response()
}

async fn api_config(State(app): State<App>) -> Response {
    let body = app.config_json.borrow().to_string();
    json_text(StatusCode::OK, body)
}

async fn not_found() -> Response {
    error(
        StatusCode::NOT_FOUND,
        "no such page: the live page is at /, its API at /api/config, /api/events (GET), /api/recalibrate and /api/rollback (POST)",
    )
}

async fn events(
    State(app): State<App>,
    method: Method,
    ConnectInfo(conn): ConnectInfo<Peer>,
) -> Response {
    // HEAD: the stream's headers and nothing more. No subscriber is made
    // and the connection keeps its permit, so held HEAD requests count
    // among the page's connections like any other short request.
    if method == Method::HEAD {
        return (
            [
                (header::CONTENT_TYPE, "text/event-stream"),
                (header::CACHE_CONTROL, "no-store"),
            ],
            (),
        )
            .into_response();
    }
    let peer = conn.addr;
    let sub = match app
        .hub
        .try_subscribe(format!("http {peer}"), Origin::Http, true)
    {
        Ok(sub) => {
            // The hub counts it now, among the subscribers.
            conn.release();
            sub
        }
        Err(e @ (SubscribeError::Closed | SubscribeError::Full { .. })) => {
            return error(StatusCode::SERVICE_UNAVAILABLE, &e.to_string());
        }
    };
    tracing::debug!(id = sub.id(), %peer, "live page connected");
    let stream = futures_util::stream::unfold((sub, 0u64), |(mut sub, told)| async move {
        let mut lines = Vec::new();
        if !sub.recv(&mut lines, EVENT_LINES).await {
            return None;
        }
        // The page learns of its own drops before the lines that follow them.
        let dropped = sub.dropped();
        let mut data = String::new();
        if dropped != told {
            data.push_str(
                &json!({"class": "SUBSCRIBER", "id": sub.id(), "dropped": dropped}).to_string(),
            );
            data.push('\n');
        }
        for line in &lines {
            data.push_str(line);
            data.push('\n');
        }
        data.pop();
        Some((
            Ok::<_, Infallible>(Event::default().data(data)),
            (sub, dropped),
        ))
    });
    Sse::new(stream)
        .keep_alive(KeepAlive::default())
        .into_response()
}

/// Why a recalibrate body was refused.
#[cfg(test)]
fn parse_recalibrate(body: &[u8]) -> Result<Option<String>, String> {
    parse_recalibrate_body(body).map(|(sensor, _)| sensor)
}

/// The sensor and the token of a recalibrate (or rollback) body.
fn parse_recalibrate_body(body: &[u8]) -> Result<(Option<String>, Option<String>), String> {
    const ALLOWED: &str = r#"send no body for every sensor, or {"sensor":"NAME"} for one (with "token":"..." where one is configured)"#;
    if body.len() > MAX_COMMAND_LEN {
        return Err(format!(
            "the body is longer than {MAX_COMMAND_LEN} bytes; {ALLOWED}"
        ));
    }
    if body.iter().all(u8::is_ascii_whitespace) {
        return Ok((None, None));
    }
    let value: Value = serde_json::from_slice(body)
        .map_err(|e| format!("the body is not JSON ({e}); {ALLOWED}"))?;
    let Value::Object(map) = value else {
        return Err(format!("the body is not a JSON object; {ALLOWED}"));
    };
    if let Some(key) = map
        .keys()
        .find(|k| !["sensor", "token"].contains(&k.as_str()))
    {
        return Err(format!("unknown field {key:?}; {ALLOWED}"));
    }
    let token = match map.get("token") {
        None => None,
        Some(Value::String(t)) => Some(t.clone()),
        Some(_) => return Err(format!("\"token\" must be a string; {ALLOWED}")),
    };
    match map.get("sensor") {
        None => Ok((None, token)),
        Some(Value::String(s)) if !s.is_empty() => Ok((Some(s.clone()), token)),
        Some(_) => Err(format!(
            "\"sensor\" must be a non-empty string naming a configured sensor; {ALLOWED}"
        )),
    }
}

async fn recalibrate(State(app): State<App>, body: Bytes) -> Response {
    command(app, body, false).await
}

async fn rollback(State(app): State<App>, body: Bytes) -> Response {
    command(app, body, true).await
}

/// A recalibrate (or, with `rollback`, a rollback) request: the client's
/// command, with the same rights, sent to the daemon's loop; its answer
/// (an ERROR, then a STATUS) becomes the response.
async fn command(app: App, body: Bytes, rollback: bool) -> Response {
    let (sensor, token) = match parse_recalibrate_body(&body) {
        Ok(parsed) => parsed,
        Err(message) => return error(StatusCode::BAD_REQUEST, &message),
    };
    if let Err(message) = app.access.check_recalibrate(Origin::Http, token.as_deref()) {
        return error(StatusCode::FORBIDDEN, &message);
    }
    let (what, done) = if rollback {
        ("rollback", "rolled_back")
    } else {
        ("recalibrate", "recalibrating")
    };
    let mut mailbox = app.hub.mailbox(format!("http {what}"));
    let command = if rollback {
        ClientCommand::Rollback {
            sensor: sensor.clone(),
        }
    } else {
        ClientCommand::Recalibrate {
            sensor: sensor.clone(),
        }
    };
    match tokio::time::timeout(
        ANSWER_TIMEOUT,
        app.commands.send((command, mailbox.reply_to())),
    )
    .await
    {
        Ok(Ok(())) => {}
        Ok(Err(_)) => {
            return error(
                StatusCode::SERVICE_UNAVAILABLE,
                "the daemon takes no commands now (it is shutting down)",
            );
        }
        Err(_) => {
            return error(
                StatusCode::SERVICE_UNAVAILABLE,
                "the daemon's command queue stayed full; try again",
            );
        }
    }
    // The loop answers with an ERROR for an unknown sensor, then a STATUS.
    let answer = tokio::time::timeout(ANSWER_TIMEOUT, async {
        let mut lines = Vec::new();
        let mut error_message = None;
        while lines.len() < ANSWER_LINES && mailbox.recv(&mut lines, ANSWER_LINES).await {
            for line in lines.drain(..) {
                let Ok(value) = serde_json::from_str::<Value>(&line) else {
                    continue;
                };
                match value["class"].as_str() {
                    Some("ERROR") => {
                        error_message = value["message"].as_str().map(str::to_owned);
                    }
                    Some("STATUS") => return Some((error_message, value)),
                    _ => {}
                }
            }
        }
        None
    })
    .await;
    match answer {
        Ok(Some((None, status))) => json_text(
            StatusCode::OK,
            json!({ done: sensor, "status": status }).to_string(),
        ),
        // An unknown sensor; for a rollback also one with no earlier
        // calibration kept, which the request cannot change: 409.
        Ok(Some((Some(message), _))) if rollback && !message.starts_with("no sensor named") => {
            error(StatusCode::CONFLICT, &message)
        }
        Ok(Some((Some(message), _))) => error(StatusCode::NOT_FOUND, &message),
        Ok(None) | Err(_) => error(
            StatusCode::GATEWAY_TIMEOUT,
            &format!("the daemon did not answer the {what} in time; see its log"),
        ),
    }
}

fn json_text(status: StatusCode, body: String) -> Response {
    (
        status,
        [
            (header::CONTENT_TYPE, "application/json"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        body,
    )
        .into_response()
}

fn error(status: StatusCode, message: &str) -> Response {
    json_text(status, json!({ "error": message }).to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recalibrate_bodies() {
        assert_eq!(parse_recalibrate(b""), Ok(None));
        assert_eq!(parse_recalibrate(b" \n"), Ok(None));
        assert_eq!(parse_recalibrate(b"{}"), Ok(None));
        assert_eq!(
            parse_recalibrate(br#"{"sensor":"compass"}"#),
            Ok(Some("compass".into()))
        );
        for (body, words) in [
            (&b"compass"[..], "not JSON"),
            (b"[1]", "not a JSON object"),
            (br#"{"sensor":""}"#, "non-empty string"),
            (br#"{"sensor":1}"#, "non-empty string"),
            (br#"{"sensr":"x"}"#, "unknown field \"sensr\""),
        ] {
            let err = parse_recalibrate(body).unwrap_err();
            assert!(
                err.contains(words) && err.contains(r#"{"sensor":"NAME"}"#),
                "{err}"
            );
        }
        let long = vec![b' '; MAX_COMMAND_LEN + 1];
        assert!(
            parse_recalibrate(&long)
                .unwrap_err()
                .contains("longer than")
        );
    }
}
