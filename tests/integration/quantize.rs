//! `jetpilot model quantize` end to end on a random ResNet-18 and a generated JetBot xy
//! folder: the QDQ model is written with its contract, ONNX Runtime runs every convolution
//! of it as QLinearConv, a tolerance it misses writes nothing and says by how much, and
//! bad calibration data is named. `jetpilot model optimize`: the pre-optimised model gives
//! the same answers through the daemon's loader and is refused on another machine.
//!
//! Needs the ONNX Runtime library (scripts/install-onnxruntime.sh).

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use jetpilot::dataset::{encode_jpeg, jetbot_xy};
use jetpilot::policy::Policy;
use jetpilot::policy::optimize::{META_OPTIMIZED_FOR, append_metadata};

fn jetpilot(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_jetpilot"))
        .args(args)
        .output()
        .expect("run jetpilot")
}

fn text(out: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// 30 frames, one a second, each a different pattern of stripes and shades.
fn xy_folder(dir: &Path) -> PathBuf {
    let out = dir.join("xy");
    std::fs::create_dir_all(&out).unwrap();
    for i in 0..30u32 {
        let rgb: Vec<u8> = (0..64 * 64)
            .flat_map(|p| {
                let (x, y) = (p % 64, p / 64);
                let v = ((x * (i + 1) + y * (30 - i)) % 256) as u8;
                [v, v.wrapping_mul(3), 255 - v]
            })
            .collect();
        let mut jpeg = Vec::new();
        encode_jpeg(&rgb, 64, 64, &mut jpeg).unwrap();
        let uuid1 = format!("{:08x}-0000-1000-8000-000000000000", i * 10_000_000);
        jetbot_xy::write_sample(&out, 100 + i, 120, &jpeg, &uuid1).unwrap();
    }
    out
}

/// `jetpilot model quantize FLOAT -o OUT --calibration DATA --threads 1 EXTRA...`.
fn quantize(float: &Path, out: &Path, data: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "model",
        "quantize",
        float.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--calibration",
        data.to_str().unwrap(),
        "--threads",
        "1",
    ];
    args.extend_from_slice(extra);
    jetpilot(&args)
}

#[test]
fn quantizes_keeps_the_contract_and_runs_as_integer_convolutions() {
    let dir = tempfile::tempdir().unwrap();
    let (float, data) = (
        common::write_model(dir.path(), 32, 1),
        xy_folder(dir.path()),
    );
    let out = dir.path().join("int8.onnx");
    let run = quantize(&float, &out, &data, &[]);
    let t = text(&run);
    assert!(run.status.success(), "{t}");
    assert!(t.contains("20 batch norms folded, 30 activations"), "{t}");
    assert!(t.contains("calibrating on 24 frames (6 held out)"), "{t}");
    assert!(
        t.contains(
            "runs 20 convolutions as QLinearConv (0 left in float), 8 additions as QLinearAdd"
        ),
        "{t}"
    );
    assert!(t.contains("on the held-out frames"), "{t}");
    // int8 weights: about a quarter of the float file.
    let (fs, qs) = (
        std::fs::metadata(&float).unwrap().len(),
        std::fs::metadata(&out).unwrap().len(),
    );
    assert!(qs * 3 < fs, "int8 {qs} bytes, float {fs}");

    let info = jetpilot(&["model", "info", out.to_str().unwrap()]);
    let t = text(&info);
    assert!(info.status.success(), "{t}");
    assert!(t.contains("contract   input [1,3,32,32]"), "{t}");
    assert!(t.contains("quantized  int8 QDQ: per-channel symmetric 8-bit weights, uint8 activations, percentile 99.99 ranges from 24 frames"), "{t}");
    assert!(t.contains("QuantizeLinear 30"), "{t}");
}

#[test]
fn the_first_or_last_convolutions_can_stay_float() {
    let dir = tempfile::tempdir().unwrap();
    let (float, data) = (
        common::write_model(dir.path(), 32, 1),
        xy_folder(dir.path()),
    );
    let out = dir.path().join("int8.onnx");
    let run = quantize(&float, &out, &data, &["--float-last", "1"]);
    let t = text(&run);
    assert!(run.status.success(), "{t}");
    assert!(
        t.contains(
            "runs 19 convolutions as QLinearConv (1 left in float), 7 additions as QLinearAdd"
        ),
        "{t}"
    );
    let info = jetpilot(&["model", "info", out.to_str().unwrap()]);
    assert!(
        text(&info).contains("8-bit weights, uint8 activations, the last 1 convolution(s) float32"),
        "{}",
        text(&info)
    );

    // The stem in float: the input is no longer quantized, the additions all still are.
    let run = quantize(&float, &out, &data, &["--float-first", "1"]);
    let t = text(&run);
    assert!(run.status.success(), "{t}");
    assert!(t.contains("29 activations to quantize"), "{t}");
    assert!(
        t.contains(
            "runs 19 convolutions as QLinearConv (1 left in float), 8 additions as QLinearAdd"
        ),
        "{t}"
    );

    let run = quantize(
        &float,
        &out,
        &data,
        &["--float-first", "4", "--float-last", "16"],
    );
    assert!(!run.status.success());
    assert!(
        text(&run).contains(
            "the model has 20 convolutions; leaving the first 4 and the last 16 in float would quantize none"
        ),
        "{}",
        text(&run)
    );
}

#[test]
fn a_missed_tolerance_writes_nothing_and_says_by_how_much() {
    let dir = tempfile::tempdir().unwrap();
    let (float, data) = (
        common::write_model(dir.path(), 32, 1),
        xy_folder(dir.path()),
    );
    let out = dir.path().join("int8.onnx");
    let run = quantize(
        &float,
        &out,
        &data,
        &["--method", "minmax", "--tolerance", "0"],
    );
    let t = text(&run);
    assert!(!run.status.success(), "{t}");
    assert!(
        t.contains("refused: the quantized outputs differ from the float model's by up to"),
        "{t}"
    );
    assert!(
        t.contains("more than --tolerance 0; nothing written"),
        "{t}"
    );
    assert!(!out.exists());
}

#[test]
fn bad_calibration_data_and_models_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let float = common::write_model(dir.path(), 32, 1);
    let out = dir.path().join("int8.onnx");
    let missing = dir.path().join("no-such-folder");
    let run = quantize(&float, &out, &missing, &[]);
    assert!(!run.status.success());
    assert!(text(&run).contains("no-such-folder"), "{}", text(&run));

    let junk = dir.path().join("junk.onnx");
    std::fs::write(&junk, b"not a model").unwrap();
    let data = xy_folder(dir.path());
    let run = quantize(&junk, &out, &data, &[]);
    assert!(!run.status.success());
    assert!(text(&run).contains("junk.onnx"), "{}", text(&run));
    assert!(!out.exists());
}

#[test]
fn optimize_writes_a_model_that_loads_as_it_is_and_only_on_its_machine() {
    let dir = tempfile::tempdir().unwrap();
    let float = common::write_model(dir.path(), 32, 1);
    let out = dir.path().join("opt.onnx");
    let run = jetpilot(&[
        "model",
        "optimize",
        float.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    let t = text(&run);
    assert!(run.status.success(), "{t}");
    assert!(t.contains("outputs match the original"), "{t}");
    // The weights live in opt.onnx.data; the model file itself is small.
    let data = dir.path().join("opt.onnx.data");
    assert!(std::fs::metadata(&out).unwrap().len() < 100_000);
    assert!(std::fs::metadata(&data).unwrap().len() > 40_000_000);
    let (mut a, mut b) = (
        common::try_load_ort(&float).unwrap(),
        common::try_load_ort(&out).unwrap(),
    );
    let x: Vec<f32> = (0..3 * 32 * 32)
        .map(|i| (i % 17) as f32 / 8.0 - 1.0)
        .collect();
    let (u, v) = (a.infer(&x).unwrap(), b.infer(&x).unwrap());
    assert!(
        (u[0] - v[0]).abs() < 1e-5 && (u[1] - v[1]).abs() < 1e-5,
        "{u:?} {v:?}"
    );
    assert_eq!(b.contract(), a.contract(), "the contract survives");

    // A model made for another machine is refused, both machines named.
    let mut bytes = std::fs::read(&float).unwrap();
    append_metadata(
        &mut bytes,
        META_OPTIMIZED_FOR,
        "onnxruntime 0.0.1, riscv64, elsewhere",
    );
    let other = dir.path().join("other.onnx");
    std::fs::write(&other, &bytes).unwrap();
    let err = common::try_load_ort(&other)
        .err()
        .expect("refused")
        .to_string();
    assert!(
        err.contains("pre-optimised for `onnxruntime 0.0.1, riscv64, elsewhere`")
            && err.contains("this machine is `onnxruntime ")
            && err.contains("jetpilot model optimize"),
        "{err}"
    );

    // Writing over the input is refused before anything is written.
    let run = jetpilot(&[
        "model",
        "optimize",
        float.to_str().unwrap(),
        "-o",
        float.to_str().unwrap(),
    ]);
    assert!(!run.status.success());
    assert!(
        text(&run).contains("must differ from the input"),
        "{}",
        text(&run)
    );
}

#[test]
fn a_speed_steering_model_calibrates_on_a_jetbot_xy_folder() {
    // Calibration needs the frames, not their labels: an xy folder serves a speed_steering
    // model (it was refused as the wrong head's labels before 2026-12-06).
    use jetpilot::policy::onnx::{self, Resnet18Weights};
    use jetpilot::policy::{ModelContract, OutputKind};
    let dir = tempfile::tempdir().unwrap();
    let contract = ModelContract {
        input_size: 32,
        output: OutputKind::SpeedSteering,
        ..ModelContract::default()
    };
    let model =
        onnx::resnet18_model(32, &Resnet18Weights::random(2, 1), &contract, "test").expect("model");
    let float = dir.path().join("speed_steering.onnx");
    onnx::write_model(&float, &model).expect("write model");
    let (data, out) = (xy_folder(dir.path()), dir.path().join("int8.onnx"));
    let run = quantize(&float, &out, &data, &[]);
    let t = text(&run);
    assert!(run.status.success(), "{t}");
    assert!(t.contains("calibrating on 24 frames (6 held out)"), "{t}");
    let info = text(&jetpilot(&["model", "info", out.to_str().unwrap()]));
    assert!(info.contains("speed_steering"), "{info}");
}
