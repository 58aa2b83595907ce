//! Every integration test of jetpilot, in one test binary: `cargo nextest run` (or
//! `scripts/test.sh`) runs each test in its own process all the same, and one binary is
//! compiled and linked once, where 21 binaries each linked every dependency and
//! instantiated the same generic code again (most of CI's test build).
//!
//! Each module is what was one file under `tests/`; filter by its name, e.g.
//! `scripts/test.sh -E 'test(/^poses::/)'` or `cargo test --test integration poses::`.
//! `common` holds the fixtures they share.

mod common;

mod bench;
mod cli;
mod configs;
mod daemon;
mod dataset;
mod frames_lib;
mod hil_hbridge;
mod hil_motor_hat;
mod hil_oled;
mod image_install;
mod interventions_kill;
mod layouts_ilddpg;
mod lp_ft;
mod model_ensemble;
mod paper_experiment;
mod poses;
mod pretrained;
mod probe;
mod process_faults;
mod providers;
mod quantize;
mod real_replay;
mod score;
mod sim;
mod train_device;
mod train_gradients;
mod train_loop;
mod train_parity;
mod web;
mod web_browser;
mod zero_shot;
