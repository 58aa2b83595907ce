//! `scripts/paper-experiment.sh`'s settings: an `IL_INIT` it does not know is refused before
//! any work (the whole protocol takes hours; its runs are in docs/results/paper-experiment.md
//! and docs/results/pretrained-backbones.md).

use std::path::Path;
use std::process::Command;

#[test]
fn an_unknown_imitation_start_is_refused_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let o = Command::new("bash")
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/paper-experiment.sh"))
        .arg(&out)
        .env("BIN", env!("CARGO_BIN_EXE_jetpilot"))
        .env("IL_INIT", "resnet18")
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains(
            "IL_INIT must be empty (train il from random weights) or imagenet, not 'resnet18'"
        ),
        "{err}"
    );
    assert!(!out.exists(), "wrote {} before refusing", out.display());
}
