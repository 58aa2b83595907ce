//! The ext2/3/4 superblock of the root partition: is it an ext filesystem, its block size
//! and free space (for the free-space check before anything is written).

use super::ImageError;

/// What the installer needs from the superblock.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Superblock {
    pub block_size: u64,
    pub free_blocks: u64,
    pub free_inodes: u32,
    /// The `extents` feature: ext4 proper (Jetson images), not ext2/ext3.
    pub extents: bool,
}

impl Superblock {
    pub fn free_bytes(&self) -> u64 {
        self.free_blocks * self.block_size
    }
}

/// Parses the 1024-byte superblock found 1024 bytes into the partition.
pub fn parse(sb: &[u8; 1024], path: &str, partition: &str) -> Result<Superblock, ImageError> {
    let u32_at = |at: usize| u32::from_le_bytes([sb[at], sb[at + 1], sb[at + 2], sb[at + 3]]);
    if u16::from_le_bytes([sb[0x38], sb[0x39]]) != 0xEF53 {
        return Err(ImageError::NotExt4 {
            path: path.to_string(),
            partition: partition.to_string(),
        });
    }
    let log = u32_at(0x18);
    if log > 6 {
        return Err(ImageError::NotExt4 {
            path: path.to_string(),
            partition: partition.to_string(),
        });
    }
    let incompat = u32_at(0x60);
    let mut free_blocks = u64::from(u32_at(0x0C));
    if incompat & 0x80 != 0 {
        free_blocks |= u64::from(u32_at(0x158)) << 32;
    }
    Ok(Superblock {
        block_size: 1024 << log,
        free_blocks,
        free_inodes: u32_at(0x10),
        extents: incompat & 0x40 != 0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_block_size_and_free_space() {
        let mut sb = [0u8; 1024];
        sb[0x38..0x3A].copy_from_slice(&0xEF53u16.to_le_bytes());
        sb[0x18] = 2; // 4096-byte blocks
        sb[0x0C..0x10].copy_from_slice(&1000u32.to_le_bytes());
        sb[0x10..0x14].copy_from_slice(&77u32.to_le_bytes());
        sb[0x60] = 0x40 | 0x80;
        sb[0x158] = 1; // 64-bit: 2^32 more blocks
        let s = parse(&sb, "t.img", "1 APP").unwrap();
        assert_eq!(s.block_size, 4096);
        assert_eq!(s.free_blocks, (1 << 32) + 1000);
        assert_eq!(s.free_inodes, 77);
        assert!(s.extents);
    }

    #[test]
    fn anything_else_is_not_ext4() {
        let e = parse(&[0u8; 1024], "t.img", "1 APP")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("t.img") && e.contains("1 APP") && e.contains("ext4"),
            "{e}"
        );
    }
}
