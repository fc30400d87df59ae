//! Requests from other sites. The live page answers only requests addressed
//! to this machine (`Host`: an IP address, `localhost`, this machine's name,
//! or a name of `[outputs] http_hosts`), which a page of another site cannot
//! forge by pointing its own name at this address (DNS rebinding). It
//! changes state (recalibrate, rollback) only for a request from its own
//! page: an `Origin` (or `Sec-Fetch-Site`) of the page's own, and a JSON
//! body, which a form or another site's script cannot send without the
//! browser first asking the daemon (a CORS preflight), which it never
//! grants. A client that is no browser (curl, a script) sends no `Origin`
//! and passes with its `Content-Type: application/json`.

use std::net::{Ipv4Addr, Ipv6Addr};
use std::sync::Arc;

use axum::extract::{Request, State};
use axum::http::{HeaderMap, Method, StatusCode, header};
use axum::middleware::Next;
use axum::response::Response;

/// The names, besides IP addresses and `localhost`, the page answers to.
#[derive(Debug, Clone)]
pub struct Hosts {
    names: Arc<[String]>,
}

/// This machine's host name, if it has one.
fn machine_name() -> Option<String> {
    let mut buf = [0u8; 256];
    // SAFETY: gethostname writes at most `len` bytes into the buffer given.
    let ok = unsafe { libc::gethostname(buf.as_mut_ptr().cast(), buf.len()) } == 0;
    let end = buf.iter().position(|&b| b == 0)?;
    let name = std::str::from_utf8(&buf[..end]).ok()?;
    (ok && !name.is_empty()).then(|| name.to_ascii_lowercase())
}

impl Hosts {
    /// `configured` (`[outputs] http_hosts`), and this machine's host name
    /// with its mDNS form (`NAME.local`).
    pub fn new(configured: &[String]) -> Self {
        let mut names: Vec<String> = configured.iter().map(|n| normal(n)).collect();
        if let Some(name) = machine_name() {
            names.push(format!("{name}.local"));
            names.push(name);
        }
        Hosts {
            names: names.into(),
        }
    }

    /// Whether a `Host` value (a name or address, with or without a port)
    /// is this machine.
    pub fn allows(&self, host: &str) -> bool {
        let host = normal(host);
        let name = if let Some(rest) = host.strip_prefix('[') {
            // [v6]:port
            return rest
                .split_once(']')
                .is_some_and(|(ip, port)| ip.parse::<Ipv6Addr>().is_ok() && is_port(port));
        } else {
            match host.rsplit_once(':') {
                Some((name, port)) if is_port(&format!(":{port}")) => name,
                Some(_) => return false,
                None => host.as_str(),
            }
        };
        name.parse::<Ipv4Addr>().is_ok()
            || name == "localhost"
            || name.ends_with(".localhost")
            || self.names.iter().any(|n| n == name)
    }

    fn listed(&self) -> String {
        let mut listed = vec!["an IP address".to_string(), "localhost".to_string()];
        listed.extend(self.names.iter().cloned());
        listed.join(", ")
    }
}

/// Lower case, without a final dot (before a port too: `robot.lan.:8080`).
fn normal(host: &str) -> String {
    let host = host.trim().to_ascii_lowercase();
    let (name, port) = match host.rsplit_once(':') {
        Some((name, port)) if !name.contains(':') && !name.starts_with('[') => {
            (name.to_string(), format!(":{port}"))
        }
        _ => (host.clone(), String::new()),
    };
    match name.strip_suffix('.') {
        Some(h) => format!("{h}{port}"),
        None => host,
    }
}

/// Empty, or `:` and a port number.
fn is_port(rest: &str) -> bool {
    rest.is_empty()
        || rest
            .strip_prefix(':')
            .is_some_and(|p| !p.is_empty() && p.len() <= 5 && p.bytes().all(|b| b.is_ascii_digit()))
}

/// Why a request is refused, if it is: its status and message.
pub fn check(
    hosts: &Hosts,
    method: &Method,
    headers: &HeaderMap,
) -> Result<(), (StatusCode, String)> {
    let text = |name: header::HeaderName| {
        headers
            .get(&name)
            .map(|v| v.to_str().map(str::to_owned).unwrap_or_else(|_| "?".into()))
    };
    let host = text(header::HOST);
    if let Some(host) = &host
        && !hosts.allows(host)
    {
        return Err((
            StatusCode::FORBIDDEN,
            format!(
                "this live page answers requests addressed to this machine ({}); Host {host:?} is none of them, and a page of another site must not read it (DNS rebinding): open the page by this machine's address, or add the name to [outputs] http_hosts",
                hosts.listed()
            ),
        ));
    }
    if method != Method::POST {
        return Ok(());
    }
    if let Some(site) = text(header::HeaderName::from_static("sec-fetch-site"))
        && !["same-origin", "none"].contains(&site.as_str())
    {
        return Err((
            StatusCode::FORBIDDEN,
            format!(
                "a recalibrate or rollback must come from this daemon's own page; the browser says it came from a {site} page (Sec-Fetch-Site): use the page's button, or send it without a browser (curl, the TCP socket)"
            ),
        ));
    }
    if let Some(origin) = text(header::ORIGIN) {
        let own = origin
            .strip_prefix("http://")
            .filter(|rest| !rest.contains('/'))
            .is_some_and(|rest| match &host {
                Some(host) => rest.eq_ignore_ascii_case(host),
                None => hosts.allows(rest),
            });
        if !own {
            return Err((
                StatusCode::FORBIDDEN,
                format!(
                    "a recalibrate or rollback must come from this daemon's own page; it came from {origin:?} (Origin): use the page's button, or send it without a browser (curl, the TCP socket)"
                ),
            ));
        }
    }
    let json = text(header::CONTENT_TYPE).is_some_and(|t| {
        t.split(';')
            .next()
            .is_some_and(|media| media.trim().eq_ignore_ascii_case("application/json"))
    });
    if !json {
        return Err((
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "a POST must carry Content-Type: application/json (curl: -H 'Content-Type: application/json'); a form or another site's page cannot send that without the browser asking the daemon first, which it never allows".into(),
        ));
    }
    Ok(())
}

/// The middleware: [`check`] before every route.
pub async fn guard(State(hosts): State<Hosts>, request: Request, next: Next) -> Response {
    if let Err((status, message)) = check(&hosts, request.method(), request.headers()) {
        return super::error(status, &message);
    }
    // While the handler runs, the connection is busy: never closed to make
    // room for another client.
    let peer = request
        .extensions()
        .get::<axum::extract::ConnectInfo<super::Peer>>()
        .map(|c| c.0.clone());
    if let Some(peer) = &peer {
        peer.set_busy(true);
    }
    let response = next.run(request).await;
    if let Some(peer) = &peer {
        peer.set_busy(false);
    }
    response
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hosts() -> Hosts {
        Hosts {
            names: vec!["robot.lan".to_string()].into(),
        }
    }

    #[test]
    fn hosts_of_this_machine_and_no_others() {
        let h = hosts();
        for ok in [
            "127.0.0.1:8080",
            "192.168.1.20",
            "[::1]:8080",
            "[fe80::1]",
            "localhost:8080",
            "LOCALHOST",
            "app.localhost:80",
            "robot.lan:8080",
            "Robot.LAN.",
            "robot.lan.:8080",
            "localhost.:80",
        ] {
            assert!(h.allows(ok), "{ok}");
        }
        for bad in [
            "evil.example",
            "evil.example:8080",
            "127.0.0.1.evil.example",
            "localhost.evil.example",
            "robot.lan.evil.example",
            "[::1",
            "[::1]x",
            "127.0.0.1:80:80",
            "127.0.0.1:abc",
            "",
        ] {
            assert!(!h.allows(bad), "{bad}");
        }
    }

    fn headers(pairs: &[(&'static str, &str)]) -> HeaderMap {
        let mut map = HeaderMap::new();
        for (name, value) in pairs {
            map.insert(
                header::HeaderName::from_static(name),
                value.parse().unwrap(),
            );
        }
        map
    }

    #[test]
    fn state_changes_only_from_the_page_itself() {
        let h = hosts();
        let json = ("content-type", "application/json");
        let ok = |pairs: &[(&'static str, &str)]| check(&h, &Method::POST, &headers(pairs));
        assert!(ok(&[("host", "127.0.0.1:8080"), json]).is_ok());
        assert!(
            ok(&[
                ("host", "127.0.0.1:8080"),
                ("origin", "http://127.0.0.1:8080"),
                ("sec-fetch-site", "same-origin"),
                ("content-type", "application/json; charset=utf-8"),
            ])
            .is_ok()
        );
        for (pairs, status) in [
            (
                vec![
                    ("host", "127.0.0.1:8080"),
                    ("origin", "http://evil.example"),
                    json,
                ],
                StatusCode::FORBIDDEN,
            ),
            (
                vec![("host", "127.0.0.1:8080"), ("origin", "null"), json],
                StatusCode::FORBIDDEN,
            ),
            (
                vec![
                    ("host", "127.0.0.1:8080"),
                    ("sec-fetch-site", "cross-site"),
                    json,
                ],
                StatusCode::FORBIDDEN,
            ),
            (
                vec![("host", "127.0.0.1:8080"), ("content-type", "text/plain")],
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
            ),
            (
                vec![("host", "127.0.0.1:8080")],
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
            ),
            (
                vec![("host", "evil.example:8080"), json],
                StatusCode::FORBIDDEN,
            ),
        ] {
            let refused = ok(&pairs).unwrap_err();
            assert_eq!(refused.0, status, "{pairs:?}: {}", refused.1);
        }
        // Reads need only the host.
        assert!(check(&h, &Method::GET, &headers(&[("host", "localhost")])).is_ok());
        assert!(check(&h, &Method::GET, &headers(&[("host", "evil.example")])).is_err());
    }
}
