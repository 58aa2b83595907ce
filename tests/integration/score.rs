//! `jetpilot score` on a small generated JetBot xy folder with a known answer: a ResNet-18
//! whose fc weights are zero answers its fc bias, (0.25, -0.5) = pixel (140, 56), for
//! every frame, so each frame's error is the distance from its label to that pixel.
//! Bad files (zero bytes, truncated) are skipped by name and the run goes on. The four
//! frames are one picture labelled four times, so the labels' own disagreement is known.
//!
//! Needs the ONNX Runtime library (scripts/install-onnxruntime.sh).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use jetpilot::dataset::{encode_jpeg, jetbot_xy};
use jetpilot::policy::ModelContract;
use jetpilot::policy::onnx::{self, Dim, GraphBuilder, Resnet18Weights, attr_int};

fn jetpilot(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_jetpilot"))
        .args(args)
        .output()
        .expect("run jetpilot")
}

/// A model that answers (0.25, -0.5) whatever it sees.
fn constant_model(dir: &Path) -> PathBuf {
    let mut w = Resnet18Weights::random(2, 1);
    w.tensors.get_mut("fc.weight").unwrap().1.fill(0.0);
    w.tensors.get_mut("fc.bias").unwrap().1 = vec![0.25, -0.5];
    let contract = ModelContract {
        input_size: 32,
        ..ModelContract::default()
    };
    let path = dir.join("constant.onnx");
    onnx::write_model(
        &path,
        &onnx::resnet18_model(32, &w, &contract, "test").unwrap(),
    )
    .unwrap();
    path
}

/// Labels (pixels of the 224x224 frame) in capture order, and the model's distance to each:
/// 0, 30, 40 and |(60, 56)| = 82.0776 px.
const LABELS: [(u32, u32); 4] = [(140, 56), (170, 56), (140, 96), (200, 112)];

/// The folder: the four frames named with uuid1s whose times increase in that order, a
/// zero-byte JPEG and a truncated one.
fn xy_folder(dir: &Path) -> PathBuf {
    let out = dir.join("xy");
    std::fs::create_dir_all(&out).unwrap();
    let mut jpeg = Vec::new();
    encode_jpeg(&vec![90u8; 224 * 224 * 3], 224, 224, &mut jpeg).unwrap();
    for (i, (px, py)) in LABELS.iter().enumerate() {
        // time_low in 100 ns steps: one frame a second.
        let uuid1 = format!("{:08x}-0000-1000-8000-000000000000", i * 10_000_000);
        jetbot_xy::write_sample(&out, *px, *py, &jpeg, &uuid1).unwrap();
    }
    std::fs::write(out.join("xy_100_100_empty.jpg"), b"").unwrap();
    std::fs::write(
        out.join("xy_100_100_truncated.jpg"),
        &jpeg[..jpeg.len() / 3],
    )
    .unwrap();
    out
}

/// `jetpilot score --model M --data D --out O` plus `extra`.
fn score(model: &Path, data: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "score",
        "--model",
        model.to_str().unwrap(),
        "--data",
        data.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    jetpilot(&args)
}

fn text(o: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn score_gives_the_known_pixel_errors_and_skips_bad_files_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let model = constant_model(dir.path());
    let data = xy_folder(dir.path());
    let out = dir.path().join("score");
    let run = score(&model, &data, &out, &[]);
    let (stdout, stderr) = text(&run);
    assert!(run.status.success(), "{stdout}\n{stderr}");
    // Model: errors 0, 30, 40, 82.08 -> mean 38.0, median 35.0, p90 82.1.
    assert!(
        stdout.contains("model     mean 38.0 px, median 35.0 px, p90 82.1 px"),
        "{stdout}"
    );
    // Baseline: the mean label, pixel (162.5, 80): 32.90, 25.14, 27.61, 49.30 -> mean 33.7.
    assert!(stdout.contains("baseline  mean 33.7 px"), "{stdout}");
    assert!(stdout.contains("over 4 frames"), "{stdout}");
    // All four frames show one view (the same grey picture): each label's distance to the
    // mean (162.5, 80) times sqrt(4 / 3) (the others' mean, corrected for their noise):
    // 37.99, 29.03, 31.88, 56.92 -> mean 39.0, median 34.9; 38.96 / 33.74 = 1.15.
    assert!(
        stdout.contains(
            "labels    4 of 4 frames share their view with a neighbour (1 view(s) labelled more than once); \
             a label lies mean 39.0 px, median 34.9 px from its view's mean label (1.15 of the baseline)"
        ),
        "{stdout}"
    );
    for bad in ["xy_100_100_empty.jpg", "xy_100_100_truncated.jpg"] {
        assert!(
            stderr.contains(bad) && stderr.contains("skipped"),
            "{bad}: {stderr}"
        );
    }
    assert!(stderr.contains("the file is empty"), "{stderr}");
    assert!(stdout.contains("skipped 2 unreadable image(s)"), "{stdout}");
    // One CSV row per scored frame, with the prediction.
    let csv = std::fs::read_to_string(out.join("frames.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().skip(1).collect();
    assert_eq!(rows.len(), 4, "{csv}");
    assert!(
        rows.iter().all(|r| r.contains(",0.25000,-0.50000,")),
        "{csv}"
    );
    let png = image::open(out.join("frames.png")).unwrap();
    assert!(png.width() > 100 && png.height() > 100);
}

#[test]
fn a_split_by_time_scores_the_latest_frames_against_the_earlier_mean() {
    let dir = tempfile::tempdir().unwrap();
    let model = constant_model(dir.path());
    let data = xy_folder(dir.path());
    // The two bad files carry no uuid1: a split by time cannot place them.
    let run = score(
        &model,
        &data,
        &dir.path().join("s"),
        &["--split-by-time", "0.5"],
    );
    let (stdout, stderr) = text(&run);
    assert!(!run.status.success());
    assert!(
        stderr.contains("xy_100_100_") && stderr.contains("no capture time"),
        "{stderr}"
    );
    for bad in ["xy_100_100_empty.jpg", "xy_100_100_truncated.jpg"] {
        std::fs::remove_file(data.join(bad)).unwrap();
    }
    let run = score(
        &model,
        &data,
        &dir.path().join("s"),
        &["--split-by-time", "0.5"],
    );
    let (stdout2, stderr) = text(&run);
    assert!(run.status.success(), "{stdout}{stdout2}\n{stderr}");
    // The latest two: errors 40 and 82.08 -> mean 61.0. Baseline: the earlier two's mean,
    // pixel (155, 56): |(15, 40)| = 42.72 and |(45, 56)| = 71.84 -> mean 57.3.
    assert!(stdout2.contains("over 2 frames"), "{stdout2}");
    assert!(stdout2.contains("model     mean 61.0 px"), "{stdout2}");
    assert!(stdout2.contains("baseline  mean 57.3 px"), "{stdout2}");
    // A constant answers the same everywhere: no correlation, no spread. The labels: x 140
    // and 200 (sd 30 px), y 96 and 112 (sd 8 px).
    assert!(
        stdout2.contains(
            "tracking  labels sd (30.0, 8.0), predictions sd (0.0, 0.0), correlation (-, -) (px)"
        ),
        "{stdout2}"
    );
    // The best constant for these two, their own mean (170, 104): |(30, 8)| = 31.0 px each,
    // 31.05 / 57.28 = 0.54 of the baseline.
    assert!(
        stdout2.contains("own mean label (0.518, -0.071): mean 31.0 px")
            && stdout2.contains("(0.54 of the baseline)"),
        "{stdout2}"
    );
}

#[test]
fn a_folder_with_no_readable_frame_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let model = constant_model(dir.path());
    let data = dir.path().join("bad");
    std::fs::create_dir_all(&data).unwrap();
    std::fs::write(data.join("xy_010_020_a.jpg"), b"").unwrap();
    let run = score(&model, &data, &dir.path().join("s"), &[]);
    let (_, stderr) = text(&run);
    assert!(!run.status.success());
    assert!(
        stderr.contains("xy_010_020_a.jpg") && stderr.contains("none of the frames could be read"),
        "{stderr}"
    );
}

/// A 32x32 model blind to the right half of its input: x = the mean of the red plane's
/// left half over 512 (`Flatten` then `Gemm`), y = 0.
fn left_eyed_model(dir: &Path) -> PathBuf {
    let s = 32usize;
    let mut b = vec![0.0f32; 3 * s * s * 2];
    for y in 0..s {
        for x in 0..s / 2 {
            b[(y * s + x) * 2] = 1.0 / 512.0; // [3072, 2] row-major: plane 0, output 0
        }
    }
    let contract = ModelContract {
        input_size: s as u32,
        ..ModelContract::default()
    };
    let mut g = GraphBuilder::new("left_eyed");
    g.input_f32("input", &[1, 3, 32, 32].map(Dim::Fixed));
    g.initializer_f32("b", &[3 * 32 * 32, 2], &b).unwrap();
    g.initializer_f32("c", &[2], &[0.0, 0.0]).unwrap();
    g.node("Flatten", &["input"], &["flat"], vec![attr_int("axis", 1)]);
    g.node("Gemm", &["flat", "b", "c"], &["output"], vec![]);
    g.output_f32("output", &[1, 2].map(Dim::Fixed));
    let model = g.finish("test", "0", &contract.to_metadata()).unwrap();
    let path = dir.join("left_eyed.onnx");
    onnx::write_model(&path, &model).unwrap();
    path
}

#[test]
fn explain_maps_show_a_blind_right_half_as_cold() {
    let dir = tempfile::tempdir().unwrap();
    let model = left_eyed_model(dir.path());
    let data = xy_folder(dir.path());
    let out = dir.path().join("s");
    let run = score(&model, &data, &out, &["--explain", "2"]);
    let (stdout, stderr) = text(&run);
    assert!(run.status.success(), "{stdout}\n{stderr}");
    // Patches of round(32 / 7) = 5 px every 2 px: starts 0, 2, ..., 26 and 27 (flush).
    assert!(
        stdout.contains("explaining the 2 worst frames: 5x5-pixel grey squares every 2 pixels of the 32x32 input, 226 runs of the model per frame"),
        "{stdout}"
    );
    // Every frame is grey 90: (90/255 - 0.485) / 0.229 = -0.57668 in the red plane, the
    // patch's grey (0.5 - 0.485) / 0.229 = 0.06550. A patch in the left half moves x by
    // 25 * 0.64218 / 512 = 0.031356, i.e. 3.512 px of the 224 frame.
    let csv = std::fs::read_to_string(out.join("explain.csv")).unwrap();
    let rows: Vec<Vec<&str>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    assert_eq!(rows.len(), 2, "{csv}");
    for r in &rows {
        let max_shift: f64 = r[3].parse().unwrap();
        let centroid_x: f64 = r[4].parse().unwrap();
        assert!((max_shift - 3.512).abs() < 0.01, "{csv}");
        // All heat lies left of the middle, save what straddling patches carry over it.
        assert!(centroid_x < 0.35, "{csv}");
    }
    let png = image::open(out.join("explain.png")).unwrap().to_rgb8();
    // Two rows of three 160-pixel tiles with 2-pixel gaps.
    assert_eq!(png.dimensions(), (3 * 162 + 2, 2 * 162 + 2));
    // The heat-alone tile of the first row: hot on the left, black on the right.
    let hot = png.get_pixel(2 + 2 * 162 + 20, 2 + 80).0;
    let cold = png.get_pixel(2 + 2 * 162 + 140, 2 + 80).0;
    assert!(hot[0] > 200, "{hot:?}");
    assert_eq!(cold, [0, 0, 0]);
}
