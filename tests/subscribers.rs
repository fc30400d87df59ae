//! Subscribers with limits and rights (issue 12, points 3 and 4): at most
//! `max_subscribers`, commands paced per subscriber, `recalibrate` only
//! from allowed listeners or with the token, a stdout that is never
//! evicted, duplicate keys refused, the bound port logged, the descriptor
//! reserve that keeps the state writer working, and memory given back
//! after a crowd leaves. In process against a hub, and through the real
//! `fieldcal run`.
//!
//! Waits poll for a condition with generous bounds, so a loaded machine
//! only makes them slower.

mod common;

use std::io::Read;
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::os::unix::process::CommandExt;
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::daemon::{Daemon, ask, errors, is_class, replay_config, write_config};
use fieldcal::daemon::publish::{
    ClientCommand, CommandError, Hub, Lane, Policy, ReplyTo, SubscribeError, parse_command,
};
use serde_json::Value;
use tokio::io::{AsyncBufReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{mpsc, watch};

const T: Duration = Duration::from_secs(30);

async fn bounded<F: std::future::Future>(f: F) -> F::Output {
    tokio::time::timeout(Duration::from_secs(90), f)
        .await
        .expect("test took too long")
}

async fn wait_for(what: &str, mut cond: impl FnMut() -> bool) {
    let start = Instant::now();
    while !cond() {
        assert!(start.elapsed() < T, "timed out waiting for {what}");
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
}

fn reading(i: usize, pad: usize) -> Arc<str> {
    format!(
        r#"{{"class":"READING","sensor":"compass","seq":{i},"pad":"{}"}}"#,
        "x".repeat(pad)
    )
    .into()
}

/// A hub serving TCP on a free loopback port.
async fn tcp_hub(
    queue: usize,
    policy: Policy,
) -> (
    Hub,
    std::net::SocketAddr,
    mpsc::Receiver<(ClientCommand, ReplyTo)>,
    watch::Sender<bool>,
) {
    let hub = Hub::with_policy(queue, 1024, policy);
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (tx, rx) = mpsc::channel(64);
    let (stop, stop_rx) = watch::channel(false);
    tokio::spawn({
        let hub = hub.clone();
        async move { hub.serve_tcp(listener, tx, stop_rx).await }
    });
    (hub, addr, rx, stop)
}

#[test]
fn a_command_object_with_a_key_twice_is_refused_naming_the_key() {
    let err = parse_command(br#"{"command":"status","command":"recalibrate"}"#);
    assert_eq!(err, Err(CommandError::DuplicateKey("command".into())));
    let message = err.unwrap_err().to_string();
    assert!(message.contains("\"command\" is given twice"), "{message}");
    assert_eq!(
        parse_command(br#"{"command":"recalibrate","sensor":"a","sensor":"b"}"#),
        Err(CommandError::DuplicateKey("sensor".into()))
    );
    assert_eq!(
        parse_command(br#"{"command":"recalibrate","sensor":"a"}"#),
        Ok(ClientCommand::Recalibrate {
            sensor: Some("a".into())
        })
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stalled_stdout_keeps_its_connection_and_gets_lines_again() {
    bounded(async {
        // Small queues: the stall overflows them at once.
        let hub = Hub::with_control_len(16, 4);
        let (out, input) = tokio::io::duplex(256);
        let (_stop, stop_rx) = watch::channel(false);
        let writer = tokio::spawn(hub.serve_writer(out, stop_rx));
        // stdout not read: far more control lines than its queue holds.
        for i in 0..200 {
            hub.publish(
                Lane::Control,
                format!(r#"{{"class":"STATUS","n":{i}}}"#).into(),
            );
            hub.publish(
                Lane::Control,
                format!(r#"{{"class":"ERROR","message":"e{i}"}}"#).into(),
            );
            hub.publish(Lane::Reading, reading(i, 10));
            if i % 40 == 0 {
                hub.publish(
                    Lane::Control,
                    format!(r#"{{"class":"CALIBRATION","sensor":"compass","id":{i}}}"#).into(),
                );
            }
        }
        let stats = hub.stats();
        assert_eq!(stats.evicted, 0, "stdout was evicted: {stats:?}");
        assert!(stats.coalesced > 0, "{stats:?}");
        assert_eq!(stats.subscribers, 1, "{stats:?}");
        // stdout is read again: what was kept, then what comes next.
        let mut lines = tokio::io::BufReader::new(input).lines();
        hub.publish(Lane::Control, r#"{"class":"STATUS","n":"after"}"#.into());
        let mut seen = Vec::new();
        while let Some(line) = tokio::time::timeout(T, lines.next_line())
            .await
            .expect("stdout went silent")
            .unwrap()
        {
            let done = line.contains(r#""n":"after""#);
            seen.push(line);
            if done {
                break;
            }
        }
        // Every CALIBRATION is there, in order; STATUS lines coalesced.
        let calibrations: Vec<&String> =
            seen.iter().filter(|l| l.contains("CALIBRATION")).collect();
        assert_eq!(calibrations.len(), 5, "{seen:#?}");
        let statuses = seen.iter().filter(|l| l.contains("STATUS")).count();
        // 200 were published; a few went out before the stall, one waited.
        assert!(statuses <= 8, "{statuses} STATUS lines: not coalesced");
        assert!(!writer.is_finished());
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_subscriber_after_the_maximum_gets_one_error_line_and_is_closed() {
    bounded(async {
        let policy = Policy {
            max_subscribers: 3,
            ..Policy::default()
        };
        let (hub, addr, _rx, _stop) = tcp_hub(16, policy).await;
        // stdout does not count.
        let (out, _input) = tokio::io::duplex(1 << 16);
        let (_wstop, wrx) = watch::channel(false);
        tokio::spawn(hub.serve_writer(out, wrx));
        let mut held = Vec::new();
        for _ in 0..3 {
            held.push(TcpStream::connect(addr).await.unwrap());
        }
        wait_for("3 subscribers and the writer", || {
            hub.stats().subscribers == 4
        })
        .await;
        let extra = TcpStream::connect(addr).await.unwrap();
        let mut lines = tokio::io::BufReader::new(extra).lines();
        let line = tokio::time::timeout(T, lines.next_line())
            .await
            .unwrap()
            .unwrap()
            .expect("an ERROR line");
        let v: Value = serde_json::from_str(&line).unwrap();
        assert_eq!(v["class"], "ERROR");
        let message = v["message"].as_str().unwrap();
        assert!(
            message.starts_with("too many subscribers (3, [outputs] max_subscribers)"),
            "{message}"
        );
        // Then closed.
        let eof = tokio::time::timeout(T, lines.next_line()).await.unwrap();
        assert!(matches!(eof, Ok(None)), "{eof:?}");
        assert_eq!(hub.stats().subscribers, 4);
        assert!(hub.stats().refused >= 1);
        // The live page's streams count too.
        assert!(matches!(
            hub.try_subscribe(
                "page".into(),
                fieldcal::daemon::publish::Origin::Http,
                false
            ),
            Err(SubscribeError::Full { max: 3 })
        ));
        drop(held.pop());
        wait_for("a place freed", || hub.stats().subscribers == 3).await;
        assert!(hub.subscribe("page".into(), false).is_some());
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_command_flood_is_held_to_the_rate_and_slows_no_other_subscriber() {
    bounded(async {
        let (hub, addr, mut rx, _stop) = tcp_hub(4096, Policy::default()).await;
        let forwarded = Arc::new(std::sync::atomic::AtomicU64::new(0));
        tokio::spawn({
            let forwarded = forwarded.clone();
            async move {
                while let Some((_, reply)) = rx.recv().await {
                    forwarded.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    reply.send_status(r#"{"class":"STATUS"}"#);
                }
            }
        });
        let reader = TcpStream::connect(addr).await.unwrap();
        let flooder = TcpStream::connect(addr).await.unwrap();
        wait_for("2 subscribers", || hub.stats().subscribers == 2).await;
        let start = Instant::now();
        // The flooder writes status commands as fast as the daemon takes
        // them (and never reads its replies) ...
        let flood = tokio::spawn(async move {
            let (_r, mut w) = flooder.into_split();
            let chunk = "{\"command\":\"status\"}\n".repeat(1000);
            loop {
                if w.write_all(chunk.as_bytes()).await.is_err() {
                    break;
                }
            }
        });
        // ... while readings go to the other client at 500 a second.
        let mut lines = tokio::io::BufReader::new(reader).lines();
        let mut worst = Duration::ZERO;
        for i in 0..1000 {
            let sent = Instant::now();
            hub.publish(Lane::Reading, reading(i, 0));
            let line = tokio::time::timeout(T, lines.next_line())
                .await
                .unwrap()
                .unwrap()
                .unwrap();
            assert!(line.contains(&format!("\"seq\":{i},")), "{line}");
            worst = worst.max(sent.elapsed());
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
        let elapsed = start.elapsed().as_secs_f64();
        let n = forwarded.load(std::sync::atomic::Ordering::Relaxed) as f64;
        flood.abort();
        // 10 a second in bursts of 20 (+5 for timing slack).
        let allowed = 20.0 + 10.0 * elapsed + 5.0;
        assert!(
            n <= allowed,
            "{n} commands forwarded in {elapsed:.1} s (at most {allowed:.0})"
        );
        assert!(
            n >= 10.0,
            "the flooder's commands were not taken at all: {n}"
        );
        assert!(worst < Duration::from_secs(2), "a reading took {worst:?}");
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_status_reply_accounts_for_every_reading_before_it() {
    bounded(async {
        let (hub, addr, mut rx, _stop) = tcp_hub(64, Policy::default()).await;
        tokio::spawn(async move {
            while let Some((_, reply)) = rx.recv().await {
                reply.send_status(r#"{"class":"STATUS","sensors":[]}"#);
            }
        });
        let client = TcpStream::connect(addr).await.unwrap();
        wait_for("the subscriber", || hub.stats().subscribers == 1).await;
        let (rd, mut wr) = client.into_split();
        // Readings while the client does not read: far more than the socket
        // buffers and its queue of 64 hold, so many are dropped for it.
        let publisher = tokio::spawn({
            let hub = hub.clone();
            async move {
                for i in 0..6000 {
                    hub.publish(Lane::Reading, reading(i, 2000));
                    if i % 100 == 0 {
                        tokio::task::yield_now().await;
                    }
                }
            }
        });
        tokio::time::sleep(Duration::from_millis(200)).await;
        // Ask while readings still come, then read everything.
        for _ in 0..3 {
            wr.write_all(b"{\"command\":\"status\"}\n").await.unwrap();
        }
        let mut lines = tokio::io::BufReader::new(rd).lines();
        let mut received = 0u64;
        let mut replies = 0;
        let mut dropped_total = 0;
        while replies < 3 {
            let line = tokio::time::timeout(T, lines.next_line())
                .await
                .unwrap()
                .unwrap()
                .unwrap();
            if line.starts_with(r#"{"class":"READING""#) {
                received += 1;
                continue;
            }
            let v: Value = serde_json::from_str(&line).unwrap();
            assert_eq!(v["class"], "STATUS", "{line}");
            let sub = &v["subscriber"];
            let readings = sub["readings"].as_u64().unwrap();
            let dropped = sub["dropped"].as_u64().unwrap();
            assert!(sub["id"].as_u64().is_some() && sub["peer"].as_str().is_some());
            assert!(sub["queued"].as_u64().is_some());
            assert_eq!(
                received,
                readings - dropped,
                "READING lines before the reply vs its accounting: {sub}"
            );
            dropped_total = dropped;
            replies += 1;
        }
        publisher.await.unwrap();
        assert!(
            dropped_total > 0,
            "nothing was dropped: the test shows nothing"
        );
    })
    .await;
}

// ---------------------------------------------------------------------------
// The real daemon.

/// A configuration whose only source is a serial port that is not there:
/// the daemon runs (retrying) and answers commands.
fn idle_config(dir: &std::path::Path, outputs: &str) -> std::path::PathBuf {
    write_config(
        dir,
        &format!(
            r#"
[daemon]
state_dir = "{state}"
status_interval_s = 0.2

[outputs]
stdout = false
{outputs}

[[source]]
name = "imu"
kind = "falcon"
port = "{port}"
retry_s = 1.0

[[sensor]]
name = "compass"
source = "imu"
field = "mag"
axes = ["x", "y"]
"#,
            state = dir.join("state").display(),
            port = dir.join("ttyNONE").display(),
        ),
    )
}

/// The address the log says the TCP listener is bound to.
fn tcp_address(daemon: &Daemon) -> std::net::SocketAddr {
    let log = daemon.wait_for_log(T, "listening on TCP");
    let line = log
        .lines()
        .find(|l| l.contains("listening on TCP"))
        .unwrap();
    let at = line.find("address=").expect("the address in the log") + "address=".len();
    let addr = line[at..].split_whitespace().next().unwrap();
    let addr = addr.trim_matches(|c: char| c == '"' || c == ',');
    addr.parse()
        .unwrap_or_else(|_| panic!("not an address: {addr} in {line}"))
}

#[test]
fn recalibrate_over_tcp_needs_the_configuration_or_the_token_and_the_port_bound_is_logged() {
    let dir = tempfile::tempdir().unwrap();
    let token = dir.path().join("token");
    std::fs::write(&token, "s3cret-token-0123\n").unwrap();
    std::fs::set_permissions(&token, std::fs::Permissions::from_mode(0o600)).unwrap();
    let config = idle_config(
        dir.path(),
        &format!(
            "tcp = \"127.0.0.1:0\"\ntoken_file = \"{}\"",
            token.display()
        ),
    );
    let mut daemon = Daemon::start(&config, &[]);
    let addr = tcp_address(&daemon);
    assert_ne!(addr.port(), 0, "the log names port 0, not the port bound");
    let mut client = std::net::TcpStream::connect(addr).unwrap();
    let refused = errors(&ask(&mut client, r#"{"command":"recalibrate"}"#));
    assert_eq!(refused.len(), 1, "{refused:?}");
    assert!(
        refused[0].contains("recalibrate refused from tcp")
            && refused[0].contains("token_file")
            && refused[0].contains("recalibrate_from"),
        "{}",
        refused[0]
    );
    let wrong = errors(&ask(
        &mut client,
        r#"{"command":"recalibrate","token":"guess"}"#,
    ));
    assert!(wrong[0].contains("does not match"), "{wrong:?}");
    let answer = ask(
        &mut client,
        r#"{"command":"recalibrate","token":"s3cret-token-0123"}"#,
    );
    assert!(errors(&answer).is_empty(), "{answer:?}");
    // Duplicate keys: refused, naming the key, not run.
    let dup = errors(&ask(
        &mut client,
        r#"{"command":"status","command":"recalibrate"}"#,
    ));
    assert!(
        dup.iter().any(|e| e.contains("\"command\" is given twice")),
        "{dup:?}"
    );
    // status stays open to all.
    assert!(errors(&ask(&mut client, r#"{"command":"status"}"#)).is_empty());
    assert!(daemon.terminate().success());

    // Without a token: the message names recalibrate_from; with "tcp" in it, allowed.
    let dir = tempfile::tempdir().unwrap();
    let config = idle_config(dir.path(), "tcp = \"127.0.0.1:0\"");
    let mut daemon = Daemon::start(&config, &[]);
    let mut client = std::net::TcpStream::connect(tcp_address(&daemon)).unwrap();
    let refused = errors(&ask(&mut client, r#"{"command":"recalibrate"}"#));
    assert!(
        refused[0].contains(r#"add "tcp" there"#)
            && refused[0].contains("[outputs] recalibrate_from"),
        "{refused:?}"
    );
    assert!(daemon.terminate().success());
    let config = idle_config(
        dir.path(),
        "tcp = \"127.0.0.1:0\"\nrecalibrate_from = [\"unix\", \"tcp\"]",
    );
    let mut daemon = Daemon::start(&config, &[]);
    let mut client = std::net::TcpStream::connect(tcp_address(&daemon)).unwrap();
    let answer = ask(&mut client, r#"{"command":"recalibrate"}"#);
    assert!(errors(&answer).is_empty(), "{answer:?}");
    assert!(daemon.terminate().success());
}

#[test]
fn the_socket_mode_and_group_come_from_the_configuration() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("f.sock");
    // SAFETY: getegid has no preconditions.
    let gid = unsafe { libc::getegid() };
    let config = idle_config(
        dir.path(),
        &format!(
            "unix = \"{}\"\nunix_mode = \"0600\"\nunix_group = {gid}",
            sock.display()
        ),
    );
    let mut daemon = Daemon::start(&config, &[]);
    daemon.wait_for_log(T, "listening on a Unix socket");
    let meta = std::fs::metadata(&sock).unwrap();
    assert_eq!(meta.permissions().mode() & 0o777, 0o600);
    assert_eq!(meta.gid(), gid);
    assert!(daemon.terminate().success());

    // An unknown group is refused at the key, before anything starts.
    let config = idle_config(
        dir.path(),
        &format!(
            "unix = \"{}\"\nunix_group = \"no-such-group-fieldcal\"",
            sock.display()
        ),
    );
    let r = common::run(&["run", "--config", config.to_str().unwrap()]);
    assert_ne!(r.code, Some(0));
    assert!(
        r.stderr.contains("outputs.unix_group") && r.stderr.contains("no group named"),
        "{}",
        r.stderr
    );
    // A token of one byte is refused: it would be guessed.
    let short = dir.path().join("short");
    std::fs::write(&short, "t\n").unwrap();
    std::fs::set_permissions(&short, std::fs::Permissions::from_mode(0o600)).unwrap();
    let config = idle_config(dir.path(), &format!("token_file = \"{}\"", short.display()));
    let r = common::run(&["run", "--config", config.to_str().unwrap()]);
    assert!(
        r.code != Some(0) && r.stderr.contains("at least 16"),
        "{}",
        r.stderr
    );
    // A token file others can read is refused.
    let token = dir.path().join("token");
    std::fs::write(&token, "t").unwrap();
    std::fs::set_permissions(&token, std::fs::Permissions::from_mode(0o644)).unwrap();
    let config = idle_config(dir.path(), &format!("token_file = \"{}\"", token.display()));
    let r = common::run(&["run", "--config", config.to_str().unwrap()]);
    assert!(
        r.code != Some(0) && r.stderr.contains("outputs.token_file"),
        "{}",
        r.stderr
    );
}

/// Sets the child's descriptor limit (soft, and hard when lower) before
/// it starts; at most the hard limit.
fn limit_descriptors(command: &mut std::process::Command, n: u64) {
    // SAFETY: getrlimit and setrlimit are async-signal-safe; nothing else
    // runs in pre_exec.
    unsafe {
        command.pre_exec(move || {
            let mut now = libc::rlimit {
                rlim_cur: 0,
                rlim_max: 0,
            };
            libc::getrlimit(libc::RLIMIT_NOFILE, &mut now);
            let lim = libc::rlimit {
                rlim_cur: n.min(now.rlim_max),
                rlim_max: n.min(now.rlim_max),
            };
            let lim = if n < now.rlim_max {
                lim
            } else {
                libc::rlimit {
                    rlim_cur: now.rlim_max,
                    rlim_max: now.rlim_max,
                }
            };
            if libc::setrlimit(libc::RLIMIT_NOFILE, &lim) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
}

#[test]
fn a_crowd_beyond_the_descriptor_limit_cannot_stop_a_calibration_being_stored() {
    let dir = tempfile::tempdir().unwrap();
    // Two turns in 20 s played at 2x: calibrated after about 5 s.
    let capture = common::repo_path("tests/data/falcon_garbage.fcap");
    let port = free_port();
    let config = replay_config(
        dir.path(),
        &capture,
        "2.0",
        &format!("stdout = true\ntcp = \"127.0.0.1:{port}\""),
    );
    let mut daemon = Daemon::start_with(&config, |c| limit_descriptors(c, 64));
    daemon.wait_for_log(T, "listening on TCP");
    let addr = std::net::SocketAddr::from(([127, 0, 0, 1], port));
    // More clients than the daemon has descriptors, held open.
    let mut held = Vec::new();
    let mut refused = 0;
    for _ in 0..100 {
        let Ok(mut s) = std::net::TcpStream::connect(addr) else {
            continue;
        };
        s.set_read_timeout(Some(Duration::from_millis(300)))
            .unwrap();
        let mut first = [0u8; 512];
        if let Ok(n) = s.read(&mut first)
            && String::from_utf8_lossy(&first[..n]).contains("too many subscribers (26,")
        {
            refused += 1;
        }
        held.push(s);
    }
    assert!(refused > 0, "nobody was refused");
    let (_, calibration) = daemon.wait_for(Duration::from_secs(60), "a CALIBRATION", |v| {
        is_class(v, "CALIBRATION") || is_class(v, "ERROR")
    });
    assert_eq!(calibration["class"], "CALIBRATION", "{calibration}");
    assert_eq!(calibration["accepted"], true, "{calibration}");
    // Stored: no ERROR from the state writer, the file is there.
    let state = dir.path().join("state").join("compass.json");
    let deadline = Instant::now() + T;
    while !state.exists() {
        assert!(
            Instant::now() < deadline,
            "no state file; stderr:\n{}",
            daemon.stderr()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(
        !daemon.stderr().contains("Too many open files"),
        "{}",
        daemon.stderr()
    );
    drop(held);
    assert!(daemon.terminate().success());
}

/// A loopback port free now (so the test also runs against a build that
/// logs port 0 for `127.0.0.1:0`).
fn free_port() -> u16 {
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    l.local_addr().unwrap().port()
}

/// Resident memory of `pid`, in kB.
fn rss_kb(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let line = status.lines().find(|l| l.starts_with("VmRSS:")).unwrap();
    line.split_whitespace().nth(1).unwrap().parse().unwrap()
}

#[test]
fn memory_is_back_near_its_baseline_after_a_crowd_leaves() {
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("long.fcap");
    common::run_ok(&[
        "simulate",
        "--format",
        "falcon",
        "--turns",
        "2000",
        "--noise",
        "2",
        "-o",
        capture.to_str().unwrap(),
    ]);
    // 400,000 frames at 1000x: 20 s of 20,000 readings a second, more than
    // the test needs.
    let port = free_port();
    let config = replay_config(
        dir.path(),
        &capture,
        "1000.0",
        &format!("stdout = false\ntcp = \"127.0.0.1:{port}\""),
    );
    let mut daemon = Daemon::start_with(&config, |c| limit_descriptors(c, 4096));
    daemon.wait_for_log(T, "listening on TCP");
    let addr = std::net::SocketAddr::from(([127, 0, 0, 1], port));
    std::thread::sleep(Duration::from_millis(500));
    let baseline = rss_kb(daemon.pid());
    // 600 idle clients that never read (the default allows 64).
    let crowd: Vec<_> = (0..600)
        .filter_map(|_| std::net::TcpStream::connect(addr).ok())
        .collect();
    // Their queues fill (4096 readings each, after the socket buffers).
    std::thread::sleep(Duration::from_secs(4));
    assert!(daemon.is_running(), "the daemon ended: {}", daemon.stderr());
    let peak = rss_kb(daemon.pid());
    drop(crowd);
    std::thread::sleep(Duration::from_secs(2));
    assert!(daemon.is_running(), "the daemon ended: {}", daemon.stderr());
    let after = rss_kb(daemon.pid());
    eprintln!("RSS: baseline {baseline} kB, with the crowd {peak} kB, after {after} kB");
    // Allocators keep some: 20 MB over the baseline at most.
    assert!(
        after <= baseline + 20 * 1024,
        "RSS {after} kB after the crowd left, baseline {baseline} kB (peak {peak} kB)"
    );
    assert!(daemon.terminate().success());
}
