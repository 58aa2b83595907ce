//! `jetpilot model optimize`: ONNX Runtime's optimisations saved once for this machine
//! (`jetpilot::policy::optimize`), checked against the original before the copy is kept.

use std::path::Path;
use std::process::ExitCode;

use jetpilot::policy::ort_policy::OrtOptions;
use jetpilot::policy::{ModelContract, OrtPolicy, Policy};

/// The optimised copy, checked against the original on deterministic inputs before it is
/// kept.
pub fn main(input: &Path, output: &Path) -> anyhow::Result<ExitCode> {
    if input == output {
        anyhow::bail!(
            "--output must differ from the input model ({})",
            input.display()
        );
    }
    let data = jetpilot::policy::optimize::optimize(input, output)?;
    let load = |p: &Path| OrtPolicy::load(p, &OrtOptions::cpu(0, false, &ModelContract::default()));
    let check = (|| -> anyhow::Result<f32> {
        let (mut a, mut b) = (load(input)?, load(output)?);
        let s = a.contract().input_size as usize;
        let mut worst = 0.0f32;
        for k in 0..4u32 {
            let x: Vec<f32> = (0..3 * s * s)
                .map(|i| {
                    ((i as u32).wrapping_mul(2_654_435_761).wrapping_add(k * 97) % 1000) as f32
                        / 250.0
                        - 2.0
                })
                .collect();
            let (u, v) = (a.infer(&x)?, b.infer(&x)?);
            worst = worst.max((u[0] - v[0]).abs()).max((u[1] - v[1]).abs());
        }
        Ok(worst)
    })();
    let remove = || {
        let _ = std::fs::remove_file(output);
        let _ = std::fs::remove_file(&data);
    };
    match check {
        Ok(d) if d <= 1e-3 => {
            let bytes = |p: &Path| std::fs::metadata(p).map(|m| m.len()).unwrap_or(0);
            println!(
                "wrote {} ({:.1} KB) and {} ({:.1} MB): outputs match the original to {d:.1e} on 4 test inputs; it loads only on this machine ({})",
                output.display(),
                bytes(output) as f64 / 1e3,
                data.display(),
                bytes(&data) as f64 / 1e6,
                jetpilot::policy::optimize::optimized_for(output).unwrap_or_default()
            );
            Ok(ExitCode::SUCCESS)
        }
        Ok(d) => {
            remove();
            anyhow::bail!(
                "the optimised model's outputs differ from the original's by {d:.3e} (more than 1e-3): not kept"
            )
        }
        Err(e) => {
            remove();
            Err(e.context("checking the optimised model against the original"))
        }
    }
}
