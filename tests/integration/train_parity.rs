//! The trainer's ResNet-18 on burn (Flex CPU backend) against ONNX Runtime on the same ONNX
//! file: our export loaded by `load_onnx`, and burn's weights exported back through the
//! ONNX writer. BatchNorm has random affine parameters and running statistics, so it is
//! not the identity, and burn must use the running statistics as ONNX does.
#![cfg(feature = "train")]

use crate::common;

use burn::module::Module;
use burn::tensor::{Device, Tensor, TensorData};
use jetpilot::policy::onnx::{self, Resnet18Weights};
use jetpilot::policy::{ModelContract, Policy};
use jetpilot::train::{Resnet18, load_onnx};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const SIZE: u32 = 64;
const TOLERANCE: f32 = 1e-4;

fn contract() -> ModelContract {
    ModelContract {
        input_size: SIZE,
        ..ModelContract::default()
    }
}

/// `Resnet18Weights::random(2, 11)` with every BatchNorm's weight, bias, running mean and
/// running variance drawn at random.
fn weights() -> Resnet18Weights {
    let mut w = Resnet18Weights::random(2, 11);
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    for (name, (dims, values)) in w.tensors.iter_mut() {
        // BatchNorm tensors are the 1-d ones outside `fc`.
        if dims.len() != 1 || name.starts_with("fc.") {
            continue;
        }
        let range = if name.ends_with(".weight") {
            0.5..1.5
        } else if name.ends_with(".running_var") {
            0.5..2.0
        } else {
            -0.3..0.3 // bias, running_mean
        };
        for v in values.iter_mut() {
            *v = rng.random_range(range.clone());
        }
    }
    w
}

/// Three NCHW `[1,3,64,64]` inputs, roughly normalised-image values.
fn inputs() -> Vec<Vec<f32>> {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let n = 3 * (SIZE * SIZE) as usize;
    (0..3)
        .map(|_| (0..n).map(|_| rng.random_range(-2.0f32..2.5)).collect())
        .collect()
}

/// burn's outputs for `inputs` as one batch `[3,3,64,64] -> [3,2]`.
fn burn_outputs(model: &Resnet18, inputs: &[Vec<f32>], device: &Device) -> Vec<[f32; 2]> {
    let s = SIZE as usize;
    let flat: Vec<f32> = inputs.concat();
    let x = Tensor::<4>::from_data(TensorData::new(flat, [inputs.len(), 3, s, s]), device);
    let y = model.forward(x).into_data().try_into_vec::<f32>().unwrap();
    y.chunks_exact(2).map(|c| [c[0], c[1]]).collect()
}

fn max_diff(burn: &[[f32; 2]], ort: &[[f32; 2]]) -> f32 {
    burn.iter()
        .zip(ort)
        .flat_map(|(a, b)| [(a[0] - b[0]).abs(), (a[1] - b[1]).abs()])
        .fold(0.0, f32::max)
}

#[test]
fn burn_forward_matches_onnx_runtime() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("parity.onnx");
    let w = weights();
    let model = onnx::resnet18_model(SIZE, &w, &contract(), "test").unwrap();
    onnx::write_model(&path, &model).unwrap();

    let device = Device::flex();
    let (net, c) = load_onnx(&path, &device).unwrap();
    assert_eq!(c, contract());
    assert_eq!(net.to_weights().unwrap(), w);

    let xs = inputs();
    let mut policy = common::load_ort(&path);
    let want: Vec<[f32; 2]> = xs.iter().map(|x| policy.infer(x).unwrap()).collect();
    let got = burn_outputs(&net, &xs, &device);
    let diff = max_diff(&got, &want);
    let scale = want.iter().flatten().fold(0.0f32, |m, v| m.max(v.abs()));
    println!("burn vs ONNX Runtime: max |diff| {diff:e} (max |output| {scale}); ort {want:?}");
    assert!(scale > 1e-3, "outputs are all near zero: {want:?}");
    assert!(diff <= TOLERANCE, "max |burn - ort| = {diff}");

    // Row 0 of a batch does not depend on the others (BN uses running statistics).
    let single = burn_outputs(&net, &xs[..1], &device);
    assert!(max_diff(&single, &got[..1]) <= TOLERANCE);

    // On an autodiff (training) device, BatchNorm uses batch statistics unless the model is
    // put in validation mode with `valid()`; a training forward pass updates the running
    // statistics in place (through `&self`, as PyTorch's train mode does).
    let ad = Device::flex().autodiff();
    let (trainable, _) = load_onnx(&path, &ad).unwrap();
    let eval = trainable.valid();
    let diff = max_diff(&burn_outputs(&eval, &xs, &ad.clone().inner()), &want);
    println!("autodiff device after valid(): max |diff| {diff:e}");
    assert!(diff <= TOLERANCE, "max |burn - ort| after valid() = {diff}");
    let training = burn_outputs(&trainable, &xs, &ad);
    assert!(max_diff(&training, &want) > 1e-2, "{training:?}");
    let after = trainable.to_weights().unwrap();
    assert_ne!(
        after.tensors["bn1.running_mean"], w.tensors["bn1.running_mean"],
        "a training forward pass updates the running statistics"
    );
    assert_eq!(after.tensors["bn1.weight"], w.tensors["bn1.weight"]);
}

#[test]
fn burn_weights_export_back_to_the_same_onnx_outputs() {
    let device = Device::flex();
    let w = weights();
    let net = Resnet18::from_weights(&w, &device).unwrap();
    let exported = net.to_weights().unwrap();
    assert_eq!(exported, w);

    let dir = tempfile::tempdir().unwrap();
    let original = dir.path().join("original.onnx");
    let round_trip = dir.path().join("round_trip.onnx");
    onnx::write_model(
        &original,
        &onnx::resnet18_model(SIZE, &w, &contract(), "test").unwrap(),
    )
    .unwrap();
    onnx::write_model(
        &round_trip,
        &onnx::resnet18_model(SIZE, &exported, &contract(), "test").unwrap(),
    )
    .unwrap();
    let (mut a, mut b) = (common::load_ort(&original), common::load_ort(&round_trip));
    let xs = inputs();
    let got: Vec<[f32; 2]> = xs.iter().map(|x| b.infer(x).unwrap()).collect();
    let want: Vec<[f32; 2]> = xs.iter().map(|x| a.infer(x).unwrap()).collect();
    assert_eq!(got, want);
    let diff = max_diff(&burn_outputs(&net, &xs, &device), &got);
    println!("round trip: burn vs ONNX Runtime max |diff| {diff:e}");
    assert!(diff <= TOLERANCE, "max |burn - ort| = {diff}");
}
