//! Integration tests of the data set formats: DonkeyCar tub v2 and JetBot's xy folder.

use std::path::Path;

use jetpilot::dataset::DatasetError;
use jetpilot::dataset::jetbot_xy::{self, XyFolder};
use jetpilot::dataset::tub::{DriveMode, TubInputs, TubReader, TubRecord, TubWriter};
use serde_json::{Value, json};

/// 2025-11-21 18:33:20.25 UTC
const T0: f64 = 1_763_750_000.25;
const T0_MS: u64 = 1_763_750_000_250;

fn jpeg_8x8(seed: u8) -> Vec<u8> {
    let img = image::RgbImage::from_fn(8, 8, |x, y| {
        image::Rgb([seed.wrapping_add(x as u8 * 20), y as u8 * 20, 128])
    });
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Jpeg).unwrap();
    out.into_inner()
}

/// Record `i` of the test episodes: every optional field present on some records, absent
/// on others, values that are not round in binary.
fn record(i: u64) -> TubRecord {
    let f = i as f32;
    let mode = match i % 3 {
        0 => DriveMode::User,
        1 => DriveMode::LocalAngle,
        _ => DriveMode::Local,
    };
    let mut r = TubRecord::new(T0_MS + i * 50, (f * 0.013).sin(), 0.2 + f * 1e-4, mode);
    if i % 2 == 0 {
        r.pilot_angle = Some(-(f * 0.007).cos());
        r.pilot_throttle = Some(0.31);
    }
    if i % 5 != 0 {
        r.wheels = Some((0.1 + f * 1e-3, -0.45));
    }
    if i % 7 != 3 {
        r.pose = Some((
            f * 0.01,
            -f * 0.02,
            (f * 0.1).rem_euclid(std::f32::consts::TAU),
        ));
    }
    if i % 4 == 1 {
        r.reward = Some(f / 3000.0);
    }
    if i % 3 == 2 {
        r.target = Some((-0.991_071_4, 1.0 / 3.0));
    }
    r
}

fn expected(i: u64, session: &str) -> TubRecord {
    TubRecord {
        index: i,
        session_id: session.to_string(),
        image: format!("{i}_cam_image_array_.jpg"),
        ..record(i)
    }
}

fn write_tub(dir: &Path, n: u64) -> String {
    let jpeg = jpeg_8x8(3);
    let mut w = TubWriter::create(dir, &TubInputs::ALL, T0).unwrap();
    assert_eq!(w.session_id(), "25-11-21_0");
    for i in 0..n {
        assert_eq!(w.append(&record(i), &jpeg).unwrap(), i);
    }
    w.flush_and_sync().unwrap();
    assert_eq!(w.len(), n as usize);
    w.session_id().to_string()
}

fn lines(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(str::to_owned)
        .collect()
}

#[test]
fn tub_of_2345_records_reads_back_exactly() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("tub_1");
    let session = write_tub(&dir, 2345);

    // Catalogs of 1000, 1000, 345 records, with their manifests.
    for (k, (count, start)) in [(1000, 0u64), (1000, 1000), (345, 2000)].iter().enumerate() {
        let cat = dir.join(format!("catalog_{k}.catalog"));
        let text = std::fs::read_to_string(&cat).unwrap();
        assert_eq!(text.lines().count(), *count, "catalog_{k}");
        assert!(text.ends_with('\n'));
        let cm = lines(&dir.join(format!("catalog_{k}.catalog_manifest")));
        assert_eq!(cm.len(), 1);
        assert!(cm[0].starts_with("{\"created_at\": "), "{}", cm[0]);
        let cm: Value = serde_json::from_str(&cm[0]).unwrap();
        assert_eq!(cm["path"], json!(format!("catalog_{k}.catalog")));
        assert_eq!(cm["start_index"], json!(start));
        let lengths: Vec<u64> = serde_json::from_value(cm["line_lengths"].clone()).unwrap();
        assert_eq!(lengths.len(), *count);
        assert_eq!(lengths.iter().sum::<u64>(), text.len() as u64);
        assert_eq!(
            lengths,
            text.split_inclusive('\n')
                .map(|l| l.len() as u64)
                .collect::<Vec<_>>()
        );
        // A new catalog is dated by the record that opened it.
        let created = cm["created_at"].as_f64().unwrap();
        let want = if k == 0 {
            T0
        } else {
            (T0_MS + start * 50) as f64 / 1000.0
        };
        assert!((created - want).abs() < 1e-6, "{created} {want}");
    }
    assert!(!dir.join("catalog_3.catalog").exists());

    // manifest.json: five lines, as DonkeyCar writes them.
    let m = lines(&dir.join("manifest.json"));
    assert_eq!(m.len(), 5);
    assert_eq!(
        m[0],
        r#"["cam/image_array", "user/angle", "user/throttle", "user/mode", "pilot/angle", "pilot/throttle", "wheels/left", "wheels/right", "pose/x", "pose/y", "pose/heading", "reward", "target/x", "target/y"]"#
    );
    assert_eq!(
        m[1],
        r#"["image_array", "float", "float", "str", "float", "float", "float", "float", "float", "float", "float", "float", "float", "float"]"#
    );
    assert_eq!(m[2], "{}");
    let meta: Value = serde_json::from_str(&m[3]).unwrap();
    assert_eq!(meta["created_at"], json!(T0));
    assert_eq!(
        meta["sessions"],
        json!({"all_full_ids": ["25-11-21_0"], "last_id": 0, "last_full_id": "25-11-21_0"})
    );
    assert_eq!(
        m[4],
        r#"{"paths": ["catalog_0.catalog", "catalog_1.catalog", "catalog_2.catalog"], "current_index": 2345, "max_len": 1000, "deleted_indexes": []}"#
    );

    // Record lines: DonkeyCar's keys, sorted, Python separators.
    let first = lines(&dir.join("catalog_0.catalog"))[0].clone();
    assert_eq!(
        first,
        format!(
            r#"{{"_index": 0, "_session_id": "25-11-21_0", "_timestamp_ms": {T0_MS}, "cam/image_array": "0_cam_image_array_.jpg", "pilot/angle": -1.0, "pilot/throttle": 0.31, "pose/heading": 0.0, "pose/x": 0.0, "pose/y": -0.0, "user/angle": 0.0, "user/mode": "user", "user/throttle": 0.2}}"#
        )
    );
    assert!(dir.join("images/2344_cam_image_array_.jpg").is_file());
    // No temporary files left behind.
    for d in [dir.clone(), dir.join("images")] {
        for e in std::fs::read_dir(&d).unwrap() {
            let name = e.unwrap().file_name().to_string_lossy().into_owned();
            assert!(!name.ends_with(".tmp"), "{name}");
        }
    }

    let reader = TubReader::open(&dir).unwrap();
    assert!(reader.warnings().is_empty(), "{:?}", reader.warnings());
    assert_eq!(reader.len(), 2345);
    for (i, rec) in reader.records().enumerate() {
        assert_eq!(rec, &expected(i as u64, &session));
    }
    assert_eq!(reader.session_ids(), ["25-11-21_0"]);
    assert_eq!(reader.inputs().len(), 14);
    let rec = reader.records().nth(1234).unwrap();
    assert_eq!(
        reader.image_path(rec),
        dir.join("images").join("1234_cam_image_array_.jpg")
    );
    let (w, h, rgb) = reader.load_rgb(rec).unwrap();
    assert_eq!((w, h, rgb.len()), (8, 8, 8 * 8 * 3));
}

#[test]
fn reopening_appends_a_new_session_and_soft_deletes() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("tub");
    let s0 = write_tub(&dir, 1995);
    let images_before = std::fs::read(dir.join("images/7_cam_image_array_.jpg")).unwrap();

    // Next day, second session: indexes continue, nothing is overwritten.
    let jpeg = jpeg_8x8(200);
    let mut w = TubWriter::create(&dir, &TubInputs::DONKEY, T0 + 86_400.0).unwrap();
    assert!(w.warnings().is_empty(), "{:?}", w.warnings());
    assert_eq!(w.session_id(), "25-11-22_1");
    assert_eq!(w.next_index(), 1995);
    for i in 1995..2345 {
        assert_eq!(w.append(&record(i), &jpeg).unwrap(), i);
    }
    w.flush_and_sync().unwrap();
    assert_eq!(
        std::fs::read(dir.join("images/7_cam_image_array_.jpg")).unwrap(),
        images_before
    );
    assert_eq!(
        std::fs::read_to_string(dir.join("catalog_1.catalog"))
            .unwrap()
            .lines()
            .count(),
        1000
    );
    let reader = TubReader::open(&dir).unwrap();
    assert_eq!(reader.len(), 2345);
    assert_eq!(reader.session_ids(), ["25-11-21_0", "25-11-22_1"]);
    for (i, rec) in reader.records().enumerate() {
        let i = i as u64;
        let s = if i < 1995 { s0.as_str() } else { "25-11-22_1" };
        assert_eq!(rec, &expected(i, s));
    }
    // The manifest keeps its first created_at and all inputs.
    let meta: Value = serde_json::from_str(&lines(&dir.join("manifest.json"))[3]).unwrap();
    assert_eq!(meta["created_at"], json!(T0));
    assert_eq!(meta["sessions"]["last_id"], json!(1));

    // Soft delete of the last 100: records and images stay, readers skip them.
    assert_eq!(w.delete_last(100).unwrap(), 100);
    assert_eq!(w.len(), 2245);
    let reader = TubReader::open(&dir).unwrap();
    assert_eq!(reader.len(), 2245);
    assert_eq!(reader.records().last().unwrap().index, 2244);
    assert_eq!(
        reader.deleted_indexes().iter().copied().collect::<Vec<_>>(),
        (2245..2345).collect::<Vec<u64>>()
    );
    assert!(dir.join("images/2344_cam_image_array_.jpg").is_file());
    assert_eq!(lines(&dir.join("catalog_2.catalog")).len(), 345);
    let m5: Value = serde_json::from_str(&lines(&dir.join("manifest.json"))[4]).unwrap();
    assert_eq!(m5["current_index"], json!(2345));
    assert_eq!(m5["deleted_indexes"].as_array().unwrap().len(), 100);

    // Deleting again skips what is already deleted; more than are live stops at zero.
    assert_eq!(w.delete_last(5).unwrap(), 5);
    let reader = TubReader::open(&dir).unwrap();
    assert_eq!(reader.records().last().unwrap().index, 2239);
    assert_eq!(w.delete_last(10_000).unwrap(), 2240);
    assert_eq!(w.len(), 0);
    assert_eq!(w.delete_last(1).unwrap(), 0);
    assert!(TubReader::open(&dir).unwrap().is_empty());
    // The next record still gets a fresh index.
    assert_eq!(w.append(&record(0), &jpeg).unwrap(), 2345);
}

#[test]
fn torn_last_line_is_skipped_and_repaired_without_losing_records() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("tub");
    let session = write_tub(&dir, 1200);
    let cat = dir.join("catalog_1.catalog");
    let full = std::fs::read(&cat).unwrap();
    // Cut the last record (index 1199) in the middle, as a crash mid-write would.
    let last_start = full[..full.len() - 1]
        .iter()
        .rposition(|&b| b == b'\n')
        .unwrap()
        + 1;
    let cut = last_start + 40;
    std::fs::write(&cat, &full[..cut]).unwrap();

    let reader = TubReader::open(&dir).unwrap();
    assert_eq!(reader.len(), 1199);
    assert_eq!(reader.warnings().len(), 1, "{:?}", reader.warnings());
    let w0 = &reader.warnings()[0];
    assert!(w0.contains("catalog_1.catalog line 200"), "{w0}");
    assert!(w0.contains("torn"), "{w0}");
    for (i, rec) in reader.records().enumerate() {
        assert_eq!(rec, &expected(i as u64, &session));
    }

    // Reopening moves the torn bytes aside (not lost) and continues at index 1199, so
    // indexes stay the records' positions as DonkeyCar counts them.
    let mut w = TubWriter::create(&dir, &TubInputs::ALL, T0 + 60.0).unwrap();
    assert_eq!(w.next_index(), 1199);
    assert_eq!(w.warnings().len(), 3, "{:?}", w.warnings());
    let aside = dir.join(format!("catalog_1.catalog.torn.{last_start}"));
    assert_eq!(std::fs::read(&aside).unwrap(), &full[last_start..cut]);
    let orphan = dir.join("images/1199_cam_image_array_.jpg.orphan");
    assert!(orphan.is_file());
    assert_eq!(std::fs::read(&cat).unwrap(), &full[..last_start]);
    let jpeg = jpeg_8x8(9);
    assert_eq!(w.append(&record(1199), &jpeg).unwrap(), 1199);
    let reader = TubReader::open(&dir).unwrap();
    assert!(reader.warnings().is_empty(), "{:?}", reader.warnings());
    assert_eq!(reader.len(), 1200);
    assert_eq!(reader.records().last().unwrap().session_id, "25-11-21_1");
    assert_eq!(
        std::fs::read(reader.image_path(reader.records().last().unwrap())).unwrap(),
        jpeg
    );
}

#[test]
fn record_written_before_the_manifest_caught_up_is_counted() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("tub");
    write_tub(&dir, 10);
    // A crash after the record line but before the manifests: the catalog holds one more
    // complete record than manifest.json counts (the last one even lacks its newline).
    let manifest = std::fs::read_to_string(dir.join("manifest.json")).unwrap();
    let cm = std::fs::read(dir.join("catalog_0.catalog_manifest")).unwrap();
    let mut w = TubWriter::create(&dir, &TubInputs::ALL, T0).unwrap();
    w.append(&record(10), &jpeg_8x8(1)).unwrap();
    drop(w);
    std::fs::write(dir.join("manifest.json"), manifest).unwrap();
    std::fs::write(dir.join("catalog_0.catalog_manifest"), cm).unwrap();
    let cat = dir.join("catalog_0.catalog");
    let mut bytes = std::fs::read(&cat).unwrap();
    bytes.pop();
    std::fs::write(&cat, &bytes).unwrap();

    let r = TubReader::open(&dir).unwrap();
    assert_eq!(r.len(), 11);
    assert_eq!(r.warnings().len(), 1, "{:?}", r.warnings());
    let w = TubWriter::create(&dir, &TubInputs::ALL, T0).unwrap();
    assert_eq!(w.next_index(), 11);
    assert_eq!(w.warnings().len(), 2, "{:?}", w.warnings());
    let r = TubReader::open(&dir).unwrap();
    assert_eq!(r.len(), 11);
    assert!(r.warnings().is_empty(), "{:?}", r.warnings());
}

#[test]
fn garbage_line_is_an_error_naming_file_and_line() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("tub");
    write_tub(&dir, 1500);
    let cat = dir.join("catalog_1.catalog");
    let mut ls = lines(&cat);
    ls[99] = "{\"_index\": 1099, this is not json".into();
    std::fs::write(&cat, ls.join("\n") + "\n").unwrap();
    let err = TubReader::open(&dir).unwrap_err();
    match &err {
        DatasetError::Parse { path, line, .. } => {
            assert!(path.ends_with("catalog_1.catalog"), "{path}");
            assert_eq!(*line, 100);
        }
        other => panic!("{other:?}"),
    }
    assert!(
        err.to_string().contains("catalog_1.catalog line 100"),
        "{err}"
    );

    // Valid JSON with a bad value names the key.
    ls[99] = "{\"_index\": 1099, \"_timestamp_ms\": 1, \"cam/image_array\": \"1099_cam_image_array_.jpg\", \"user/angle\": \"left\", \"user/throttle\": 0.1, \"user/mode\": \"user\"}".into();
    std::fs::write(&cat, ls.join("\n") + "\n").unwrap();
    let err = TubReader::open(&dir).unwrap_err().to_string();
    assert!(err.contains("catalog_1.catalog line 100"), "{err}");
    assert!(err.contains("user/angle"), "{err}");

    // A path escaping the tub is refused.
    ls[99] = ls[98]
        .replace("1098_cam_image_array_.jpg", "../../etc/passwd")
        .replace("\"_index\": 1098", "\"_index\": 1099");
    std::fs::write(&cat, ls.join("\n") + "\n").unwrap();
    let err = TubReader::open(&dir).unwrap_err().to_string();
    assert!(
        err.contains("line 100") && err.contains("cam/image_array"),
        "{err}"
    );

    // A broken manifest names its line.
    let m = dir.join("manifest.json");
    let mut ml = lines(&m);
    ml[4] =
        "{\"paths\": [\"catalog_0.catalog\"], \"max_len\": 1000, \"deleted_indexes\": []}".into();
    std::fs::write(&m, ml.join("\n") + "\n").unwrap();
    let err = TubReader::open(&dir).unwrap_err().to_string();
    assert!(
        err.contains("manifest.json line 5") && err.contains("current_index"),
        "{err}"
    );
    // The writer refuses it too, and leaves the files alone.
    let before = std::fs::read(&m).unwrap();
    assert!(TubWriter::create(&dir, &TubInputs::ALL, T0).is_err());
    assert_eq!(std::fs::read(&m).unwrap(), before);
}

/// A tub as DonkeyCar writes it: only DonkeyCar's keys plus a part's extra keys.
fn donkey_tub(dir: &Path) {
    std::fs::create_dir_all(dir.join("images")).unwrap();
    let manifest = [
        r#"["cam/image_array", "user/angle", "user/throttle", "user/mode", "user/extra"]"#,
        r#"["image_array", "float", "float", "str", "float"]"#,
        r#"{"car": "donkey1"}"#,
        r#"{"created_at": 1637500000.123, "sessions": {"all_full_ids": ["21-11-21_0"], "last_id": 0, "last_full_id": "21-11-21_0"}}"#,
        r#"{"paths": ["catalog_0.catalog"], "current_index": 3, "max_len": 1000, "deleted_indexes": [1]}"#,
    ];
    std::fs::write(dir.join("manifest.json"), manifest.join("\n") + "\n").unwrap();
    let records = [
        r#"{"_index": 0, "_session_id": "21-11-21_0", "_timestamp_ms": 1637500001000, "cam/image_array": "0_cam_image_array_.jpg", "user/angle": 0.0, "user/extra": 5.5, "user/mode": "user", "user/throttle": 0.25}"#,
        r#"{"_index": 1, "_session_id": "21-11-21_0", "_timestamp_ms": 1637500001050, "cam/image_array": "1_cam_image_array_.jpg", "user/angle": -0.5, "user/mode": "user", "user/throttle": 0.25}"#,
        r#"{"_index": 2, "_timestamp_ms": 1637500001100, "cam/image_array": "2_cam_image_array_.jpg", "user/angle": 1, "user/mode": "local_angle", "user/throttle": -0.125, "localizer/location": [1, 2], "pilot/angle": null}"#,
    ];
    std::fs::write(dir.join("catalog_0.catalog"), records.join("\n") + "\n").unwrap();
    std::fs::write(
        dir.join("catalog_0.catalog_manifest"),
        r#"{"created_at": 1637500000.2, "line_lengths": [200, 180, 220], "path": "catalog_0.catalog_manifest", "start_index": 0}"#,
    )
    .unwrap();
    for i in 0..3 {
        std::fs::write(
            dir.join(format!("images/{i}_cam_image_array_.jpg")),
            jpeg_8x8(i),
        )
        .unwrap();
    }
}

#[test]
fn donkeycar_tub_reads_and_continues() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("donkey");
    donkey_tub(&dir);
    let r = TubReader::open(&dir).unwrap();
    assert!(r.warnings().is_empty(), "{:?}", r.warnings());
    let recs: Vec<&TubRecord> = r.records().collect();
    assert_eq!(recs.len(), 2);
    assert_eq!(
        recs[0],
        &TubRecord {
            index: 0,
            session_id: "21-11-21_0".into(),
            image: "0_cam_image_array_.jpg".into(),
            ..TubRecord::new(1_637_500_001_000, 0.0, 0.25, DriveMode::User)
        }
    );
    assert_eq!(
        recs[1],
        &TubRecord {
            index: 2,
            image: "2_cam_image_array_.jpg".into(),
            ..TubRecord::new(1_637_500_001_100, 1.0, -0.125, DriveMode::LocalAngle)
        }
    );
    assert!(recs.iter().all(|r| r.pilot_angle.is_none()
        && r.pilot_throttle.is_none()
        && r.wheels.is_none()
        && r.pose.is_none()
        && r.reward.is_none()
        && r.target.is_none()));

    // Continue it: user metadata, inputs and sessions kept, keys added, index 3 next.
    let mut w = TubWriter::create(&dir, &TubInputs::DONKEY, 1_763_750_000.0).unwrap();
    assert_eq!(w.session_id(), "25-11-21_1");
    let mut rec = TubRecord::new(T0_MS, 0.5, 0.5, DriveMode::Local);
    rec.reward = Some(0.75);
    assert_eq!(w.append(&rec, &jpeg_8x8(50)).unwrap(), 3);
    let m = lines(&dir.join("manifest.json"));
    assert_eq!(
        m[0],
        r#"["cam/image_array", "user/angle", "user/throttle", "user/mode", "user/extra", "reward"]"#
    );
    assert_eq!(m[2], r#"{"car": "donkey1"}"#);
    let meta: Value = serde_json::from_str(&m[3]).unwrap();
    assert_eq!(meta["created_at"], json!(1637500000.123));
    assert_eq!(
        meta["sessions"]["all_full_ids"],
        json!(["21-11-21_0", "25-11-21_1"])
    );
    let m5: Value = serde_json::from_str(&m[4]).unwrap();
    assert_eq!(m5["deleted_indexes"], json!([1]));
    assert_eq!(m5["current_index"], json!(4));
    let r = TubReader::open(&dir).unwrap();
    assert_eq!(r.len(), 3);
    assert_eq!(r.records().last().unwrap().reward, Some(0.75));
    // DonkeyCar's record lines were left as they were.
    assert!(lines(&dir.join("catalog_0.catalog"))[2].contains("localizer/location"));
}

#[test]
fn missing_image_is_reported_and_skipped() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("tub");
    write_tub(&dir, 20);
    std::fs::remove_file(dir.join("images/7_cam_image_array_.jpg")).unwrap();
    let r = TubReader::open(&dir).unwrap();
    assert_eq!(r.len(), 19);
    assert!(r.records().all(|rec| rec.index != 7));
    assert_eq!(r.warnings().len(), 1);
    assert!(
        r.warnings()[0].contains("7_cam_image_array_.jpg"),
        "{:?}",
        r.warnings()
    );
}

#[test]
fn a_donkeycar_tub_with_a_missing_image_a_torn_line_and_no_index_is_read_with_warnings() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("donkey");
    donkey_tub(&dir);
    // Record 2's image gone, a torn line after the last record, and DonkeyCar's index of
    // the catalog's line lengths deleted.
    std::fs::remove_file(dir.join("images/2_cam_image_array_.jpg")).unwrap();
    let catalog = dir.join("catalog_0.catalog");
    let mut text = std::fs::read(&catalog).unwrap();
    text.extend_from_slice(br#"{"_index": 3, "_session_id": "21-11-21_0", "_timest"#);
    std::fs::write(&catalog, text).unwrap();
    std::fs::remove_file(dir.join("catalog_0.catalog_manifest")).unwrap();
    let r = TubReader::open(&dir).unwrap();
    // Record 1 is soft-deleted, 2 has no image: record 0 is left.
    assert_eq!(r.records().map(|r| r.index).collect::<Vec<_>>(), vec![0]);
    let w = r.warnings();
    assert_eq!(w.len(), 3, "{w:?}");
    assert!(
        w[0].contains("catalog_0.catalog_manifest: missing"),
        "{w:?}"
    );
    assert!(w[1].contains("line 4: torn last line"), "{w:?}");
    assert!(
        w[2].contains("record 2") && w[2].contains("2_cam_image_array_.jpg is missing"),
        "{w:?}"
    );
    // A catalog the manifest lists but that is gone: its records are lost, with a warning.
    let m = dir.join("manifest.json");
    let text = std::fs::read_to_string(&m).unwrap().replace(
        r#"["catalog_0.catalog"]"#,
        r#"["catalog_0.catalog", "catalog_1.catalog"]"#,
    );
    std::fs::write(&m, text).unwrap();
    let r = TubReader::open(&dir).unwrap();
    assert_eq!(r.len(), 1);
    assert!(
        r.warnings()
            .iter()
            .any(|w| w.contains("catalog_1.catalog: listed in manifest.json but missing")),
        "{:?}",
        r.warnings()
    );
}

#[test]
fn bad_input_is_refused_before_anything_is_written() {
    let tmp = tempfile::tempdir().unwrap();
    // A folder holding something else is not turned into a tub.
    let other = tmp.path().join("photos");
    std::fs::create_dir(&other).unwrap();
    std::fs::write(other.join("holiday.jpg"), b"x").unwrap();
    let err = TubWriter::create(&other, &TubInputs::ALL, T0)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("photos") && err.contains("holiday.jpg"),
        "{err}"
    );
    assert_eq!(std::fs::read_dir(&other).unwrap().count(), 1);
    assert!(TubWriter::create(&tmp.path().join("t"), &TubInputs::ALL, f64::NAN).is_err());

    let dir = tmp.path().join("tub");
    let mut w = TubWriter::create(&dir, &TubInputs::DONKEY, T0).unwrap();
    let jpeg = jpeg_8x8(0);
    w.append(&record(0), &jpeg).unwrap();
    let mut bad = record(1);
    bad.pose = Some((0.0, f32::NAN, 0.0));
    let err = w.append(&bad, &jpeg).unwrap_err().to_string();
    assert!(err.contains("pose/y"), "{err}");
    let err = w.append(&record(1), b"GIF89a").unwrap_err().to_string();
    assert!(err.contains("JPEG"), "{err}");
    assert_eq!(w.len(), 1);
    assert_eq!(w.next_index(), 1);
    assert!(!dir.join("images/1_cam_image_array_.jpg").exists());
    assert_eq!(lines(&dir.join("catalog_0.catalog")).len(), 1);
    assert_eq!(w.append(&record(1), &jpeg).unwrap(), 1);
    let r = TubReader::open(&dir).unwrap();
    assert_eq!(r.len(), 2);
    // Keys not declared at create time were added, not dropped.
    assert!(r.inputs().iter().any(|k| k == "pose/heading"));
    assert_eq!(r.records().nth(1).unwrap(), &expected(1, "25-11-21_0"));

    // An empty folder, and one left by an interrupted create, are fine.
    let empty = tmp.path().join("empty");
    std::fs::create_dir_all(empty.join("images")).unwrap();
    std::fs::write(empty.join("catalog_0.catalog"), b"").unwrap();
    let mut w = TubWriter::create(&empty, &TubInputs::ALL, T0).unwrap();
    assert_eq!(w.append(&record(0), &jpeg).unwrap(), 0);
}

#[test]
fn jetbot_xy_folder() {
    use rand::SeedableRng;
    assert_eq!(jetbot_xy::label(112, 112, 224, 224), (0.0, 0.0));
    let (x, y) = jetbot_xy::label(223, 0, 224, 224);
    assert!((x - 0.991_071_4).abs() < 1e-6 && y == -1.0);
    assert_eq!(
        jetbot_xy::parse_file_name("xy_057_101_0b7e5f4c-2d1a-11ea-9c3a-00044be5a7c1.jpg"),
        Some((57, 101))
    );
    for (px, py) in [(0, 0), (57, 101), (223, 223), (112, 7)] {
        let (x, y) = jetbot_xy::label(px, py, 224, 224);
        assert_eq!(jetbot_xy::pixel_for_label(x, y, 224, 224), (px, py));
    }

    let tmp = tempfile::tempdir().unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(42);
    let jpeg = jpeg_8x8(1);
    let mut written = Vec::new();
    for (px, py) in [(10, 20), (200, 5), (112, 112)] {
        let id = jetbot_xy::uuid_from_rng(&mut rng);
        written.push(jetbot_xy::write_sample(tmp.path(), px, py, &jpeg, &id).unwrap());
    }
    std::fs::write(tmp.path().join("xy_12_34_short.jpg"), &jpeg).unwrap();
    let folder = XyFolder::open(tmp.path()).unwrap();
    assert_eq!(folder.samples().len(), 3);
    assert_eq!(folder.warnings().len(), 1);
    let coords: Vec<(u32, u32)> = folder.samples().iter().map(|s| (s.px, s.py)).collect();
    assert_eq!(coords, [(10, 20), (112, 112), (200, 5)]);
    written.sort();
    let paths: Vec<_> = folder.samples().iter().map(|s| s.path.clone()).collect();
    assert_eq!(paths, written);
}
