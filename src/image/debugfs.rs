//! e2fsprogs as the installer's hands: `debugfs` reads and writes the ext4 filesystem inside
//! the image file at a byte offset (`image?offset=N`, no loop mount, no root), `e2fsck -fn`
//! checks it, and `e2undo` with debugfs's undo file takes a failed write back.
//!
//! debugfs exits 0 whatever its commands do, so its standard error is the verdict: any
//! line but its version banner is a failed command.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use super::ImageError;

/// Where e2fsprogs lives on Debian and Ubuntu (often not on a user's PATH).
fn tool(name: &str) -> Result<PathBuf, ImageError> {
    for dir in ["/usr/sbin", "/sbin", "/usr/bin", "/bin"] {
        let p = Path::new(dir).join(name);
        if p.is_file() {
            return Ok(p);
        }
    }
    Err(ImageError::Tool {
        tool: name.to_string(),
        reason: "not found: install e2fsprogs (`sudo apt install e2fsprogs`)".into(),
    })
}

/// One entry of `ls -p`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Entry {
    pub name: String,
    pub mode: u32,
    pub uid: u32,
    pub gid: u32,
    pub size: u64,
}

impl Entry {
    pub fn is_dir(&self) -> bool {
        self.mode & 0o170000 == 0o040000
    }
}

/// The ext filesystem at `offset` bytes into `image`.
#[derive(Debug, Clone)]
pub struct Fs {
    pub image: PathBuf,
    pub offset: u64,
}

impl Fs {
    fn spec(&self) -> String {
        format!("{}?offset={}", self.image.display(), self.offset)
    }

    /// Runs `commands` through `debugfs -f`; with `undo`, writable and recording an undo
    /// file there. Returns standard output; a command's error is an `Err` listing them all.
    pub fn run(&self, commands: &[String], undo: Option<&Path>) -> Result<String, ImageError> {
        let dir = tempfile::tempdir().map_err(|e| ImageError::Tool {
            tool: "debugfs".into(),
            reason: format!("temporary folder: {e}"),
        })?;
        let script = dir.path().join("commands");
        std::fs::write(&script, commands.join("\n") + "\n").map_err(|e| ImageError::Tool {
            tool: "debugfs".into(),
            reason: format!("{}: {e}", script.display()),
        })?;
        let mut cmd = Command::new(tool("debugfs")?);
        if let Some(u) = undo {
            cmd.arg("-w").arg("-z").arg(u);
        }
        let out = cmd
            .arg("-f")
            .arg(&script)
            .arg(self.spec())
            .output()
            .map_err(|e| ImageError::Tool {
                tool: "debugfs".into(),
                reason: e.to_string(),
            })?;
        let stderr = String::from_utf8_lossy(&out.stderr);
        let errors: Vec<&str> = stderr
            .lines()
            .filter(|l| !l.trim().is_empty() && !l.starts_with("debugfs "))
            .collect();
        if !out.status.success() || !errors.is_empty() {
            return Err(ImageError::Tool {
                tool: "debugfs".into(),
                reason: if errors.is_empty() {
                    format!("exited with {}", out.status)
                } else {
                    errors.join("; ")
                },
            });
        }
        Ok(String::from_utf8_lossy(&out.stdout).into_owned())
    }

    /// The entries of each directory in `dirs` (absolute paths); `None` for one that does
    /// not exist. Read-only.
    pub fn list(
        &self,
        dirs: &[String],
    ) -> Result<BTreeMap<String, Option<Vec<Entry>>>, ImageError> {
        // Missing folders are errors on debugfs's standard error; list each parent that
        // exists by walking down from the root, one debugfs run per depth.
        let mut result: BTreeMap<String, Option<Vec<Entry>>> = BTreeMap::new();
        let mut by_depth: BTreeMap<usize, Vec<&String>> = BTreeMap::new();
        for d in dirs {
            by_depth.entry(d.matches('/').count()).or_default().push(d);
        }
        for (_, level) in by_depth {
            let mut ask = Vec::new();
            for d in level {
                let exists = d == "/" || {
                    let (parent, name) = split(d);
                    match result.get(parent) {
                        Some(Some(entries)) => entries.iter().any(|e| e.name == name && e.is_dir()),
                        Some(None) => false,
                        // Not asked for: ask debugfs itself.
                        None => true,
                    }
                };
                if exists {
                    ask.push(d.clone());
                } else {
                    result.insert(d.clone(), None);
                }
            }
            if ask.is_empty() {
                continue;
            }
            let cmds: Vec<String> = ask.iter().map(|d| format!("ls -p \"{d}\"")).collect();
            let out = self.run(&cmds, None)?;
            for (d, section) in ask.iter().zip(sections(&out)) {
                result.insert(d.clone(), Some(parse_ls(&section)));
            }
        }
        Ok(result)
    }

    /// Copies `path` out of the filesystem into `to`.
    pub fn dump(&self, path: &str, to: &Path) -> Result<(), ImageError> {
        self.run(&[format!("dump \"{path}\" \"{}\"", to.display())], None)
            .map(|_| ())
    }

    /// `e2fsck -fn`: a full read-only check. `Err` with its report when not clean.
    pub fn fsck(&self) -> Result<(), ImageError> {
        let out = Command::new(tool("e2fsck")?)
            .arg("-fn")
            .arg(self.spec())
            .output()
            .map_err(|e| ImageError::Tool {
                tool: "e2fsck".into(),
                reason: e.to_string(),
            })?;
        if out.status.success() {
            return Ok(());
        }
        Err(ImageError::Tool {
            tool: "e2fsck -fn".into(),
            reason: format!(
                "{}{}",
                String::from_utf8_lossy(&out.stdout),
                String::from_utf8_lossy(&out.stderr)
            ),
        })
    }

    /// Takes back what a debugfs run recorded in `undo`.
    pub fn undo(&self, undo: &Path) -> Result<(), ImageError> {
        let out = Command::new(tool("e2undo")?)
            .arg("-o")
            .arg(self.offset.to_string())
            .arg(undo)
            .arg(&self.image)
            .output()
            .map_err(|e| ImageError::Tool {
                tool: "e2undo".into(),
                reason: e.to_string(),
            })?;
        if out.status.success() {
            Ok(())
        } else {
            Err(ImageError::Tool {
                tool: "e2undo".into(),
                reason: String::from_utf8_lossy(&out.stderr).into_owned(),
            })
        }
    }
}

/// What `list` says is at `path`, if anything.
pub fn lookup<'a>(
    listing: &'a BTreeMap<String, Option<Vec<Entry>>>,
    path: &str,
) -> Option<&'a Entry> {
    let (parent, name) = split(path);
    listing
        .get(parent)
        .and_then(|e| e.as_ref())
        .and_then(|es| es.iter().find(|e| e.name == name))
}

/// (parent, name) of an absolute path.
pub fn split(path: &str) -> (&str, &str) {
    match path.rfind('/') {
        Some(0) => ("/", &path[1..]),
        Some(i) => (&path[..i], &path[i + 1..]),
        None => ("/", path),
    }
}

/// debugfs echoes each command as `debugfs: CMD`; the output of each follows it.
fn sections(out: &str) -> Vec<String> {
    let mut all = Vec::new();
    for line in out.lines() {
        if line.starts_with("debugfs: ") {
            all.push(String::new());
        } else if let Some(s) = all.last_mut() {
            s.push_str(line);
            s.push('\n');
        }
    }
    all
}

/// `ls -p` lines: `/inode/mode/uid/gid/name/size/`.
fn parse_ls(section: &str) -> Vec<Entry> {
    section
        .lines()
        .filter_map(|l| {
            let f: Vec<&str> = l.split('/').collect();
            if f.len() < 7 || f[5] == "." || f[5] == ".." {
                return None;
            }
            Some(Entry {
                name: f[5].to_string(),
                mode: u32::from_str_radix(f[2], 8).ok()?,
                uid: f[3].parse().ok()?,
                gid: f[4].parse().ok()?,
                size: f[6].parse().unwrap_or(0),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ls_output_is_parsed_without_dot_entries() {
        let out = "debugfs: ls -p /etc\n/12/040755/0/0/.//\n/2/040755/0/0/..//\n\
                   /13/100644/0/0/hostname/3/\n/19/120777/0/0/l/29/\n\ndebugfs: ls -p /x\n";
        let s = sections(out);
        assert_eq!(s.len(), 2);
        let e = parse_ls(&s[0]);
        assert_eq!(e.len(), 2);
        assert_eq!(
            e[0],
            Entry {
                name: "hostname".into(),
                mode: 0o100644,
                uid: 0,
                gid: 0,
                size: 3
            }
        );
        assert!(parse_ls(&s[1]).is_empty());
    }

    #[test]
    fn split_paths() {
        assert_eq!(split("/etc"), ("/", "etc"));
        assert_eq!(split("/etc/jetpilot/a.toml"), ("/etc/jetpilot", "a.toml"));
    }
}
