//! The live page's HTTP API: server-sent events from the hub (a slow page
//! loses its oldest readings, counted, and never blocks the daemon; a late
//! page gets the current state at once), and the recalibrate POST, in
//! process against a hub and through the real `fieldcal run`.

mod common;

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::daemon::{Daemon, replay_config};
use common::http::{Events, live_address, request};
use fieldcal::daemon::http::{ConnectionLimits, PAGE, router, serve, serve_with};
use fieldcal::daemon::publish::{ClientCommand, Hub, Lane, ReplyTo, error_line};
use serde_json::{Value, json};
use tokio::sync::{mpsc, watch};

const T: Duration = Duration::from_secs(30);

/// Serves the page's routes for `hub` on a free loopback port.
async fn start(hub: &Hub) -> (String, mpsc::Receiver<(ClientCommand, ReplyTo)>) {
    let (tx, rx) = mpsc::channel(64);
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let (stop_tx, stop) = watch::channel(false);
    let app = router(hub.clone(), tx, &common::http::page_config());
    tokio::spawn(async move {
        let _keep = stop_tx;
        serve(listener, app, stop).await
    });
    (addr, rx)
}

/// [`start`] with chosen connection limits.
async fn start_with(hub: &Hub, limits: ConnectionLimits) -> String {
    let (tx, rx) = mpsc::channel(64);
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let (stop_tx, stop) = watch::channel(false);
    let app = router(hub.clone(), tx, &common::http::page_config());
    tokio::spawn(async move {
        let _keep = (stop_tx, rx);
        serve_with(listener, app, stop, limits).await
    });
    addr
}

/// Seconds until the server closes a connection on which the client sends
/// nothing (EOF or reset), or `None` after `within`.
fn closed_after(stream: &mut std::net::TcpStream, within: Duration) -> Option<f64> {
    use std::io::Read as _;
    let start = Instant::now();
    stream.set_read_timeout(Some(within)).unwrap();
    let mut buf = [0u8; 256];
    match stream.read(&mut buf) {
        Ok(0) => Some(start.elapsed().as_secs_f64()),
        Ok(_) => panic!("the server sent bytes on a connection that asked nothing"),
        Err(e)
            if matches!(
                e.kind(),
                std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
            ) =>
        {
            None
        }
        Err(_) => Some(start.elapsed().as_secs_f64()),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_connections_are_bounded_and_closed_so_they_cannot_use_up_descriptors() {
    let hub = Hub::new(8);
    let idle = Duration::from_millis(400);
    let limits = ConnectionLimits {
        requests: 2,
        idle,
        head: idle,
    };
    let addr = start_with(&hub, limits).await;
    let (times, answer) = blocking(move || {
        // Four clients connect and send nothing: two are served, one waits
        // for room and one in the kernel's backlog (no descriptor of the
        // daemon's); each is closed when its head does not come.
        let mut idle_clients: Vec<_> = (0..4)
            .map(|_| std::net::TcpStream::connect(&addr).unwrap())
            .collect();
        let times: Vec<Option<f64>> = idle_clients
            .iter_mut()
            .map(|c| closed_after(c, Duration::from_secs(10)))
            .collect();
        // A real request afterwards is answered.
        let answer = request(&addr, "GET", "/api/config", None, Duration::from_secs(20));
        (times, answer)
    })
    .await;
    for (i, t) in times.iter().enumerate() {
        let t = t.unwrap_or_else(|| panic!("idle connection {i} was still open after 10 s"));
        assert!(t < 5.0, "idle connection {i} closed after {t} s");
    }
    assert_eq!(answer.status, 200, "{}", answer.text());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_event_stream_gives_its_connection_permit_back_to_the_page_requests() {
    let hub = Hub::new(8);
    let addr = start_with(
        &hub,
        ConnectionLimits {
            requests: 1,
            idle: Duration::from_secs(60),
            ..ConnectionLimits::default()
        },
    )
    .await;
    let (streaming, elapsed, answer) = blocking(move || {
        let events = Events::connect(&addr, "/api/events");
        let start = Instant::now();
        // The only permit went to the event stream; the hub counts it now.
        let answer = request(&addr, "GET", "/api/config", None, Duration::from_secs(20));
        (events, start.elapsed(), answer)
    })
    .await;
    assert_eq!(answer.status, 200, "{}", answer.text());
    assert!(
        elapsed < Duration::from_secs(10),
        "answered after {elapsed:?}"
    );
    drop(streaming);
}

async fn blocking<R: Send + 'static>(f: impl FnOnce() -> R + Send + 'static) -> R {
    tokio::time::timeout(T * 2, tokio::task::spawn_blocking(f))
        .await
        .expect("the client finished in time")
        .unwrap()
}

async fn wait_until(what: &str, mut cond: impl FnMut() -> bool) {
    let deadline = Instant::now() + T;
    while !cond() {
        assert!(
            Instant::now() < deadline,
            "{what} did not happen within {T:?}"
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

fn reading(i: usize, pad: usize) -> Arc<str> {
    Arc::from(
        json!({"class": "READING", "sensor": "compass", "time": i as f64, "raw": [i as f64, 0.0], "pad": "x".repeat(pad)})
            .to_string(),
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_slow_page_loses_its_oldest_readings_counted_and_never_blocks_the_daemon() {
    const QUEUE: usize = 8;
    // 30 MB of readings: far more than loopback socket buffers hold.
    const N: usize = 30_000;
    let hub = Hub::new(QUEUE);
    let (addr, _commands) = start(&hub).await;
    let events = {
        let addr = addr.clone();
        blocking(move || Events::connect(&addr, "/api/events")).await
    };
    assert_eq!(events.status, 200);
    wait_until("the page subscribed", || hub.stats().subscribers == 1).await;

    // The page does not read. Publishing never waits for it.
    let started = Instant::now();
    for i in 0..N {
        hub.publish(Lane::Reading, reading(i, 1000));
        if i % 1000 == 0 {
            tokio::task::yield_now().await;
        }
    }
    let publishing = started.elapsed();
    assert!(
        publishing < Duration::from_secs(5),
        "publishing took {publishing:?}"
    );
    let subs = hub.subscribers();
    assert_eq!(subs.len(), 1);
    assert!(subs[0].peer.starts_with("http 127.0.0.1:"), "{subs:?}");
    assert!(subs[0].queued <= QUEUE, "queue not bounded: {subs:?}");
    assert!(subs[0].dropped > 0, "nothing dropped: {subs:?}");
    hub.publish(Lane::Control, Arc::from(r#"{"class":"END"}"#));

    // Now it reads: every reading either arrives, in order, or was counted
    // as dropped; the newest one arrives.
    let (received, last, told) = blocking(move || {
        let mut events = events;
        let lines = events.until(T, |v| v["class"] == "END");
        let mut received = 0usize;
        let mut last = None;
        let mut told = None;
        for v in &lines {
            match v["class"].as_str() {
                Some("READING") => {
                    let i = v["time"].as_f64().unwrap() as usize;
                    assert!(
                        last.is_none_or(|l| i > l),
                        "out of order: {i} after {last:?}"
                    );
                    last = Some(i);
                    received += 1;
                }
                Some("SUBSCRIBER") => told = v["dropped"].as_u64(),
                _ => {}
            }
        }
        (received, last, told)
    })
    .await;
    let dropped = hub.stats().dropped;
    assert!(dropped > 0);
    assert_eq!(told, Some(dropped), "the page is told its drops");
    assert_eq!(received as u64 + dropped, N as u64);
    assert_eq!(last, Some(N - 1), "the newest reading is kept");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_late_page_gets_the_current_state_at_once_then_the_live_lines() {
    let hub = Hub::new(64);
    hub.keep_for_replay(5);
    let (addr, _commands) = start(&hub).await;
    let cal = |sensor: &str, id: Option<u64>| -> Arc<str> {
        let mut v =
            json!({"class": "CALIBRATION", "sensor": sensor, "accepted": id.is_some(), "n": 200});
        if let Some(id) = id {
            v["id"] = json!(id);
        }
        Arc::from(v.to_string())
    };
    hub.publish(Lane::Control, cal("compass", Some(1)));
    hub.publish(Lane::Control, Arc::from(r#"{"class":"STATUS","time":1.0}"#));
    for i in 0..10 {
        hub.publish(Lane::Reading, reading(i, 0));
    }
    hub.publish(Lane::Control, cal("compass", None));
    hub.publish(Lane::Control, cal("accel", Some(4)));
    hub.publish(Lane::Control, error_line("not kept"));
    hub.publish(Lane::Control, Arc::from(r#"{"class":"STATUS","time":2.0}"#));

    let lines = {
        let addr = addr.clone();
        blocking(move || {
            let mut events = Events::connect(&addr, "/api/events");
            events.until(T, |v| v["class"] == "STATUS")
        })
        .await
    };
    let summary: Vec<String> = lines
        .iter()
        .map(|v| match v["class"].as_str().unwrap() {
            "CALIBRATION" => format!("{} {}", v["sensor"].as_str().unwrap(), v["id"]),
            "READING" => format!("r{}", v["time"]),
            "STATUS" => format!("status {}", v["time"]),
            other => other.to_owned(),
        })
        .collect();
    assert_eq!(
        summary,
        [
            "compass 1",
            "r5.0",
            "r6.0",
            "r7.0",
            "r8.0",
            "r9.0",
            "compass null",
            "accel 4",
            "status 2.0"
        ]
    );

    // A page without the replay (the hub keeps nothing) starts with the
    // live lines only; and the replaying page then gets each live line once.
    let hub2 = Hub::new(64);
    let (addr2, _c2) = start(&hub2).await;
    hub2.publish(Lane::Control, cal("compass", Some(1)));
    let client = blocking(move || Events::connect(&addr2, "/api/events")).await;
    wait_until("the second page subscribed", || {
        hub2.stats().subscribers == 1
    })
    .await;
    hub2.publish(Lane::Reading, reading(42, 0));
    let first = blocking(move || {
        let mut client = client;
        client.next_lines().unwrap()
    })
    .await;
    assert_eq!(first.len(), 1, "{first:?}");
    assert_eq!(first[0]["time"], 42.0);
}

/// A stand-in for the daemon's loop: answers as `run` does (an ERROR for an
/// unknown sensor, then a STATUS) and records the commands.
fn fake_loop(
    mut rx: mpsc::Receiver<(ClientCommand, ReplyTo)>,
    answer: bool,
) -> Arc<Mutex<Vec<ClientCommand>>> {
    let seen = Arc::new(Mutex::new(Vec::new()));
    let record = seen.clone();
    tokio::spawn(async move {
        while let Some((command, reply)) = rx.recv().await {
            record.lock().unwrap().push(command.clone());
            if !answer {
                continue;
            }
            match &command {
                ClientCommand::Recalibrate { sensor: Some(name) }
                | ClientCommand::Rollback { sensor: Some(name) }
                    if name != "compass" =>
                {
                    reply.send(error_line(&format!("no sensor named '{name}'")));
                }
                ClientCommand::Rollback { sensor: Some(_) } => reply.send(error_line(
                    "sensor 'compass' cannot roll back: no earlier calibration is kept",
                )),
                _ => {}
            }
            reply.send(Arc::from(
                r#"{"class":"STATUS","sensors":[{"sensor":"compass","state":"recalibrating"}]}"#,
            ));
        }
    });
    seen
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn recalibrate_sends_the_clients_command_and_answers_errors_clearly() {
    let hub = Hub::new(64);
    let (addr, rx) = start(&hub).await;
    let seen = fake_loop(rx, true);
    let post = |body: Option<&'static str>| {
        let addr = addr.clone();
        blocking(move || request(&addr, "POST", "/api/recalibrate", body, T))
    };

    let r = post(Some(r#"{"sensor":"compass"}"#)).await;
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(
        r.header("content-type").as_deref(),
        Some("application/json")
    );
    let body = r.json();
    assert_eq!(body["recalibrating"], "compass");
    assert_eq!(body["status"]["sensors"][0]["state"], "recalibrating");

    let r = post(None).await;
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(r.json()["recalibrating"], Value::Null);

    let r = post(Some(r#"{"sensor":"nope"}"#)).await;
    assert_eq!(r.status, 404, "{}", r.text());
    assert_eq!(r.json()["error"], "no sensor named 'nope'");

    for bad in ["compass", r#"{"sensor":3}"#, r#"{"name":"compass"}"#] {
        let r = post(Some(bad)).await;
        assert_eq!(r.status, 400, "{bad}: {}", r.text());
        assert!(
            r.json()["error"]
                .as_str()
                .unwrap()
                .contains(r#"{"sensor":"NAME"}"#)
        );
    }
    assert_eq!(
        *seen.lock().unwrap(),
        [
            ClientCommand::Recalibrate {
                sensor: Some("compass".into())
            },
            ClientCommand::Recalibrate { sensor: None },
            ClientCommand::Recalibrate {
                sensor: Some("nope".into())
            },
        ],
        "bad bodies send nothing"
    );
    // The answer's mailbox is not a subscriber.
    assert_eq!(hub.stats().subscribers, 0);

    // A loop that never answers: 504 after the answer timeout.
    let hub = Hub::new(64);
    let (addr, rx) = start(&hub).await;
    let _seen = fake_loop(rx, false);
    let r = blocking(move || request(&addr, "POST", "/api/recalibrate", None, T)).await;
    assert_eq!(r.status, 504, "{}", r.text());
    assert!(
        r.json()["error"]
            .as_str()
            .unwrap()
            .contains("did not answer")
    );

    // A daemon that takes no more commands: 503.
    let hub = Hub::new(64);
    let (addr, rx) = start(&hub).await;
    drop(rx);
    let r = blocking(move || request(&addr, "POST", "/api/recalibrate", None, T)).await;
    assert_eq!(r.status, 503, "{}", r.text());
    assert!(
        r.json()["error"]
            .as_str()
            .unwrap()
            .contains("shutting down")
    );
}

/// `POST /api/rollback`: the client's rollback command with the same
/// body and answers; 409 when the sensor keeps no earlier calibration.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rollback_sends_the_clients_command_and_says_when_there_is_nothing_to_return_to() {
    let hub = Hub::new(64);
    let (addr, rx) = start(&hub).await;
    let seen = fake_loop(rx, true);
    let post = |body: Option<&'static str>| {
        let addr = addr.clone();
        blocking(move || request(&addr, "POST", "/api/rollback", body, T))
    };
    let r = post(None).await;
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(r.json()["rolled_back"], Value::Null);
    assert_eq!(r.json()["status"]["sensors"][0]["sensor"], "compass");
    let r = post(Some(r#"{"sensor":"compass"}"#)).await;
    assert_eq!(r.status, 409, "{}", r.text());
    assert_eq!(
        r.json()["error"],
        "sensor 'compass' cannot roll back: no earlier calibration is kept"
    );
    let r = post(Some(r#"{"sensor":"nope"}"#)).await;
    assert_eq!(r.status, 404, "{}", r.text());
    let r = post(Some("compass")).await;
    assert_eq!(r.status, 400, "{}", r.text());
    assert_eq!(
        *seen.lock().unwrap(),
        [
            ClientCommand::Rollback { sensor: None },
            ClientCommand::Rollback {
                sensor: Some("compass".into())
            },
            ClientCommand::Rollback {
                sensor: Some("nope".into())
            },
        ]
    );
}

#[test]
fn the_page_loads_nothing_from_the_network() {
    // No CDN: no external script, style, font or image.
    for needle in ["http://", "https://", "//cdn", "@import", "<link", "src="] {
        assert!(!PAGE.contains(needle), "the page contains {needle:?}");
    }
}

/// `fieldcal run` end to end: the page, its config, a late page's state,
/// and the button's POST through the daemon's own command loop.
#[test]
fn the_daemon_serves_the_page_its_state_and_the_recalibrate_button() {
    let dir = tempfile::tempdir().unwrap();
    // Two turns in 20 s played at 2x: calibrated after about 5 s, then 5 s
    // more of corrected readings.
    let capture = common::repo_path("tests/data/falcon_garbage.fcap");
    let config = replay_config(
        dir.path(),
        &capture,
        "2.0",
        "stdout = false\nhttp = \"127.0.0.1:0\"\nrecalibrate_from = [\"unix\", \"tcp\", \"http\"]",
    );
    let daemon = Daemon::start(&config, &[]);
    let log = daemon.wait_for_log(T, "live page at http://");
    let addr = live_address(&log);

    let page = request(&addr, "GET", "/", None, T);
    assert_eq!(page.status, 200);
    assert_eq!(
        page.header("content-type").as_deref(),
        Some("text/html; charset=utf-8")
    );
    assert!(page.text().contains("<title>fieldcal live</title>"));
    let cfg = request(&addr, "GET", "/api/config", None, T).json();
    assert_eq!(cfg["sensors"][0]["name"], "compass");
    assert_eq!(cfg["sensors"][0]["limits"]["max_rms"], 0.05);
    assert_eq!(cfg["sensors"][0]["rotation"]["max_gap_deg"], 30.0);
    let missing = request(&addr, "GET", "/nothing", None, T);
    assert_eq!(missing.status, 404);
    assert!(missing.text().contains("/api/events"));

    let mut early = Events::connect(&addr, "/api/events");
    let lines = early.until(T, |v| v["class"] == "CALIBRATION" && v["accepted"] == true);
    let calibration = lines.last().unwrap().clone();
    assert!(lines.iter().any(|v| v["class"] == "READING"));
    assert!(lines.iter().any(|v| v["class"] == "STATUS"
        && v["sensors"][0]["rotation"]["coverage_pct"].as_f64() > Some(50.0)));

    // A page opened after the calibration gets it, the readings so far and
    // a STATUS at once, before any new reading.
    let mut late = Events::connect(&addr, "/api/events");
    let connected = Instant::now();
    let seen = std::cell::Cell::new((false, false));
    let first = late.until(Duration::from_secs(5), |v| {
        let (cal, status) = seen.get();
        let now = (cal || *v == calibration, status || v["class"] == "STATUS");
        seen.set(now);
        now == (true, true)
    });
    // Waiting would mean the next rotation's CALIBRATION (5 s at 2x); 3 s
    // leaves room for a loaded machine.
    assert!(connected.elapsed() < Duration::from_secs(3), "not at once");
    let replayed = first.iter().filter(|v| v["class"] == "READING").count();
    assert!(
        (100..=fieldcal::daemon::http::REPLAY_READINGS).contains(&replayed),
        "{replayed} readings replayed"
    );
    let r = request(
        &addr,
        "POST",
        "/api/recalibrate",
        Some(r#"{"sensor":"nope"}"#),
        T,
    );
    assert_eq!(r.status, 404);
    assert_eq!(r.json()["error"], "no sensor named 'nope'");
    let r = request(
        &addr,
        "POST",
        "/api/recalibrate",
        Some(r#"{"sensor":"compass"}"#),
        T,
    );
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(r.json()["status"]["sensors"][0]["state"], "recalibrating");
    // Every page sees the sensor collecting again.
    late.until(T, |v| {
        v["class"] == "STATUS" && v["sensors"][0]["state"] == "recalibrating"
    });
    drop(daemon);
}

/// A port already held stops the start with a message that names the key.
#[test]
fn a_live_page_address_in_use_stops_the_start_and_says_what_to_do() {
    let dir = tempfile::tempdir().unwrap();
    let held = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = held.local_addr().unwrap();
    let capture = common::repo_path("tests/data/falcon_turn.fcap");
    let config = replay_config(
        dir.path(),
        &capture,
        "\"max\"",
        &format!("stdout = false\nhttp = \"{addr}\""),
    );
    let r = common::run(&["run", "--config", config.to_str().unwrap()]);
    assert_ne!(r.code, Some(0), "{}", r.stderr);
    assert!(
        r.stderr
            .contains(&format!("cannot listen for the live page on {addr}"))
            && r.stderr.contains("[outputs] http"),
        "{}",
        r.stderr
    );
}
