//! `jetpilot image install` on generated SD card images: a GPT disk with small dummy
//! partitions and an ext4 `APP` partition at sector 28672 (where Jetson SD images put it),
//! built with sgdisk and `mkfs.ext4 -E offset=... -d` under fakeroot. The install is read
//! back with debugfs (files byte for byte, modes, owners, the enable symlinks) and checked
//! with `e2fsck -fn`; every bad input is refused with the image unchanged; a failure after
//! the write is undone byte for byte.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Command;

use jetpilot::image::plan::KITS;
use jetpilot::image::{InstallOptions, install};

const APP_SECTOR: u64 = 28672;
const OFFSET: u64 = APP_SECTOR * 512;

fn run(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap_or_else(|e| panic!("{cmd:?}: {e}"));
    assert!(
        out.status.success(),
        "{cmd:?}: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn sbin(tool: &str) -> PathBuf {
    ["/usr/sbin", "/sbin", "/usr/bin", "/bin"]
        .iter()
        .map(|d| Path::new(d).join(tool))
        .find(|p| p.is_file())
        .unwrap_or_else(|| panic!("{tool} not installed (scripts/install-build-deps.sh)"))
}

/// A GPT image of `mib` MiB: TBC and RP1 dummy partitions, then APP (`app_name`) from sector
/// 28672 on, `app_mib` MiB of ext4 (or nothing, with `ext4 = false`) holding a small root
/// tree owned by root: /etc/hostname, /usr/bin, /lib/systemd/system, an old
/// /usr/bin/jetpilot to be replaced.
fn make_image(dir: &Path, app_name: &str, app_mib: u64, ext4: bool) -> PathBuf {
    let img = dir.join("jetbot.img");
    let total = APP_SECTOR * 512 + (app_mib + 1) * 1048576;
    std::fs::File::create(&img).unwrap().set_len(total).unwrap();
    let last = APP_SECTOR + app_mib * 2048 - 1;
    run(Command::new(sbin("sgdisk"))
        .args([
            "-o",
            "-n",
            "2:2048:+1M",
            "-c",
            "2:TBC",
            "-n",
            "3:4096:+1M",
            "-c",
            "3:RP1",
        ])
        .arg("-n")
        .arg(format!("1:{APP_SECTOR}:{last}"))
        .arg("-c")
        .arg(format!("1:{app_name}"))
        .arg(&img));
    if ext4 {
        let root = dir.join("rootfs");
        for d in [
            "etc/systemd/system",
            "usr/bin",
            "lib/systemd/system",
            "var/lib",
        ] {
            std::fs::create_dir_all(root.join(d)).unwrap();
        }
        std::fs::write(root.join("etc/hostname"), "jetbot\n").unwrap();
        std::fs::write(root.join("usr/bin/jetpilot"), "an old version").unwrap();
        run(Command::new("fakeroot")
            .arg(sbin("mkfs.ext4"))
            .args(["-q", "-F", "-b", "4096"])
            .arg("-E")
            .arg(format!("offset={OFFSET}"))
            .arg("-d")
            .arg(&root)
            .arg(&img)
            .arg(format!("{}M", app_mib)));
    }
    img
}

/// A file that passes for an aarch64 ELF (the header is what the installer checks).
fn fake_elf(path: &Path, machine: u16, body: &str) -> PathBuf {
    let mut b = vec![0u8; 64];
    b[..4].copy_from_slice(b"\x7FELF");
    b[4] = 2;
    b[5] = 1;
    b[18..20].copy_from_slice(&machine.to_le_bytes());
    b.extend_from_slice(body.as_bytes());
    std::fs::write(path, b).unwrap();
    path.to_path_buf()
}

struct Inputs {
    _dir: tempfile::TempDir,
    opts: InstallOptions,
}

fn inputs(app_mib: u64) -> Inputs {
    let dir = tempfile::tempdir().unwrap();
    let image = make_image(dir.path(), "APP", app_mib, true);
    let model = common::write_model(dir.path(), 32, 7);
    let opts = InstallOptions {
        image,
        partition: None,
        binary: fake_elf(&dir.path().join("jetpilot"), 0xB7, "the new jetpilot"),
        onnxruntime: fake_elf(&dir.path().join("libonnxruntime.so.1.23.2"), 0xB7, "ort"),
        model,
        config: ("config/jetbot.toml".into(), KITS[0].1.to_string()),
        wifi: Some(("robots".into(), "secret123".into())),
        dry_run: false,
        fail_after_write: false,
    };
    Inputs { _dir: dir, opts }
}

fn debugfs(img: &Path, cmd: &str) -> String {
    let out = Command::new(sbin("debugfs"))
        .arg("-R")
        .arg(cmd)
        .arg(format!("{}?offset={OFFSET}", img.display()))
        .output()
        .unwrap();
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// (mode, uid, gid) from `stat`.
fn stat(img: &Path, path: &str) -> (String, String, String) {
    let s = debugfs(img, &format!("stat \"{path}\""));
    let field = |key: &str| {
        s.split(key)
            .nth(1)
            .and_then(|r| r.split_whitespace().next())
            .unwrap_or_else(|| panic!("{path}: no {key} in {s}"))
            .to_string()
    };
    (field("Mode:"), field("User:"), field("Group:"))
}

fn dump(img: &Path, path: &str, dir: &Path) -> Vec<u8> {
    let to = dir.join("dumped");
    let _ = std::fs::remove_file(&to);
    debugfs(img, &format!("dump \"{path}\" \"{}\"", to.display()));
    std::fs::read(&to).unwrap_or_else(|e| panic!("{path}: {e}"))
}

fn fsck_clean(img: &Path) {
    run(Command::new(sbin("e2fsck"))
        .arg("-fn")
        .arg(format!("{}?offset={OFFSET}", img.display())));
}

#[test]
fn installs_into_a_generated_jetson_image_and_twice_is_the_same() {
    let i = inputs(96);
    let img = &i.opts.image;
    let dir = i._dir.path();
    let report = install(&i.opts).unwrap();
    assert_eq!(
        (report.partition.as_str(), report.offset),
        ("1 (APP)", OFFSET)
    );
    assert!(report.actions.contains(&"mkdir /etc/jetpilot".to_string()));
    assert!(
        report
            .actions
            .iter()
            .any(|a| a.starts_with("replace /usr/bin/jetpilot (0755"))
    );
    fsck_clean(img);

    let check = |img: &Path| {
        for (path, src, mode) in [
            (
                "/usr/bin/jetpilot",
                std::fs::read(&i.opts.binary).unwrap(),
                "0755",
            ),
            (
                "/usr/lib/jetpilot/libonnxruntime.so.1.23.2",
                std::fs::read(&i.opts.onnxruntime).unwrap(),
                "0644",
            ),
            (
                "/var/lib/jetpilot/model.onnx",
                std::fs::read(&i.opts.model).unwrap(),
                "0644",
            ),
            (
                "/etc/jetpilot/jetpilot.toml",
                KITS[0].1.as_bytes().to_vec(),
                "0644",
            ),
            (
                "/etc/jetpilot/l298n-nano.toml",
                KITS[3].1.as_bytes().to_vec(),
                "0644",
            ),
            (
                "/lib/systemd/system/jetpilot.service",
                std::fs::read("systemd/jetpilot.service").unwrap(),
                "0644",
            ),
            (
                "/usr/lib/sysusers.d/jetpilot.conf",
                std::fs::read("systemd/jetpilot.sysusers.conf").unwrap(),
                "0644",
            ),
            (
                "/usr/lib/tmpfiles.d/jetpilot.conf",
                std::fs::read("systemd/jetpilot.tmpfiles.conf").unwrap(),
                "0644",
            ),
            (
                "/lib/udev/rules.d/99-jetpilot.rules",
                std::fs::read("systemd/99-jetpilot.rules").unwrap(),
                "0644",
            ),
            (
                "/etc/systemd/system/jetpilot.service.d/csi-camera.conf",
                std::fs::read("systemd/csi-camera.conf").unwrap(),
                "0644",
            ),
        ] {
            assert_eq!(dump(img, path, dir), src, "{path}: contents");
            assert_eq!(
                stat(img, path),
                (mode.into(), "0".into(), "0".into()),
                "{path}"
            );
        }
        let wifi = "/etc/NetworkManager/system-connections/jetpilot-wifi.nmconnection";
        assert_eq!(stat(img, wifi).0, "0600");
        let keyfile = String::from_utf8(dump(img, wifi, dir)).unwrap();
        assert!(keyfile.contains("ssid=robots\n") && keyfile.contains("psk=secret123\n"));
        let link = debugfs(
            img,
            "stat /etc/systemd/system/multi-user.target.wants/jetpilot.service",
        );
        assert!(
            link.contains("Type: symlink") && link.contains("/lib/systemd/system/jetpilot.service"),
            "{link}"
        );
        let first = debugfs(
            img,
            "stat /etc/systemd/system/sysinit.target.wants/jetpilot-firstboot.service",
        );
        assert!(first.contains("Type: symlink"), "{first}");
        // What was there before is still there.
        assert_eq!(dump(img, "/etc/hostname", dir), b"jetbot\n");
    };
    check(img);

    // Again: the same files, nothing created twice, still clean.
    let again = install(&i.opts).unwrap();
    assert!(
        !again.actions.iter().any(|a| a.starts_with("mkdir")),
        "{:?}",
        again.actions
    );
    assert!(
        again
            .actions
            .iter()
            .any(|a| a.starts_with("replace /var/lib/jetpilot/model.onnx"))
    );
    fsck_clean(img);
    check(img);
}

#[test]
fn a_dry_run_lists_the_writes_and_touches_nothing() {
    let mut i = inputs(96);
    i.opts.dry_run = true;
    let before = std::fs::read(&i.opts.image).unwrap();
    let report = install(&i.opts).unwrap();
    assert!(
        report
            .actions
            .iter()
            .any(|a| a.starts_with("write /var/lib/jetpilot/model.onnx"))
    );
    assert!(report.needed_bytes > std::fs::metadata(&i.opts.model).unwrap().len());
    assert!(
        std::fs::read(&i.opts.image).unwrap() == before,
        "the image changed"
    );
}

#[test]
fn a_failure_after_the_write_puts_the_image_back_byte_for_byte() {
    let mut i = inputs(96);
    i.opts.fail_after_write = true;
    let before = std::fs::read(&i.opts.image).unwrap();
    let e = install(&i.opts).unwrap_err().to_string();
    assert!(
        e.contains("injected failure") && e.contains("put back as it was"),
        "{e}"
    );
    let after = std::fs::read(&i.opts.image).unwrap();
    let differing = before.iter().zip(&after).filter(|(a, b)| a != b).count();
    assert_eq!(differing, 0, "{differing} bytes differ after the undo");
    let undo = i
        .opts
        .image
        .parent()
        .unwrap()
        .join(".jetbot.img.jetpilot-undo");
    assert!(!undo.exists(), "the undo file is removed once used");
}

/// Each bad input is refused with an error naming the file and the reason, and the image
/// is byte for byte what it was.
#[test]
fn bad_inputs_are_refused_without_touching_the_image() {
    let base = inputs(96);
    let dir = base._dir.path();
    let image_bytes = std::fs::read(&base.opts.image).unwrap();
    let refused = |opts: &InstallOptions, want: &[&str]| {
        let before = std::fs::read(&opts.image).ok();
        let e = install(opts).unwrap_err().to_string();
        for w in want {
            assert!(e.contains(w), "wanted {w:?} in: {e}");
        }
        assert!(
            std::fs::read(&opts.image).ok() == before,
            "{e}: the image changed"
        );
    };

    let mut o = base.opts.clone();
    o.binary = fake_elf(&dir.join("x86"), 0x3E, "");
    refused(
        &o,
        &["jetpilot binary is an x86-64 ELF", "build-aarch64.sh"],
    );

    let mut o = base.opts.clone();
    o.onnxruntime = dir.join("hostname.txt");
    std::fs::write(&o.onnxruntime, "not a library").unwrap();
    refused(&o, &["hostname.txt", "not an ELF file"]);

    let mut o = base.opts.clone();
    o.model = dir.join("broken.onnx");
    std::fs::write(&o.model, b"\x08\x07garbage").unwrap();
    refused(&o, &["broken.onnx"]);

    // A model pre-optimised for the machine building the image would be refused by the
    // robot; one whose weights live in a data file would arrive without them.
    let mut o = base.opts.clone();
    o.model = dir.join("optimised.onnx");
    let mut bytes = std::fs::read(&base.opts.model).unwrap();
    jetpilot::policy::optimize::append_metadata(
        &mut bytes,
        jetpilot::policy::optimize::META_OPTIMIZED_FOR,
        "onnxruntime 1.23.2, x86_64, laptop",
    );
    std::fs::write(&o.model, &bytes).unwrap();
    refused(
        &o,
        &[
            "optimised.onnx",
            "pre-optimised for `onnxruntime 1.23.2, x86_64, laptop`",
            "on the robot",
        ],
    );
    let mut o = base.opts.clone();
    o.model = dir.join("external.onnx");
    let mut m = <jetpilot::policy::onnx::ModelProto as prost::Message>::decode(
        &std::fs::read(&base.opts.model).unwrap()[..],
    )
    .unwrap();
    let t = &mut m.graph.as_mut().unwrap().initializer[0];
    t.data_location = jetpilot::policy::onnx::proto::DATA_LOCATION_EXTERNAL;
    t.raw_data = Default::default();
    jetpilot::policy::onnx::write_model(&o.model, &m).unwrap();
    refused(
        &o,
        &[
            "external.onnx",
            "1 of its initializers live in a separate data file",
        ],
    );

    let mut o = base.opts.clone();
    o.config = (
        "demo.toml".into(),
        "[model]\npath = \"/var/lib/jetpilot/model.onnx\"\n[motors]\nbackend = \"log\"\n".into(),
    );
    refused(&o, &["demo.toml", "log"]);

    let mut o = base.opts.clone();
    o.config = ("bad.toml".into(), "[control]\nsteering_gain = 7.5\n".into());
    refused(&o, &["bad.toml", "steering_gain"]);

    let mut o = base.opts.clone();
    o.config = (
        "sneaky.toml".into(),
        "[model]\npath = \"/var/lib/x\\\" \\\"/etc/shadow\"\n".into(),
    );
    refused(&o, &["sneaky.toml", "letters, digits"]);

    let mut o = base.opts.clone();
    o.wifi = Some(("robots".into(), "short".into()));
    refused(&o, &["8 to 63"]);

    let mut o = base.opts.clone();
    o.partition = Some(3);
    refused(&o, &["partition 3 (RP1) is not an ext4 filesystem"]);

    let mut o = base.opts.clone();
    o.image = dir.join("jetbot.img.xz");
    std::fs::write(&o.image, b"\xFD7zXZ\x00rest").unwrap();
    refused(&o, &["jetbot.img.xz is xz-compressed", "xz -dk"]);

    let mut o = base.opts.clone();
    o.image = dir.join("tiny.img");
    std::fs::write(&o.image, b"hello").unwrap();
    refused(&o, &["tiny.img: not a disk image"]);

    let mut o = base.opts.clone();
    o.image = dir.join("mbr.img");
    let mut mbr = vec![0u8; 1 << 20];
    mbr[510] = 0x55;
    mbr[511] = 0xAA;
    std::fs::write(&o.image, &mbr).unwrap();
    refused(&o, &["mbr.img: no GPT", "MBR"]);

    let other = tempfile::tempdir().unwrap();
    let mut o = base.opts.clone();
    o.image = make_image(other.path(), "ROOT", 8, true);
    refused(&o, &["no partition named APP", "1 ROOT", "--partition"]);

    let other = tempfile::tempdir().unwrap();
    let mut o = base.opts.clone();
    o.image = make_image(other.path(), "APP", 8, false);
    refused(&o, &["partition 1 (APP) is not an ext4 filesystem"]);

    // A real ResNet-18 (45 MB) does not fit in a 16 MiB root filesystem.
    let other = tempfile::tempdir().unwrap();
    let mut o = base.opts.clone();
    o.image = make_image(other.path(), "APP", 16, true);
    o.model = common::write_model(other.path(), 32, 1);
    refused(&o, &["partition 1 (APP) is full", "MiB are free"]);

    // A journal that was never replayed (a card pulled without unmounting).
    let mut o = base.opts.clone();
    o.image = dir.join("dirty.img");
    let mut dirty = image_bytes.clone();
    dirty[(OFFSET + 1024 + 0x60) as usize] |= 0x4;
    std::fs::write(&o.image, &dirty).unwrap();
    refused(&o, &["dirty.img", "journal needs recovery", "e2fsck -fy"]);

    let mut o = base.opts.clone();
    o.image = dir.join("what?.img");
    std::fs::copy(&base.opts.image, &o.image).unwrap();
    refused(&o, &["what?.img", "rename it"]);

    assert!(std::fs::read(&base.opts.image).unwrap() == image_bytes);
}

/// From the command line, as a user would: a JetBot image downloaded as a .zip is unpacked
/// beside the archive (left unchanged) and installed into; a second run uses that image
/// again; a dry run does not unpack.
#[test]
fn the_cli_unpacks_a_zipped_download_and_installs_into_it() {
    let i = inputs(96);
    let dir = i._dir.path();
    let zip = dir.join("jetbot-043.zip");
    run(Command::new("zip")
        .arg("-q")
        .arg("-1")
        .arg("-j")
        .arg(&zip)
        .arg(&i.opts.image));
    std::fs::remove_file(&i.opts.image).unwrap();
    let zipped = std::fs::read(&zip).unwrap();
    let jp = || {
        let mut c = Command::new(env!("CARGO_BIN_EXE_jetpilot"));
        c.args(["image", "install", "--kit", "l298n-nano", "--image"])
            .arg(&zip)
            .arg("--model")
            .arg(&i.opts.model)
            .arg("--binary")
            .arg(&i.opts.binary)
            .arg("--onnxruntime")
            .arg(&i.opts.onnxruntime);
        c
    };
    let out = jp().output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}{stdout}",
        String::from_utf8_lossy(&out.stderr)
    );
    let img = dir.join("jetbot.img");
    assert!(
        stdout.contains(&format!("done: flash {}", img.display())),
        "{stdout}"
    );
    assert!(
        stdout.contains("gpio-motors.conf"),
        "the H-bridge kit's drop-in: {stdout}"
    );
    assert_eq!(std::fs::read(&zip).unwrap(), zipped, "the archive changed");
    fsck_clean(&img);
    assert_eq!(
        dump(&img, "/etc/jetpilot/jetpilot.toml", dir),
        KITS[3].1.as_bytes()
    );
    // Again: the unpacked image is used as it is, and installed into again.
    let out = jp().output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && err.contains("unpacked from"),
        "{err}"
    );
    fsck_clean(&img);
    // A dry run on the archive with no image unpacked yet says why it does not unpack.
    std::fs::remove_file(&img).unwrap();
    let out = jp().arg("--dry-run").output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("does not unpack"),
        "{err}"
    );
    assert!(!img.exists());
}
