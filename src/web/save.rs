//! "Save to config": writes the gains back into the config's `[control]` table, keeping
//! the rest of the file (comments, order, other keys) as it was. The new text must load as
//! a valid config before it replaces the old file, which happens by a rename of a fully
//! written temporary file beside it (a crash leaves the old file or the new one, never half).

use std::io::Write;
use std::path::{Path, PathBuf};

use toml_edit::{DocumentMut, Item, Table, Value};

use crate::control::SteeringGains;

#[derive(Debug, thiserror::Error)]
pub enum SaveError {
    #[error("config {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("config {path}: cannot edit: {why}")]
    Edit { path: PathBuf, why: String },
}

/// `text` with `[control]`'s gains set to `g` (4 decimals); a value's trailing comment is kept.
pub fn with_gains(text: &str, g: &SteeringGains) -> Result<String, String> {
    let mut doc: DocumentMut = text.parse().map_err(|e| format!("{e}"))?;
    let control = doc
        .entry("control")
        .or_insert_with(|| Item::Table(Table::new()))
        .as_table_mut()
        .ok_or("`control` is not a table")?;
    let round = |v: f32| (f64::from(v) * 10_000.0).round() / 10_000.0;
    for (key, v) in [
        ("speed_gain", g.speed_gain),
        ("steering_gain", g.steering_gain),
        ("steering_kd", g.steering_kd),
        ("steering_bias", g.steering_bias),
        ("steering_ki", g.steering_ki),
    ] {
        let mut new = Value::from(round(v));
        match control.get_mut(key).and_then(Item::as_value_mut) {
            Some(old) => {
                *new.decor_mut() = old.decor().clone();
                *old = new;
            }
            None => {
                control.insert(key, Item::Value(new));
            }
        }
    }
    Ok(doc.to_string())
}

/// Rewrites the config at `path` with the gains `g`.
pub fn save_gains(path: &Path, g: &SteeringGains) -> Result<(), SaveError> {
    let io = |source| SaveError::Io {
        path: path.to_path_buf(),
        source,
    };
    let text = std::fs::read_to_string(path).map_err(io)?;
    let new = with_gains(&text, g).map_err(|why| SaveError::Edit {
        path: path.to_path_buf(),
        why,
    })?;
    crate::config::Config::parse(&new, &path.display().to_string()).map_err(|e| {
        SaveError::Edit {
            path: path.to_path_buf(),
            why: format!("the result would not load: {e}"),
        }
    })?;
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_default();
    let perms = std::fs::metadata(path).map_err(io)?.permissions();
    // One save at a time in this process; each into its own temporary file beside the
    // config (removed if anything fails), renamed over it only when complete.
    static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _guard = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let write = || -> std::io::Result<()> {
        let mut tmp = tempfile::Builder::new()
            .prefix(&format!(".{name}."))
            .suffix(".jetpilot-save")
            .tempfile_in(dir)?;
        tmp.write_all(new.as_bytes())?;
        tmp.as_file().set_permissions(perms.clone())?;
        tmp.as_file().sync_all()?;
        tmp.persist(path).map_err(|e| e.error)?;
        if let Ok(d) = std::fs::File::open(dir) {
            let _ = d.sync_all();
        }
        Ok(())
    };
    write().map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gains() -> SteeringGains {
        SteeringGains {
            speed_gain: 0.25,
            steering_gain: 0.3,
            steering_kd: 0.05,
            steering_bias: -0.02,
            steering_ki: 0.0,
            ..Default::default()
        }
    }

    #[test]
    fn gains_replace_values_and_keep_comments_and_other_keys() {
        let text = "# my robot\n[camera]\nfps = 30.0\n\n[control]\nspeed_gain = 0.1   # slow at first\nsteering_gain = 0.2\nintegral_limit = 0.3\n";
        let out = with_gains(text, &gains()).unwrap();
        assert!(
            out.starts_with("# my robot\n[camera]\nfps = 30.0\n"),
            "{out}"
        );
        assert!(
            out.contains("speed_gain = 0.25   # slow at first\n"),
            "{out}"
        );
        assert!(out.contains("steering_gain = 0.3\n"), "{out}");
        assert!(out.contains("integral_limit = 0.3\n"), "{out}");
        assert!(out.contains("steering_kd = 0.05\n"), "{out}");
        assert!(out.contains("steering_bias = -0.02\n"), "{out}");
        // Without a [control] table, one is added.
        let out = with_gains("[camera]\nfps = 30.0\n", &gains()).unwrap();
        assert!(out.contains("[control]\nspeed_gain = 0.25\n"), "{out}");
        assert!(with_gains("control = 3\n", &gains()).is_err());
    }

    #[test]
    fn saving_rewrites_the_file_atomically_and_refuses_a_broken_one() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("robot.toml");
        std::fs::write(&path, "[control]\nspeed_gain = 0.1 # keep\n").unwrap();
        save_gains(&path, &gains()).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.contains("speed_gain = 0.25 # keep"), "{text}");
        let cfg = crate::config::Config::load(&path).unwrap();
        assert_eq!(cfg.control.gains().steering_kd, 0.05);
        // No temporary file is left behind.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        // A file that does not parse is left as it was.
        std::fs::write(&path, "[control\n").unwrap();
        let e = save_gains(&path, &gains()).unwrap_err().to_string();
        assert!(e.contains("robot.toml"), "{e}");
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "[control\n");
        let e = save_gains(&dir.path().join("missing.toml"), &gains())
            .unwrap_err()
            .to_string();
        assert!(e.contains("missing.toml"), "{e}");
    }
}
