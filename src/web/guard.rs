//! What a connection to the web page may cost the robot: owns the listener that admits at
//! most `web.max_connections` at once and the per-connection time limits.
//!
//! ```text
//!  accept --(a permit of max_connections; the rest wait in the kernel's backlog)--> Guarded
//!  Guarded: closed with TimedOut when
//!    A  nothing was sent within request_ms of the accept   (a request that never ends: slowloris)
//!    B  a send has waited stall_ms for the peer to take it  (a client gone without a FIN)
//!    C  nothing was sent for idle_ms                         (an idle keep-alive; the page's
//!                                                             socket pings every 2 s)
//! ```
//!
//! Reading never counts as progress: a client that dribbles bytes keeps nothing open. The
//! rules act on the socket under hyper, so they hold for every route, the MJPEG stream and
//! the WebSocket alike, without a timer in hyper.

use std::future::Future;
use std::io;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tokio::time::{Instant, Sleep};

/// The time limits (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    pub request: Duration,
    pub stall: Duration,
    pub idle: Duration,
}

/// Which limit closed a connection.
fn timed_out(rule: &str) -> io::Error {
    io::Error::new(
        io::ErrorKind::TimedOut,
        format!("web connection closed: {rule}"),
    )
}

/// A stream under [`Limits`], holding its connection permit until dropped.
pub struct Guarded<S> {
    io: S,
    limits: Limits,
    accepted: Instant,
    last_sent: Option<Instant>,
    send_waiting_since: Option<Instant>,
    timer: Pin<Box<Sleep>>,
    armed_for: Instant,
    _permit: Option<OwnedSemaphorePermit>,
}

impl<S> Guarded<S> {
    pub fn new(io: S, limits: Limits, permit: Option<OwnedSemaphorePermit>) -> Self {
        let now = Instant::now();
        let first = now + limits.request;
        Self {
            io,
            limits,
            accepted: now,
            last_sent: None,
            send_waiting_since: None,
            timer: Box::pin(tokio::time::sleep_until(first)),
            armed_for: first,
            _permit: permit,
        }
    }

    /// The earliest deadline that applies now, and its rule.
    fn deadline(&self) -> (Instant, &'static str) {
        let mut d = match self.last_sent {
            None => (
                self.accepted + self.limits.request,
                "no response within web.request_timeout_ms",
            ),
            Some(t) => (t + self.limits.idle, "nothing sent for web.idle_timeout_ms"),
        };
        if let Some(w) = self.send_waiting_since {
            let stall = w + self.limits.stall;
            if stall < d.0 {
                d = (stall, "the client took nothing for web.stall_timeout_ms");
            }
        }
        d
    }

    /// `Err` once the deadline has passed; otherwise arms the timer to wake this task then.
    fn check(&mut self, cx: &mut Context<'_>) -> io::Result<()> {
        let (at, rule) = self.deadline();
        if at != self.armed_for {
            self.timer.as_mut().reset(at);
            self.armed_for = at;
        }
        match self.timer.as_mut().poll(cx) {
            Poll::Ready(()) => Err(timed_out(rule)),
            Poll::Pending => Ok(()),
        }
    }
}

impl<S: AsyncRead + Unpin> AsyncRead for Guarded<S> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        if let Err(e) = self.check(cx) {
            return Poll::Ready(Err(e));
        }
        Pin::new(&mut self.io).poll_read(cx, buf)
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for Guarded<S> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let polled = Pin::new(&mut self.io).poll_write(cx, buf);
        match &polled {
            Poll::Ready(Ok(n)) if *n > 0 => {
                self.last_sent = Some(Instant::now());
                self.send_waiting_since = None;
            }
            Poll::Pending => {
                if self.send_waiting_since.is_none() {
                    self.send_waiting_since = Some(Instant::now());
                }
                if let Err(e) = self.check(cx) {
                    return Poll::Ready(Err(e));
                }
            }
            _ => {}
        }
        polled
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.io).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.io).poll_shutdown(cx)
    }
}

/// A TCP listener that admits at most `max` connections at once, each [`Guarded`].
pub struct GuardedListener {
    inner: TcpListener,
    permits: Arc<Semaphore>,
    limits: Limits,
}

impl GuardedListener {
    pub fn new(inner: TcpListener, max: usize, limits: Limits) -> Self {
        Self {
            inner,
            permits: Arc::new(Semaphore::new(max.max(1))),
            limits,
        }
    }
}

impl axum::serve::Listener for GuardedListener {
    type Io = Guarded<TcpStream>;
    type Addr = std::net::SocketAddr;

    async fn accept(&mut self) -> (Self::Io, Self::Addr) {
        // The permit first: while all are taken, new connections wait in the backlog.
        let permit = self.permits.clone().acquire_owned().await.ok();
        loop {
            match self.inner.accept().await {
                Ok((stream, addr)) => {
                    let _ = stream.set_nodelay(true);
                    return (Guarded::new(stream, self.limits, permit), addr);
                }
                Err(e) => {
                    // Out of file descriptors and the like: log, back off, go on.
                    tracing::warn!(error = %e, "web: accept failed");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                }
            }
        }
    }

    fn local_addr(&self) -> io::Result<Self::Addr> {
        self.inner.local_addr()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt, duplex};

    const LIMITS: Limits = Limits {
        request: Duration::from_secs(10),
        stall: Duration::from_secs(5),
        idle: Duration::from_secs(60),
    };

    #[tokio::test(start_paused = true)]
    async fn a_request_that_never_ends_is_closed_after_the_request_limit() {
        let (server, mut client) = duplex(1024);
        let mut g = Guarded::new(server, LIMITS, None);
        let t0 = Instant::now();
        // The client dribbles a byte a second: reading is no progress.
        let dribble = tokio::spawn(async move {
            for _ in 0..30 {
                if client.write_all(b"G").await.is_err() {
                    break;
                }
                tokio::time::sleep(Duration::from_secs(1)).await;
            }
        });
        let mut buf = [0u8; 16];
        let err = loop {
            match g.read(&mut buf).await {
                Ok(_) => continue,
                Err(e) => break e,
            }
        };
        assert_eq!(err.kind(), io::ErrorKind::TimedOut);
        assert!(err.to_string().contains("request_timeout_ms"), "{err}");
        assert_eq!(t0.elapsed(), Duration::from_secs(10));
        drop(g);
        let _ = dribble.await;
    }

    #[tokio::test(start_paused = true)]
    async fn a_client_that_stops_taking_data_is_closed_after_the_stall_limit() {
        // A 64-byte pipe nobody reads: the second write waits, and 5 s later fails.
        let (server, _client) = duplex(64);
        let mut g = Guarded::new(server, LIMITS, None);
        g.write_all(&[0u8; 64]).await.unwrap();
        let t0 = Instant::now();
        let err = g.write_all(&[0u8; 64]).await.unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::TimedOut);
        assert!(err.to_string().contains("stall_timeout_ms"), "{err}");
        assert_eq!(t0.elapsed(), Duration::from_secs(5));
    }

    #[tokio::test(start_paused = true)]
    async fn sending_keeps_a_connection_open_and_silence_closes_it_after_the_idle_limit() {
        let (server, mut client) = duplex(1 << 16);
        let mut g = Guarded::new(server, LIMITS, None);
        let t0 = Instant::now();
        // A status every 2 s for 100 s: past every limit, still open.
        for _ in 0..50 {
            g.write_all(b"status").await.unwrap();
            let mut got = [0u8; 6];
            client.read_exact(&mut got).await.unwrap();
            tokio::time::sleep(Duration::from_secs(2)).await;
        }
        assert_eq!(t0.elapsed(), Duration::from_secs(100));
        // Then nothing is sent: a read waiting for the next request ends 60 s after the
        // last send (58 s from here).
        let t1 = Instant::now();
        let mut buf = [0u8; 4];
        let err = g.read(&mut buf).await.unwrap_err();
        assert!(err.to_string().contains("idle_timeout_ms"), "{err}");
        assert_eq!(t1.elapsed(), Duration::from_secs(58));
    }

    #[tokio::test]
    async fn the_listener_admits_at_most_max_connections() {
        use axum::serve::Listener;
        let tcp = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = tcp.local_addr().unwrap();
        let mut l = GuardedListener::new(tcp, 1, LIMITS);
        let _a = TcpStream::connect(addr).await.unwrap();
        let _b = TcpStream::connect(addr).await.unwrap();
        let (first, _) = l.accept().await;
        // The second waits for the first's permit...
        let waited = tokio::time::timeout(Duration::from_millis(200), l.accept()).await;
        assert!(waited.is_err(), "a second connection was admitted");
        // ... and is admitted once the first closes.
        drop(first);
        let second = tokio::time::timeout(Duration::from_secs(2), l.accept()).await;
        assert!(second.is_ok());
    }
}
