//! The ext2/3/4 superblock of the root partition: is it an ext filesystem, its block size
//! and free space (for the free-space check before anything is written).

use super::ImageError;

/// What the installer needs from the superblock.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Superblock {
    pub block_size: u64,
    /// Free blocks less the blocks reserved for root.
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
/// `offset` is the partition's byte offset, for the repair command in errors.
pub fn parse(
    sb: &[u8; 1024],
    path: &str,
    partition: &str,
    offset: u64,
) -> Result<Superblock, ImageError> {
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
    let wide = incompat & 0x80 != 0;
    let count = |lo: usize, hi: usize| {
        let mut n = u64::from(u32_at(lo));
        if wide {
            n |= u64::from(u32_at(hi)) << 32;
        }
        n
    };
    let (free, reserved) = (count(0x0C, 0x158), count(0x08, 0x154));
    let state = u16::from_le_bytes([sb[0x3A], sb[0x3B]]);
    let unclean = |what: &str| ImageError::Unclean {
        path: path.to_string(),
        partition: partition.to_string(),
        offset,
        what: what.to_string(),
    };
    if incompat & 0x4 != 0 {
        return Err(unclean(
            "its journal needs recovery (it was not unmounted cleanly)",
        ));
    }
    if state & 0x1 == 0 || state & 0x2 != 0 {
        return Err(unclean(
            "it is marked as not cleanly unmounted or as having errors",
        ));
    }
    if incompat & 0x40 == 0 {
        return Err(ImageError::NotExt4 {
            path: path.to_string(),
            partition: partition.to_string(),
        });
    }
    Ok(Superblock {
        block_size: 1024 << log,
        // libext2fs (debugfs) does not keep root's reserve: leave it alone.
        free_blocks: free.saturating_sub(reserved),
        free_inodes: u32_at(0x10),
        extents: true,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_block_size_and_free_space() {
        let mut sb = [0u8; 1024];
        sb[0x38..0x3A].copy_from_slice(&0xEF53u16.to_le_bytes());
        sb[0x3A] = 1; // cleanly unmounted
        sb[0x08..0x0C].copy_from_slice(&100u32.to_le_bytes()); // reserved for root
        sb[0x18] = 2; // 4096-byte blocks
        sb[0x0C..0x10].copy_from_slice(&1000u32.to_le_bytes());
        sb[0x10..0x14].copy_from_slice(&77u32.to_le_bytes());
        sb[0x60] = 0x40 | 0x80;
        sb[0x158] = 1; // 64-bit: 2^32 more blocks
        let s = parse(&sb, "t.img", "1 APP", 512).unwrap();
        assert_eq!(s.block_size, 4096);
        assert_eq!(s.free_blocks, (1 << 32) + 1000 - 100);
        assert_eq!(s.free_inodes, 77);
        assert!(s.extents);
    }

    #[test]
    fn a_filesystem_needing_recovery_or_ext3_is_refused() {
        let mut sb = [0u8; 1024];
        sb[0x38..0x3A].copy_from_slice(&0xEF53u16.to_le_bytes());
        sb[0x3A] = 1;
        sb[0x60] = 0x40 | 0x4;
        let e = parse(&sb, "t.img", "1 APP", 512).unwrap_err().to_string();
        assert!(
            e.contains("journal needs recovery") && e.contains("e2fsck"),
            "{e}"
        );
        sb[0x60] = 0x40;
        sb[0x3A] = 0;
        assert!(parse(&sb, "t.img", "1 APP", 512).is_err());
        sb[0x3A] = 1;
        sb[0x60] = 0; // no extents: ext2/ext3
        assert!(
            parse(&sb, "t.img", "1 APP", 512)
                .unwrap_err()
                .to_string()
                .contains("not an ext4")
        );
    }

    #[test]
    fn anything_else_is_not_ext4() {
        let e = parse(&[0u8; 1024], "t.img", "1 APP", 512)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("t.img") && e.contains("1 APP") && e.contains("ext4"),
            "{e}"
        );
    }
}
