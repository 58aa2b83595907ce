//! The web page's token: made on first start (32 random bytes from the OS, as hex), kept
//! in a file only its owner can read (0600), printed once to the log; checked on every
//! route but the login page. A browser presents it as a cookie (set by the login page or
//! by opening `/?token=...` once); scripts send `Authorization: Bearer ...` or `?token=`.

use std::io::Write;
use std::os::unix::fs::{DirBuilderExt, OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};

use axum::http::HeaderMap;

/// The cookie that carries the token.
pub const COOKIE: &str = "jetpilot_token";

#[derive(Debug, thiserror::Error)]
pub enum TokenError {
    #[error("web token {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("web token {path}: {why}; delete it and a new one is made at the next start")]
    Bad { path: PathBuf, why: String },
}

/// The token in `path`, made (with its folder) if the file does not exist. Returns the
/// token and whether it was just made. A token file that others can read is made private.
pub fn load_or_create(path: &Path) -> Result<(String, bool), TokenError> {
    let io = |source| TokenError::Io {
        path: path.to_path_buf(),
        source,
    };
    match std::fs::read_to_string(path) {
        Ok(text) => {
            let token = text.trim().to_string();
            if token.len() < 32 || !token.chars().all(|c| c.is_ascii_alphanumeric()) {
                return Err(TokenError::Bad {
                    path: path.to_path_buf(),
                    why: "not a token (32 or more letters and digits)".into(),
                });
            }
            let mode = std::fs::metadata(path).map_err(io)?.permissions().mode();
            if mode & 0o077 != 0 {
                tracing::warn!(path = %path.display(), mode = format!("{:o}", mode & 0o777), "web token readable by others: made private (0600)");
                std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o600))
                    .map_err(io)?;
            }
            Ok((token, false))
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::DirBuilder::new()
                    .recursive(true)
                    .mode(0o700)
                    .create(dir)
                    .map_err(io)?;
            }
            let token = new_token().map_err(io)?;
            let mut f = std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .mode(0o600)
                .open(path)
                .map_err(io)?;
            f.write_all(format!("{token}\n").as_bytes())
                .and_then(|_| f.sync_all())
                .map_err(io)?;
            Ok((token, true))
        }
        Err(e) => Err(io(e)),
    }
}

/// 32 bytes from the OS's random source, as 64 hex digits.
fn new_token() -> std::io::Result<String> {
    use std::io::Read;
    let mut bytes = [0u8; 32];
    std::fs::File::open("/dev/urandom")?.read_exact(&mut bytes)?;
    Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
}

/// Compares in time independent of where the strings differ.
pub fn same(given: &str, expected: &str) -> bool {
    let (a, b) = (given.as_bytes(), expected.as_bytes());
    let mut diff = a.len() ^ b.len();
    for (i, &y) in b.iter().enumerate() {
        let x = a.get(i).copied().unwrap_or(0);
        diff |= usize::from(x ^ y);
    }
    diff == 0
}

/// The token a request presents: `Authorization: Bearer`, the cookie, or `token=` in the
/// query, in that order.
pub fn presented(headers: &HeaderMap, query: Option<&str>) -> Option<String> {
    let header = |name| headers.get(name).and_then(|v| v.to_str().ok());
    if let Some(t) =
        header(axum::http::header::AUTHORIZATION).and_then(|v| v.strip_prefix("Bearer "))
    {
        return Some(t.trim().to_string());
    }
    for value in headers.get_all(axum::http::header::COOKIE) {
        let Ok(v) = value.to_str() else { continue };
        for pair in v.split(';') {
            if let Some(t) = pair
                .trim()
                .strip_prefix(COOKIE)
                .and_then(|r| r.strip_prefix('='))
            {
                return Some(t.to_string());
            }
        }
    }
    query_token(query)
}

/// `token=...` from a query string.
pub fn query_token(query: Option<&str>) -> Option<String> {
    query?
        .split('&')
        .find_map(|kv| kv.strip_prefix("token="))
        .map(str::to_string)
}

/// The `Set-Cookie` value that keeps `token` in the browser.
pub fn cookie(token: &str) -> String {
    format!("{COOKIE}={token}; Path=/; HttpOnly; SameSite=Strict; Max-Age=31536000")
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::http::HeaderValue;

    #[test]
    fn a_new_token_folder_is_private_and_tokens_are_random() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a/b/web-token");
        let (t1, made) = load_or_create(&path).unwrap();
        assert!(made && t1.len() == 64 && t1.chars().all(|c| c.is_ascii_hexdigit()));
        for d in [dir.path().join("a"), dir.path().join("a/b")] {
            let mode = std::fs::metadata(&d).unwrap().permissions().mode() & 0o777;
            assert_eq!(mode, 0o700, "{}", d.display());
        }
        // The OS's random source, not a constant.
        let (t2, _) = load_or_create(&dir.path().join("c/web-token")).unwrap();
        assert_ne!(t1, t2);
        // A file holding anything but letters and digits is refused, not sent as a token.
        std::fs::write(&path, "0123456789abcdef0123456789abcdef; x=1\n").unwrap();
        assert!(load_or_create(&path).is_err());
    }

    #[test]
    fn a_token_is_made_once_private_and_then_reused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("state/web-token");
        let (t1, made) = load_or_create(&path).unwrap();
        assert!(made);
        assert_eq!(t1.len(), 64);
        let meta = std::fs::metadata(&path).unwrap();
        assert_eq!(meta.permissions().mode() & 0o777, 0o600);
        let (t2, made) = load_or_create(&path).unwrap();
        assert!(!made);
        assert_eq!(t1, t2);
        // Widened by someone: made private again, same token.
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o644)).unwrap();
        assert_eq!(load_or_create(&path).unwrap().0, t1);
        assert_eq!(
            std::fs::metadata(&path).unwrap().permissions().mode() & 0o777,
            0o600
        );
        std::fs::write(&path, "short\n").unwrap();
        let e = load_or_create(&path).unwrap_err().to_string();
        assert!(e.contains("web-token") && e.contains("not a token"), "{e}");
    }

    #[test]
    fn comparison_and_extraction() {
        assert!(same("abc", "abc"));
        assert!(!same("abd", "abc"));
        assert!(!same("ab", "abc"));
        assert!(!same("abcd", "abc"));
        assert!(!same("", "abc"));
        let mut h = HeaderMap::new();
        assert_eq!(presented(&h, Some("a=1&token=xyz")), Some("xyz".into()));
        h.insert(
            axum::http::header::COOKIE,
            HeaderValue::from_static("theme=dark; jetpilot_token=c00k1e"),
        );
        assert_eq!(presented(&h, Some("token=xyz")), Some("c00k1e".into()));
        h.insert(
            axum::http::header::AUTHORIZATION,
            HeaderValue::from_static("Bearer b3arer"),
        );
        assert_eq!(presented(&h, None), Some("b3arer".into()));
        assert_eq!(presented(&HeaderMap::new(), None), None);
    }
}
