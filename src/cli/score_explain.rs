//! `score --explain N`: occlusion maps of the N worst-scored frames, through the same
//! preprocessing and session as the score (see `jetpilot::score::explain`), written as
//! `explain.png` (frame, frame under heat, heat) and `explain.csv`, with a line per frame.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;
use jetpilot::policy::{ModelContract, Policy, Preprocessor};
use jetpilot::score::explain::{self, OcclusionMap, Patches};
use jetpilot::score::sheet::Tile;

/// A frame as decoded, and its map.
struct Mapped {
    width: u32,
    height: u32,
    rgb: Vec<u8>,
    map: OcclusionMap,
}

/// One frame to explain.
pub struct Worst<'a> {
    pub path: &'a Path,
    pub label: [f32; 2],
    pub prediction: [f32; 2],
    pub error: f64,
}

/// Maps `frames` (worst first) and writes `out/explain.png` and `out/explain.csv`.
pub fn write(
    policy: &mut dyn Policy,
    contract: &ModelContract,
    frames: &[Worst<'_>],
    patch: Option<usize>,
    out: &Path,
) -> anyhow::Result<()> {
    let size = contract.input_size as usize;
    let patches = match patch {
        Some(p) => Patches::new(size, p),
        None => Patches::default_for(size),
    };
    let cells = patches.starts().len();
    println!(
        "explaining the {} worst frames: {px}x{px}-pixel grey squares every {} pixels of the {size}x{size} input, {} runs of the model per frame",
        frames.len(),
        patches.stride,
        cells * cells + 1,
        px = patches.patch,
    );
    let fill = explain::grey(contract);
    let mut pre = Preprocessor::new(contract);
    let mut maps: Vec<Mapped> = Vec::new();
    let mut csv = String::from(
        "rank,file,error,max_shift,centroid_x,centroid_y,top_third_share,prediction_0,prediction_1\n",
    );
    for (rank, f) in frames.iter().enumerate() {
        let (w, h, rgb) = jetpilot::dataset::load_rgb(f.path)
            .with_context(|| format!("reading {}", f.path.display()))?;
        let input = pre
            .run(w, h, &rgb)
            .with_context(|| format!("preprocessing {}", f.path.display()))?
            .to_vec();
        let map = explain::occlusion(&input, patches, fill, contract.output, |x| policy.infer(x))
            .with_context(|| format!("inference on {}", f.path.display()))?;
        let centre = map.centroid();
        let (cx, cy) = centre.map_or((f32::NAN, f32::NAN), |c| (c[0], c[1]));
        println!(
            "  {:>2}. {}: error {:.3}; a grey square moves the answer up to {:.3}; {}",
            rank + 1,
            f.path.display(),
            f.error,
            map.max_shift(),
            match centre {
                Some(c) => format!(
                    "the heat centres at ({:.0} %, {:.0} %) of the frame, {:.0} % of it in the top third",
                    c[0] * 100.0,
                    c[1] * 100.0,
                    map.top_third_share() * 100.0
                ),
                None => "no square moves it: the answer ignores the frame".into(),
            }
        );
        let _ = writeln!(
            csv,
            "{},{},{:.4},{:.4},{:.4},{:.4},{:.4},{:.5},{:.5}",
            rank + 1,
            f.path.display(),
            f.error,
            map.max_shift(),
            cx,
            cy,
            map.top_third_share(),
            f.prediction[0],
            f.prediction[1]
        );
        maps.push(Mapped {
            width: w,
            height: h,
            rgb,
            map,
        });
    }
    let rows: Vec<(Tile<'_>, &OcclusionMap)> = maps
        .iter()
        .zip(frames)
        .map(|(m, f)| {
            (
                Tile {
                    rgb: &m.rgb,
                    width: m.width,
                    height: m.height,
                    label: f.label,
                    prediction: f.prediction,
                },
                &m.map,
            )
        })
        .collect();
    let png = out.join("explain.png");
    explain::draw(contract.output, &rows, 160)
        .save(&png)
        .with_context(|| format!("writing {}", png.display()))?;
    let csv_path = out.join("explain.csv");
    std::fs::write(&csv_path, csv).with_context(|| format!("writing {}", csv_path.display()))?;
    println!(
        "wrote {} (per row: the frame with label in green and answer in red, the frame under its heat, the heat; each row scaled to its own largest move) and {}",
        png.display(),
        csv_path.display()
    );
    Ok(())
}
