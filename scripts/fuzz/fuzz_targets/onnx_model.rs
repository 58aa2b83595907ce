//! ONNX model bytes as `jetpilot model info` and the daemon's model check read them: the
//! protobuf decode, the graph summary and the model contract in its metadata.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let bytes = bytes::Bytes::copy_from_slice(data);
    if let Ok(summary) = jetpilot::policy::onnx::inspect_bytes(bytes, "fuzz.onnx") {
        let _ = summary.contract();
        for t in summary.inputs.iter().chain(&summary.outputs) {
            let _ = t.shape_string();
        }
    }
});
