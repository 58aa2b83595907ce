//! The disk structures `jetpilot image install` reads from an SD card image: the GPT (header
//! and entries, read through the same callback the installer gives it) and an ext4
//! superblock.
#![no_main]
use jetpilot::image::{ext4, gpt};

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    if data.len() >= 1024 {
        let sb: &[u8; 1024] = data[..1024].try_into().expect("1024 bytes");
        let _ = ext4::parse(sb, "fuzz.img", "APP", 0);
    }
    // The image is the input, repeated to a plausible size so the header checks pass the
    // size test: reads past the input's end see zeros.
    let image_len = (data.len() as u64).max(34 * 512) * 64;
    let _ = gpt::parse("fuzz.img", image_len, |offset, buf| {
        for (i, b) in buf.iter_mut().enumerate() {
            let at = offset as usize + i;
            *b = data.get(at).copied().unwrap_or(0);
        }
        Ok(())
    });
});
