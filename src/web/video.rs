//! Live video: MJPEG (`multipart/x-mixed-replace`).
//!
//! One encoder task turns the newest frame the daemon acted on into a JPEG, at most
//! `web.video_fps` times a second and only while a browser watches, off the async threads
//! (`spawn_blocking`). It puts the JPEG in a `watch` slot; every client's stream waits for
//! that slot to change and sends the newest JPEG, so a client never gets a frame twice and
//! a slow client simply skips frames: there is no queue to grow. The frames it sent are
//! kept a short while for click-to-label ([`super::label`]).

use std::sync::Arc;
use std::time::Duration;

use axum::body::Bytes;
use tokio::sync::watch;
use tokio_util::sync::CancellationToken;

use crate::drive::LiveFrame;
use crate::policy::contract::OutputKind;

/// The multipart boundary.
pub const BOUNDARY: &str = "jetpilotframe";

/// One encoded frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Jpeg {
    pub seq: u64,
    pub bytes: Bytes,
}

/// Encoding settings.
#[derive(Debug, Clone, Copy)]
pub struct VideoParams {
    pub fps: f32,
    pub quality: u8,
    /// Draw the overlay for this model output (`None`: no overlay).
    pub overlay: Option<OutputKind>,
}

/// A frame as JPEG, with the overlay drawn on a copy.
pub fn encode(frame: &LiveFrame, p: &VideoParams) -> Result<Bytes, image::ImageError> {
    let mut rgb = frame.rgb.as_ref().clone();
    if let Some(kind) = p.overlay {
        super::overlay::draw(
            &mut rgb,
            frame.width,
            frame.height,
            kind,
            frame.outputs,
            frame.wheels,
        );
    }
    let mut out = Vec::with_capacity(rgb.len() / 8);
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, p.quality.clamp(1, 100)).encode(
        &rgb,
        frame.width,
        frame.height,
        image::ExtendedColorType::Rgb8,
    )?;
    Ok(Bytes::from(out))
}

/// Runs the encoder until `cancel`: frames from `live`, JPEGs into `out`.
pub async fn encoder(
    mut live: watch::Receiver<Option<LiveFrame>>,
    out: Arc<watch::Sender<Option<Arc<Jpeg>>>>,
    labels: Arc<super::label::Labeller>,
    p: VideoParams,
    cancel: CancellationToken,
) {
    let period = Duration::from_secs_f32(1.0 / p.fps.max(0.1));
    loop {
        tokio::select! {
            _ = cancel.cancelled() => return,
            r = live.changed() => if r.is_err() { return },
        }
        if out.receiver_count() == 0 {
            continue; // nobody watches: no encoding
        }
        let started = tokio::time::Instant::now();
        let Some(frame) = live.borrow_and_update().clone() else {
            continue;
        };
        let seq = frame.seq;
        let kept = frame.clone();
        match tokio::task::spawn_blocking(move || encode(&frame, &p)).await {
            Ok(Ok(bytes)) => {
                // Kept before it is sent: a click on it always finds it.
                labels.recent.push(kept);
                out.send_replace(Some(Arc::new(Jpeg { seq, bytes })));
            }
            Ok(Err(e)) => tracing::warn!(error = %e, seq, "web video: cannot encode a frame"),
            Err(e) => tracing::warn!(error = %e, "web video: the encoder failed"),
        }
        tokio::select! {
            _ = cancel.cancelled() => return,
            _ = tokio::time::sleep_until(started + period) => {}
        }
    }
}

/// One multipart part for `jpeg`.
pub fn part(jpeg: &Jpeg) -> Bytes {
    let head = format!(
        "--{BOUNDARY}\r\nContent-Type: image/jpeg\r\nContent-Length: {}\r\nX-Frame-Seq: {}\r\n\r\n",
        jpeg.bytes.len(),
        jpeg.seq
    );
    let mut v = Vec::with_capacity(head.len() + jpeg.bytes.len() + 2);
    v.extend_from_slice(head.as_bytes());
    v.extend_from_slice(&jpeg.bytes);
    v.extend_from_slice(b"\r\n");
    Bytes::from(v)
}

/// A client's stream: each new JPEG once, the newest first; ends with the encoder.
pub fn stream(
    mut rx: watch::Receiver<Option<Arc<Jpeg>>>,
) -> impl futures_util::Stream<Item = Result<Bytes, std::convert::Infallible>> {
    rx.mark_changed();
    futures_util::stream::unfold(rx, |mut rx| async move {
        loop {
            rx.changed().await.ok()?;
            let jpeg = rx.borrow_and_update().clone();
            if let Some(j) = jpeg {
                return Some((Ok(part(&j)), rx));
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::WheelCommand;
    use futures_util::StreamExt;

    fn frame(seq: u64) -> LiveFrame {
        LiveFrame {
            seq,
            width: 32,
            height: 24,
            rgb: Arc::new(vec![120; 32 * 24 * 3]),
            outputs: [0.0, 0.0],
            wheels: WheelCommand::new(0.2, 0.2),
        }
    }

    #[test]
    fn a_frame_encodes_to_a_jpeg_of_its_size() {
        let p = VideoParams {
            fps: 10.0,
            quality: 70,
            overlay: Some(OutputKind::Xy),
        };
        let bytes = encode(&frame(1), &p).unwrap();
        assert_eq!(&bytes[..2], &[0xFF, 0xD8]);
        let img = image::load_from_memory(&bytes).unwrap();
        assert_eq!((img.width(), img.height()), (32, 24));
        let part = part(&Jpeg {
            seq: 9,
            bytes: bytes.clone(),
        });
        let head = String::from_utf8_lossy(&part[..80]).to_string();
        assert!(
            head.starts_with("--jetpilotframe\r\nContent-Type: image/jpeg\r\nContent-Length: "),
            "{head}"
        );
        assert!(part.ends_with(b"\r\n"));
    }

    #[tokio::test]
    async fn a_slow_client_gets_only_the_newest_frame_never_a_repeat() {
        let (tx, rx) = watch::channel(None);
        let mut s = Box::pin(stream(rx));
        let jpeg = |seq| {
            Some(Arc::new(Jpeg {
                seq,
                bytes: Bytes::from_static(b"x"),
            }))
        };
        // Three frames arrive before the client reads: it gets the last one only.
        for seq in 1..=3 {
            tx.send_replace(jpeg(seq));
        }
        let first = s.next().await.unwrap().unwrap();
        assert!(String::from_utf8_lossy(&first).contains("X-Frame-Seq: 3"));
        // Nothing new: nothing sent.
        let waited = tokio::time::timeout(Duration::from_millis(50), s.next()).await;
        assert!(waited.is_err(), "a frame was sent twice");
        tx.send_replace(jpeg(4));
        let next = s.next().await.unwrap().unwrap();
        assert!(String::from_utf8_lossy(&next).contains("X-Frame-Seq: 4"));
        drop(tx);
        assert!(s.next().await.is_none());
    }
}
