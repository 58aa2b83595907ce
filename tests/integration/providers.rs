//! GPU execution providers asked for on a library without them (the CPU wheel's, as on a
//! Jetson Nano): the model loads on the CPU provider, answers as it does there, and no
//! TensorRT cache folder is made.
//!
//! Needs the ONNX Runtime library (scripts/install-onnxruntime.sh).

use crate::common;

use jetpilot::policy::ort_policy::OrtOptions;
use jetpilot::policy::providers::{self, CudaOptions, GpuOptions, TensorrtOptions};
use jetpilot::policy::runtime::Provider;
use jetpilot::policy::{ModelContract, OrtPolicy, Policy};

#[test]
fn gpu_providers_missing_from_the_library_fall_back_to_the_cpu() {
    let dir = tempfile::tempdir().unwrap();
    let model = common::write_model(dir.path(), 32, 1);
    let cache = dir.path().join("trt-cache");
    let mut gpu = OrtPolicy::load(
        &model,
        &OrtOptions {
            library: None,
            providers: &[Provider::Tensorrt, Provider::Cuda, Provider::Cpu],
            gpu: GpuOptions {
                tensorrt: TensorrtOptions {
                    cache_dir: Some(cache.clone()),
                    ..TensorrtOptions::default()
                },
                ..GpuOptions::default()
            },
            intra_threads: 1,
            allow_spinning: false,
            fallback_contract: &ModelContract::default(),
        },
    )
    .expect("load model (is ONNX Runtime installed? scripts/install-onnxruntime.sh)");
    assert_eq!(gpu.provider(), Provider::Cpu);
    assert!(!cache.exists(), "no cache folder without TensorRT");

    let mut cpu = common::load_ort(&model);
    let x: Vec<f32> = (0..3 * 32 * 32)
        .map(|i| (i % 13) as f32 / 6.0 - 1.0)
        .collect();
    assert_eq!(gpu.infer(&x).unwrap(), cpu.infer(&x).unwrap());
}

#[test]
fn the_cpu_library_has_no_gpu_provider_and_makes_no_cache_folder() {
    // The CPU wheel's library (scripts/install-onnxruntime.sh) has neither GPU provider.
    jetpilot::policy::runtime::environment(None)
        .expect("the ONNX Runtime library (scripts/install-onnxruntime.sh)");
    let dir = tempfile::tempdir().unwrap();
    let gpu = GpuOptions {
        tensorrt: TensorrtOptions {
            cache_dir: Some(dir.path().join("trt")),
            ..TensorrtOptions::default()
        },
        cuda: CudaOptions::default(),
    };
    let model = dir.path().join("m.onnx");
    std::fs::write(&model, b"model").unwrap();
    assert!(!providers::dispatch(Provider::Tensorrt, &gpu, &model).0);
    assert!(!providers::dispatch(Provider::Cuda, &gpu, &model).0);
    assert!(providers::dispatch(Provider::Cpu, &gpu, &model).0);
    assert!(!dir.path().join("trt").exists());
}
