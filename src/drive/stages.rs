//! The two blocking stages of the pipeline, each on its own thread:
//!
//! - capture: pulls frames from the [`FrameSource`] into the [`LatestFrame`] slot;
//! - infer: takes the newest frame, preprocesses it, runs the policy, checks the outputs
//!   and applies the steering law, then hands a [`Command`] to the actuator.
//!
//! Any failure becomes a [`StageMsg::Fault`]; the actuator stops the motors on it.

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

use super::DriveError;
use crate::camera::latest::{CloseGuard, SourceEnd, Wait};
use crate::camera::{FrameSource, LatestFrame};
use crate::clock::Clock;
use crate::control::{SteeringGains, SteeringLaw, WheelCommand};
use crate::policy::{Policy, Preprocessor};

/// A wheel command with where it came from and what it cost.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Command {
    pub seq: u64,
    pub captured_at: Duration,
    pub outputs: [f32; 2],
    pub wheels: WheelCommand,
    pub preprocess: Duration,
    pub inference: Duration,
    pub control: Duration,
}

/// What the inference stage sends to the actuator.
#[derive(Debug)]
pub enum StageMsg {
    Command(Command),
    /// The frame source ended normally (a replay without `loop`).
    SourceFinished,
    Fault(DriveError),
}

/// Runs the frame source until it ends, fails, or `cancel` fires.
pub fn capture(
    mut source: Box<dyn FrameSource>,
    slot: Arc<LatestFrame>,
    cancel: CancellationToken,
) {
    let guard = CloseGuard::new(&slot);
    while !cancel.is_cancelled() {
        match source.next_frame() {
            Ok(Some(frame)) => slot.put(frame),
            Ok(None) => {
                slot.close(SourceEnd::Finished);
                break;
            }
            Err(e) => {
                slot.close(SourceEnd::Failed(e.to_string()));
                break;
            }
        }
    }
    guard.disarm();
}

/// What the inference stage needs besides its channels.
pub struct InferParams {
    pub gains: SteeringGains,
    pub max_abs_output: f32,
    pub clock: Arc<dyn Clock>,
}

/// Takes frames from the slot until it closes, `cancel` fires or the actuator is gone.
pub fn infer(
    mut policy: Box<dyn Policy>,
    slot: Arc<LatestFrame>,
    tx: mpsc::Sender<StageMsg>,
    cancel: CancellationToken,
    params: InferParams,
) {
    let contract = policy.contract().clone();
    let mut pre = Preprocessor::new(&contract);
    let mut law = SteeringLaw::new(params.gains, contract.output);
    let mut last_capture: Option<Duration> = None;
    let clock = params.clock;
    let send = |msg| tx.blocking_send(msg).is_ok();
    while !cancel.is_cancelled() {
        let frame = match slot.wait(Duration::from_millis(50)) {
            Wait::Timeout => continue,
            Wait::Closed(SourceEnd::Finished) => {
                send(StageMsg::SourceFinished);
                return;
            }
            Wait::Closed(SourceEnd::Failed(msg)) => {
                send(StageMsg::Fault(DriveError::Camera(msg)));
                return;
            }
            Wait::Frame(f) => f,
        };
        let t0 = clock.now();
        let input = match pre.run(frame.width, frame.height, &frame.rgb) {
            Ok(i) => i,
            Err(e) => {
                send(StageMsg::Fault(DriveError::Preprocess {
                    seq: frame.seq,
                    source: e,
                }));
                return;
            }
        };
        let t1 = clock.now();
        let outputs = match policy.infer(input) {
            Ok(o) => o,
            Err(e) => {
                send(StageMsg::Fault(DriveError::Policy(e)));
                return;
            }
        };
        let t2 = clock.now();
        if outputs
            .iter()
            .any(|v| !v.is_finite() || v.abs() > params.max_abs_output)
        {
            send(StageMsg::Fault(DriveError::BadOutput {
                seq: frame.seq,
                outputs,
                limit: params.max_abs_output,
            }));
            return;
        }
        let dt = last_capture
            .map(|t| frame.captured_at.saturating_sub(t).as_secs_f32())
            .unwrap_or(0.0);
        last_capture = Some(frame.captured_at);
        let wheels = law.step(outputs, dt).wheels;
        let t3 = clock.now();
        let cmd = Command {
            seq: frame.seq,
            captured_at: frame.captured_at,
            outputs,
            wheels,
            preprocess: t1.saturating_sub(t0),
            inference: t2.saturating_sub(t1),
            control: t3.saturating_sub(t2),
        };
        if !send(StageMsg::Command(cmd)) {
            return; // the actuator has finished
        }
    }
}
