//! `scripts/real-replay.sh` end to end on a DonkeyCar tub (issue 49 item 3): a simulated
//! car's drive written as a DonkeyCar writes one (frames, `user/angle`, `user/throttle`,
//! nothing else), then the script's every step with a tiny DDPG budget: poses, the three
//! replays (training, selection, report), imitation, the evaluations and the report. Needs the `train` feature, ONNX
//! Runtime and python3 with pip (the script installs the ImageNet weights).
#![cfg(feature = "train")]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use jetpilot::dataset::tub::{TubInputs, TubReader, TubWriter};

fn repo(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

/// A DonkeyCar's drive: 20 s round the mat at 0.4 m/s through DonkeyCar's wide lens
/// (config/donkeycar.toml), steering tightened to a 0.25 m radius at full lock so the
/// scripted expert drives the mat's bends without an intervention; 1.1 laps, so the
/// script's `--turn-from-loops` has a loop.
fn donkeycar_tub(dir: &Path) -> PathBuf {
    let camera = std::fs::read_to_string(repo("config/donkeycar.toml")).unwrap();
    let tightened = camera.replace("curvature_per_unit = -2.0", "curvature_per_unit = -4.0");
    assert_ne!(camera, tightened, "config/donkeycar.toml changed shape");
    let cfg = dir.join("car.toml");
    std::fs::write(
        &cfg,
        format!(
            "[control]\nmixing = \"car\"\nspeed_gain = 0.25\n[sim]\nvehicle = \"car\"\n\
             [sim.expert]\nspeed_mps = 0.4\n{tightened}"
        ),
    )
    .unwrap();
    // What a DonkeyCar records: no poses, rewards, labels or pilot fields.
    owner_tub(dir, &cfg, &TubInputs::DONKEY)
}

/// 20 s of the scripted expert under `cfg`, copied into `dir/tub` with `inputs`' fields
/// only (frames, the commands, and the wheels where `inputs` has them): what the owner's
/// robot would have recorded, without the simulator's poses, rewards, labels or pilot
/// fields.
fn owner_tub(dir: &Path, cfg: &Path, inputs: &TubInputs) -> PathBuf {
    let drive = dir.join("drive");
    let o = Command::new(env!("CARGO_BIN_EXE_jetpilot"))
        .args(["-q", "sim", "--expert", "--seconds", "20", "--config"])
        .arg(cfg)
        .arg("--record")
        .arg(&drive)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let tub = dir.join("tub");
    let r = TubReader::open(&drive).unwrap();
    assert!(
        r.records().all(|rec| rec.wheels.is_some() == inputs.wheels),
        "the simulated drive's wheels do not match the robot's"
    );
    let mut w = TubWriter::create(&tub, inputs, 1.7e9).unwrap();
    for rec in r.records() {
        let mut copy = rec.clone();
        copy.pose = None;
        copy.reward = None;
        copy.target = None;
        copy.pilot_angle = None;
        copy.pilot_throttle = None;
        w.append(&copy, &std::fs::read(r.image_path(rec)).unwrap())
            .unwrap();
    }
    w.flush_and_sync().unwrap();
    tub
}

fn real_replay(tub: &Path, out: &Path) -> Output {
    real_replay_with(tub, out, &[])
}

/// The script with the quick settings above and `extra` variables in its environment.
fn real_replay_with(tub: &Path, out: &Path, extra: &[(&str, &str)]) -> Output {
    Command::new("bash")
        .arg(repo("scripts/real-replay.sh"))
        .arg(tub)
        .arg(out)
        .env("BIN", env!("CARGO_BIN_EXE_jetpilot"))
        .env("EVAL_SECONDS", "3")
        .env("DDPG_EVAL_SECONDS", "3")
        .env("MINUTES", "5")
        .env(
            "DDPG_FLAGS",
            "--episodes 2 --episode-steps 60 --warmup-updates 10 --batch 16 --search-step 0.1",
        )
        .envs(extra.iter().copied())
        .output()
        .unwrap()
}

/// Runs the script and asserts it succeeded; its output.
fn real_replay_ok(tub: &Path, out: &Path, extra: &[(&str, &str)]) -> String {
    let o = real_replay_with(tub, out, extra);
    let log = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(o.status.success(), "{log}");
    log
}

/// The report's table: every policy's row on the three replays, with numbers in each
/// cell.
fn assert_report_rows(report: &str) {
    for policy in ["expert", "il", "ddpg_last", "ddpg_best"] {
        let row = report
            .lines()
            .find(|l| l.starts_with(&format!("| {policy} |")))
            .unwrap_or_else(|| panic!("no row for {policy}: {report}"));
        let cells: Vec<&str> = row.split('|').map(str::trim).collect();
        assert_eq!(cells.len(), 12, "{row}");
        let interventions = [cells[2], cells[5], cells[8]];
        assert!(
            interventions.iter().all(|c| c.parse::<u32>().is_ok()),
            "{row}"
        );
        assert!(
            [cells[4], cells[7], cells[10]]
                .iter()
                .all(|c| c.ends_with(" m")),
            "{row}"
        );
    }
}

#[test]
fn real_replay_sh_runs_a_donkeycar_tub_to_its_report() {
    let dir = tempfile::tempdir().unwrap();
    let tub = donkeycar_tub(dir.path());
    let out = dir.path().join("out");
    let log = real_replay_ok(&tub, &out, &[]);

    // The car was found from the tub's fields, with the wide lens, and the three replays
    // split the recording by time.
    let poses_log = std::fs::read_to_string(out.join("poses.log")).unwrap();
    assert!(poses_log.contains("car-like"), "{poses_log}");
    let part =
        |name: &str| std::fs::read_to_string(out.join(format!("poses/{name}.toml"))).unwrap();
    let (early, middle, late) = (part("early"), part("middle"), part("late"));
    assert!(early.contains("recording_span = [0.0, 0.7000]"), "{early}");
    assert!(
        middle.contains("recording_span = [0.7000, 0.8500]"),
        "{middle}"
    );
    assert!(late.contains("recording_span = [0.8500, 1.0]"), "{late}");
    assert!(early.contains("vehicle = \"car\""), "{early}");
    // DDPG trained on the early replay and chose best.onnx on the middle one.
    let ddpg_log = std::fs::read_to_string(out.join("ddpg.log")).unwrap();
    assert!(ddpg_log.contains("best in middle.toml: "), "{ddpg_log}");
    for f in [
        "poses/poses.png",
        "poses/check-views.png",
        "il/probe.onnx",
        "ddpg/last.onnx",
        "ddpg/best.onnx",
        "eval_expert_late.png",
        "eval_il_late.png",
        "eval_ddpg_last_early.png",
        "eval_ddpg_best_middle.png",
    ] {
        assert!(out.join(f).is_file(), "{f} missing; {log}");
    }
    // The expert's recoveries were recorded as DonkeyCar's fields.
    let demos = TubReader::open(&out.join("demos")).unwrap();
    assert!(demos.len() > 10, "{} demonstrations", demos.len());
    assert!(demos.records().all(|r| r.wheels.is_none()));

    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert_report_rows(&report);
    assert!(report.contains("\nDDPG: "), "{report}");
    assert!(report.contains("- Demonstrations: recorded "), "{report}");
    assert!(
        report.contains("- DDPG evaluations (3 s, middle replay): start "),
        "{report}"
    );

    // A second run never writes over the first.
    let again = real_replay(&tub, &out);
    assert_eq!(again.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&again.stderr).contains("exists"));
}

/// A folder the script takes for a tub (it has a manifest), for settings it refuses first.
fn manifest_only_tub(dir: &Path) -> PathBuf {
    let tub = dir.join("tub");
    std::fs::create_dir_all(&tub).unwrap();
    std::fs::write(tub.join("manifest.json"), "{}").unwrap();
    tub
}

#[test]
fn a_selection_part_as_large_as_the_held_out_part_is_refused_before_any_work() {
    // SELECT is cut from the held-out part, so it must leave some of it to report on.
    let dir = tempfile::tempdir().unwrap();
    let (tub, out) = (manifest_only_tub(dir.path()), dir.path().join("out"));
    let o = real_replay_with(&tub, &out, &[("SELECT", "0.3")]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("SELECT must be 0 or more and below SPLIT (0.3), got '0.3'"),
        "{err}"
    );
    assert!(!out.exists(), "nothing written");
}

#[test]
fn an_unknown_imitation_is_refused_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let (tub, out) = (manifest_only_tub(dir.path()), dir.path().join("out"));
    let o = real_replay_with(&tub, &out, &[("IL", "resnet")]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("IL must be probe or finetune, got 'resnet'"),
        "{err}"
    );
    assert!(!out.exists(), "nothing written");
}

/// A JetBot's drive as the daemon records one: frames, the commands and the wheel duties
/// (`wheels/*`), no poses: 20 s of the scripted expert on the mat through JetBot's camera
/// (config/sim.toml).
fn jetbot_tub(dir: &Path) -> PathBuf {
    let inputs = TubInputs {
        wheels: true,
        ..TubInputs::DONKEY
    };
    owner_tub(dir, &repo("config/sim.toml"), &inputs)
}

#[test]
fn real_replay_sh_runs_a_jetbot_recording_to_its_report() {
    let dir = tempfile::tempdir().unwrap();
    let tub = jetbot_tub(dir.path());
    let out = dir.path().join("out");
    // With the imitation policy fine-tuned (one epoch here) instead of a probe.
    real_replay_ok(&tub, &out, &[("IL", "finetune"), ("IL_EPOCHS", "1")]);
    // The wheels' fields chose the differential-drive prior and JetBot's defaults.
    let poses_log = std::fs::read_to_string(out.join("poses.log")).unwrap();
    assert!(poses_log.contains("differential drive"), "{poses_log}");
    let early = std::fs::read_to_string(out.join("poses/early.toml")).unwrap();
    assert!(!early.contains("vehicle = \"car\""), "{early}");
    let ddpg_log = std::fs::read_to_string(out.join("ddpg.log")).unwrap();
    assert!(ddpg_log.contains("best in middle.toml: "), "{ddpg_log}");
    // `train il` learnt from the training part only: its policy is the imitation row.
    let il_log = std::fs::read_to_string(out.join("il.log")).unwrap();
    assert!(il_log.contains("imitation learning: 1 epochs"), "{il_log}");
    assert!(out.join("il/last.onnx").is_file() && !out.join("il/probe.onnx").exists());
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert_report_rows(&report);
    assert!(report.contains("(IL=finetune SPLIT=0.3 "), "{report}");
}
