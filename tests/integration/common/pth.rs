//! A PyTorch state dict file as `torch.save(model.state_dict(), f)` writes it (the ZIP
//! container, pickle protocol 2, one storage entry per tensor), for tests that need a
//! `.pth` of a shape no registry ships: a torchvision-layout ResNet-18, a dict with a tensor
//! missing, an int64 `num_batches_tracked`. Test support only; the project reads these files
//! with burn's `pytorch-reader`.

use std::io::Write;
use std::path::Path;

/// One tensor's values.
pub enum Values {
    F32(Vec<f32>),
    I64(Vec<i64>),
    /// This many f32 elements declared in the pickle, with no bytes stored behind them.
    Declared(usize),
}

/// Writes `tensors` (name, shape, values) to `path` under the archive root `archive/`.
pub fn write_state_dict(path: &Path, tensors: &[(String, Vec<i64>, Values)]) {
    let mut pkl = vec![0x80, 2]; // PROTO 2
    global(&mut pkl, "collections", "OrderedDict");
    pkl.extend_from_slice(b")R("); // EMPTY_TUPLE, REDUCE, MARK
    for (i, (name, shape, values)) in tensors.iter().enumerate() {
        let (storage, numel) = match values {
            Values::F32(v) => ("FloatStorage", v.len()),
            Values::I64(v) => ("LongStorage", v.len()),
            Values::Declared(n) => ("FloatStorage", *n),
        };
        unicode(&mut pkl, name);
        global(&mut pkl, "torch._utils", "_rebuild_tensor_v2");
        pkl.extend_from_slice(b"(("); // args tuple, persistent id tuple
        unicode(&mut pkl, "storage");
        global(&mut pkl, "torch", storage);
        unicode(&mut pkl, &i.to_string());
        unicode(&mut pkl, "cpu");
        int(&mut pkl, numel as i64);
        pkl.extend_from_slice(b"tQ"); // TUPLE, BINPERSID
        int(&mut pkl, 0); // storage offset
        pkl.push(b'(');
        for &d in shape {
            int(&mut pkl, d);
        }
        pkl.push(b't');
        pkl.push(b'(');
        let mut stride = vec![1i64; shape.len()];
        for k in (0..shape.len().saturating_sub(1)).rev() {
            stride[k] = stride[k + 1] * shape[k + 1];
        }
        for s in stride {
            int(&mut pkl, s);
        }
        pkl.push(b't');
        pkl.push(0x89); // NEWFALSE: requires_grad
        global(&mut pkl, "collections", "OrderedDict");
        pkl.extend_from_slice(b")R"); // backward hooks
        pkl.extend_from_slice(b"tR"); // TUPLE, REDUCE
    }
    pkl.extend_from_slice(b"u."); // SETITEMS, STOP

    let file = std::fs::File::create(path).unwrap();
    let mut zip = zip::ZipWriter::new(file);
    let stored =
        zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    zip.start_file("archive/data.pkl", stored).unwrap();
    zip.write_all(&pkl).unwrap();
    zip.start_file("archive/byteorder", stored).unwrap();
    zip.write_all(b"little").unwrap();
    for (i, (_, _, values)) in tensors.iter().enumerate() {
        zip.start_file(format!("archive/data/{i}"), stored).unwrap();
        let bytes: Vec<u8> = match values {
            Values::F32(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Values::I64(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Values::Declared(_) => Vec::new(),
        };
        zip.write_all(&bytes).unwrap();
    }
    zip.start_file("archive/version", stored).unwrap();
    zip.write_all(b"3\n").unwrap();
    zip.finish().unwrap();
}

/// A ZIP checkpoint whose `data.pkl` is `pkl` as given (stored, root `archive/`).
pub fn write_pickle_zip(path: &Path, pkl: &[u8]) {
    let mut zip = zip::ZipWriter::new(std::fs::File::create(path).unwrap());
    let stored =
        zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    zip.start_file("archive/data.pkl", stored).unwrap();
    zip.write_all(pkl).unwrap();
    zip.start_file("archive/version", stored).unwrap();
    zip.write_all(b"3\n").unwrap();
    zip.finish().unwrap();
}

fn global(out: &mut Vec<u8>, module: &str, name: &str) {
    out.push(b'c');
    out.extend_from_slice(module.as_bytes());
    out.push(b'\n');
    out.extend_from_slice(name.as_bytes());
    out.push(b'\n');
}

fn unicode(out: &mut Vec<u8>, s: &str) {
    out.push(b'X'); // BINUNICODE
    out.extend_from_slice(&(s.len() as u32).to_le_bytes());
    out.extend_from_slice(s.as_bytes());
}

fn int(out: &mut Vec<u8>, v: i64) {
    out.push(b'J'); // BININT (i32)
    out.extend_from_slice(&(v as i32).to_le_bytes());
}
