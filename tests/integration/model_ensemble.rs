//! `jetpilot model ensemble` end to end: two random ResNet-18s become one file that ONNX
//! Runtime runs, and its answer is the mean of theirs on the same input; a model of another
//! input size is refused with both files named; an ensemble is no start for training.
//!
//! Needs the ONNX Runtime library (scripts/install-onnxruntime.sh).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use jetpilot::policy::onnx::{self, Dim, GraphBuilder};
use jetpilot::policy::{ModelContract, Policy};

use crate::common::{load_ort, log_of, write_model};

fn ensemble(models: &[&Path], out: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_jetpilot"))
        .args(["model", "ensemble"])
        .args(models)
        .arg("-o")
        .arg(out)
        .output()
        .unwrap()
}

#[test]
fn an_ensemble_answers_the_mean_of_its_models() {
    let dir = tempfile::tempdir().unwrap();
    let a = write_model(dir.path(), 32, 1);
    let b = write_model(dir.path(), 32, 2);
    let c = write_model(dir.path(), 32, 3);
    let e = dir.path().join("ensemble.onnx");
    let o = ensemble(&[&a, &b, &c], &e);
    let log = log_of(&o);
    assert!(o.status.success(), "{log}");
    assert!(log.contains("the mean output of 3 models"), "{log}");

    // One input, a ramp over the three planes, through each model and the ensemble.
    let input: Vec<f32> = (0..3 * 32 * 32)
        .map(|i| (i % 97) as f32 / 48.0 - 1.0)
        .collect();
    let answers: Vec<[f32; 2]> = [&a, &b, &c]
        .iter()
        .map(|m| load_ort(m).infer(&input).unwrap())
        .collect();
    let mut ens = load_ort(&e);
    assert_eq!(ens.contract().input_size, 32);
    let got = ens.infer(&input).unwrap();
    for k in 0..2 {
        let mean = answers.iter().map(|a| a[k]).sum::<f32>() / 3.0;
        assert!(
            (got[k] - mean).abs() <= 1e-5 * (1.0 + mean.abs()),
            "output {k}: ensemble {} against the mean {mean} of {answers:?}",
            got[k]
        );
    }
    // The members differ, so the mean is not any one of them.
    assert!(answers[0] != answers[1], "{answers:?}");

    let o = Command::new(env!("CARGO_BIN_EXE_jetpilot"))
        .args(["model", "info"])
        .arg(&e)
        .output()
        .unwrap();
    let info = log_of(&o);
    assert!(
        info.contains(&format!(
            "ensemble   mean of 3 models: {}, {}, {}",
            a.display(),
            b.display(),
            c.display()
        )),
        "{info}"
    );

    // An ensemble holds several networks' weights: no start for `train il --init`.
    let err = onnx::read_net_weights(&e).unwrap_err().to_string();
    assert!(
        err.contains("it is an ensemble") && err.contains("mean of 3 models"),
        "{err}"
    );
}

/// A one-node model (its output is its input's mean) with the contract of `size`.
fn tiny(dir: &Path, size: u32) -> PathBuf {
    let mut g = GraphBuilder::new("tiny");
    let s = i64::from(size);
    g.input_f32(
        "input",
        &[Dim::Fixed(1), Dim::Fixed(3), Dim::Fixed(s), Dim::Fixed(s)],
    );
    g.node("ReduceMean", &["input"], &["output"], vec![]);
    g.output_f32(
        "output",
        &[Dim::Fixed(1), Dim::Fixed(1), Dim::Fixed(1), Dim::Fixed(1)],
    );
    let contract = ModelContract {
        input_size: size,
        ..ModelContract::default()
    };
    let path = dir.join(format!("tiny_{size}.onnx"));
    onnx::write_model(
        &path,
        &g.finish("test", "0", &contract.to_metadata()).unwrap(),
    )
    .unwrap();
    path
}

#[test]
fn a_model_of_another_input_size_is_refused_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let a = tiny(dir.path(), 32);
    let b = tiny(dir.path(), 64);
    let e = dir.path().join("ensemble.onnx");
    let o = ensemble(&[&a, &b], &e);
    let log = log_of(&o);
    assert!(!o.status.success(), "{log}");
    assert!(
        log.contains(&format!(
            "{} cannot join an ensemble with {}: its contract is",
            b.display(),
            a.display()
        )),
        "{log}"
    );
    assert!(!e.exists());

    // One model is not an ensemble: clap asks for two.
    let o = ensemble(&[&a], &e);
    assert!(!o.status.success());
    assert!(!e.exists());
}
