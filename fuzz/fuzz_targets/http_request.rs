//! The live page's request path (issue 23): any bytes a client sends on a
//! connection get an HTTP answer or a close, never a panic (a panic in the
//! server's tasks aborts the fuzzer through libFuzzer's hook). The server
//! is the real one: `http::serve` with its connection limits, head
//! deadline and guard, on the page's router, started once on loopback.
#![no_main]

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::Path;
use std::sync::OnceLock;
use std::time::Duration;

use fieldcal::daemon::http::{router, serve};
use fieldcal::daemon::publish::Hub;
use libfuzzer_sys::fuzz_target;

const CONFIG: &str = "[outputs]\nhttp = \"127.0.0.1:0\"\nrecalibrate_from = [\"unix\", \"http\"]\n\
    [[source]]\nname = \"imu\"\nkind = \"falcon\"\nport = \"/dev/null\"\n\
    [[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n";

/// Most of an answer read: a page, an error or the start of the events.
const MAX_ANSWER: usize = 1 << 16;

fn server() -> SocketAddr {
    static ADDR: OnceLock<SocketAddr> = OnceLock::new();
    *ADDR.get_or_init(|| {
        // libFuzzer's C main does not set up what a Rust binary's does: a
        // write to a connection the server closed would kill the fuzzer
        // with SIGPIPE instead of failing with EPIPE, as it does in
        // fieldcal itself.
        // SAFETY: setting a signal's disposition to SIG_IGN touches no
        // memory; it is done once, before any thread of ours writes.
        unsafe { libc::signal(libc::SIGPIPE, libc::SIG_IGN) };
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let runtime = tokio::runtime::Builder::new_multi_thread()
                .worker_threads(1)
                .enable_all()
                .build()
                .expect("a runtime");
            runtime.block_on(async move {
                let config = fieldcal::daemon::config::parse(CONFIG, Path::new("fuzz.toml"))
                    .expect("the fuzz configuration");
                let hub = Hub::new(64);
                let (commands, mut asked) = tokio::sync::mpsc::channel(64);
                // Commands are taken and never answered, as by a daemon
                // too busy to: the page's deadline answers them.
                tokio::spawn(async move { while asked.recv().await.is_some() {} });
                let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
                    .await
                    .expect("a loopback port");
                tx.send(listener.local_addr().expect("its address"))
                    .expect("the fuzzer waits");
                let (_stop, stop) = tokio::sync::watch::channel(false);
                serve(listener, router(hub, commands, &config), stop).await;
            });
        });
        rx.recv().expect("the server's address")
    })
}

fuzz_target!(|data: &[u8]| {
    let Ok(mut stream) = TcpStream::connect(server()) else {
        return;
    };
    let _ = stream.set_read_timeout(Some(Duration::from_secs(5)));
    let _ = stream.write_all(data);
    let _ = stream.shutdown(std::net::Shutdown::Write);
    let mut answer = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        match stream.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => answer.extend_from_slice(&buf[..n]),
        }
        // The events stream goes on: its head is enough.
        let head_done = answer.windows(4).any(|w| w == b"\r\n\r\n");
        if answer.len() > MAX_ANSWER
            || (head_done && answer.windows(17).any(|w| w == b"text/event-stream"))
        {
            break;
        }
    }
    if !answer.is_empty() {
        assert!(
            answer.starts_with(b"HTTP/1."),
            "not an HTTP answer: {:?}",
            String::from_utf8_lossy(&answer[..answer.len().min(200)])
        );
    }
});
