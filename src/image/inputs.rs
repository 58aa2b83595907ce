//! Checks on the installer's input files before anything is written: compressed images,
//! the architecture of the binary and the ONNX Runtime library (ELF headers).

use std::io::Read;
use std::path::Path;

use super::ImageError;

/// The compression a file's first bytes show, with what to do about it.
pub fn compression(head: &[u8]) -> Option<(&'static str, &'static str)> {
    if head.starts_with(b"PK\x03\x04") {
        Some(("zip", "unzip it first: `unzip FILE`"))
    } else if head.starts_with(b"\xFD7zXZ\x00") {
        Some(("xz", "decompress it first: `xz -dk FILE`"))
    } else if head.starts_with(b"\x1F\x8B") {
        Some(("gzip", "decompress it first: `gunzip -k FILE`"))
    } else if head.starts_with(b"\x28\xB5\x2F\xFD") {
        Some(("zstd", "decompress it first: `zstd -d FILE`"))
    } else {
        None
    }
}

/// The machine an ELF file is built for (`e_machine`), by name.
pub fn elf_machine(head: &[u8]) -> Option<&'static str> {
    if head.len() < 20 || !head.starts_with(b"\x7FELF") {
        return None;
    }
    let little = head[5] == 1;
    let m = if little {
        u16::from_le_bytes([head[18], head[19]])
    } else {
        u16::from_be_bytes([head[18], head[19]])
    };
    Some(match (head[4], m) {
        (2, 0xB7) => "aarch64",
        (2, 0x3E) => "x86-64",
        (1, 0x28) => "32-bit ARM",
        (1, 0x03) => "x86",
        (2, 0xF3) => "64-bit RISC-V",
        _ => "another machine",
    })
}

/// The first `n` bytes of `path` (fewer if it is shorter).
pub fn head(path: &Path, n: usize) -> Result<Vec<u8>, ImageError> {
    let mut buf = Vec::with_capacity(n);
    std::fs::File::open(path)
        .and_then(|f| f.take(n as u64).read_to_end(&mut buf))
        .map_err(|e| ImageError::Input {
            path: path.display().to_string(),
            reason: e.to_string(),
        })?;
    Ok(buf)
}

/// Refuses a file that is not an aarch64 ELF, naming what it is. `what` says which input.
pub fn require_aarch64(path: &Path, what: &str, hint: &str) -> Result<(), ImageError> {
    let found = match elf_machine(&head(path, 64)?) {
        Some("aarch64") => return Ok(()),
        Some(m) => format!("an {m} ELF file"),
        None => "not an ELF file".to_string(),
    };
    Err(ImageError::WrongArch {
        path: path.display().to_string(),
        what: what.to_string(),
        found,
        hint: hint.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compressed_images_are_recognised() {
        assert_eq!(compression(b"\xFD7zXZ\x00\x00").unwrap().0, "xz");
        assert_eq!(compression(b"PK\x03\x04....").unwrap().0, "zip");
        assert_eq!(compression(b"\x1F\x8B\x08").unwrap().0, "gzip");
        assert!(compression(&[0u8; 16]).is_none());
    }

    #[test]
    fn elf_machines() {
        let mut h = [0u8; 64];
        h[..4].copy_from_slice(b"\x7FELF");
        h[4] = 2;
        h[5] = 1;
        h[18] = 0xB7;
        assert_eq!(elf_machine(&h), Some("aarch64"));
        h[18] = 0x3E;
        assert_eq!(elf_machine(&h), Some("x86-64"));
        assert_eq!(elf_machine(b"#!/bin/sh\n"), None);
    }
}
