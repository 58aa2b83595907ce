//! The book's generated reference pages, so they cannot drift from the code (tests compare
//! them; `JETPILOT_BLESS=1` rewrites them):
//! - `docs/reference/cli-help.md`: every command's `--help`, from the clap definitions;
//! - `docs/reference/config-keys.md`: every config key with its type, default and unit:
//!   the defaults from `Config::default()`, the keys that are unset by default from the
//!   shipped configs (each checked to parse) and from the config structs' fields in `src/`
//!   (each checked to be a key serde knows); the meaning is the field's doc comment, else the
//!   shipped configs' comment on the key.

use std::collections::BTreeMap;
use std::path::Path;

use clap::CommandFactory;
use jetpilot::config::Config;

/// The page's text: one section per command, depth first, each with its long help at a
/// fixed width of 100 columns.
pub fn markdown() -> String {
    let mut out = String::from(
        "# Command reference\n\n\
         Generated from the binary's clap definitions (a build with `--features train`, as the\n\
         test suite builds it; without it the `train il`, `train ddpg`, ... commands are\n\
         absent). A test keeps it in step: after changing a command, run\n\
         `JETPILOT_BLESS=1 scripts/test.sh -E 'test(/cli_reference/)'`. The overview with\n\
         examples: [Commands](cli.md).\n",
    );
    let mut root = super::Cli::command().term_width(100).max_term_width(100);
    root.build();
    section(&mut out, &mut root, "jetpilot");
    out
}

fn section(out: &mut String, cmd: &mut clap::Command, path: &str) {
    let help = cmd.render_long_help().to_string();
    out.push_str(&format!("\n## `{path}`\n\n```text\n"));
    for line in help.trim_end().lines() {
        out.push_str(line.trim_end());
        out.push('\n');
    }
    out.push_str("```\n");
    let mut subs: Vec<clap::Command> = cmd
        .get_subcommands()
        .filter(|s| s.get_name() != "help")
        .cloned()
        .collect();
    for sub in &mut subs {
        let name = format!("{path} {}", sub.get_name());
        section(out, sub, &name);
    }
}

/// One key of the config page.
struct Key {
    kind: String,
    default: Option<String>,
    comment: Option<String>,
}

fn kind(v: &toml::Value) -> &'static str {
    match v {
        toml::Value::String(_) => "string",
        toml::Value::Integer(_) => "integer",
        toml::Value::Float(_) => "float",
        toml::Value::Boolean(_) => "bool",
        toml::Value::Datetime(_) => "datetime",
        toml::Value::Array(_) => "array",
        toml::Value::Table(_) => "table",
    }
}

/// `value` as TOML, shortened past 60 characters.
fn shown(v: &toml::Value) -> String {
    // An f32 default as the f32's shortest decimal (0.3, not 0.30000001192092896).
    let s = match v {
        toml::Value::Float(f) if f64::from(*f as f32) == *f => {
            let short = (*f as f32).to_string();
            if short.contains(['.', 'e', 'i', 'N']) {
                short
            } else {
                format!("{short}.0")
            }
        }
        v => v.to_string(),
    };
    if s.chars().count() > 60 {
        format!("{} ...", s.chars().take(56).collect::<String>())
    } else {
        s
    }
}

/// Dotted keys of `table` (sub-tables recursed into) into `keys`.
fn flatten(prefix: &str, table: &toml::Table, keys: &mut BTreeMap<String, Key>) {
    for (k, v) in table {
        let key = format!("{prefix}{k}");
        match v {
            toml::Value::Table(t) => flatten(&format!("{key}."), t, keys),
            v => {
                keys.insert(
                    key,
                    Key {
                        kind: kind(v).into(),
                        default: Some(shown(v)),
                        comment: None,
                    },
                );
            }
        }
    }
}

/// `key = value  # comment` lines of a shipped config, commented out (`# key = value`) or not,
/// under their `[table]` (also commented out): `(dotted key, value text, comment)`.
fn config_lines(text: &str) -> Vec<(String, String, Option<String>)> {
    let mut table = String::new();
    let mut out = Vec::new();
    for line in text.lines() {
        let l = line.trim().trim_start_matches('#').trim();
        if let Some(name) = l.strip_prefix('[').and_then(|r| r.split_once(']')) {
            let name = name.0.trim();
            if !name.is_empty()
                && name
                    .chars()
                    .all(|c| c.is_ascii_lowercase() || c == '_' || c == '.')
            {
                table = name.to_string();
            }
            continue;
        }
        let Some((k, rest)) = l.split_once('=') else {
            continue;
        };
        let k = k.trim();
        if k.is_empty()
            || !k
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
        {
            continue;
        }
        let (value, comment) = match rest.split_once(" #") {
            Some((v, c)) => (
                v.trim(),
                Some(c.trim().to_string()).filter(|c| !c.is_empty()),
            ),
            None => (rest.trim(), None),
        };
        let key = if table.is_empty() {
            k.to_string()
        } else {
            format!("{table}.{k}")
        };
        out.push((key, value.to_string(), comment));
    }
    out
}

/// A struct field as the source declares it: its type's name and its doc comment.
struct Field {
    ty: String,
    doc: String,
}

/// The fields of every struct in `src/` (`name -> field -> Field`), read from the source
/// text: `///` lines, then `pub name: Type,` (a `#[serde(rename = "...")]` names the key).
/// `src/config.rs` is read first, and the first struct of a name wins.
fn struct_fields(repo: &Path) -> BTreeMap<String, BTreeMap<String, Field>> {
    let mut files = vec![repo.join("src/config.rs")];
    let mut stack = vec![repo.join("src")];
    while let Some(dir) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        let mut paths: Vec<_> = entries.filter_map(|e| e.ok()).map(|e| e.path()).collect();
        paths.sort();
        for p in paths {
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|e| e == "rs") && !files.contains(&p) {
                files.push(p);
            }
        }
    }
    let mut structs: BTreeMap<String, BTreeMap<String, Field>> = BTreeMap::new();
    for file in files {
        let text = std::fs::read_to_string(&file).unwrap_or_default();
        let mut current: Option<(String, String, BTreeMap<String, Field>)> = None;
        let (mut doc, mut rename) = (Vec::<String>::new(), None::<String>);
        for line in text.lines() {
            let t = line.trim();
            if current.is_none() {
                let head = t
                    .trim_start_matches("pub ")
                    .trim_start_matches("pub(crate) ");
                if let Some(rest) = head.strip_prefix("struct ")
                    && rest.ends_with('{')
                {
                    let name: String = rest
                        .chars()
                        .take_while(|c| c.is_alphanumeric() || *c == '_')
                        .collect();
                    let indent = line.len() - line.trim_start().len();
                    current = Some((name, " ".repeat(indent) + "}", BTreeMap::new()));
                    doc.clear();
                    rename = None;
                }
                continue;
            }
            let Some((_, close, fields)) = current.as_mut() else {
                continue;
            };
            if line == close.as_str() {
                let (name, _, fields) = current.take().unwrap_or_default();
                structs.entry(name).or_insert(fields);
                continue;
            }
            if let Some(d) = t.strip_prefix("///") {
                doc.push(d.trim().to_string());
            } else if t.starts_with("#[") {
                if let Some(r) = t
                    .split("rename = \"")
                    .nth(1)
                    .and_then(|r| r.split('"').next())
                {
                    rename = Some(r.to_string());
                }
            } else if let Some((field, ty)) = t
                .strip_prefix("pub ")
                .or_else(|| t.strip_prefix("pub(crate) "))
                .and_then(|f| f.split_once(": "))
            {
                let key = rename
                    .take()
                    .unwrap_or_else(|| field.trim_start_matches("r#").to_string());
                let ty = ty.trim_end_matches(',');
                let ty = ty
                    .strip_prefix("Option<")
                    .and_then(|t| t.strip_suffix('>'))
                    .unwrap_or(ty);
                let ty = ty.rsplit("::").next().unwrap_or(ty).to_string();
                fields.insert(
                    key,
                    Field {
                        ty,
                        doc: doc.join(" "),
                    },
                );
                doc.clear();
            } else {
                doc.clear();
                rename = None;
            }
        }
    }
    structs
}

/// The doc comment of dotted `key`, found by walking from `Config` through the field types.
fn key_doc(structs: &BTreeMap<String, BTreeMap<String, Field>>, key: &str) -> Option<String> {
    let mut ty = "Config".to_string();
    let mut doc = None;
    for part in key.split('.') {
        let field = structs.get(&ty)?.get(part)?;
        doc = Some(field.doc.clone());
        ty = field.ty.clone();
    }
    doc.filter(|d| !d.is_empty()).map(|d| plain(&d))
}

/// Doc-comment markdown made plain for a table cell: `[text](target)` and `[`path`]` become
/// their text.
fn plain(doc: &str) -> String {
    let mut out = String::new();
    let mut rest = doc;
    while let Some(open) = rest.find('[') {
        out.push_str(&rest[..open]);
        let after = &rest[open + 1..];
        let Some(close) = after.find(']') else {
            out.push_str(&rest[open..]);
            return out;
        };
        out.push_str(&after[..close]);
        rest = &after[close + 1..];
        if let Some(target) = rest.strip_prefix('(')
            && let Some(end) = target.find(')')
        {
            rest = &target[end + 1..];
        }
    }
    out.push_str(rest);
    out
}

/// Every leaf key reachable from `Config` through the struct fields read from `src/`: a field
/// whose type is one of those structs is a table, any other field a key. Returns `(dotted
/// key, the field's Rust type)`.
fn source_keys(structs: &BTreeMap<String, BTreeMap<String, Field>>) -> Vec<(String, String)> {
    let mut out = Vec::new();
    let mut stack = vec![(String::new(), "Config".to_string(), 0)];
    while let Some((prefix, ty, depth)) = stack.pop() {
        let Some(fields) = structs.get(&ty) else {
            continue;
        };
        for (name, field) in fields {
            let key = format!("{prefix}{name}");
            if structs.contains_key(&field.ty) && depth < 6 {
                stack.push((format!("{key}."), field.ty.clone(), depth + 1));
            } else {
                out.push((key, field.ty.clone()));
            }
        }
    }
    out
}

/// Whether serde knows dotted `key` (a value of the wrong type is fine: only an unknown
/// field or table is refused, since every config struct denies unknown fields).
fn known(key: &str) -> bool {
    let (table, k) = key.rsplit_once('.').unwrap_or(("", key));
    let text = if table.is_empty() {
        format!("{k} = {{}}\n")
    } else {
        format!("[{table}]\n{k} = {{}}\n")
    };
    match toml::from_str::<Config>(&text) {
        Ok(_) => true,
        Err(e) => !e.to_string().contains("unknown field"),
    }
}

/// The TOML type a Rust field type takes: a primitive's, an array's, else the type's own name
/// (an enum written as a string; its values are in the meaning).
fn rust_kind(ty: &str) -> String {
    match ty {
        "String" | "PathBuf" => "string".into(),
        "f32" | "f64" => "float".into(),
        "bool" => "bool".into(),
        "u8" | "u16" | "u32" | "u64" | "usize" | "i8" | "i16" | "i32" | "i64" => "integer".into(),
        t if t.starts_with("Vec<") || t.starts_with('[') => "array".into(),
        t => format!("`{t}`"),
    }
}

/// The unit of `key`: from its name's suffix (`_ms`, `_s`, `_m`, `_deg`, ...), else from a
/// unit its meaning names ("metres", "(m/s)", ...); empty where neither says one.
fn unit(key: &str, meaning: &str) -> &'static str {
    const SUFFIXES: [(&str, &str); 12] = [
        ("_px_per_m", "px/m"),
        ("_ms", "ms"),
        ("_s", "s"),
        ("_seconds", "s"),
        ("_m", "m"),
        ("_mps", "m/s"),
        ("_deg", "degrees"),
        ("_hz", "Hz"),
        ("_mib", "MiB"),
        ("_mb", "MB"),
        ("_px", "px"),
        ("_frames", "frames"),
    ];
    let name = key.rsplit('.').next().unwrap_or(key);
    if let Some((_, u)) = SUFFIXES.iter().find(|(s, _)| name.ends_with(s)) {
        return u;
    }
    const WORDS: [(&str, &str); 11] = [
        ("(m/s)", "m/s"),
        ("metres", "m"),
        ("(m)", "m"),
        ("degrees", "degrees"),
        ("milliseconds", "ms"),
        ("(s)", "s"),
        ("seconds", "s"),
        ("in pixels", "px"),
        (", pixels", "px"),
        ("frames per second", "Hz"),
        ("fraction", "fraction"),
    ];
    let meaning = meaning.to_lowercase();
    WORDS
        .iter()
        .find(|(w, _)| meaning.contains(w))
        .map_or("", |(_, u)| u)
}

/// Whether `key = value` alone parses as a config (the key exists, the value has its type).
fn parses(key: &str, value: &str) -> bool {
    let (table, k) = key.rsplit_once('.').unwrap_or(("", key));
    let text = if table.is_empty() {
        format!("{k} = {value}\n")
    } else {
        format!("[{table}]\n{k} = {value}\n")
    };
    toml::from_str::<Config>(&text).is_ok()
}

/// The config page.
pub fn config_markdown(repo: &Path) -> String {
    let mut keys = BTreeMap::new();
    let mut root = toml::Table::try_from(Config::default()).unwrap_or_default();
    if let Ok(g) = toml::Table::try_from(jetpilot::hw::gamepad::GamepadConfig::default()) {
        root.insert("gamepad".into(), toml::Value::Table(g));
    }
    flatten("", &root, &mut keys);
    let mut files: Vec<_> = std::fs::read_dir(repo.join("config"))
        .map(|d| d.filter_map(|e| e.ok()).map(|e| e.path()).collect())
        .unwrap_or_default();
    files.retain(|p: &std::path::PathBuf| p.extension().is_some_and(|e| e == "toml"));
    // The JetBot's and the simulator's configs speak first (their comments are the fullest).
    files.sort_by_key(|p| {
        let name = p.file_name().map(|n| n.to_string_lossy().to_string());
        let rank = match name.as_deref() {
            Some("jetbot.toml") => 0,
            Some("sim.toml") => 1,
            _ => 2,
        };
        (rank, p.clone())
    });
    for file in &files {
        let text = std::fs::read_to_string(file).unwrap_or_default();
        for (key, value, comment) in config_lines(&text) {
            if let Some(k) = keys.get_mut(&key) {
                if k.comment.is_none() {
                    k.comment = comment;
                }
            } else if parses(&key, &value) {
                let v: Option<toml::Value> = toml::from_str::<toml::Table>(&format!("v = {value}"))
                    .ok()
                    .and_then(|t| t.get("v").cloned());
                keys.insert(
                    key,
                    Key {
                        kind: v.as_ref().map_or("?", kind).into(),
                        default: None,
                        comment,
                    },
                );
            }
        }
    }
    let structs = struct_fields(repo);
    for (key, ty) in source_keys(&structs) {
        if !keys.contains_key(&key) && known(&key) {
            keys.insert(
                key,
                Key {
                    kind: rust_kind(&ty),
                    default: None,
                    comment: None,
                },
            );
        }
    }
    // A shipped config's inline table (`pwm = { chip = 0, channel = 0 }`) is listed by its keys.
    let tables: Vec<String> = keys
        .keys()
        .filter(|k| keys.keys().any(|o| o.starts_with(&format!("{k}."))))
        .cloned()
        .collect();
    for t in tables {
        keys.remove(&t);
    }
    let mut out = String::from(
        "# Config keys\n\n\
         Generated from the code: each key's type and default come from `Config::default()`\n\
         (`[gamepad]`: from its default, used when the table is present); keys unset by\n\
         default (*unset*) are the ones the shipped configs in `config/` set or show commented\n\
         out (each checked to parse) and every other field of the config structs in `src/`\n\
         (found by walking the field types from `Config`, each checked to be a key the parser\n\
         knows; a type in backticks is the Rust type, its values in the meaning). The meaning\n\
         is the doc comment of the key's field, else the shipped configs' comment on the key.\n\
         The unit comes from the key's name (`_ms`, `_s`, `_m`, `_hz`, `_deg`, ...) or from a\n\
         unit the meaning names; an empty unit is a count, a ratio or a name. A test\n\
         keeps it in step: after changing a key, run\n\
         `JETPILOT_BLESS=1 scripts/test.sh -E 'test(/config_reference/)'`. How files are read\n\
         and checked: [Configs](configs.md).\n",
    );
    let mut section = String::from("\u{0}");
    for (key, k) in &keys {
        let table = key.rsplit_once('.').map_or("", |(t, _)| t);
        let top = table.split('.').next().unwrap_or("");
        if top != section {
            section = top.to_string();
            out.push_str(&format!(
                "\n## `[{top}]`\n\n| key | type | default | unit | meaning |\n|---|---|---|---|---|\n"
            ));
        }
        // Markdown table cells: `|` escaped, `<uuid>` not read as an HTML tag.
        let cell = |s: &str| {
            s.replace('|', "\\|")
                .replace('<', "&lt;")
                .replace('>', "&gt;")
        };
        let meaning = key_doc(&structs, key)
            .or_else(|| k.comment.clone())
            .unwrap_or_default();
        out.push_str(&format!(
            "| `{key}` | {} | {} | {} | {} |\n",
            k.kind,
            k.default
                .as_deref()
                .map_or("*unset*".into(), |d| format!("`{}`", cell(d))),
            unit(key, &meaning),
            cell(&meaning),
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn cli_reference_page_is_the_help_the_binary_prints() {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/reference/cli-help.md");
        let want = super::markdown();
        if std::env::var_os("JETPILOT_BLESS").is_some() {
            std::fs::write(&path, &want).unwrap();
        }
        let have = std::fs::read_to_string(&path).unwrap_or_default();
        assert!(
            have == want,
            "{} is out of date: run JETPILOT_BLESS=1 scripts/test.sh -E 'test(/cli_reference/)' and commit it",
            path.display()
        );
    }

    #[test]
    fn config_reference_page_lists_every_key_with_its_default() {
        let repo = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let path = repo.join("docs/reference/config-keys.md");
        let want = super::config_markdown(repo);
        if std::env::var_os("JETPILOT_BLESS").is_some() {
            std::fs::write(&path, &want).unwrap();
        }
        let have = std::fs::read_to_string(&path).unwrap_or_default();
        assert!(
            have == want,
            "{} is out of date: run JETPILOT_BLESS=1 scripts/test.sh -E 'test(/config_reference/)' and commit it",
            path.display()
        );
        // Worked rows: a default, and a key unset by default found in the shipped configs.
        assert!(
            want.contains("| `web.heartbeat_ms` | integer | `500` | ms |"),
            "{want}"
        );
        assert!(
            want.contains("| `web.xy_dir` | string | *unset* |"),
            "{want}"
        );
        // Keys unset by default that no shipped config mentions, found in the source.
        for key in [
            "web.token_path",
            "gamepad.axes.left_x",
            "motors.gpio.left.in1_pwm.chip",
        ] {
            assert!(
                want.contains(&format!("| `{key}` |")),
                "{key} missing:\n{want}"
            );
        }
    }

    #[test]
    fn every_key_serde_knows_is_found_and_nothing_else() {
        // A key of the walk that is not a config key is refused; a real one is known.
        assert!(super::known("web.token_path"));
        assert!(super::known("sim.robot.motor.time_constant_s"));
        assert!(!super::known("web.no_such_key"));
        assert!(!super::known("no_such_table.key"));
        assert_eq!(super::unit("safety.watchdog_ms", ""), "ms");
        assert_eq!(super::unit("sim.camera.height_m", ""), "m");
        assert_eq!(
            super::unit("sim.camera.forward", "Distance ahead, metres."),
            "m"
        );
        assert_eq!(super::unit("model.std", "Per-channel std."), "");
        assert_eq!(super::unit("sim.mat_px_per_m", ""), "px/m");
        assert_eq!(
            super::unit("camera.fps", "Frames per second delivered."),
            "Hz"
        );
        assert_eq!(super::rust_kind("Option<u8>"), "`Option<u8>`");
        assert_eq!(super::rust_kind("PathBuf"), "string");
    }
}
