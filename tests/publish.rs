//! The publisher hub over real sockets: loopback TCP and a Unix socket.
//!
//! Every test is bounded in time; waits poll for a condition rather than
//! sleeping a fixed time, so a loaded machine only makes them slower.

use std::future::Future;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use fieldcal::daemon::publish::{ClientCommand, Hub, Lane, ReplyTo};
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::{TcpListener, TcpStream, UnixListener, UnixStream};
use tokio::sync::{mpsc, watch};
use tokio::time::timeout;

const TEST_LIMIT: Duration = Duration::from_secs(60);

type Commands = mpsc::Receiver<(ClientCommand, ReplyTo)>;

struct Server {
    hub: Hub,
    addr: std::net::SocketAddr,
    commands: Commands,
    shutdown: watch::Sender<bool>,
    accept: tokio::task::JoinHandle<()>,
}

async fn tcp_server(queue_len: usize) -> Server {
    let hub = Hub::new(queue_len);
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (tx, commands) = mpsc::channel(64);
    let (shutdown, rx) = watch::channel(false);
    let accept = tokio::spawn({
        let hub = hub.clone();
        async move { hub.serve_tcp(listener, tx, rx).await }
    });
    Server {
        hub,
        addr,
        commands,
        shutdown,
        accept,
    }
}

/// Polls `cond` until it holds; panics with `what` after 20 s.
async fn wait_for(what: &str, mut cond: impl FnMut() -> bool) {
    let start = Instant::now();
    while !cond() {
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "timed out waiting for {what}"
        );
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
}

async fn bounded<F: Future>(f: F) -> F::Output {
    timeout(TEST_LIMIT, f).await.expect("test took too long")
}

async fn next_line<R: AsyncBufReadExt + Unpin>(r: &mut R) -> String {
    let mut s = String::new();
    let n = timeout(Duration::from_secs(20), r.read_line(&mut s))
        .await
        .expect("no line within 20 s")
        .unwrap();
    assert!(n > 0, "unexpected EOF");
    s.pop();
    s
}

fn reading(i: usize) -> Arc<str> {
    format!(r#"{{"class":"READING","sensor":"compass","seq":{i},"x":0.125,"y":-0.5}}"#).into()
}

fn seq_of(line: &str) -> Option<usize> {
    let v: serde_json::Value = serde_json::from_str(line).ok()?;
    v["seq"].as_u64().map(|s| s as usize)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_prompt_subscribers_get_every_line_in_order() {
    bounded(async {
        let server = tcp_server(10_000).await;
        let a = TcpStream::connect(server.addr).await.unwrap();
        let b = TcpStream::connect(server.addr).await.unwrap();
        wait_for("2 subscribers", || server.hub.stats().subscribers == 2).await;

        const N: usize = 5000;
        let read_all = |s: TcpStream| {
            tokio::spawn(async move {
                let mut r = BufReader::new(s);
                let mut got = Vec::with_capacity(N);
                for _ in 0..N {
                    got.push(next_line(&mut r).await);
                }
                got
            })
        };
        let (ra, rb) = (read_all(a), read_all(b));
        for i in 0..N {
            let lane = if i % 1000 == 0 {
                Lane::Control
            } else {
                Lane::Reading
            };
            server.hub.publish(lane, reading(i));
        }
        let expected: Vec<String> = (0..N).map(|i| reading(i).to_string()).collect();
        assert_eq!(ra.await.unwrap(), expected);
        assert_eq!(rb.await.unwrap(), expected);
        let stats = server.hub.stats();
        assert_eq!(stats.published, N as u64);
        assert_eq!(stats.dropped, 0);
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stuck_subscriber_loses_its_oldest_readings_only() {
    bounded(async {
        const QUEUE: usize = 1024;
        const N: usize = 200_000;
        const CONTROL_EVERY: usize = 10_000;
        let server = tcp_server(QUEUE).await;
        let prompt = TcpStream::connect(server.addr).await.unwrap();
        wait_for("the prompt subscriber", || server.hub.stats().subscribers == 1).await;
        let stuck = TcpStream::connect(server.addr).await.unwrap();
        wait_for("the stuck subscriber", || server.hub.stats().subscribers == 2).await;

        // The prompt reader checks order as it goes and reports progress,
        // so the publisher can stay within its queue.
        let received = Arc::new(AtomicU64::new(0));
        let reader = tokio::spawn({
            let received = Arc::clone(&received);
            async move {
                let mut r = BufReader::new(prompt);
                for i in 0..N {
                    let line = next_line(&mut r).await;
                    assert_eq!(line, *reading(i), "prompt subscriber, line {i}");
                    received.store(i as u64 + 1, Ordering::Release);
                }
                r // Stays connected until the checks below.
            }
        });

        let mut in_publish = Duration::ZERO;
        let mut slowest_chunk = Duration::ZERO;
        for chunk in (0..N).collect::<Vec<_>>().chunks(QUEUE / 2) {
            let start = Instant::now();
            for &i in chunk {
                let lane = if i % CONTROL_EVERY == 0 {
                    Lane::Control
                } else {
                    Lane::Reading
                };
                server.hub.publish(lane, reading(i));
            }
            let took = start.elapsed();
            in_publish += took;
            slowest_chunk = slowest_chunk.max(took);
            let end = chunk[chunk.len() - 1] as u64 + 1;
            wait_for("the prompt subscriber to catch up", || {
                received.load(Ordering::Acquire) + (QUEUE as u64 / 2) >= end
            })
            .await;
        }
        let _prompt = reader.await.unwrap();
        eprintln!(
            "published {N} lines in {in_publish:?} of publish calls (slowest {} lines: {slowest_chunk:?})",
            QUEUE / 2
        );
        // A blocking publish would hang on the stuck socket; a cheap one
        // takes microseconds a line even in a debug build.
        assert!(
            in_publish < Duration::from_secs(5),
            "publish too slow: {in_publish:?}"
        );

        let stats = server.hub.stats();
        assert_eq!(stats.published, N as u64);
        assert!(stats.dropped > 0, "{stats:?}");
        let subs = server.hub.subscribers();
        assert_eq!(subs.len(), 2);
        let by_drops: Vec<u64> = subs.iter().map(|s| s.dropped).collect();
        assert!(by_drops.contains(&0), "the prompt one dropped nothing: {subs:?}");
        assert_eq!(by_drops.iter().sum::<u64>(), stats.dropped);

        // Now the stuck one reads: readings in increasing order with gaps,
        // and every control line.
        let mut r = BufReader::new(stuck);
        let controls: Vec<usize> = (0..N).step_by(CONTROL_EVERY).collect();
        let mut seen_controls = Vec::new();
        let mut last = None;
        let mut lines = 0usize;
        loop {
            let line = next_line(&mut r).await;
            let seq = seq_of(&line).expect("a reading line");
            assert!(last.is_none_or(|l| seq > l), "out of order: {seq} after {last:?}");
            last = Some(seq);
            lines += 1;
            if seq.is_multiple_of(CONTROL_EVERY) {
                seen_controls.push(seq);
            }
            if seq == N - 1 {
                break;
            }
        }
        assert_eq!(seen_controls, controls, "every control line reached the stuck subscriber");
        assert!(lines < N, "it lost readings: {lines} of {N}");
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn commands_are_forwarded_and_bad_ones_answered() {
    bounded(async {
        let mut server = tcp_server(100).await;
        let (rd, mut wr) = TcpStream::connect(server.addr).await.unwrap().into_split();
        let mut rd = BufReader::new(rd);
        let other = TcpStream::connect(server.addr).await.unwrap();
        let mut other = BufReader::new(other);
        wait_for("2 subscribers", || server.hub.stats().subscribers == 2).await;

        wr.write_all(b"{\"command\":\"recalibrate\",\"sensor\":\"compass\"}\n")
            .await
            .unwrap();
        let (cmd, _) = server.commands.recv().await.unwrap();
        assert_eq!(
            cmd,
            ClientCommand::Recalibrate {
                sensor: Some("compass".into())
            }
        );

        // Status, in two pieces and with CRLF; the reply goes to the asker only.
        wr.write_all(b"{\"command\":").await.unwrap();
        wr.flush().await.unwrap();
        tokio::time::sleep(Duration::from_millis(20)).await;
        wr.write_all(b"\"status\"}\r\n").await.unwrap();
        let (cmd, reply) = server.commands.recv().await.unwrap();
        assert_eq!(cmd, ClientCommand::Status);
        assert!(reply.is_connected());
        reply.send(r#"{"class":"STATUS","sensors":1}"#.into());
        server.hub.publish(Lane::Reading, reading(7));
        assert_eq!(
            next_line(&mut rd).await,
            r#"{"class":"STATUS","sensors":1}"#
        );
        assert_eq!(next_line(&mut rd).await, *reading(7));
        assert_eq!(
            next_line(&mut other).await,
            *reading(7),
            "no STATUS for the other"
        );

        let error = |line: &str| -> String {
            let v: serde_json::Value = serde_json::from_str(line).unwrap();
            assert_eq!(v["class"], "ERROR", "{line}");
            v["message"].as_str().unwrap().to_owned()
        };
        wr.write_all(b"hello there\n").await.unwrap();
        let message = error(&next_line(&mut rd).await);
        assert!(message.contains("not JSON"), "{message}");
        assert!(
            message.contains("\"status\""),
            "says what is allowed: {message}"
        );

        wr.write_all(b"{\"command\":\"fly\"}\n").await.unwrap();
        let message = error(&next_line(&mut rd).await);
        assert!(message.contains("unknown command \"fly\""), "{message}");

        // Over-long: refused once, discarded to the newline, then back to normal.
        let long = vec![b'x'; 10_000];
        wr.write_all(&long).await.unwrap();
        wr.write_all(b"{\"command\":\"status\"}\n").await.unwrap();
        let message = error(&next_line(&mut rd).await);
        assert!(message.contains("longer than 4096 bytes"), "{message}");
        wr.write_all(b"\n{\"command\":\"recalibrate\"}\n")
            .await
            .unwrap();
        let (cmd, _) = server.commands.recv().await.unwrap();
        assert_eq!(cmd, ClientCommand::Recalibrate { sensor: None });

        server.hub.publish(Lane::Reading, reading(8));
        assert_eq!(next_line(&mut rd).await, *reading(8), "still connected");
        assert!(
            server.commands.try_recv().is_err(),
            "nothing else forwarded"
        );
        assert_eq!(server.hub.stats().subscribers, 2);
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn subscribers_that_vanish_mid_line_or_mid_write_are_removed() {
    bounded(async {
        let server = tcp_server(64).await;

        // Mid-line: half a command, then gone.
        let mut s = TcpStream::connect(server.addr).await.unwrap();
        wait_for("1 subscriber", || server.hub.stats().subscribers == 1).await;
        s.write_all(b"{\"command\":\"sta").await.unwrap();
        drop(s);
        wait_for("0 subscribers", || server.hub.stats().subscribers == 0).await;

        // Mid-write: reads part of a long stream, then resets.
        let s = TcpStream::connect(server.addr).await.unwrap();
        wait_for("1 subscriber", || server.hub.stats().subscribers == 1).await;
        let stop = Arc::new(AtomicBool::new(false));
        let publisher = std::thread::spawn({
            let hub = server.hub.clone();
            let stop = Arc::clone(&stop);
            move || {
                let mut i = 0;
                while !stop.load(Ordering::Relaxed) {
                    hub.publish(Lane::Reading, reading(i));
                    i += 1;
                    if i % 64 == 0 {
                        std::thread::sleep(Duration::from_micros(200));
                    }
                }
            }
        });
        let mut r = BufReader::new(s);
        let mut partial = [0u8; 100];
        r.read_exact(&mut partial).await.unwrap();
        drop(r);
        wait_for("0 subscribers", || server.hub.stats().subscribers == 0).await;
        stop.store(true, Ordering::Relaxed);
        publisher.join().unwrap();
        assert!(server.hub.subscribers().is_empty());

        // The accept loop is still alive.
        let s = TcpStream::connect(server.addr).await.unwrap();
        wait_for("1 subscriber", || server.hub.stats().subscribers == 1).await;
        drop(s);
        wait_for("0 subscribers", || server.hub.stats().subscribers == 0).await;
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fifty_subscribers_come_and_go_without_leaks() {
    bounded(async {
        let mut server = tcp_server(256).await;
        let stop = Arc::new(AtomicBool::new(false));
        let publisher = std::thread::spawn({
            let hub = server.hub.clone();
            let stop = Arc::clone(&stop);
            move || {
                let mut i = 0;
                while !stop.load(Ordering::Relaxed) {
                    let lane = if i % 100 == 0 {
                        Lane::Control
                    } else {
                        Lane::Reading
                    };
                    hub.publish(lane, reading(i));
                    i += 1;
                    if i % 16 == 0 {
                        std::thread::sleep(Duration::from_micros(500));
                    }
                }
            }
        });

        let mut replies = Vec::new();
        for round in 0..20 {
            let mut clients = Vec::new();
            for _ in 0..50 {
                clients.push(TcpStream::connect(server.addr).await.unwrap());
            }
            wait_for("50 subscribers", || server.hub.stats().subscribers == 50).await;
            for (k, c) in clients.iter_mut().enumerate() {
                match k % 3 {
                    // Some read a line, some ask for status, some do nothing.
                    0 => {
                        let mut b = [0u8; 1];
                        timeout(Duration::from_secs(20), c.read_exact(&mut b))
                            .await
                            .unwrap()
                            .unwrap();
                    }
                    1 if round % 5 == 0 => {
                        c.write_all(b"{\"command\":\"status\"}\n").await.unwrap()
                    }
                    _ => {}
                }
            }
            let asked = if round % 5 == 0 {
                (0..50).filter(|k| k % 3 == 1).count()
            } else {
                0
            };
            for _ in 0..asked {
                let (cmd, reply) = timeout(Duration::from_secs(20), server.commands.recv())
                    .await
                    .unwrap()
                    .unwrap();
                assert_eq!(cmd, ClientCommand::Status);
                reply.send(r#"{"class":"STATUS"}"#.into());
                replies.push(reply);
            }
            drop(clients);
            wait_for("0 subscribers", || server.hub.stats().subscribers == 0).await;
        }
        stop.store(true, Ordering::Relaxed);
        publisher.join().unwrap();

        assert!(server.hub.subscribers().is_empty());
        assert_eq!(server.hub.stats().subscribers, 0);
        assert!(!replies.is_empty());
        // Replies hold their subscriber weakly: all are gone, nothing leaked.
        assert!(
            replies
                .iter()
                .all(|r| !r.is_connected() && r.peer().is_none())
        );
        replies[0].send("ignored".into());
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unix_socket_subscribers_work_the_same() {
    bounded(async {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("fieldcal.sock");
        let hub = Hub::new(100);
        let listener = UnixListener::bind(&path).unwrap();
        let (tx, mut commands) = mpsc::channel(8);
        let (shutdown, rx) = watch::channel(false);
        let accept = tokio::spawn({
            let hub = hub.clone();
            async move { hub.serve_unix(listener, tx, rx).await }
        });

        let (rd, mut wr) = UnixStream::connect(&path).await.unwrap().into_split();
        let mut rd = BufReader::new(rd);
        wait_for("1 subscriber", || hub.stats().subscribers == 1).await;
        for i in 0..50 {
            hub.publish(Lane::Reading, reading(i));
        }
        for i in 0..50 {
            assert_eq!(next_line(&mut rd).await, *reading(i));
        }
        wr.write_all(b"{\"command\":\"recalibrate\",\"sensor\":\"tilt\"}\n{oops\n")
            .await
            .unwrap();
        let (cmd, reply) = commands.recv().await.unwrap();
        assert_eq!(
            cmd,
            ClientCommand::Recalibrate {
                sensor: Some("tilt".into())
            }
        );
        assert_eq!(reply.peer().as_deref(), Some("unix"));
        assert!(next_line(&mut rd).await.contains(r#""class":"ERROR""#));

        shutdown.send(true).unwrap();
        accept.await.unwrap();
        hub.close().await;
        assert_eq!(hub.stats().subscribers, 0);
        let mut rest = String::new();
        rd.read_to_string(&mut rest).await.unwrap();
        assert_eq!(rest, "", "closed cleanly");
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn close_flushes_queued_lines_and_cuts_off_stuck_subscribers() {
    bounded(async {
        let server = tcp_server(100_000).await;
        let prompt = TcpStream::connect(server.addr).await.unwrap();
        let stuck = TcpStream::connect(server.addr).await.unwrap();
        wait_for("2 subscribers", || server.hub.stats().subscribers == 2).await;
        const N: usize = 5_000;
        for i in 0..N {
            server.hub.publish(Lane::Reading, reading(i));
        }
        let reader = tokio::spawn(async move {
            let mut r = BufReader::new(prompt);
            let mut n = 0;
            let mut line = String::new();
            while r.read_line(&mut line).await.unwrap() > 0 {
                assert_eq!(line.trim_end(), &*reading(n));
                n += 1;
                line.clear();
            }
            n
        });
        server.shutdown.send(true).unwrap();
        server.accept.await.unwrap();
        let start = Instant::now();
        server.hub.close().await;
        let took = start.elapsed();
        assert!(took < Duration::from_secs(5), "close took {took:?}");
        assert_eq!(server.hub.stats().subscribers, 0);
        assert_eq!(
            reader.await.unwrap(),
            N,
            "the prompt one got everything, then EOF"
        );
        drop(stuck);

        // A closed hub takes no new subscribers.
        let (a, _b) = tokio::io::duplex(64);
        let (_tx, rx) = watch::channel(false);
        server.hub.serve_writer(a, rx).await;
        assert_eq!(server.hub.stats().subscribers, 0);
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn serve_writer_is_a_subscriber_and_flushes_on_shutdown() {
    bounded(async {
        let hub = Hub::new(1000);
        let (out, input) = tokio::io::duplex(256);
        let (shutdown, rx) = watch::channel(false);
        let writer = tokio::spawn({
            let hub = hub.clone();
            async move { hub.serve_writer(out, rx).await }
        });
        wait_for("the writer", || hub.stats().subscribers == 1).await;
        for i in 0..500 {
            hub.publish(Lane::Reading, reading(i));
        }
        shutdown.send(true).unwrap();
        let mut text = String::new();
        BufReader::new(input)
            .read_to_string(&mut text)
            .await
            .unwrap();
        writer.await.unwrap();
        let expected: String = (0..500).map(|i| format!("{}\n", reading(i))).collect();
        assert_eq!(text, expected);
        assert_eq!(hub.stats().subscribers, 0);
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_subscriber_that_lets_control_lines_pile_up_is_evicted() {
    bounded(async {
        let hub = Hub::with_control_len(16, 4);
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let (tx, _commands) = mpsc::channel(8);
        let (_shutdown, rx) = watch::channel(false);
        tokio::spawn({
            let hub = hub.clone();
            async move { hub.serve_tcp(listener, tx, rx).await }
        });
        let _stuck = TcpStream::connect(addr).await.unwrap();
        wait_for("1 subscriber", || hub.stats().subscribers == 1).await;
        // Far more than the socket buffers hold, so the control queue fills.
        let big: Arc<str> =
            format!(r#"{{"class":"STATUS","pad":"{}"}}"#, "x".repeat(256 * 1024)).into();
        for _ in 0..200 {
            hub.publish(Lane::Control, Arc::clone(&big));
            if hub.stats().evicted > 0 {
                break;
            }
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        assert_eq!(hub.stats().evicted, 1);
        wait_for("the evicted subscriber to go", || {
            hub.stats().subscribers == 0
        })
        .await;
        assert!(hub.subscribers().is_empty());
    })
    .await;
}
