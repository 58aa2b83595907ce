//! DonkeyCar tub v2: the project's episode format, so DonkeyCar users' tools (`donkey train`,
//! `donkey ui`, tub cleaning) keep working on what jetpilot records.
//!
//! A tub is a folder:
//!
//! ```text
//! manifest.json                  five lines of JSON (see below)
//! catalog_0.catalog              newline-delimited JSON records, 1000 per catalog
//! catalog_0.catalog_manifest     {"created_at", "line_lengths", "path", "start_index"}
//! catalog_1.catalog ...
//! images/<index>_cam_image_array_.jpg
//! ```
//!
//! `manifest.json` lines, as DonkeyCar's `datastore_v2` writes them: 1. the input keys,
//! 2. their types, 3. user metadata, 4. `{"created_at", "sessions": {"all_full_ids",
//! "last_id", "last_full_id"}}`, 5. `{"paths", "current_index", "max_len",
//! "deleted_indexes"}`. Deletes are soft: the index goes into `deleted_indexes`, the record
//! and its image stay.
//!
//! Besides DonkeyCar's keys (`cam/image_array`, `user/angle`, `user/throttle`, `user/mode`)
//! our records carry, when known, `pilot/angle`, `pilot/throttle`, `wheels/left`,
//! `wheels/right`, `pose/x`, `pose/y`, `pose/heading`, `reward`, `target/x`, `target/y`
//! (see [`TubRecord`]). Unknown keys written by other tools are ignored when reading.
//!
//! Crash safety of [`TubWriter::append`]: the image is written first (temporary name, then
//! rename), then the record line in one write, then the catalog manifest and `manifest.json`
//! (each to a temporary file renamed into place). Reopening a tub repairs what a crash can
//! leave: a torn last line is moved aside into `<catalog>.torn.<offset>` (never deleted)
//! and its image into `images/<name>.orphan`, so indexes stay the records' positions as
//! DonkeyCar expects; a record written before the manifests caught up is counted. [`TubReader`] skips a
//! torn last line with a warning and reads every complete record before it; a record
//! whose image is missing, a listed catalog that is missing and a catalog whose
//! `.catalog_manifest` is missing are warnings too, not errors.
//!
//! The library never reads the wall clock: record timestamps and `created_at` come from
//! the caller. The session id `YY-MM-DD_<n>` takes its date (UTC) from `created_at`.

use std::collections::BTreeSet;
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

use serde::Serialize;
use serde_json::{Map, Value};

use super::{DatasetError, Result, io_err, looks_like_jpeg, sync_path, write_atomic};

/// Records per catalog file, as DonkeyCar.
pub const MAX_CATALOG_LEN: u64 = 1000;
/// The manifest's file name.
pub const MANIFEST: &str = "manifest.json";
/// The folder of the images, inside the tub.
pub const IMAGES_DIR: &str = "images";

/// Who drives, in DonkeyCar's words (`user/mode`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DriveMode {
    /// The human steers and throttles (`"user"`).
    User,
    /// The autopilot steers, the human throttles (`"local_angle"`).
    LocalAngle,
    /// The autopilot drives (`"local"`).
    Local,
}

impl DriveMode {
    /// DonkeyCar's string for the mode.
    pub fn as_str(self) -> &'static str {
        match self {
            DriveMode::User => "user",
            DriveMode::LocalAngle => "local_angle",
            DriveMode::Local => "local",
        }
    }

    /// Parses DonkeyCar's string.
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "user" => Some(DriveMode::User),
            "local_angle" => Some(DriveMode::LocalAngle),
            "local" => Some(DriveMode::Local),
            _ => None,
        }
    }
}

/// One control step. Angles: -1 full left .. +1 full right; throttles -1..1.
#[derive(Debug, Clone, PartialEq)]
pub struct TubRecord {
    /// `_index`, set by the writer (counts from 0 over the whole tub, with no gaps).
    pub index: u64,
    /// `_session_id`, `YY-MM-DD_<n>`, set by the writer (empty when an old tub has none).
    pub session_id: String,
    /// `_timestamp_ms`, from the caller's clock.
    pub timestamp_ms: u64,
    /// `cam/image_array`: the file name under `images/`, set by the writer.
    pub image: String,
    /// `user/angle`: the human's steering.
    pub user_angle: f32,
    /// `user/throttle`: the human's throttle.
    pub user_throttle: f32,
    /// `user/mode`.
    pub mode: DriveMode,
    /// `pilot/angle`: the autopilot's steering.
    pub pilot_angle: Option<f32>,
    /// `pilot/throttle`: the autopilot's throttle.
    pub pilot_throttle: Option<f32>,
    /// `wheels/left`, `wheels/right`: the motor commands actually sent, -1..1.
    pub wheels: Option<(f32, f32)>,
    /// `pose/x`, `pose/y` (metres), `pose/heading` (radians), from the simulator or a
    /// tracker.
    pub pose: Option<(f32, f32, f32)>,
    /// `reward`: the paper's per-step reward.
    pub reward: Option<f32>,
    /// `target/x`, `target/y`: JetBot's target-point label, -1..1.
    pub target: Option<(f32, f32)>,
}

impl TubRecord {
    /// A record with DonkeyCar's keys only; `index`, `session_id` and `image` are left for
    /// the writer to fill, the optional fields are `None`.
    pub fn new(timestamp_ms: u64, user_angle: f32, user_throttle: f32, mode: DriveMode) -> Self {
        Self {
            index: 0,
            session_id: String::new(),
            timestamp_ms,
            image: String::new(),
            user_angle,
            user_throttle,
            mode,
            pilot_angle: None,
            pilot_throttle: None,
            wheels: None,
            pose: None,
            reward: None,
            target: None,
        }
    }
}

/// The image file name DonkeyCar gives record `index`: `<index>_cam_image_array_.jpg`.
pub fn image_file_name(index: u64) -> String {
    format!("{index}_cam_image_array_.jpg")
}

/// Which optional groups of keys a tub declares in `manifest.json` (lines 1 and 2).
/// DonkeyCar's four keys are always declared. A record carrying a key that is not declared
/// yet is still written in full, and the key is added to the manifest.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct TubInputs {
    /// `pilot/angle`, `pilot/throttle`.
    pub pilot: bool,
    /// `wheels/left`, `wheels/right`.
    pub wheels: bool,
    /// `pose/x`, `pose/y`, `pose/heading`.
    pub pose: bool,
    /// `reward`.
    pub reward: bool,
    /// `target/x`, `target/y`.
    pub target: bool,
}

impl TubInputs {
    /// DonkeyCar's keys only.
    pub const DONKEY: Self = Self {
        pilot: false,
        wheels: false,
        pose: false,
        reward: false,
        target: false,
    };
    /// Every key jetpilot records.
    pub const ALL: Self = Self {
        pilot: true,
        wheels: true,
        pose: true,
        reward: true,
        target: true,
    };

    /// The groups a record has values for.
    fn of_record(rec: &TubRecord) -> Self {
        Self {
            pilot: rec.pilot_angle.is_some() || rec.pilot_throttle.is_some(),
            wheels: rec.wheels.is_some(),
            pose: rec.pose.is_some(),
            reward: rec.reward.is_some(),
            target: rec.target.is_some(),
        }
    }

    /// `(key, DonkeyCar type)` pairs, in manifest order.
    pub fn keys(&self) -> Vec<(&'static str, &'static str)> {
        let mut keys = vec![
            ("cam/image_array", "image_array"),
            ("user/angle", "float"),
            ("user/throttle", "float"),
            ("user/mode", "str"),
        ];
        if self.pilot {
            keys.extend([("pilot/angle", "float"), ("pilot/throttle", "float")]);
        }
        if self.wheels {
            keys.extend([("wheels/left", "float"), ("wheels/right", "float")]);
        }
        if self.pose {
            keys.extend([
                ("pose/x", "float"),
                ("pose/y", "float"),
                ("pose/heading", "float"),
            ]);
        }
        if self.reward {
            keys.push(("reward", "float"));
        }
        if self.target {
            keys.extend([("target/x", "float"), ("target/y", "float")]);
        }
        keys
    }
}

// ---------------------------------------------------------------------------------------
// JSON in Python's style

/// serde_json formatter with Python `json.dumps` separators (`", "` and `": "`), so the
/// files read like DonkeyCar's own.
struct PyFormatter;

impl serde_json::ser::Formatter for PyFormatter {
    fn begin_array_value<W: ?Sized + Write>(
        &mut self,
        w: &mut W,
        first: bool,
    ) -> std::io::Result<()> {
        if first { Ok(()) } else { w.write_all(b", ") }
    }
    fn begin_object_key<W: ?Sized + Write>(
        &mut self,
        w: &mut W,
        first: bool,
    ) -> std::io::Result<()> {
        if first { Ok(()) } else { w.write_all(b", ") }
    }
    fn begin_object_value<W: ?Sized + Write>(&mut self, w: &mut W) -> std::io::Result<()> {
        w.write_all(b": ")
    }
}

fn to_py_json<T: Serialize + ?Sized>(
    value: &T,
    out: &mut Vec<u8>,
) -> std::result::Result<(), String> {
    let mut ser = serde_json::Serializer::with_formatter(out, PyFormatter);
    value.serialize(&mut ser).map_err(|e| e.to_string())
}

/// A record line; fields in sorted key order, as DonkeyCar's `json.dumps(sort_keys=True)`.
#[derive(Serialize)]
struct RecordLine<'a> {
    #[serde(rename = "_index")]
    index: u64,
    #[serde(rename = "_session_id")]
    session_id: &'a str,
    #[serde(rename = "_timestamp_ms")]
    timestamp_ms: u64,
    #[serde(rename = "cam/image_array")]
    image: &'a str,
    #[serde(rename = "pilot/angle", skip_serializing_if = "Option::is_none")]
    pilot_angle: Option<f32>,
    #[serde(rename = "pilot/throttle", skip_serializing_if = "Option::is_none")]
    pilot_throttle: Option<f32>,
    #[serde(rename = "pose/heading", skip_serializing_if = "Option::is_none")]
    pose_heading: Option<f32>,
    #[serde(rename = "pose/x", skip_serializing_if = "Option::is_none")]
    pose_x: Option<f32>,
    #[serde(rename = "pose/y", skip_serializing_if = "Option::is_none")]
    pose_y: Option<f32>,
    #[serde(rename = "reward", skip_serializing_if = "Option::is_none")]
    reward: Option<f32>,
    #[serde(rename = "target/x", skip_serializing_if = "Option::is_none")]
    target_x: Option<f32>,
    #[serde(rename = "target/y", skip_serializing_if = "Option::is_none")]
    target_y: Option<f32>,
    #[serde(rename = "user/angle")]
    user_angle: f32,
    #[serde(rename = "user/mode")]
    mode: &'static str,
    #[serde(rename = "user/throttle")]
    user_throttle: f32,
    #[serde(rename = "wheels/left", skip_serializing_if = "Option::is_none")]
    wheels_left: Option<f32>,
    #[serde(rename = "wheels/right", skip_serializing_if = "Option::is_none")]
    wheels_right: Option<f32>,
}

/// A catalog manifest (`catalog_<n>.catalog_manifest`), keys sorted as DonkeyCar writes it.
#[derive(Serialize)]
struct CatalogManifestOut<'a> {
    created_at: f64,
    line_lengths: &'a [u64],
    path: &'a str,
    start_index: u64,
}

/// Line 5 of `manifest.json`.
#[derive(Serialize)]
struct CatalogMetaOut<'a> {
    paths: &'a [String],
    current_index: u64,
    max_len: u64,
    deleted_indexes: Vec<u64>,
}

// ---------------------------------------------------------------------------------------
// manifest.json

#[derive(Debug, Clone)]
struct Manifest {
    inputs: Vec<String>,
    types: Vec<String>,
    /// Line 3, kept as found.
    metadata: Value,
    /// Line 4, kept as found apart from `sessions`.
    manifest_metadata: Map<String, Value>,
    paths: Vec<String>,
    current_index: u64,
    max_len: u64,
    deleted: BTreeSet<u64>,
}

impl Manifest {
    fn new(inputs: &TubInputs, created_at: f64) -> Self {
        let mut manifest_metadata = Map::new();
        manifest_metadata.insert("created_at".into(), json_f64(created_at));
        let mut m = Self {
            inputs: Vec::new(),
            types: Vec::new(),
            metadata: Value::Object(Map::new()),
            manifest_metadata,
            paths: Vec::new(),
            current_index: 0,
            max_len: MAX_CATALOG_LEN,
            deleted: BTreeSet::new(),
        };
        m.declare(inputs);
        m
    }

    /// Adds the keys of `inputs` that are not declared yet; true when something was added.
    fn declare(&mut self, inputs: &TubInputs) -> bool {
        let mut added = false;
        for (key, ty) in inputs.keys() {
            if !self.inputs.iter().any(|k| k == key) {
                self.inputs.push(key.to_string());
                self.types.push(ty.to_string());
                added = true;
            }
        }
        added
    }

    fn read(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(io_err(path))?;
        let parse_err = |line: usize, reason: String| DatasetError::Parse {
            path: path.display().to_string(),
            line,
            reason,
        };
        let text = std::str::from_utf8(&bytes).map_err(|e| {
            let line = bytes[..e.valid_up_to()]
                .iter()
                .filter(|&&b| b == b'\n')
                .count()
                + 1;
            parse_err(line, "not UTF-8 text".into())
        })?;
        let lines: Vec<&str> = text.lines().collect();
        if lines.len() < 5 {
            return Err(parse_err(
                lines.len() + 1,
                format!(
                    "a tub manifest has 5 lines of JSON, this one has {}",
                    lines.len()
                ),
            ));
        }
        let json = |i: usize| -> Result<Value> {
            serde_json::from_str(lines[i]).map_err(|e| parse_err(i + 1, format!("bad JSON: {e}")))
        };
        let strings = |i: usize, what: &str| -> Result<Vec<String>> {
            serde_json::from_value::<Vec<String>>(json(i)?)
                .map_err(|e| parse_err(i + 1, format!("{what} must be a list of strings: {e}")))
        };
        let inputs = strings(0, "the input keys")?;
        let types = strings(1, "the input types")?;
        if inputs.len() != types.len() {
            return Err(parse_err(
                2,
                format!("{} types for {} input keys", types.len(), inputs.len()),
            ));
        }
        let metadata = json(2)?;
        let manifest_metadata = match json(3)? {
            Value::Object(m) => m,
            other => return Err(parse_err(4, format!("expected an object, found {other}"))),
        };
        let Value::Object(cat) = json(4)? else {
            return Err(parse_err(5, "expected an object with \"paths\"".into()));
        };
        let key = |k: &str| -> Result<&Value> {
            cat.get(k)
                .ok_or_else(|| parse_err(5, format!("key {k:?} is missing")))
        };
        let paths: Vec<String> = serde_json::from_value(key("paths")?.clone())
            .map_err(|e| parse_err(5, format!("key \"paths\" must be a list of strings: {e}")))?;
        for p in &paths {
            if !is_plain_file_name(p) {
                return Err(parse_err(
                    5,
                    format!("catalog path {p:?} is not a file name in the tub"),
                ));
            }
        }
        let current_index = key("current_index")?.as_u64().ok_or_else(|| {
            parse_err(
                5,
                "key \"current_index\" must be a non-negative integer".into(),
            )
        })?;
        let max_len = key("max_len")?
            .as_u64()
            .filter(|&n| n > 0)
            .ok_or_else(|| parse_err(5, "key \"max_len\" must be a positive integer".into()))?;
        let deleted: BTreeSet<u64> = serde_json::from_value(key("deleted_indexes")?.clone())
            .map_err(|e| {
                parse_err(
                    5,
                    format!("key \"deleted_indexes\" must be a list of non-negative integers: {e}"),
                )
            })?;
        Ok(Self {
            inputs,
            types,
            metadata,
            manifest_metadata,
            paths,
            current_index,
            max_len,
            deleted,
        })
    }

    fn to_bytes(&self) -> std::result::Result<Vec<u8>, String> {
        let mut out = Vec::new();
        to_py_json(&self.inputs, &mut out)?;
        out.push(b'\n');
        to_py_json(&self.types, &mut out)?;
        out.push(b'\n');
        to_py_json(&self.metadata, &mut out)?;
        out.push(b'\n');
        to_py_json(&self.manifest_metadata, &mut out)?;
        out.push(b'\n');
        to_py_json(
            &CatalogMetaOut {
                paths: &self.paths,
                current_index: self.current_index,
                max_len: self.max_len,
                deleted_indexes: self.deleted.iter().copied().collect(),
            },
            &mut out,
        )?;
        out.push(b'\n');
        Ok(out)
    }

    fn write(&self, path: &Path) -> Result<()> {
        let bytes = self.to_bytes().map_err(|reason| DatasetError::Format {
            path: path.display().to_string(),
            reason: format!("cannot serialise the manifest: {reason}"),
        })?;
        write_atomic(path, &bytes)
    }

    /// `(last_id, all_full_ids)` of line 4's `sessions`, `(-1, [])` when there is none.
    fn sessions(&self) -> (i64, Vec<String>) {
        let Some(Value::Object(s)) = self.manifest_metadata.get("sessions") else {
            return (-1, Vec::new());
        };
        let last_id = s.get("last_id").and_then(Value::as_i64).unwrap_or(-1);
        let all = s
            .get("all_full_ids")
            .and_then(Value::as_array)
            .map(|a| {
                a.iter()
                    .filter_map(|v| v.as_str().map(str::to_owned))
                    .collect()
            })
            .unwrap_or_default();
        (last_id, all)
    }

    fn register_session(&mut self, id: i64, full_id: &str) {
        let (_, mut all) = self.sessions();
        all.push(full_id.to_string());
        let mut s = Map::new();
        s.insert("all_full_ids".into(), Value::from(all));
        s.insert("last_id".into(), Value::from(id));
        s.insert("last_full_id".into(), Value::from(full_id));
        self.manifest_metadata
            .insert("sessions".into(), Value::Object(s));
    }
}

fn json_f64(x: f64) -> Value {
    serde_json::Number::from_f64(x)
        .map(Value::Number)
        .unwrap_or(Value::Null)
}

/// A name that stays inside its folder: no separators, not `.`/`..`, not empty.
fn is_plain_file_name(name: &str) -> bool {
    !name.is_empty() && name != "." && name != ".." && !name.contains(['/', '\\', '\0'])
}

/// The catalog manifest path for catalog file `name` (`catalog_3.catalog` ->
/// `catalog_3.catalog_manifest`).
fn catalog_manifest_name(name: &str) -> String {
    let stem = name.strip_suffix(".catalog").unwrap_or(name);
    format!("{stem}.catalog_manifest")
}

/// The session id DonkeyCar gives session `n` started at `created_at` (unix seconds):
/// `YY-MM-DD_<n>`, the date in UTC.
pub fn session_id(created_at: f64, n: i64) -> String {
    let days = (created_at / 86_400.0).floor() as i64;
    let (y, m, d) = civil_from_days(days);
    format!("{:02}-{m:02}-{d:02}_{n}", y.rem_euclid(100))
}

/// Days since 1970-01-01 -> (year, month, day), proleptic Gregorian (H. Hinnant's algorithm).
fn civil_from_days(z: i64) -> (i64, u32, u32) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let y = yoe + era * 400;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    (if m <= 2 { y + 1 } else { y }, m, d)
}

// ---------------------------------------------------------------------------------------
// Writer

/// The catalog being appended to.
#[derive(Debug)]
struct OpenCatalog {
    name: String,
    file: File,
    created_at: f64,
    start_index: u64,
    line_lengths: Vec<u64>,
}

impl OpenCatalog {
    fn write_manifest(&self, dir: &Path) -> Result<()> {
        let path = dir.join(catalog_manifest_name(&self.name));
        let mut out = Vec::new();
        to_py_json(
            &CatalogManifestOut {
                created_at: self.created_at,
                line_lengths: &self.line_lengths,
                path: &self.name,
                start_index: self.start_index,
            },
            &mut out,
        )
        .map_err(|reason| DatasetError::Format {
            path: path.display().to_string(),
            reason: format!("cannot serialise the catalog manifest: {reason}"),
        })?;
        out.push(b'\n');
        write_atomic(&path, &out)
    }

    fn byte_len(&self) -> u64 {
        self.line_lengths.iter().sum()
    }
}

/// Appends records to a tub (creating it, or continuing an existing one in a new session).
#[derive(Debug)]
pub struct TubWriter {
    dir: PathBuf,
    manifest: Manifest,
    catalog: OpenCatalog,
    session_id: String,
    session_n: i64,
    session_registered: bool,
    /// Files written or renamed since the last [`flush_and_sync`](Self::flush_and_sync).
    unsynced: Vec<PathBuf>,
    warnings: Vec<String>,
}

impl TubWriter {
    /// Opens the tub at `dir` for appending: creates it (and the folder) when there is none,
    /// otherwise continues it with a new session id and the next free index; nothing already
    /// recorded is overwritten. `inputs` are the optional keys to declare in the manifest
    /// (added to an existing tub's). `created_at` (unix seconds, from the caller's clock) goes
    /// into the new manifest and catalog, and dates the session id.
    ///
    /// A folder that exists without `manifest.json` is refused unless it is empty (or holds
    /// only what an interrupted `create` leaves: an empty `images/`, an empty `catalog_0`).
    pub fn create(dir: &Path, inputs: &TubInputs, created_at: f64) -> Result<Self> {
        if !(created_at.is_finite() && created_at >= 0.0) {
            return Err(DatasetError::InvalidInput {
                path: dir.display().to_string(),
                reason: format!("created_at must be unix seconds >= 0, got {created_at}"),
            });
        }
        let manifest_path = dir.join(MANIFEST);
        let mut warnings = Vec::new();
        let (manifest, catalog, unsynced) = if manifest_path.exists() {
            let mut manifest = Manifest::read(&manifest_path)?;
            manifest.declare(inputs);
            let catalog = if manifest.paths.is_empty() {
                add_catalog(dir, &mut manifest, created_at)?
            } else {
                reopen_last_catalog(dir, &mut manifest, &mut warnings)?
            };
            (manifest, catalog, Vec::new())
        } else {
            check_fresh_folder(dir)?;
            std::fs::create_dir_all(dir.join(IMAGES_DIR)).map_err(io_err(dir))?;
            let mut manifest = Manifest::new(inputs, created_at);
            let catalog = add_catalog(dir, &mut manifest, created_at)?;
            (
                manifest,
                catalog,
                vec![dir.join(IMAGES_DIR), dir.to_path_buf()],
            )
        };
        std::fs::create_dir_all(dir.join(IMAGES_DIR)).map_err(io_err(dir))?;
        let (last_id, _) = manifest.sessions();
        let session_n = last_id + 1;
        let session_id = session_id(created_at, session_n);
        manifest.write(&manifest_path)?;
        let mut w = Self {
            dir: dir.to_path_buf(),
            manifest,
            catalog,
            session_id,
            session_n,
            session_registered: false,
            unsynced,
            warnings,
        };
        w.unsynced.push(manifest_path);
        Ok(w)
    }

    /// Appends one record with its camera frame (JPEG bytes) and returns the index given to
    /// it. `record.index`, `record.session_id` and `record.image` are ignored: the writer
    /// sets them. Order on disk: the image, then the record line, then the catalog manifest
    /// and `manifest.json`. A record that cannot be recorded (NaN, not JPEG data) is refused
    /// before anything is written.
    pub fn append(&mut self, record: &TubRecord, jpeg_bytes: &[u8]) -> Result<u64> {
        self.validate(record, jpeg_bytes)?;
        let manifest_path = self.dir.join(MANIFEST);
        // A key not declared yet is added to the manifest (rewritten below), never dropped.
        self.manifest.declare(&TubInputs::of_record(record));
        if self.catalog.line_lengths.len() as u64 >= self.manifest.max_len {
            let created_at = record.timestamp_ms as f64 / 1000.0;
            let next = add_catalog(&self.dir, &mut self.manifest, created_at)?;
            self.manifest.write(&manifest_path)?;
            self.unsynced.push(self.dir.join(&self.catalog.name));
            self.unsynced
                .push(self.dir.join(catalog_manifest_name(&self.catalog.name)));
            self.catalog = next;
        }

        let index = self.manifest.current_index;
        let image = image_file_name(index);
        let image_path = self.dir.join(IMAGES_DIR).join(&image);
        write_atomic(&image_path, jpeg_bytes)?;
        self.unsynced.push(image_path);

        let mut line = Vec::with_capacity(320);
        let (wl, wr) = split2(record.wheels);
        let (px, py, ph) = split3(record.pose);
        let (tx, ty) = split2(record.target);
        to_py_json(
            &RecordLine {
                index,
                session_id: &self.session_id,
                timestamp_ms: record.timestamp_ms,
                image: &image,
                pilot_angle: record.pilot_angle,
                pilot_throttle: record.pilot_throttle,
                pose_heading: ph,
                pose_x: px,
                pose_y: py,
                reward: record.reward,
                target_x: tx,
                target_y: ty,
                user_angle: record.user_angle,
                mode: record.mode.as_str(),
                user_throttle: record.user_throttle,
                wheels_left: wl,
                wheels_right: wr,
            },
            &mut line,
        )
        .map_err(|reason| self.invalid(format!("cannot serialise record {index}: {reason}")))?;
        line.push(b'\n');
        let catalog_path = self.dir.join(&self.catalog.name);
        if let Err(e) = self.catalog.file.write_all(&line) {
            // Take a partial line back out, so the next record does not glue onto it.
            let _ = self.catalog.file.set_len(self.catalog.byte_len());
            return Err(io_err(&catalog_path)(e));
        }
        self.catalog.line_lengths.push(line.len() as u64);
        self.catalog.write_manifest(&self.dir)?;

        self.manifest.current_index = index + 1;
        if !self.session_registered {
            self.manifest
                .register_session(self.session_n, &self.session_id);
            self.session_registered = true;
        }
        self.manifest.write(&manifest_path)?;
        Ok(index)
    }

    fn invalid(&self, reason: String) -> DatasetError {
        DatasetError::InvalidInput {
            path: self.dir.display().to_string(),
            reason,
        }
    }

    fn validate(&self, r: &TubRecord, jpeg: &[u8]) -> Result<()> {
        let mut values: Vec<(&str, f32)> = vec![
            ("user/angle", r.user_angle),
            ("user/throttle", r.user_throttle),
        ];
        let opt = |values: &mut Vec<(&str, f32)>, key: &'static str, v: Option<f32>| {
            if let Some(v) = v {
                values.push((key, v));
            }
        };
        opt(&mut values, "pilot/angle", r.pilot_angle);
        opt(&mut values, "pilot/throttle", r.pilot_throttle);
        opt(&mut values, "reward", r.reward);
        if let Some((l, rt)) = r.wheels {
            values.extend([("wheels/left", l), ("wheels/right", rt)]);
        }
        if let Some((x, y, h)) = r.pose {
            values.extend([("pose/x", x), ("pose/y", y), ("pose/heading", h)]);
        }
        if let Some((x, y)) = r.target {
            values.extend([("target/x", x), ("target/y", y)]);
        }
        for (key, v) in values {
            if !v.is_finite() {
                return Err(self.invalid(format!(
                    "record at timestamp {} ms: key {key} is {v}, JSON holds finite numbers only",
                    r.timestamp_ms
                )));
            }
        }
        if !looks_like_jpeg(jpeg) {
            return Err(self.invalid(format!(
                "record at timestamp {} ms: the image is not JPEG data ({} bytes)",
                r.timestamp_ms,
                jpeg.len()
            )));
        }
        Ok(())
    }

    /// fsyncs everything written since the last call (images, catalog, manifests) and the
    /// folders, so it survives a power cut. Call it at the end of a session and every few
    /// seconds while recording.
    pub fn flush_and_sync(&mut self) -> Result<()> {
        let catalog_path = self.dir.join(&self.catalog.name);
        self.catalog.file.flush().map_err(io_err(&catalog_path))?;
        self.catalog
            .file
            .sync_all()
            .map_err(io_err(&catalog_path))?;
        let mut paths = std::mem::take(&mut self.unsynced);
        paths.push(self.dir.join(catalog_manifest_name(&self.catalog.name)));
        paths.push(self.dir.join(MANIFEST));
        paths.push(self.dir.join(IMAGES_DIR));
        paths.push(self.dir.clone());
        paths.sort();
        paths.dedup();
        // Files first, folders (which make the renames durable) last.
        let (dirs, files): (Vec<PathBuf>, Vec<PathBuf>) =
            paths.into_iter().partition(|p| p.is_dir());
        for p in files.iter().chain(dirs.iter()) {
            match sync_path(p) {
                Ok(()) => {}
                // Moved away since (e.g. by a tub-cleaning tool): nothing left to sync.
                Err(DatasetError::Io { source, .. })
                    if source.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => {
                    self.unsynced = files.into_iter().chain(dirs).collect();
                    return Err(e);
                }
            }
        }
        Ok(())
    }

    /// Soft-deletes the last `n` live records (DonkeyCar's "erase last 100 records"
    /// button): their indexes go into `deleted_indexes`, the records and images stay.
    /// Returns how many were deleted (fewer than `n` when fewer are live).
    pub fn delete_last(&mut self, n: usize) -> Result<usize> {
        let mut newly = Vec::new();
        let mut i = self.manifest.current_index;
        while newly.len() < n && i > 0 {
            i -= 1;
            if !self.manifest.deleted.contains(&i) {
                newly.push(i);
            }
        }
        if newly.is_empty() {
            return Ok(0);
        }
        self.manifest.deleted.extend(newly.iter().copied());
        self.manifest.write(&self.dir.join(MANIFEST))?;
        Ok(newly.len())
    }

    /// Live records in the tub (all sessions): written minus soft-deleted.
    pub fn len(&self) -> usize {
        (self.manifest.current_index as usize).saturating_sub(self.manifest.deleted.len())
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The index the next record gets.
    pub fn next_index(&self) -> u64 {
        self.manifest.current_index
    }

    /// This writer's session id, `YY-MM-DD_<n>`.
    pub fn session_id(&self) -> &str {
        &self.session_id
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// What reopening the tub found and repaired (a torn line moved aside, records the
    /// manifests had not counted yet, ...).
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }
}

fn split2(v: Option<(f32, f32)>) -> (Option<f32>, Option<f32>) {
    v.map_or((None, None), |(a, b)| (Some(a), Some(b)))
}

fn split3(v: Option<(f32, f32, f32)>) -> (Option<f32>, Option<f32>, Option<f32>) {
    v.map_or((None, None, None), |(a, b, c)| (Some(a), Some(b), Some(c)))
}

/// Refuses a folder that holds anything but what an interrupted `create` leaves behind.
fn check_fresh_folder(dir: &Path) -> Result<()> {
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(io_err(dir)(e)),
    };
    let not_tub = |what: String| DatasetError::Format {
        path: dir.display().to_string(),
        reason: format!(
            "the folder has no {MANIFEST} but holds {what}; refusing to write a tub over it"
        ),
    };
    for entry in entries {
        let entry = entry.map_err(io_err(dir))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        let path = entry.path();
        let meta = entry.metadata().map_err(io_err(&path))?;
        let leftover = if meta.is_dir() {
            name == IMAGES_DIR
                && std::fs::read_dir(&path)
                    .map_err(io_err(&path))?
                    .next()
                    .is_none()
        } else {
            (name == "catalog_0.catalog" && meta.len() == 0)
                || name == "catalog_0.catalog_manifest"
                || (name.starts_with('.') && name.ends_with(".tmp"))
        };
        if !leftover {
            return Err(not_tub(format!("{name:?}")));
        }
    }
    Ok(())
}

/// Starts catalog `catalog_<len(paths)>.catalog` at `manifest.current_index` (the caller
/// writes `manifest.json` afterwards). An existing non-empty file of that name is refused.
fn add_catalog(dir: &Path, manifest: &mut Manifest, created_at: f64) -> Result<OpenCatalog> {
    let name = format!("catalog_{}.catalog", manifest.paths.len());
    let path = dir.join(&name);
    if let Ok(meta) = std::fs::metadata(&path) {
        if meta.len() > 0 {
            return Err(DatasetError::Format {
                path: path.display().to_string(),
                reason: format!(
                    "holds {} bytes but {MANIFEST} does not list it; refusing to overwrite it",
                    meta.len()
                ),
            });
        }
    }
    let file = OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .map_err(io_err(&path))?;
    let catalog = OpenCatalog {
        name: name.clone(),
        file,
        created_at,
        start_index: manifest.current_index,
        line_lengths: Vec::new(),
    };
    catalog.write_manifest(dir)?;
    manifest.paths.push(name);
    Ok(catalog)
}

/// Opens the last catalog of an existing tub for appending, repairing what a crash leaves:
/// a torn last line is moved into `<catalog>.torn.<offset>` and cut off; complete records
/// the manifests had not counted yet are counted.
fn reopen_last_catalog(
    dir: &Path,
    manifest: &mut Manifest,
    warnings: &mut Vec<String>,
) -> Result<OpenCatalog> {
    let k = manifest.paths.len() - 1;
    let name = manifest.paths[k].clone();
    let path = dir.join(&name);
    let cm_path = dir.join(catalog_manifest_name(&name));
    let mut bytes = match std::fs::read(&path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            warnings.push(format!("{}: missing, started empty", path.display()));
            Vec::new()
        }
        Err(e) => return Err(io_err(&path)(e)),
    };

    // start_index and created_at from the catalog manifest, when it is there.
    let (mut start_index, mut created_at) = (k as u64 * manifest.max_len, 0.0);
    match std::fs::read(&cm_path) {
        Ok(cm) => {
            let v: Value = serde_json::from_slice(&cm).map_err(|e| DatasetError::Parse {
                path: cm_path.display().to_string(),
                line: 1,
                reason: format!("bad JSON: {e}"),
            })?;
            match v.get("start_index").and_then(Value::as_u64) {
                Some(s) => start_index = s,
                None => {
                    return Err(DatasetError::Parse {
                        path: cm_path.display().to_string(),
                        line: 1,
                        reason: "key \"start_index\" is missing or not a non-negative integer"
                            .into(),
                    });
                }
            }
            created_at = v.get("created_at").and_then(Value::as_f64).unwrap_or(0.0);
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            warnings.push(format!(
                "{}: missing, rebuilt with start_index {start_index}",
                cm_path.display()
            ));
        }
        Err(e) => return Err(io_err(&cm_path)(e)),
    }

    let mut file = OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .map_err(io_err(&path))?;
    let complete = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1);
    if complete < bytes.len() {
        let tail = bytes[complete..].to_vec();
        if parse_tail(&tail).is_some() {
            // A whole record that only lacks its newline: keep it.
            file.write_all(b"\n").map_err(io_err(&path))?;
            bytes.push(b'\n');
            warnings.push(format!(
                "{}: the last record lacked its newline; added it",
                path.display()
            ));
        } else {
            let aside = dir.join(format!("{name}.torn.{complete}"));
            write_atomic(&aside, &tail)?;
            file.set_len(complete as u64).map_err(io_err(&path))?;
            bytes.truncate(complete);
            warnings.push(format!(
                "{}: a torn last line ({} bytes, from a crash mid-write) was moved to {}",
                path.display(),
                tail.len(),
                aside.display()
            ));
        }
    }
    let line_lengths: Vec<u64> = bytes
        .split_inclusive(|&b| b == b'\n')
        .map(|l| l.len() as u64)
        .collect();
    let counted = start_index + line_lengths.len() as u64;
    if counted > manifest.current_index {
        warnings.push(format!(
            "{}: {} record(s) after index {} were not counted in {MANIFEST} (a crash before the \
             manifest update); counted them",
            path.display(),
            counted - manifest.current_index,
            manifest.current_index
        ));
        manifest.current_index = counted;
    } else if counted < manifest.current_index {
        // The manifest counted records whose lines did not reach the disk (a torn line, or
        // data lost in a power cut). DonkeyCar numbers records by their position in the
        // catalogs, so the next record must take index `counted`. The images of the lost
        // records are moved aside, not overwritten.
        let images = dir.join(IMAGES_DIR);
        for index in counted..manifest.current_index {
            let image = images.join(image_file_name(index));
            if image.exists() {
                let mut n = 0;
                let aside = loop {
                    let suffix = if n == 0 {
                        String::new()
                    } else {
                        format!(".{n}")
                    };
                    let candidate =
                        images.join(format!("{}.orphan{suffix}", image_file_name(index)));
                    if !candidate.exists() {
                        break candidate;
                    }
                    n += 1;
                };
                std::fs::rename(&image, &aside).map_err(io_err(&image))?;
                warnings.push(format!(
                    "{}: its record is not in {}; moved to {}",
                    image.display(),
                    path.display(),
                    aside.display()
                ));
            }
        }
        let stale: Vec<u64> = manifest.deleted.range(counted..).copied().collect();
        for i in &stale {
            manifest.deleted.remove(i);
        }
        warnings.push(format!(
            "{}: holds the records below index {counted} but {MANIFEST} counted {}; the next \
             record takes index {counted}{}",
            path.display(),
            manifest.current_index,
            if stale.is_empty() {
                String::new()
            } else {
                format!(
                    " ({} deleted index(es) of lost records dropped)",
                    stale.len()
                )
            }
        ));
        manifest.current_index = counted;
    }
    let catalog = OpenCatalog {
        name,
        file,
        created_at,
        start_index,
        line_lengths,
    };
    catalog.write_manifest(dir)?;
    Ok(catalog)
}

// ---------------------------------------------------------------------------------------
// Reader

/// A tub read into memory: its live records in index order, checked.
#[derive(Debug, Clone)]
pub struct TubReader {
    dir: PathBuf,
    inputs: Vec<String>,
    types: Vec<String>,
    session_ids: Vec<String>,
    deleted: BTreeSet<u64>,
    records: Vec<TubRecord>,
    warnings: Vec<String>,
}

impl TubReader {
    /// Reads `manifest.json` and every catalog it lists. A torn last line of a catalog (a
    /// crash mid-write) is skipped and reported in [`warnings`](Self::warnings), as is a
    /// record whose image file is missing, a catalog the manifest lists that is missing
    /// (its records are lost), and a catalog whose `.catalog_manifest` (DonkeyCar's index of
    /// its line lengths) is missing (the records are read from the catalog itself); any
    /// other malformed line is an error naming the catalog file and line.
    pub fn open(dir: &Path) -> Result<Self> {
        let manifest = Manifest::read(&dir.join(MANIFEST))?;
        let images = dir.join(IMAGES_DIR);
        let mut records = Vec::new();
        let mut warnings = Vec::new();
        for name in &manifest.paths {
            let path = dir.join(name);
            if !path.exists() {
                warnings.push(format!(
                    "{}: listed in {MANIFEST} but missing; its records are skipped",
                    path.display()
                ));
                continue;
            }
            let index = dir.join(catalog_manifest_name(name));
            if !index.exists() {
                warnings.push(format!(
                    "{}: missing (DonkeyCar needs it to read the catalog); records read from {name} itself",
                    index.display()
                ));
            }
            let bytes = std::fs::read(&path).map_err(io_err(&path))?;
            let mut lines: Vec<&[u8]> = bytes.split(|&b| b == b'\n').collect();
            // The text after the last newline: empty in a clean file, else a torn record.
            let tail = lines.pop().unwrap_or_default();
            let n_complete = lines.len();
            let parse_err = |line: usize, reason: String| DatasetError::Parse {
                path: path.display().to_string(),
                line,
                reason,
            };
            for (i, raw) in lines.into_iter().enumerate() {
                let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
                let text = std::str::from_utf8(raw)
                    .map_err(|_| parse_err(i + 1, "not UTF-8 text".into()))?;
                if text.trim().is_empty() {
                    return Err(parse_err(i + 1, "empty line".into()));
                }
                let value: Value = serde_json::from_str(text)
                    .map_err(|e| parse_err(i + 1, format!("bad JSON: {e}")))?;
                let rec = record_from_json(&value).map_err(|reason| parse_err(i + 1, reason))?;
                records.push(rec);
            }
            if !tail.is_empty() {
                let line = n_complete + 1;
                match parse_tail(tail) {
                    Some(rec) => {
                        warnings.push(format!(
                            "{} line {line}: the last record lacks its newline; read it",
                            path.display()
                        ));
                        records.push(rec);
                    }
                    None => warnings.push(format!(
                        "{} line {line}: torn last line ({} bytes, a crash mid-write?) skipped",
                        path.display(),
                        tail.len()
                    )),
                }
            }
        }
        let mut live = Vec::with_capacity(records.len());
        for rec in records {
            if manifest.deleted.contains(&rec.index) {
                continue;
            }
            if !images.join(&rec.image).is_file() {
                warnings.push(format!(
                    "record {}: image {} is missing; record skipped",
                    rec.index,
                    images.join(&rec.image).display()
                ));
                continue;
            }
            live.push(rec);
        }
        let (_, session_ids) = manifest.sessions();
        Ok(Self {
            dir: dir.to_path_buf(),
            inputs: manifest.inputs,
            types: manifest.types,
            session_ids,
            deleted: manifest.deleted,
            records: live,
            warnings,
        })
    }

    /// The live (not deleted) records, in file order (index order for tubs written here).
    pub fn records(&self) -> std::slice::Iter<'_, TubRecord> {
        self.records.iter()
    }

    /// Same as [`records`](Self::records).
    pub fn iter(&self) -> std::slice::Iter<'_, TubRecord> {
        self.records.iter()
    }

    /// Number of live records.
    pub fn len(&self) -> usize {
        self.records.len()
    }

    pub fn is_empty(&self) -> bool {
        self.records.is_empty()
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// `manifest.json` line 1: the declared input keys.
    pub fn inputs(&self) -> &[String] {
        &self.inputs
    }

    /// `manifest.json` line 2: their types.
    pub fn types(&self) -> &[String] {
        &self.types
    }

    /// The sessions recorded in the manifest, oldest first.
    pub fn session_ids(&self) -> &[String] {
        &self.session_ids
    }

    /// The soft-deleted indexes.
    pub fn deleted_indexes(&self) -> &BTreeSet<u64> {
        &self.deleted
    }

    /// Torn lines skipped, records without images, ...
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    /// The image file of a record.
    pub fn image_path(&self, rec: &TubRecord) -> PathBuf {
        self.dir.join(IMAGES_DIR).join(&rec.image)
    }

    /// Decodes a record's image into RGB8: `(width, height, pixels)`.
    pub fn load_rgb(&self, rec: &TubRecord) -> Result<(u32, u32, Vec<u8>)> {
        super::load_rgb(&self.image_path(rec))
    }
}

impl<'a> IntoIterator for &'a TubReader {
    type Item = &'a TubRecord;
    type IntoIter = std::slice::Iter<'a, TubRecord>;
    fn into_iter(self) -> Self::IntoIter {
        self.records.iter()
    }
}

/// The record in the bytes after a catalog's last newline, when they hold a whole one
/// (only the newline missing); `None` for a torn line.
fn parse_tail(tail: &[u8]) -> Option<TubRecord> {
    let text = std::str::from_utf8(tail.strip_suffix(b"\r").unwrap_or(tail)).ok()?;
    let value: Value = serde_json::from_str(text).ok()?;
    record_from_json(&value).ok()
}

/// A record from its JSON object; the error names the key.
fn record_from_json(v: &Value) -> std::result::Result<TubRecord, String> {
    let Value::Object(m) = v else {
        return Err("a record must be a JSON object".into());
    };
    let present = |key: &str| m.get(key).filter(|v| !v.is_null());
    let required = |key: &str| present(key).ok_or_else(|| format!("key {key:?} is missing"));
    let uint = |key: &str| -> std::result::Result<u64, String> {
        required(key)?
            .as_u64()
            .ok_or_else(|| format!("key {key:?} must be a non-negative integer"))
    };
    let num = |key: &str, v: &Value| -> std::result::Result<f32, String> {
        match v.as_f64() {
            Some(x) if x.is_finite() && (x as f32).is_finite() => Ok(x as f32),
            _ => Err(format!("key {key:?} must be a number, found {v}")),
        }
    };
    let float = |key: &str| -> std::result::Result<f32, String> { num(key, required(key)?) };
    let opt_float = |key: &str| -> std::result::Result<Option<f32>, String> {
        present(key).map(|v| num(key, v)).transpose()
    };
    let string = |key: &str| -> std::result::Result<&str, String> {
        required(key)?
            .as_str()
            .ok_or_else(|| format!("key {key:?} must be a string"))
    };
    // A group of keys is all there or all absent.
    let group = |keys: &[&str]| -> std::result::Result<Option<Vec<f32>>, String> {
        let vals: Vec<Option<f32>> = keys
            .iter()
            .map(|k| opt_float(k))
            .collect::<std::result::Result<_, _>>()?;
        if vals.iter().all(Option::is_none) {
            return Ok(None);
        }
        match keys.iter().zip(&vals).find(|(_, v)| v.is_none()) {
            Some((k, _)) => Err(format!(
                "key {k:?} is missing while {} are present",
                keys.iter()
                    .filter(|x| *x != k)
                    .map(|x| format!("{x:?}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            )),
            None => Ok(Some(vals.into_iter().flatten().collect())),
        }
    };

    let image = string("cam/image_array")?;
    if !is_plain_file_name(image) {
        return Err(format!(
            "key \"cam/image_array\": {image:?} is not a file name under images/"
        ));
    }
    let mode_s = string("user/mode")?;
    let mode = DriveMode::parse(mode_s).ok_or_else(|| {
        format!("key \"user/mode\": {mode_s:?} is not \"user\", \"local_angle\" or \"local\"")
    })?;
    let session_id = match present("_session_id") {
        None => String::new(),
        Some(Value::String(s)) => s.clone(),
        Some(_) => return Err("key \"_session_id\" must be a string".into()),
    };
    Ok(TubRecord {
        index: uint("_index")?,
        session_id,
        timestamp_ms: uint("_timestamp_ms")?,
        image: image.to_string(),
        user_angle: float("user/angle")?,
        user_throttle: float("user/throttle")?,
        mode,
        pilot_angle: opt_float("pilot/angle")?,
        pilot_throttle: opt_float("pilot/throttle")?,
        wheels: group(&["wheels/left", "wheels/right"])?.map(|v| (v[0], v[1])),
        pose: group(&["pose/x", "pose/y", "pose/heading"])?.map(|v| (v[0], v[1], v[2])),
        reward: opt_float("reward")?,
        target: group(&["target/x", "target/y"])?.map(|v| (v[0], v[1])),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn session_ids_use_the_utc_date() {
        assert_eq!(session_id(0.0, 0), "70-01-01_0");
        // 2025-11-21 18:33:20 UTC
        assert_eq!(session_id(1_763_750_000.0, 3), "25-11-21_3");
        // 2000-02-29 23:59:59 UTC (leap day)
        assert_eq!(session_id(951_868_799.0, 1), "00-02-29_1");
        assert_eq!(session_id(951_868_800.0, 1), "00-03-01_1");
    }

    #[test]
    fn python_style_json() {
        let mut out = Vec::new();
        to_py_json(&serde_json::json!({"a": [1, 2], "b": {"c": "d"}}), &mut out).unwrap();
        assert_eq!(
            String::from_utf8(out).unwrap(),
            r#"{"a": [1, 2], "b": {"c": "d"}}"#
        );
    }

    #[test]
    fn f32_values_round_trip_exactly_through_json() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut values: Vec<f32> = (0..200_000)
            .map(|_| rng.random_range(-1.0f32..1.0))
            .collect();
        values.extend((0..100_000).map(|_| f32::from_bits(rng.random::<u32>() & 0x7F7F_FFFF)));
        values.extend([
            0.0,
            -0.0,
            0.2,
            1.0,
            -1.0,
            f32::MIN_POSITIVE,
            f32::MAX,
            1e-45,
        ]);
        for v in values {
            let mut out = Vec::new();
            to_py_json(&v, &mut out).unwrap();
            let text = String::from_utf8(out).unwrap();
            let back: Value = serde_json::from_str(&text).unwrap();
            let back = back.as_f64().unwrap() as f32;
            assert_eq!(back.to_bits(), v.to_bits(), "{v} -> {text} -> {back}");
        }
    }

    #[test]
    fn drive_mode_strings() {
        for m in [DriveMode::User, DriveMode::LocalAngle, DriveMode::Local] {
            assert_eq!(DriveMode::parse(m.as_str()), Some(m));
            assert_eq!(
                serde_json::to_string(&m).unwrap(),
                format!("\"{}\"", m.as_str())
            );
        }
        assert_eq!(DriveMode::parse("pilot"), None);
    }
}
