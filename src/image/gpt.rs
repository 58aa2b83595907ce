//! The GUID partition table of a disk image: enough to find the root filesystem's partition
//! by name (`APP` on Jetson SD images) and its byte offset. Pure parsing of the first
//! sectors; 512-byte logical sectors, as on SD cards.

use super::ImageError;

pub const SECTOR: u64 = 512;

/// One used GPT entry.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Partition {
    /// 1-based, as `sgdisk -p` and the kernel number them.
    pub number: u32,
    pub name: String,
    pub first_lba: u64,
    pub last_lba: u64,
}

impl Partition {
    pub fn offset(&self) -> u64 {
        self.first_lba * SECTOR
    }
    pub fn size(&self) -> u64 {
        (self.last_lba + 1 - self.first_lba) * SECTOR
    }
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from(u32_at(b, at)) | (u64::from(u32_at(b, at + 4)) << 32)
}

/// Parses the primary GPT. `head` is the image's first bytes (at least the header sector;
/// the entries are read through `read_at`), `path` is for errors.
pub fn parse(
    path: &str,
    image_len: u64,
    mut read_at: impl FnMut(u64, &mut [u8]) -> std::io::Result<()>,
) -> Result<Vec<Partition>, ImageError> {
    let not_image = |reason: String| ImageError::NotDiskImage {
        path: path.to_string(),
        reason,
    };
    if image_len < 34 * SECTOR {
        return Err(not_image(format!(
            "{image_len} bytes is too small for a partitioned disk image"
        )));
    }
    let mut mbr_hdr = vec![0u8; 2 * SECTOR as usize];
    read_at(0, &mut mbr_hdr).map_err(|e| not_image(e.to_string()))?;
    let hdr = &mbr_hdr[SECTOR as usize..];
    if &hdr[0..8] != b"EFI PART" {
        let mbr = mbr_hdr[510] == 0x55 && mbr_hdr[511] == 0xAA;
        return Err(ImageError::NoGpt {
            path: path.to_string(),
            detail: if mbr {
                "it has an MBR partition table only; Jetson SD images use GPT".into()
            } else {
                "no partition table at all (not an SD card image?)".into()
            },
        });
    }
    let header_size = u32_at(hdr, 12) as usize;
    if !(92..=SECTOR as usize).contains(&header_size) {
        return Err(not_image(format!(
            "GPT header size {header_size} is invalid"
        )));
    }
    let mut check = hdr[..header_size].to_vec();
    check[16..20].fill(0);
    if crc32fast::hash(&check) != u32_at(hdr, 16) {
        return Err(not_image(
            "the primary GPT header's CRC32 does not match (a damaged image?)".into(),
        ));
    }
    let entries_lba = u64_at(hdr, 72);
    let count = u32_at(hdr, 80) as usize;
    let entry_size = u32_at(hdr, 84) as usize;
    if !(128..=4096).contains(&entry_size) || count > 1024 {
        return Err(not_image(format!(
            "GPT entries ({count} of {entry_size} bytes) are invalid"
        )));
    }
    let first_usable = u64_at(hdr, 40);
    let table_at = entries_lba
        .checked_mul(SECTOR)
        .filter(|&at| at.saturating_add((count * entry_size) as u64) <= image_len)
        .ok_or_else(|| {
            not_image(format!(
                "GPT entries at LBA {entries_lba} lie outside the image"
            ))
        })?;
    let mut table = vec![0u8; count * entry_size];
    read_at(table_at, &mut table).map_err(|e| not_image(e.to_string()))?;
    if crc32fast::hash(&table) != u32_at(hdr, 88) {
        return Err(not_image(
            "the GPT partition entries' CRC32 does not match (a damaged image?)".into(),
        ));
    }
    let mut parts = Vec::new();
    for (i, e) in table.chunks(entry_size).enumerate() {
        if e[..16].iter().all(|&b| b == 0) {
            continue;
        }
        let units: Vec<u16> = e[56..128]
            .chunks(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]))
            .take_while(|&u| u != 0)
            .collect();
        let p = Partition {
            number: i as u32 + 1,
            name: String::from_utf16_lossy(&units),
            first_lba: u64_at(e, 32),
            last_lba: u64_at(e, 40),
        };
        let end = p
            .last_lba
            .checked_add(1)
            .and_then(|n| n.checked_mul(SECTOR));
        if p.last_lba < p.first_lba
            || p.first_lba < first_usable
            || end.is_none_or(|end| end > image_len)
        {
            return Err(not_image(format!(
                "partition {} ({}) lies outside the image's usable sectors: a truncated download?",
                p.number, p.name
            )));
        }
        parts.push(p);
    }
    Ok(parts)
}

/// The partition named `name`, or number `number` when given.
pub fn find<'a>(
    path: &str,
    parts: &'a [Partition],
    name: &str,
    number: Option<u32>,
) -> Result<&'a Partition, ImageError> {
    let found = match number {
        Some(n) => parts.iter().find(|p| p.number == n),
        None => parts.iter().find(|p| p.name == name),
    };
    found.ok_or_else(|| ImageError::NoPartition {
        path: path.to_string(),
        wanted: match number {
            Some(n) => format!("number {n}"),
            None => format!("named {name}"),
        },
        found: parts
            .iter()
            .map(|p| format!("{} {}", p.number, p.name))
            .collect::<Vec<_>>()
            .join(", "),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A GPT with the given (name, first, last) entries in a buffer of `sectors` sectors.
    pub(crate) fn image(sectors: u64, parts: &[(&str, u64, u64)]) -> Vec<u8> {
        let mut img = vec![0u8; (sectors * SECTOR) as usize];
        let count = 128usize;
        let mut table = vec![0u8; count * 128];
        for (i, (name, first, last)) in parts.iter().enumerate() {
            let e = &mut table[i * 128..(i + 1) * 128];
            e[0] = 0xAF; // any non-zero type GUID
            e[16] = i as u8 + 1;
            e[32..40].copy_from_slice(&first.to_le_bytes());
            e[40..48].copy_from_slice(&last.to_le_bytes());
            for (j, u) in name.encode_utf16().enumerate() {
                e[56 + 2 * j..58 + 2 * j].copy_from_slice(&u.to_le_bytes());
            }
        }
        let h = &mut img[512..1024];
        h[0..8].copy_from_slice(b"EFI PART");
        h[8..12].copy_from_slice(&0x0001_0000u32.to_le_bytes());
        h[12..16].copy_from_slice(&92u32.to_le_bytes());
        h[40..48].copy_from_slice(&34u64.to_le_bytes());
        h[72..80].copy_from_slice(&2u64.to_le_bytes());
        h[80..84].copy_from_slice(&(count as u32).to_le_bytes());
        h[84..88].copy_from_slice(&128u32.to_le_bytes());
        h[88..92].copy_from_slice(&crc32fast::hash(&table).to_le_bytes());
        let crc = crc32fast::hash(&h[..92]);
        h[16..20].copy_from_slice(&crc.to_le_bytes());
        img[1024..1024 + table.len()].copy_from_slice(&table);
        img
    }

    fn parse_buf(img: &[u8]) -> Result<Vec<Partition>, ImageError> {
        parse("t.img", img.len() as u64, |at, buf| {
            buf.copy_from_slice(&img[at as usize..at as usize + buf.len()]);
            Ok(())
        })
    }

    #[test]
    fn finds_app_by_name_at_the_jetson_offset() {
        let img = image(40_000, &[("APP", 28672, 39_000), ("TBC", 2048, 4095)]);
        let parts = parse_buf(&img).unwrap();
        let app = find("t.img", &parts, "APP", None).unwrap();
        assert_eq!((app.number, app.offset()), (1, 14_680_064));
        assert_eq!(find("t.img", &parts, "APP", Some(2)).unwrap().name, "TBC");
    }

    #[test]
    fn a_missing_partition_lists_what_is_there() {
        let img = image(40_000, &[("TBC", 2048, 4095)]);
        let parts = parse_buf(&img).unwrap();
        let e = find("t.img", &parts, "APP", None).unwrap_err().to_string();
        assert!(e.contains("named APP") && e.contains("1 TBC"), "{e}");
    }

    #[test]
    fn no_gpt_and_damaged_headers_are_named() {
        let mut img = vec![0u8; 40 * 512];
        img[510] = 0x55;
        img[511] = 0xAA;
        let e = parse_buf(&img).unwrap_err().to_string();
        assert!(e.contains("MBR partition table only"), "{e}");
        let mut img = image(40_000, &[("APP", 28672, 39_000)]);
        img[512 + 40] ^= 1;
        assert!(parse_buf(&img).unwrap_err().to_string().contains("CRC32"));
        let img = image(30_000, &[("APP", 28672, 39_000)]);
        assert!(
            parse_buf(&img)
                .unwrap_err()
                .to_string()
                .contains("truncated")
        );
    }
}
