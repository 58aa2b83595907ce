//! What a browser (or anyone on the network) sends the web page: WebSocket control messages
//! (JSON) and the request headers the token and origin checks read (Cookie, Authorization,
//! Host, the query string).
#![no_main]
use jetpilot::web::{auth, server};

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = serde_json::from_slice::<server::ClientMsg>(data);
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    // First line: the query string; the rest: `name: value` header lines.
    let mut lines = text.split('\n');
    let query = lines.next();
    let mut headers = http::HeaderMap::new();
    for line in lines {
        if let Some((k, v)) = line.split_once(':')
            && let (Ok(k), Ok(v)) = (
                http::HeaderName::from_bytes(k.trim().as_bytes()),
                http::HeaderValue::from_str(v.trim()),
            )
        {
            headers.append(k, v);
        }
    }
    let _ = auth::presented(&headers, query);
    let _ = auth::query_token(query);
    if let Some(host) = headers.get(http::header::HOST).and_then(|h| h.to_str().ok()) {
        let _ = server::loopback_host(host);
    }
    let _ = auth::same(text, "0123456789abcdef");
});
