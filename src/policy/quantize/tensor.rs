//! Initializers in and out of the quantizer: float32 tensors read from a model, and the
//! int8 / uint8 / int32 / float32 tensors a QDQ model adds, all little-endian `raw_data`.

use prost::bytes::Bytes;

use super::QuantizeError;
use crate::policy::onnx::graph::element_count;
use crate::policy::onnx::proto::{DATA_LOCATION_EXTERNAL, TensorProto, data_type};

/// The values of a float32 initializer, from `raw_data` or `float_data`.
pub fn read_f32(t: &TensorProto) -> Result<Vec<f32>, QuantizeError> {
    let bad =
        |reason: String| QuantizeError::Unsupported(format!("initializer `{}`: {reason}", t.name));
    if t.data_location == DATA_LOCATION_EXTERNAL || !t.external_data.is_empty() {
        return Err(bad("its data is in an external file".into()));
    }
    if t.data_type != data_type::FLOAT {
        return Err(bad(format!(
            "is {}, not float32",
            data_type::name(t.data_type)
        )));
    }
    let count = usize::try_from(element_count(&t.dims)).unwrap_or(usize::MAX);
    let values: Vec<f32> = if t.raw_data.is_empty() {
        t.float_data.clone()
    } else {
        if t.raw_data.len() != count.saturating_mul(4) {
            return Err(bad(format!(
                "raw_data holds {} bytes, its shape needs {}",
                t.raw_data.len(),
                count.saturating_mul(4)
            )));
        }
        t.raw_data
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect()
    };
    if values.len() != count {
        return Err(bad(format!(
            "holds {} values, its shape needs {count}",
            values.len()
        )));
    }
    Ok(values)
}

fn tensor(name: &str, dims: &[i64], data_type: i32, raw: Vec<u8>) -> TensorProto {
    TensorProto {
        dims: dims.to_vec(),
        data_type,
        name: name.to_string(),
        raw_data: Bytes::from(raw),
        ..Default::default()
    }
}

pub fn f32_tensor(name: &str, dims: &[i64], values: &[f32]) -> TensorProto {
    let raw = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    tensor(name, dims, data_type::FLOAT, raw)
}

pub fn i8_tensor(name: &str, dims: &[i64], values: &[i8]) -> TensorProto {
    let raw = values.iter().map(|v| v.to_le_bytes()[0]).collect();
    tensor(name, dims, data_type::INT8, raw)
}

pub fn u8_tensor(name: &str, dims: &[i64], values: &[u8]) -> TensorProto {
    tensor(name, dims, data_type::UINT8, values.to_vec())
}

pub fn i32_tensor(name: &str, dims: &[i64], values: &[i32]) -> TensorProto {
    let raw = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    tensor(name, dims, data_type::INT32, raw)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn float_tensors_round_trip_and_bad_lengths_are_named() {
        let t = f32_tensor("w", &[2, 2], &[1.0, -2.5, 0.0, 3.25]);
        assert_eq!(read_f32(&t).unwrap(), vec![1.0, -2.5, 0.0, 3.25]);
        let legacy = TensorProto {
            name: "v".into(),
            dims: vec![2],
            data_type: data_type::FLOAT,
            float_data: vec![0.5, 1.5],
            ..Default::default()
        };
        assert_eq!(read_f32(&legacy).unwrap(), vec![0.5, 1.5]);
        let short = f32_tensor("short", &[3], &[1.0, 2.0]);
        let err = read_f32(&short).unwrap_err().to_string();
        assert!(err.contains("`short`") && err.contains("needs 12"), "{err}");
        let int = i8_tensor("q", &[2], &[-127, 5]);
        assert_eq!(&int.raw_data[..], &[0x81, 0x05]);
        let err = read_f32(&int).unwrap_err().to_string();
        assert!(err.contains("`q`") && err.contains("int8"), "{err}");
    }
}
